// The face correction of a warm start: the tangent gradient of E against
// finite differences, the faces of a map, steps that never raise E and turn
// a tilted face back onto its data, and a warm solve that reports them.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "normal_fusion/detail/face_correction.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "solver_kernel_test_util.h"
#include "solver_test_util.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// `v` turned by `degrees` about the unit axis `axis` (Rodrigues).
void turn(const double axis[3], double degrees, float v[3]) {
  const double a = degrees * kPi / 180.0, c = std::cos(a), s = std::sin(a);
  const double dot = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2];
  const double cross[3] = {axis[1] * v[2] - axis[2] * v[1],
                           axis[2] * v[0] - axis[0] * v[2],
                           axis[0] * v[1] - axis[1] * v[0]};
  for (int k = 0; k < 3; ++k) {
    v[k] =
        static_cast<float>(v[k] * c + cross[k] * s + axis[k] * dot * (1.0 - c));
  }
}

/// v / |v| in place.
void unit(float v[3]) {
  const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  for (int k = 0; k < 3; ++k) v[k] /= len;
}

/// Unit normals facing the camera (z < 0), random but smooth enough that
/// both zones of the Huber smoothness occur.
PlanarImage randomFacingNormals(int W, int H, std::uint64_t seed) {
  PlanarImage n = test::randomImage(W, H, 3, seed);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    float v[3] = {0.3f * n.plane(0)[i], 0.3f * n.plane(1)[i],
                  -1.0f - 0.1f * std::abs(n.plane(2)[i])};
    unit(v);
    for (int k = 0; k < 3; ++k) n.plane(k)[i] = v[k];
  }
  return n;
}

TEST(FaceCorrection, TangentGradientIsTheDerivativeOfE) {
  const int W = 13, H = 9;
  for (DataPenalty penalty : {DataPenalty::kL2, DataPenalty::kSquaredL2}) {
    const internal::PreparedLevel level =
        test::randomLevel(W, H, 2, 41, penalty == DataPenalty::kL2);
    const double eps = 0.05;
    const PlanarImage n = randomFacingNormals(W, H, 3);
    PlanarImage g;
    internal::tangentEnergyGradient(level, eps, penalty, n, g, 2);
    const double h = 1e-3;
    int checked = 0;
    for (std::size_t i = 0; i < n.pixelCount(); i += 7) {
      const float m[3] = {n.plane(0)[i], n.plane(1)[i], n.plane(2)[i]};
      // A tangent direction at the pixel: (1, 0, 0) without its normal part.
      float t[3] = {1.0f - m[0] * m[0], -m[0] * m[1], -m[0] * m[2]};
      unit(t);
      auto energyAt = [&](double step) {
        PlanarImage moved = n;
        float v[3];
        for (int k = 0; k < 3; ++k)
          v[k] = static_cast<float>(m[k] + step * t[k]);
        unit(v);
        for (int k = 0; k < 3; ++k) moved.plane(k)[i] = v[k];
        return internal::energy(level, eps, penalty, moved, 1);
      };
      const double numeric = (energyAt(h) - energyAt(-h)) / (2.0 * h);
      const double analytic =
          g.plane(0)[i] * t[0] + g.plane(1)[i] * t[1] + g.plane(2)[i] * t[2];
      EXPECT_NEAR(analytic, numeric, 2e-3 + 2e-2 * std::abs(numeric))
          << "pixel " << i << ", penalty " << static_cast<int>(penalty);
      // The gradient lies in the tangent plane.
      EXPECT_NEAR(
          g.plane(0)[i] * m[0] + g.plane(1)[i] * m[1] + g.plane(2)[i] * m[2],
          0.0, 1e-5);
      ++checked;
    }
    EXPECT_GT(checked, 10);
  }
}

TEST(FaceCorrection, LabelsFacesAndLeavesSmallRegionsOut) {
  const int W = 40, H = 30;
  PlanarImage n(W, H, 3);
  const double axis[3] = {0.0, 1.0, 0.0};
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      float v[3] = {0.0f, 0.0f, -1.0f};
      // Left: facing the camera; right: 10 degrees off; a 5 x 5 block in the
      // left half 30 degrees off; the left half also bends by 0.05 degrees
      // per column, which stays within one face.
      if (x >= 20) {
        turn(axis, 10.0, v);
      } else if (x >= 5 && x < 10 && y >= 5 && y < 10) {
        turn(axis, -30.0, v);
      } else {
        turn(axis, -0.05 * x, v);
      }
      for (int k = 0; k < 3; ++k) n.at(k, y, x) = v[k];
    }
  }
  std::vector<int> label;
  internal::FaceLabelScratch scratch;
  ASSERT_EQ(internal::labelFaces(n, 2.0, label, scratch), 2);
  const int left = label[0], right = label[W - 1];
  EXPECT_NE(left, right);
  EXPECT_GE(left, 0);
  EXPECT_GE(right, 0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool block = x >= 5 && x < 10 && y >= 5 && y < 10;
      const int expected = block ? -1 : (x >= 20 ? right : left);
      ASSERT_EQ(label[y * W + x], expected) << x << "," << y;
    }
  }
  // At 12 degrees the two halves are one face.
  EXPECT_EQ(internal::labelFaces(n, 12.0, label, scratch), 1);
}

/// Faces by flood fill in raster order: the oracle of labelFaces().
std::vector<int> floodFaces(const PlanarImage& n, double degrees) {
  const int W = n.width(), H = n.height();
  const double cos_limit = std::cos(degrees * kPi / 180.0);
  std::vector<int> component(n.pixelCount(), -2), label(n.pixelCount(), -1);
  auto close = [&](int a, int b) {
    return n.plane(0)[a] * n.plane(0)[b] + n.plane(1)[a] * n.plane(1)[b] +
               n.plane(2)[a] * n.plane(2)[b] >=
           static_cast<float>(cos_limit);
  };
  int faces = 0;
  for (int start = 0; start < W * H; ++start) {
    if (component[start] != -2) continue;
    std::vector<int> members = {start}, stack = {start};
    component[start] = start;
    while (!stack.empty()) {
      const int i = stack.back();
      stack.pop_back();
      const int x = i % W, y = i / W;
      const int next[4][2] = {{x + 1, y}, {x - 1, y}, {x, y + 1}, {x, y - 1}};
      for (const auto& p : next) {
        if (p[0] < 0 || p[1] < 0 || p[0] >= W || p[1] >= H) continue;
        const int j = p[1] * W + p[0];
        if (component[j] != -2 || !close(i, j)) continue;
        component[j] = start;
        members.push_back(j);
        stack.push_back(j);
      }
    }
    if (static_cast<int>(members.size()) >= internal::kMinFacePixels) {
      for (int i : members) label[i] = faces;
      ++faces;
    }
  }
  return label;
}

TEST(FaceCorrection, LabelsAsAFloodFillOnAnyThreadCount) {
  const int W = 61, H = 47;
  // Blocks 4, 8 or 12 degrees apart, noise of about 0.3 degrees and single
  // pixels 20 degrees off: faces that merge as the angle grows, and pixels
  // left out.
  PlanarImage n(W, H, 3);
  const PlanarImage u = test::randomImage(W, H, 3, 9);
  const double axis[3] = {0.0, 1.0, 0.0};
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      float v[3] = {0.005f * u.at(0, y, x), 0.005f * u.at(1, y, x), -1.0f};
      unit(v);
      const int block = ((x / 15) * 7 + (y / 12) * 5) % 4;
      const bool spike = std::abs(u.at(2, y, x)) > 0.97f;
      turn(axis, spike ? 20.0 : 4.0 * block, v);
      for (int k = 0; k < 3; ++k) n.at(k, y, x) = v[k];
    }
  }
  for (double degrees : {1.0, 3.0, 8.0}) {
    const std::vector<int> expected = floodFaces(n, degrees);
    int expected_faces = 0, left_out = 0;
    for (int f : expected) {
      expected_faces = std::max(expected_faces, f + 1);
      left_out += f < 0 ? 1 : 0;
    }
    // The case has something to label and something to leave out.
    ASSERT_GE(expected_faces, 2) << degrees;
    ASSERT_GT(left_out, 0) << degrees;
    for (int threads : {1, 2, 3}) {
      std::vector<int> label;
      internal::FaceLabelScratch scratch;
      EXPECT_EQ(internal::labelFaces(n, degrees, label, scratch, threads),
                expected_faces)
          << degrees << " degrees, " << threads << " threads";
      EXPECT_EQ(label, expected)
          << degrees << " degrees, " << threads << " threads";
    }
  }
}

/// A map of more faces than kMaxFaces: the largest are kept (of equal
/// sizes, the first in raster order), the rest are left out.
TEST(FaceCorrection, KeepsTheLargestFaces) {
  const int block = 10, blocks = 10, W = block * blocks, H = block * blocks;
  ASSERT_GT(blocks * blocks, internal::kMaxFaces);
  PlanarImage n(W, H, 3);
  const double axis[3] = {0.0, 1.0, 0.0};
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      // A checkerboard of blocks 10 degrees apart; the blocks of the first
      // band are 20 rows tall (200 pixels), the others 10 (100 pixels).
      const int band = y < 2 * block ? 0 : y / block - 1;
      float v[3] = {0.0f, 0.0f, -1.0f};
      turn(axis, (x / block + band) % 2 == 0 ? 0.0 : 10.0, v);
      for (int k = 0; k < 3; ++k) n.at(k, y, x) = v[k];
    }
  }
  std::vector<int> label;
  internal::FaceLabelScratch scratch;
  const int all = internal::labelFaces(n, 2.0, label, scratch, 2);
  ASSERT_GT(all, internal::kMaxFaces);
  internal::FaceCorrection faces;
  faces.reserve(W, H, 2);
  int calls = 0;
  const internal::FaceCorrection::EnergyFunction energy_of =
      [&](const PlanarImage&) {
        ++calls;
        return 1.0;
      };
  ASSERT_EQ(faces.begin(n, 2.0, energy_of, 2), internal::kMaxFaces);
  EXPECT_EQ(calls, 1);
  std::vector<int> size(internal::kMaxFaces, 0);
  int left_out = 0;
  for (std::size_t i = 0; i < label.size(); ++i) {
    const int f = faces.labels()[i];
    ASSERT_GE(f, -1);
    ASSERT_LT(f, internal::kMaxFaces);
    if (f < 0) {
      ++left_out;
    } else {
      ++size[static_cast<std::size_t>(f)];
      // A kept face is one face of the full labelling.
      ASSERT_GE(label[i], 0);
    }
  }
  // The first band's 10 faces of 200 pixels are kept, then the first of the
  // faces of 100 pixels in raster order; the rest are left out.
  for (int bx = 0; bx < blocks; ++bx) {
    const int f = faces.labels()[static_cast<std::size_t>(bx * block)];
    ASSERT_GE(f, 0) << bx;
    EXPECT_EQ(size[static_cast<std::size_t>(f)], 2 * block * block) << bx;
  }
  EXPECT_GE(faces.labels()[static_cast<std::size_t>(2 * block * W)], 0);
  EXPECT_EQ(faces.labels().back(), -1);
  EXPECT_EQ(left_out, W * H - blocks * 2 * block * block -
                          (internal::kMaxFaces - blocks) * block * block);
}

/// A level of two planes seen by one clean input (uniform edge and data
/// weights, L2 data term), the left plane's warm map tilted by `tilt`.
struct TiltedFace {
  internal::PreparedLevel level;
  PlanarImage data, warm;
};

TiltedFace tiltedFace(int W, int H, double tilt) {
  TiltedFace t;
  internal::PreparedLevel& level = t.level;
  level.width = W;
  level.height = H;
  level.num_inputs = 1;
  level.K = CameraIntrinsics(0.9 * W, 0.9 * W, W / 2.0, H / 2.0);
  level.K_inv = level.K.inverse();
  level.edge_weight = PlanarImage(W, H, 2);
  level.edge_weight.fill(1.0f);
  t.data = PlanarImage(W, H, 3);
  t.warm = PlanarImage(W, H, 3);
  const double axis_y[3] = {0.0, 1.0, 0.0}, axis_x[3] = {1.0, 0.0, 0.0};
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      float f[3] = {0.0f, 0.0f, -1.0f};
      turn(axis_y, x < W / 2 ? -20.0 : 20.0, f);
      float w[3] = {f[0], f[1], f[2]};
      if (x < W / 2) turn(axis_x, tilt, w);
      for (int k = 0; k < 3; ++k) {
        t.data.at(k, y, x) = f[k];
        t.warm.at(k, y, x) = w[k];
      }
    }
  }
  level.data.push_back(t.data);
  PlanarImage c(W, H, 1);
  c.fill(0.3f);
  level.data_weight.push_back(c);
  PlanarImage delta(W, H, 1);
  delta.fill(0.0f);
  level.data_eps.push_back(delta);
  level.data_huber = false;
  return t;
}

/// The model's G is the face sum of tangentEnergyGradient(), and G . D and
/// D^T M D are E's first and second derivatives along a turn of one face:
/// exact for the squared data term without links between the faces (flat
/// faces, so the links inside one, which the model leaves out, do not
/// change), above E's curvature (a majorizer's) for the L2 data term and the
/// The candidate of a turn (the vectorized kernel) against the formula
/// pixel by pixel with projectVisible(): on both faces of a map whose middle
/// columns are noise (no face there: left as they are), directions large
/// enough that many pixels turn away from the camera, in both visibility
/// modes and for a step length below 1.
TEST(FaceCorrection, CandidateIsTheTurnOfEachFace) {
  const int W = 48, H = 36;
  TiltedFace t = tiltedFace(W, H, 3.0);
  PlanarImage n = t.warm;
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> angle(-20.0, 20.0);
  for (int y = 0; y < H; ++y) {
    for (int x = W / 2 - 3; x < W / 2 + 3; ++x) {
      float v[3] = {0.0f, 0.0f, -1.0f};
      const double axis_x[3] = {1.0, 0.0, 0.0}, axis_y[3] = {0.0, 1.0, 0.0};
      turn(axis_x, angle(rng), v);
      turn(axis_y, angle(rng), v);
      for (int k = 0; k < 3; ++k) n.at(k, y, x) = v[k];
    }
  }
  const internal::FaceCorrection::EnergyFunction energy_of =
      [&](const PlanarImage& m) {
        return internal::energy(t.level, 0.05, DataPenalty::kL2, m, 1);
      };
  internal::FaceCorrection faces;
  faces.reserve(W, H, 2);
  ASSERT_EQ(faces.begin(n, 2.0, energy_of), 2);
  // Turns of 80 degrees and more: near the image's sides the turned
  // normals face away from the camera.
  const std::vector<double> direction = {6.0, -1.0, 0.5, -8.0, 2.0, -1.0};
  PlanarImage candidate;
  for (const bool soft : {false, true}) {
    for (const double alpha : {1.0, 0.35}) {
      faces.candidateAt(t.level, soft, n, direction, alpha, candidate, 2);
      long off_face = 0, projected = 0;
      for (int y = 0; y < H; ++y) {
        for (int x = 0; x < W; ++x) {
          const std::size_t i = static_cast<std::size_t>(y) * W + x;
          const int f = faces.labels()[i];
          float v[3] = {n.plane(0)[i], n.plane(1)[i], n.plane(2)[i]};
          if (f >= 0) {
            const double* d = &direction[3 * static_cast<std::size_t>(f)];
            const double dot = d[0] * v[0] + d[1] * v[1] + d[2] * v[2];
            double u[3];
            for (int k = 0; k < 3; ++k)
              u[k] = v[k] + alpha * (d[k] - dot * v[k]);
            const double len =
                std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
            for (int k = 0; k < 3; ++k) v[k] = static_cast<float>(u[k] / len);
            float r[3];
            t.level.ray(x, y, r);
            if (r[0] * v[0] + r[1] * v[1] + r[2] * v[2] > 0.0f) {
              projected += soft ? 1 : 0;
              if (soft) internal::projectVisible(r, v);
            }
          } else {
            ++off_face;
          }
          for (int k = 0; k < 3; ++k) {
            ASSERT_NEAR(candidate.plane(k)[i], v[k], 2e-5f)
                << "soft " << soft << ", alpha " << alpha << ", pixel (" << x
                << ", " << y << "), face " << f << ", component " << k;
          }
        }
      }
      EXPECT_GE(off_face, 5 * H);
      if (soft && alpha == 1.0) {
        EXPECT_GT(projected, W * H / 10);
      }
    }
  }
}

/// links between the faces.
TEST(FaceCorrection, ModelIsTheDerivativesOfEAlongATurn) {
  const int W = 48, H = 36;
  for (DataPenalty penalty : {DataPenalty::kSquaredL2, DataPenalty::kL2}) {
    const bool exact = penalty == DataPenalty::kSquaredL2;
    TiltedFace t = tiltedFace(W, H, 3.0);
    // A second input that disagrees, so that both data terms bend.
    PlanarImage second = t.data;
    const double axis_x[3] = {1.0, 0.0, 0.0};
    for (std::size_t i = 0; i < second.pixelCount(); ++i) {
      float v[3] = {second.plane(0)[i], second.plane(1)[i], second.plane(2)[i]};
      turn(axis_x, -6.0, v);
      for (int k = 0; k < 3; ++k) second.plane(k)[i] = v[k];
    }
    t.level.data.push_back(second);
    t.level.data_weight.push_back(t.level.data_weight[0]);
    t.level.data_eps.push_back(t.level.data_eps[0]);
    t.level.num_inputs = 2;
    if (exact) {
      for (int y = 0; y < H; ++y)
        t.level.edge_weight.at(0, y, W / 2 - 1) = 0.0f;
    }
    const double eps = 0.05;
    internal::FaceCorrection faces;
    faces.reserve(W, H, 2);
    const internal::FaceCorrection::EnergyFunction energy_of =
        [&](const PlanarImage& n) {
          return internal::energy(t.level, eps, penalty, n, 1);
        };
    ASSERT_EQ(faces.begin(t.warm, 2.0, energy_of), 2);
    faces.buildModel(t.level, eps, penalty, t.warm, 2);
    const std::vector<double>& G = faces.modelGradient();
    const std::vector<double>& M = faces.modelHessian();
    ASSERT_EQ(G.size(), 6u);
    ASSERT_EQ(M.size(), 36u);
    PlanarImage g;
    internal::tangentEnergyGradient(t.level, eps, penalty, t.warm, g, 1);
    double sums[6] = {0, 0, 0, 0, 0, 0};
    for (std::size_t i = 0; i < g.pixelCount(); ++i) {
      const int f = faces.labels()[i];
      ASSERT_GE(f, 0);
      for (int k = 0; k < 3; ++k) sums[3 * f + k] += g.plane(k)[i];
    }
    for (int k = 0; k < 6; ++k) {
      EXPECT_NEAR(G[k], sums[k], 1e-4 * (1.0 + std::abs(sums[k]))) << k;
    }
    // Along D: the left face (label of pixel 0), a tangent direction.
    const int left = faces.labels()[0];
    const double D[3] = {0.6, 0.8, 0.0};
    auto turned = [&](double alpha) {
      PlanarImage n = t.warm;
      for (std::size_t i = 0; i < n.pixelCount(); ++i) {
        if (faces.labels()[i] != left) continue;
        float v[3] = {n.plane(0)[i], n.plane(1)[i], n.plane(2)[i]};
        const double dot = D[0] * v[0] + D[1] * v[1] + D[2] * v[2];
        for (int k = 0; k < 3; ++k) {
          v[k] = static_cast<float>(v[k] + alpha * (D[k] - dot * v[k]));
        }
        unit(v);
        for (int k = 0; k < 3; ++k) n.plane(k)[i] = v[k];
      }
      return energy_of(n);
    };
    const double h = 2e-3, e0 = energy_of(t.warm);
    const double first = (turned(h) - turned(-h)) / (2.0 * h);
    const double curvature = (turned(h) + turned(-h) - 2.0 * e0) / (h * h);
    double GD = 0.0, DMD = 0.0;
    for (int r = 0; r < 3; ++r) {
      GD += G[3 * left + r] * D[r];
      for (int c = 0; c < 3; ++c) {
        DMD += D[r] * M[(3 * left + r) * 6 + 3 * left + c] * D[c];
      }
    }
    EXPECT_NEAR(GD, first, 1e-2 * std::abs(first) + 1e-3);
    EXPECT_GT(curvature, 0.0);
    if (exact) {
      EXPECT_NEAR(DMD, curvature, 0.05 * curvature);
    } else {
      EXPECT_GT(DMD, curvature);
    }
    // M is symmetric.
    for (int r = 0; r < 6; ++r) {
      for (int c = 0; c < 6; ++c) {
        EXPECT_NEAR(M[r * 6 + c], M[c * 6 + r],
                    1e-9 * (1.0 + std::abs(M[r * 6 + c])));
      }
    }
  }
}

TEST(FaceCorrection, StepsNeverRaiseEAndTurnATiltedFaceBack) {
  const int W = 48, H = 36;
  TiltedFace t = tiltedFace(W, H, 3.0);
  const double eps = 0.05;
  const internal::FaceCorrection::EnergyFunction energy_of =
      [&](const PlanarImage& n) {
        return internal::energy(t.level, eps, DataPenalty::kL2, n, 2);
      };
  internal::FaceCorrection faces;
  faces.reserve(W, H, 2);
  PlanarImage n = t.warm;
  ASSERT_EQ(faces.begin(n, 2.0, energy_of), 2);
  const double start_energy = faces.energy();
  const double start_angle = angularError(n, t.data).mean_deg;
  // Half the map turned by 3 degrees about x, 2.8 degrees off its data.
  EXPECT_NEAR(start_angle, 1.41, 0.01);
  double previous = start_energy;
  int accepted = 0;
  for (int k = 0; k < 20; ++k) {
    const bool kept =
        faces.step(t.level, eps, DataPenalty::kL2, true, energy_of, n, 2);
    accepted += kept ? 1 : 0;
    EXPECT_LE(faces.energy(), previous) << "step " << k;
    // The energy it reports is the map's.
    EXPECT_NEAR(faces.energy(), energy_of(n), 1e-9 * std::abs(previous));
    previous = faces.energy();
  }
  EXPECT_GE(accepted, 3);
  EXPECT_LT(faces.energy(), start_energy);
  // The tilted face is back on its data; the right one stays there.
  EXPECT_LT(angularError(n, t.data).mean_deg, 0.1 * start_angle);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    const float len2 = n.plane(0)[i] * n.plane(0)[i] +
                       n.plane(1)[i] * n.plane(1)[i] +
                       n.plane(2)[i] * n.plane(2)[i];
    ASSERT_NEAR(len2, 1.0f, 1e-5) << "pixel " << i;
  }
}

TEST(FaceCorrection, NothingToTurnOnAMapOfSmallRegions) {
  const int W = 24, H = 16;
  TiltedFace t = tiltedFace(W, H, 3.0);
  // Every pixel 5 degrees from its neighbours: no face of 64 pixels.
  PlanarImage n = t.warm;
  const double axis[3] = {0.0, 1.0, 0.0};
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      float v[3] = {0.0f, 0.0f, -1.0f};
      turn(axis, ((x + y) % 2 == 0 ? 5.0 : -5.0), v);
      for (int k = 0; k < 3; ++k) n.at(k, y, x) = v[k];
    }
  }
  const PlanarImage before = n;
  internal::FaceCorrection faces;
  faces.reserve(W, H, 1);
  int calls = 0;
  const internal::FaceCorrection::EnergyFunction energy_of =
      [&](const PlanarImage& m) {
        ++calls;
        return internal::energy(t.level, 0.05, DataPenalty::kL2, m, 1);
      };
  EXPECT_EQ(faces.begin(n, 2.0, energy_of), 0);
  EXPECT_FALSE(
      faces.step(t.level, 0.05, DataPenalty::kL2, true, energy_of, n, 1));
  EXPECT_EQ(calls, 0);
  EXPECT_EQ(test::maxAbsDiff({{&n, &before}}), 0.0);
}

/// `state` with every normal turned by `degrees` about the x axis.
SolverState turnedAboutX(const SolverState& state, double degrees) {
  SolverState turned = state;
  const double axis[3] = {1.0, 0.0, 0.0};
  for (std::size_t i = 0; i < turned.normals.pixelCount(); ++i) {
    float v[3] = {turned.normals.plane(0)[i], turned.normals.plane(1)[i],
                  turned.normals.plane(2)[i]};
    turn(axis, degrees, v);
    for (int k = 0; k < 3; ++k) turned.normals.plane(k)[i] = v[k];
  }
  return turned;
}

/// A live warm frame (a budget, no whole-image iterations) from a converged
/// map turned by 3 degrees: the face correction turns it back, the local
/// refinement alone (which sees no unknown pixels) cannot.
TEST(FaceCorrection, WarmFrameReportsItsStepsAndEndsCloser) {
  NormalMap gt;
  const FusionProblem problem = test::twoPlanesTwoInputs(0.3, 0.2, &gt);
  SolverState converged;
  Solver(test::convergedSettings()).solve(problem, converged, false);
  const double converged_angle = angularError(converged.normals, gt).mean_deg;
  const SolverState turned = turnedAboutX(converged, 3.0);
  auto live = [&](int face_steps, SolveReport& report) {
    SolverSettings settings;
    settings.time_budget_ms = 10000.0;
    settings.warm_face_steps = face_steps;
    SolverState state = turned;
    report = Solver(settings).solve(problem, state, true);
    test::expectUnit(state.normals);
    return angularError(state.normals, gt).mean_deg;
  };
  SolveReport with, without;
  const double angle_with = live(12, with);
  const double angle_without = live(0, without);
  EXPECT_EQ(without.face_steps, 0);
  EXPECT_EQ(without.corrected_faces, 0);
  EXPECT_GE(with.corrected_faces, 2);
  EXPECT_GE(with.face_steps_accepted, 3);
  EXPECT_LE(with.face_steps_accepted, with.face_steps);
  EXPECT_GT(with.face_energy_decrease, 0.0);
  EXPECT_GT(with.face_seconds, 0.0);
  EXPECT_EQ(with.inner_iterations, 0);
  EXPECT_GT(angle_without, converged_angle + 2.0) << converged_angle;
  EXPECT_LT(angle_with, converged_angle + 1.0) << converged_angle;
}

/// Under a budget that the local refinement uses up (it never converges:
/// tolerance 0, more iterations than fit), the correction gets no time,
/// unless it is due (warm_face_period): then the refinement ends early for it.
TEST(FaceCorrection, DueCorrectionRunsWhenTheRefinementWouldTakeTheBudget) {
  NormalMap gt;
  const FusionProblem problem = test::twoPlanesTwoInputs(0.3, 0.2, &gt);
  SolverState converged;
  Solver(test::convergedSettings()).solve(problem, converged, false);
  const SolverState turned = turnedAboutX(converged, 3.0);
  constexpr int kFrames = 6;
  // The frames (of kFrames warm ones, one solver) that ran a face step.
  auto framesWithSteps = [&](int period) {
    SolverSettings settings;
    // Long enough that a loaded machine's delays are small beside it.
    settings.time_budget_ms = 100.0;
    settings.warm_refine_iterations = 100000;
    // Most of the map refined (the edges and 16 pixels around them), so
    // that the iterations outlast the budget on a fast machine too.
    settings.warm_refine_radius = 16;
    settings.relative_tolerance = 0.0;
    settings.warm_face_period = period;
    Solver solver(settings);
    SolverState state = turned;
    std::vector<int> frames;
    for (int frame = 0; frame < kFrames; ++frame) {
      const SolveReport report = solver.solve(problem, state, true);
      test::expectUnit(state.normals);
      EXPECT_GT(report.refine_iterations, 0) << "frame " << frame;
      if (report.face_steps > 0) {
        frames.push_back(frame);
        EXPECT_GT(report.corrected_faces, 0) << "frame " << frame;
      } else {
        EXPECT_TRUE(report.budget_exhausted) << "frame " << frame;
      }
    }
    return frames;
  };
  EXPECT_EQ(framesWithSteps(0), std::vector<int>{});
  // Frames 0 and 1 leave it out and frame 2 holds time back for it; then at
  // most two frames in a row without a step (a slow refinement step may
  // leave time for one on another frame).
  const std::vector<int> frames = framesWithSteps(2);
  ASSERT_GE(frames.size(), 2u);
  EXPECT_EQ(frames[0], 2);
  int last = -1;
  for (int frame : frames) {
    EXPECT_LE(frame - last - 1, 2) << "frame " << frame;
    last = frame;
  }
  EXPECT_LE(kFrames - last - 1, 2);
}

/// reserve() sizes the labelling's buffers (their memory touched there): a
/// live frame's first correction would otherwise pay for it (11 - 12 ms at
/// 640x480 after a stream's reserve).
TEST(FaceCorrection, ReserveSizesTheLabelBuffers) {
  constexpr int W = 64, H = 48;
  constexpr std::size_t N = static_cast<std::size_t>(W) * H;
  internal::FaceLabelScratch scratch;
  scratch.reserve(N, H);
  EXPECT_EQ(scratch.run_start.size(), N);
  EXPECT_EQ(scratch.run_parent.size(), N);
  EXPECT_EQ(scratch.row_runs.size(), static_cast<std::size_t>(H));
  EXPECT_EQ(scratch.right.size(), N);
  EXPECT_EQ(scratch.down.size(), N);
  internal::FaceCorrection faces;
  faces.reserve(W, H, 1);
  EXPECT_EQ(faces.labels().size(), N);
  // A labelling of that size then reuses them.
  const int* run_start = scratch.run_start.data();
  NormalMap flat(W, H, 3);
  std::fill(flat.plane(2), flat.plane(2) + N, -1.0f);
  std::vector<int> label;
  EXPECT_EQ(internal::labelFaces(flat, 2.0, label, scratch, 1), 1);
  EXPECT_EQ(scratch.run_start.data(), run_start);
}

}  // namespace
}  // namespace normal_fusion
