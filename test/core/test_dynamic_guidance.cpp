// Dynamic guidance (docs/method.md): on a flat plane under a checkerboard
// texture the output is as good as under a uniform image, across the
// texture's edges as inside its cells; a crease stays sharp; the guided energy
// is the one reported and never rises; the two backends agree.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "normal_fusion/detail/dynamic_guidance.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr int kWidth = 96;
constexpr int kHeight = 72;
constexpr int kCell = 12;  ///< checker cell, pixels
constexpr double kDegree = M_PI / 180.0;

/// A unit normal turned `deg` degrees about the vertical axis from facing
/// the camera.
void turnedNormal(double deg, float n[3]) {
  n[0] = static_cast<float>(std::sin(deg * kDegree));
  n[1] = 0.0f;
  n[2] = static_cast<float>(-std::cos(deg * kDegree));
}

/// Checkerboard of strong contrast (0.2 / 0.8), or a uniform image.
ColorImage checkerboard(bool textured) {
  ColorImage image(kWidth, kHeight, 1);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const bool dark = ((x / kCell) + (y / kCell)) % 2 == 0;
      image.at(0, y, x) = !textured ? 0.5f : dark ? 0.2f : 0.8f;
    }
  }
  return image;
}

/// The scene's normals: the plane turned by `left_deg` left of the middle
/// column and by `right_deg` right of it, one input with the paper's noise.
FusionProblem scene(bool textured, double left_deg, double right_deg,
                    double sigma, NormalMap* gt) {
  FusionProblem problem;
  problem.K = CameraIntrinsics(0.9 * kWidth, 0.9 * kWidth, (kWidth - 1) / 2.0,
                               (kHeight - 1) / 2.0);
  problem.image = checkerboard(textured);
  gt->resize(kWidth, kHeight, 3);
  float left[3], right[3];
  turnedNormal(left_deg, left);
  turnedNormal(right_deg, right);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      for (int c = 0; c < 3; ++c) {
        gt->at(c, y, x) = x < kWidth / 2 ? left[c] : right[c];
      }
    }
  }
  NormalInput input;
  input.normals = test::noisy(*gt, sigma, 5);
  problem.inputs.push_back(input);
  return problem;
}

FusionProblem texturedPlane(bool textured, double sigma, NormalMap* gt) {
  return scene(textured, 25.0, 25.0, sigma, gt);
}

/// 1 at the pixels within 1 px of a texture edge (`border`), or at the others.
ScalarMap borderMask(bool border) {
  ScalarMap mask(kWidth, kHeight, 1);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const int cx = x % kCell, cy = y % kCell;
      const bool near_edge =
          (cx == 0 && x > 0) || (cx == kCell - 1 && x + 1 < kWidth) ||
          (cy == 0 && y > 0) || (cy == kCell - 1 && y + 1 < kHeight);
      mask.at(0, y, x) = near_edge == border ? 1.0f : 0.0f;
    }
  }
  return mask;
}

/// 1 within 2 px of the crease between the middle columns.
ScalarMap creaseMask() {
  ScalarMap mask(kWidth, kHeight, 1);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      mask.at(0, y, x) = std::abs(x - kWidth / 2 + 0.5) < 2.0 ? 1.0f : 0.0f;
    }
  }
  return mask;
}

SolverSettings guided(double mu = 1.0, double deg = 20.0) {
  SolverSettings settings;
  settings.dynamic_guidance = mu;
  settings.dynamic_guidance_deg = deg;
  return settings;
}

double meanError(const NormalMap& n, const NormalMap& gt,
                 const ScalarMap& mask = ScalarMap()) {
  return angularError(n, gt, mask).mean_deg;
}

TEST(GuidancePenalty, IsTheIntegralOfTheKernelOverTheHuberPenalty) {
  for (double eps : {0.0, 0.05, 0.3}) {
    for (double scale : {0.2, 0.7}) {
      // Midpoint rule of int_0^t phi(u) huber_eps'(u) du.
      double integral = 0.0, u = 0.0;
      const double du = 1e-5;
      for (double t : {0.01, 0.1, 0.5, 2.0}) {
        for (; u + du <= t + 1e-12; u += du) {
          const double m = u + 0.5 * du;
          const double slope = eps > 0.0 ? std::min(m / eps, 1.0) : 1.0;
          integral += std::exp(-(m / scale) * (m / scale)) * slope * du;
        }
        EXPECT_NEAR(internal::guidancePenalty(t, scale, eps), integral, 1e-7)
            << "eps " << eps << " s " << scale << " t " << t;
      }
    }
  }
}

// The reweighting's Psi and its links' correction, from the kernel's value
// and without erf, stay within what the erf approximation allows (1.5e-7
// at t and at eps, times s sqrt(pi) / 2) of the exact ones; the branch-free
// exponential they are given is exact to 1e-14.
TEST(GuidancePenalty, FromTheKernelMatchesTheExactPenalty) {
  for (double eps : {0.0, 0.01, 0.05, 0.3}) {
    for (double scale : {0.087, 0.2, 0.7}) {
      const internal::GuidancePenaltyTerms psi(scale, eps);
      const double bound = 2.0 * 1.5e-7 * 0.8862269254527580 * scale;
      for (int i = 0; i <= 4000; ++i) {
        const double t = 2.0 * i / 4000.0;
        const double x = t / scale;
        const double e = internal::expNonPositive(-x * x);
        ASSERT_NEAR(e, std::exp(-x * x), 1e-14 * std::exp(-x * x));
        const double exact = internal::guidancePenalty(t, scale, eps);
        ASSERT_NEAR(psi.penalty(t, e), exact, bound)
            << "eps " << eps << " s " << scale << " t " << t;
        const double exact_correction =
            exact - std::exp(-x * x) * internal::huberPenalty(t, eps);
        ASSERT_NEAR(psi.correction(t, e), exact_correction, bound)
            << "eps " << eps << " s " << scale << " t " << t;
      }
    }
  }
  for (double t : {0.0, -1e-3, -0.5, -3.0, -40.0, -300.0, -690.0}) {
    ASSERT_NEAR(internal::expNonPositive(t), std::exp(t), 1e-14 * std::exp(t))
        << t;
  }
}

// Links with an end in a hole (no input there) keep the image weight.
TEST(DynamicGuidance, WeightsFollowTheNormalsAndTheImageWeightsComeBack) {
  internal::PreparedLevel level;
  level.width = 9;
  level.height = 7;
  level.edge_weight = test::randomImage(9, 7, 2, 3, 0.5f);
  for (std::size_t i = 0; i < 2 * 63; ++i) {
    level.edge_weight.data()[i] += 0.5f;  // w_img in [0, 1]
  }
  const PlanarImage image_weight = level.edge_weight;
  // One input observing every pixel but a 2 x 2 hole at x 3..4, y 2..3.
  level.num_inputs = 1;
  level.data_weight = {PlanarImage(9, 7, 1, 1.0f)};
  const auto in_hole = [](int x, int y) {
    return x >= 3 && x <= 4 && y >= 2 && y <= 3;
  };
  for (int y = 0; y < 7; ++y) {
    for (int x = 0; x < 9; ++x) {
      if (in_hole(x, y)) level.data_weight[0].at(0, y, x) = 0.0f;
    }
  }
  NormalMap normals(9, 7, 3);
  std::mt19937_64 rng(4);
  std::normal_distribution<float> noise(0.0f, 0.3f);
  for (std::size_t i = 0; i < 63; ++i) {
    float v[3] = {noise(rng), noise(rng), -1.0f};
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) normals.plane(c)[i] = v[c] / len;
  }
  const internal::GuidanceTerms terms{0.6f, 0.35f, 0.05f};
  internal::DynamicGuidance guidance;
  guidance.begin(level, level, terms);
  const double correction = guidance.reweight(normals, 2);
  double expected_correction = 0.0;
  for (int y = 0; y < 7; ++y) {
    for (int x = 0; x < 9; ++x) {
      for (int d = 0; d < 2; ++d) {
        const int xq = d == 0 ? x + 1 : x, yq = d == 0 ? y : y + 1;
        double chord = 0.0;
        if (xq < 9 && yq < 7) {
          for (int c = 0; c < 3; ++c) {
            const double diff = normals.at(c, yq, xq) - normals.at(c, y, x);
            chord += diff * diff;
          }
        }
        chord = std::sqrt(chord);
        const double w_img = image_weight.at(d, y, x);
        if (xq < 9 && yq < 7 && (in_hole(x, y) || in_hole(xq, yq))) {
          // An end in the hole: the image weight, no correction.
          EXPECT_EQ(level.edge_weight.at(d, y, x), image_weight.at(d, y, x));
          continue;
        }
        const double k = 0.6 * (1.0 - w_img);
        const double phi = std::exp(-(chord / 0.35) * (chord / 0.35));
        EXPECT_NEAR(level.edge_weight.at(d, y, x), w_img + k * phi, 1e-6);
        expected_correction +=
            k * (internal::guidancePenalty(chord, 0.35, 0.05) -
                 phi * internal::huberPenalty(chord, 0.05));
      }
    }
  }
  EXPECT_GT(correction, 0.0);
  EXPECT_NEAR(correction, expected_correction, 1e-5 * expected_correction);
  guidance.end();
  for (std::size_t i = 0; i < 2 * 63; ++i) {
    ASSERT_EQ(level.edge_weight.data()[i], image_weight.data()[i]);
  }
}

// Without the guidance, the texture's edges cut the smoothing: the fused
// plane is piecewise constant per cell, several times further from the truth
// than under a uniform image (what the next test rules out).
TEST(DynamicGuidance, WithoutItTheTextureShowsInTheOutput) {
  NormalMap gt;
  SolverSettings unguided;
  unguided.dynamic_guidance = 0.0;
  const double uniform =
      meanError(Solver(unguided).solve(texturedPlane(false, 0.3, &gt)), gt);
  const double textured =
      meanError(Solver(unguided).solve(texturedPlane(true, 0.3, &gt)), gt);
  EXPECT_GT(textured, 3.0 * uniform)
      << "uniform " << uniform << " textured " << textured;
}

TEST(DynamicGuidance, TexturedPlaneIsAsGoodAsUntexturedAcrossAndInsideCells) {
  for (double sigma : {0.3, 0.5}) {
    SCOPED_TRACE(::testing::Message() << "sigma " << sigma);
    const SolverSettings settings = guided();
    NormalMap gt;
    const double uniform =
        meanError(Solver(settings).solve(texturedPlane(false, sigma, &gt)), gt);
    const NormalMap n = Solver(settings).solve(texturedPlane(true, sigma, &gt));
    const double inside = meanError(n, gt, borderMask(false));
    const double border = meanError(n, gt, borderMask(true));
    EXPECT_LT(std::abs(border - inside), 0.1 * inside)
        << "inside " << inside << " border " << border;
    EXPECT_LT(meanError(n, gt), 1.2 * uniform)
        << "uniform " << uniform << " textured " << meanError(n, gt);
  }
}

TEST(DynamicGuidance, CreaseStaysSharp) {
  // Two planes meeting at 90 degrees, under a uniform image (the image then
  // cuts nothing and the guidance changes nothing) and under the
  // checkerboard, whose edge of the same contrast runs along the crease.
  for (bool textured : {false, true}) {
    SCOPED_TRACE(::testing::Message() << "textured " << textured);
    NormalMap gt;
    const FusionProblem problem = scene(textured, 45.0, -45.0, 0.3, &gt);
    const double crease_off =
        meanError(Solver().solve(problem), gt, creaseMask());
    for (double deg : {10.0, 20.0, 40.0}) {
      const double crease_on =
          meanError(Solver(guided(1.0, deg)).solve(problem), gt, creaseMask());
      EXPECT_LT(crease_on, 2.0) << "at " << deg << " degrees";
      EXPECT_LT(crease_on, crease_off + 0.2)
          << "off " << crease_off << " on " << crease_on << " at " << deg;
    }
  }
}

TEST(DynamicGuidance, ShallowCreaseKeepsTheImageCut) {
  // 50 degrees, the image bright left and dark right of it (the contrast of
  // the checkerboard): plain TV rounds this crease off, the image's cut
  // along it keeps it, and so must the guidance at scales below its angle.
  NormalMap gt;
  FusionProblem problem = scene(false, 25.0, -25.0, 0.3, &gt);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      problem.image.at(0, y, x) = x < kWidth / 2 ? 0.8f : 0.2f;
    }
  }
  const double crease_off =
      meanError(Solver().solve(problem), gt, creaseMask());
  for (double deg : {10.0, 20.0}) {
    const double crease_on =
        meanError(Solver(guided(1.0, deg)).solve(problem), gt, creaseMask());
    EXPECT_LT(crease_on, crease_off + 0.2)
        << "off " << crease_off << " on " << crease_on << " at " << deg;
  }
}

/// E of docs/method.md at `n`: the problem's E with the image weights plus,
/// per link, mu (1 - w_img) Psi(|d|).
double guidedEnergy(const FusionProblem& problem,
                    const SolverSettings& settings, const NormalMap& n) {
  const internal::PreparedLevel level =
      internal::prepareFinest(problem, settings);
  double total =
      internal::energy(level, settings.huber_eps, settings.penalty, n, 1);
  const internal::GuidanceTerms terms = internal::guidanceTerms(settings);
  for (int y = 0; y < level.height; ++y) {
    for (int x = 0; x < level.width; ++x) {
      for (int d = 0; d < 2; ++d) {
        const int xq = d == 0 ? x + 1 : x, yq = d == 0 ? y : y + 1;
        if (xq >= level.width || yq >= level.height) continue;
        double chord = 0.0;
        for (int c = 0; c < 3; ++c) {
          const double diff = n.at(c, yq, xq) - n.at(c, y, x);
          chord += diff * diff;
        }
        const double k = terms.mu * (1.0 - level.edge_weight.at(d, y, x));
        total += k * internal::guidancePenalty(std::sqrt(chord), terms.scale,
                                               terms.huber_eps);
      }
    }
  }
  return total;
}

// The step of docs/method.md's proof: the weighted energy under the weights
// of n0 plus C(n0) touches E at n0 and lies above it everywhere.
TEST(DynamicGuidance, WeightedEnergyMajorizesTheGuidedEnergy) {
  for (double eps : {0.0, 0.05}) {
    NormalMap gt;
    const FusionProblem problem = scene(true, 45.0, -45.0, 0.3, &gt);
    SolverSettings settings = guided(0.7, 20.0);
    settings.huber_eps = eps;
    internal::PreparedLevel level = internal::prepareFinest(problem, settings);
    // n0 the noisy input (its links' differences spread over the kernel).
    const NormalMap& n0 = problem.inputs[0].normals;
    internal::DynamicGuidance guidance;
    guidance.begin(level, level, internal::guidanceTerms(settings));
    const double c0 = guidance.reweight(n0, 1);
    auto weighted = [&](const NormalMap& n) {
      return internal::energy(level, eps, settings.penalty, n, 1) + c0;
    };
    EXPECT_NEAR(weighted(n0), guidedEnergy(problem, settings, n0),
                1e-5 * weighted(n0));
    // Rougher normals (larger differences), the truth and the solution
    // (smaller ones).
    const NormalMap solved = Solver(settings).solve(problem);
    for (double sigma : {0.02, 0.1, 0.5, 0.0, -1.0}) {
      const NormalMap n1 = sigma > 0.0    ? test::noisy(n0, sigma, 9)
                           : sigma == 0.0 ? gt
                                          : solved;
      EXPECT_LE(guidedEnergy(problem, settings, n1),
                weighted(n1) * (1.0 + 1e-6))
          << "eps " << eps << " sigma " << sigma;
    }
    guidance.end();
  }
}

TEST(DynamicGuidance, EnergyIsTheGuidedOneAndNeverRises) {
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    for (double eps : {0.0, 0.05}) {
      for (SolverBackend backend :
           {SolverBackend::kFast, SolverBackend::kReference}) {
        SCOPED_TRACE(::testing::Message()
                     << "penalty " << static_cast<int>(penalty) << ", eps "
                     << eps << ", backend " << static_cast<int>(backend));
        NormalMap gt;
        const FusionProblem problem = scene(true, 45.0, -45.0, 0.5, &gt);
        SolverSettings settings = guided(0.7, 20.0);
        settings.penalty = penalty;
        settings.huber_eps = eps;
        settings.backend = backend;
        settings.pyramid_levels = 1;
        settings.relative_tolerance = 0.0;
        settings.max_outer_iterations = 8;
        SolveReport report;
        const NormalMap n = Solver(settings).solve(problem, &report);
        ASSERT_GE(report.energies.size(), 4u);
        for (std::size_t k = 1; k < report.energies.size(); ++k) {
          EXPECT_LE(report.energies[k], report.energies[k - 1] * (1.0 + 1e-6))
              << "step " << k;
        }
        EXPECT_LT(report.final_energy, 0.5 * report.initial_energy);
        const double e = guidedEnergy(problem, settings, n);
        EXPECT_NEAR(report.final_energy, e, 1e-4 * e);
      }
    }
  }
}

TEST(DynamicGuidance, FastBackendMatchesReference) {
  NormalMap gt;
  const FusionProblem problem = scene(true, 45.0, -45.0, 0.4, &gt);
  SolverSettings settings = guided(0.8, 20.0);
  settings.max_total_inner_iterations = 200;
  settings.relative_tolerance = 0.0;
  settings.backend = SolverBackend::kReference;
  SolveReport ref_report, fast_report;
  Solver(settings).solve(problem, &ref_report);
  settings.backend = SolverBackend::kFast;
  Solver(settings).solve(problem, &fast_report);
  EXPECT_EQ(ref_report.inner_iterations, fast_report.inner_iterations);
  EXPECT_EQ(ref_report.outer_iterations, fast_report.outer_iterations);
  EXPECT_NEAR(fast_report.final_energy, ref_report.final_energy,
              1e-4 * ref_report.final_energy);
}

}  // namespace
}  // namespace normal_fusion
