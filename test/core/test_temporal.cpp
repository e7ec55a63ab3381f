// Temporal averaging of a stream's inputs (TemporalAverage): the running
// average against a per-pixel reference of its definition, the gate, holes,
// the rotation that carries the averages, and what it is for: a still camera's
// noisy frames averaged give a better solve than one frame.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/temporal.h"
#include "test_util.h"

namespace nf = normal_fusion;

namespace {

/// A random unit normal facing the camera (z < 0) per pixel, within about
/// `spread` of (0, 0, -1).
nf::NormalMap randomNormals(int W, int H, std::uint64_t seed, float spread) {
  nf::NormalMap n(W, H, 3);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> d(-spread, spread);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    const float v[3] = {d(rng), d(rng), -1.0f};
    const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int c = 0; c < 3; ++c) n.plane(c)[i] = v[c] / len;
  }
  return n;
}

std::vector<nf::NormalInput> oneInput(const nf::NormalMap& normals) {
  nf::NormalInput input;
  input.normals = normals;
  return {input};
}

/// Same size and the same bits in every plane (NaN included).
bool identical(const nf::NormalMap& a, const nf::NormalMap& b) {
  return a.width() == b.width() && a.height() == b.height() &&
         a.channels() == b.channels() &&
         std::memcmp(a.data(), b.data(),
                     a.pixelCount() * a.channels() * sizeof(float)) == 0;
}

/// Rotation about the y axis by `radians` (row-major).
std::array<double, 9> rotationY(double radians) {
  const double c = std::cos(radians), s = std::sin(radians);
  return {c, 0, s, 0, 1, 0, -s, 0, c};
}

}  // namespace

TEST(Temporal, StillCameraFollowsTheRunningAverageOfItsDefinition) {
  const int W = 13, H = 7, frames = 4;
  nf::TemporalSettings settings;
  settings.frames = frames;
  settings.gate_degrees = 180.0;  // every sample joins
  nf::TemporalAverage average;
  // Reference, per pixel in double: count = min(n, frames), w = 1 / count,
  // a <- normalize((1 - w) a + w f).
  std::vector<std::array<double, 3>> ref(W * H);
  for (int n = 1; n <= 9; ++n) {
    const nf::NormalMap samples = randomNormals(W, H, 100 + n, 0.6f);
    auto inputs = oneInput(samples);
    average.apply(inputs, nf::CameraIntrinsics(10, 10, 6, 3), nullptr, settings,
                  2);
    const double w = 1.0 / std::min(n, frames);
    for (int i = 0; i < W * H; ++i) {
      double m[3], len = 0.0;
      for (int c = 0; c < 3; ++c) {
        const double f = samples.plane(c)[i];
        m[c] = n == 1 ? f : (1.0 - w) * ref[i][c] + w * f;
        len += m[c] * m[c];
      }
      for (int c = 0; c < 3; ++c) ref[i][c] = m[c] / std::sqrt(len);
      for (int c = 0; c < 3; ++c) {
        ASSERT_NEAR(inputs[0].normals.plane(c)[i], ref[i][c], 2e-6)
            << "frame " << n << " pixel " << i;
      }
      ASSERT_EQ(average.count(0, i), std::min(n, frames));
    }
  }
}

TEST(Temporal, TwoSymmetricSamplesAverageToTheirBisector) {
  nf::TemporalSettings settings;
  settings.frames = 10;
  nf::TemporalAverage average;
  const float s = std::sin(0.3f), c = std::cos(0.3f);
  nf::NormalMap a(1, 1, 3), b(1, 1, 3);
  a.at(0, 0, 0) = s, a.at(1, 0, 0) = 0, a.at(2, 0, 0) = -c;
  b.at(0, 0, 0) = -s, b.at(1, 0, 0) = 0, b.at(2, 0, 0) = -c;
  auto first = oneInput(a), second = oneInput(b);
  const nf::CameraIntrinsics K(1, 1, 0, 0);
  average.apply(first, K, nullptr, settings, 1);
  average.apply(second, K, nullptr, settings, 1);
  EXPECT_NEAR(second[0].normals.at(0, 0, 0), 0.0f, 1e-6f);
  EXPECT_NEAR(second[0].normals.at(1, 0, 0), 0.0f, 1e-6f);
  EXPECT_NEAR(second[0].normals.at(2, 0, 0), -1.0f, 1e-6f);
}

TEST(Temporal, ASampleOutsideTheGateRestartsTheAverage) {
  nf::TemporalSettings settings;
  settings.frames = 5;
  settings.gate_degrees = 30.0;
  nf::TemporalAverage average;
  const nf::CameraIntrinsics K(1, 1, 0, 0);
  // 2 pixels: the second sample is 20 degrees off at pixel 0 (joins) and 40
  // degrees off at pixel 1 (restarts).
  auto make = [](double deg0, double deg1) {
    nf::NormalMap n(2, 1, 3);
    const double r[2] = {deg0 * M_PI / 180.0, deg1 * M_PI / 180.0};
    for (int x = 0; x < 2; ++x) {
      n.at(0, 0, x) = static_cast<float>(std::sin(r[x]));
      n.at(1, 0, x) = 0.0f;
      n.at(2, 0, x) = static_cast<float>(-std::cos(r[x]));
    }
    return n;
  };
  auto first = oneInput(make(0, 0)), second = oneInput(make(20, 40));
  average.apply(first, K, nullptr, settings, 1);
  average.apply(second, K, nullptr, settings, 1);
  EXPECT_EQ(average.count(0, 0), 2);
  EXPECT_NEAR(std::atan2(second[0].normals.at(0, 0, 0),
                         -second[0].normals.at(2, 0, 0)) *
                  180.0 / M_PI,
              10.0, 1e-3);  // the mean of 0 and 20 degrees
  EXPECT_EQ(average.count(0, 1), 1);
  EXPECT_NEAR(std::atan2(second[0].normals.at(0, 0, 1),
                         -second[0].normals.at(2, 0, 1)) *
                  180.0 / M_PI,
              40.0, 1e-3);  // the new sample alone
}

TEST(Temporal, HolesStayHolesAndKeepTheirAverage) {
  nf::TemporalSettings settings;
  settings.frames = 8;
  nf::TemporalAverage average;
  const nf::CameraIntrinsics K(1, 1, 0, 0);
  const nf::NormalMap a = randomNormals(3, 1, 1, 0.3f);
  nf::NormalMap holes = randomNormals(3, 1, 2, 0.3f);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int c = 0; c < 3; ++c) holes.at(c, 0, 0) = nan;   // NaN
  for (int c = 0; c < 3; ++c) holes.at(c, 0, 1) = 0.0f;  // zero
  auto first = oneInput(a), second = oneInput(holes);
  average.apply(first, K, nullptr, settings, 1);
  average.apply(second, K, nullptr, settings, 1);
  EXPECT_TRUE(std::isnan(second[0].normals.at(0, 0, 0)));
  EXPECT_EQ(second[0].normals.at(0, 0, 1), 0.0f);
  EXPECT_EQ(average.count(0, 0), 1);  // kept, not counted
  EXPECT_EQ(average.count(0, 2), 2);
  // The next sample at the holes joins the kept average.
  const nf::NormalMap b = randomNormals(3, 1, 3, 0.3f);
  auto third = oneInput(b);
  average.apply(third, K, nullptr, settings, 1);
  EXPECT_EQ(average.count(0, 0), 2);
  EXPECT_EQ(average.count(0, 1), 2);
  EXPECT_EQ(average.count(0, 2), 3);
}

TEST(Temporal, RotationCarriesEachAverageToItsNearestPixel) {
  const int W = 40, H = 30;
  const nf::CameraIntrinsics K(35, 35, 19.5, 14.5);
  const auto R = rotationY(0.07);  // about 2.5 pixels
  for (const auto& orientation :
       {nf::Orientation::optical(), nf::Orientation::opengl()}) {
    nf::TemporalSettings settings;
    settings.frames = 6;
    settings.gate_degrees = 1.0;  // only the exactly carried average joins
    nf::TemporalAverage average;
    const nf::NormalMap a = randomNormals(W, H, 7, 0.5f);
    auto first = oneInput(a);
    first[0].orientation = orientation;
    average.apply(first, K, nullptr, settings, 2);
    // Frame 2: each pixel's sample is what the rotation makes of the previous
    // sample at the nearest pixel of K R^T K^-1 x (computed here on its own),
    // in the input's frame (M^T R M); pixels coming from outside get a
    // sample far from everything.
    const auto K_inv = K.inverse();
    const auto& M = orientation.M;
    nf::NormalMap b(W, H, 3);
    std::vector<int> carried(W * H, 0);
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const double ray[3] = {K_inv[0] * x + K_inv[1] * y + K_inv[2],
                               K_inv[3] * x + K_inv[4] * y + K_inv[5],
                               K_inv[6] * x + K_inv[7] * y + K_inv[8]};
        double back[3];  // R^T ray
        for (int r = 0; r < 3; ++r) {
          back[r] = R[r] * ray[0] + R[3 + r] * ray[1] + R[6 + r] * ray[2];
        }
        const double u = K.fx() * back[0] / back[2] + K.cx();
        const double v = K.fy() * back[1] / back[2] + K.cy();
        const long ui = std::lround(u), vi = std::lround(v);
        const int i = y * W + x;
        if (u < 0 || v < 0 || u > W - 1 || v > H - 1) {
          b.at(0, y, x) = 0, b.at(1, y, x) = 1, b.at(2, y, x) = 0;
          continue;
        }
        carried[i] = 1;
        // The sample in the optical frame, rotated, back to the input frame.
        double opt[3] = {0, 0, 0}, rot[3] = {0, 0, 0};
        for (int r = 0; r < 3; ++r) {
          for (int c = 0; c < 3; ++c) {
            opt[r] += M[3 * r + c] * a.at(c, vi, ui);
          }
        }
        for (int r = 0; r < 3; ++r) {
          for (int c = 0; c < 3; ++c) rot[r] += R[3 * r + c] * opt[c];
        }
        for (int c = 0; c < 3; ++c) {
          double in = 0.0;
          for (int r = 0; r < 3; ++r) in += M[3 * r + c] * rot[r];
          b.at(c, y, x) = static_cast<float>(in);
        }
      }
    }
    auto second = oneInput(b);
    second[0].orientation = orientation;
    average.apply(second, K, &R, settings, 2);
    int joined = 0;
    for (int i = 0; i < W * H; ++i) {
      ASSERT_EQ(average.count(0, i), carried[i] ? 2 : 1) << "pixel " << i;
      joined += carried[i];
      for (int c = 0; c < 3; ++c) {
        ASSERT_NEAR(second[0].normals.plane(c)[i], b.plane(c)[i], 1e-5f);
      }
    }
    // Most pixels are carried, a band at the side the camera turned to is
    // not.
    EXPECT_GT(joined, W * H * 8 / 10);
    EXPECT_LT(joined, W * H);
  }
}

TEST(Temporal, OffChangesNothingAndBadArgumentsChangeNothing) {
  const nf::NormalMap a = randomNormals(8, 6, 11, 0.5f);
  const nf::NormalMap b = randomNormals(8, 6, 12, 0.5f);
  const nf::CameraIntrinsics K(8, 8, 3.5, 2.5);
  nf::TemporalSettings off;
  off.frames = 1;
  nf::TemporalAverage average;
  auto first = oneInput(a);
  average.apply(first, K, nullptr, off, 1);
  auto second = oneInput(b);
  average.apply(second, K, nullptr, off, 1);
  EXPECT_TRUE(identical(second[0].normals, b));

  nf::TemporalSettings on;
  on.frames = 3;
  average.apply(first, K, nullptr, on, 1);
  auto third = oneInput(b);
  const std::array<double, 9> not_a_rotation = {2, 0, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_THROW(average.apply(third, K, &not_a_rotation, on, 1), nf::InputError);
  EXPECT_TRUE(identical(third[0].normals, b));
  EXPECT_EQ(average.count(0, 0), 1);
  EXPECT_THROW(
      average.apply(third, nf::CameraIntrinsics(0, 0, 0, 0), nullptr, on, 1),
      nf::InputError);
  EXPECT_TRUE(identical(third[0].normals, b));
  nf::TemporalSettings bad = on;
  bad.gate_degrees = 0.0;
  EXPECT_THROW(average.apply(third, K, nullptr, bad, 1), nf::ParameterError);
  bad = on;
  bad.frames = -1;
  EXPECT_THROW(bad.validate(), nf::ParameterError);

  // Another size restarts the averages; so does reset().
  auto small = oneInput(randomNormals(4, 3, 13, 0.5f));
  average.apply(small, K, nullptr, on, 1);
  EXPECT_EQ(average.count(0, 0), 1);
  auto again = oneInput(randomNormals(4, 3, 14, 0.5f));
  average.apply(again, K, nullptr, on, 1);
  EXPECT_EQ(average.count(0, 0), 2);
  average.reset();
  EXPECT_EQ(average.count(0, 0), 0);
}

TEST(Temporal, ThreadCountsGiveTheSameBits) {
  const int W = 37, H = 23;
  const nf::CameraIntrinsics K(30, 30, 18, 11);
  const auto R = rotationY(0.03);
  nf::TemporalSettings settings;
  settings.frames = 5;
  nf::TemporalAverage one, three;
  for (int n = 0; n < 4; ++n) {
    auto a = oneInput(randomNormals(W, H, 50 + n, 0.7f));
    auto b = a;
    one.apply(a, K, n == 0 ? nullptr : &R, settings, 1);
    three.apply(b, K, n == 0 ? nullptr : &R, settings, 3);
    ASSERT_TRUE(identical(a[0].normals, b[0].normals));
  }
}

TEST(Temporal, AveragedFramesOfAStillCameraSolveBetterThanOneFrame) {
  // The paper's noise on a still two-plane view: the solve of 8 averaged
  // frames against the solve of the last frame alone, with a 60-degree gate
  // (which takes nearly all of sigma 0.4's samples in: about +9 dB) and with
  // the default 45 (which restarts on more of them: about +1.4 dB).
  const int W = 64, H = 48;
  nf::NormalMap gt;
  nf::FusionProblem problem = nf::test::twoPlaneScene(W, H, &gt);
  nf::SolverSettings solver_settings;
  solver_settings.num_threads = 2;
  nf::Solver solver(solver_settings);
  for (const double gate : {60.0, nf::TemporalSettings().gate_degrees}) {
    nf::TemporalSettings settings;
    settings.frames = 8;
    settings.gate_degrees = gate;
    nf::TemporalAverage average;
    double single = 0.0, averaged = 0.0;
    for (int n = 0; n < 8; ++n) {
      nf::NormalInput input;
      input.normals = nf::test::noisy(gt, 0.4, 300 + n);
      problem.inputs = {input};
      single = nf::psnr(solver.solve(problem), gt);
      average.apply(problem.inputs, problem.K, nullptr, settings, 2);
      averaged = nf::psnr(solver.solve(problem), gt);
    }
    EXPECT_GT(averaged, single + (gate >= 60.0 ? 3.0 : 1.0))
        << "gate " << gate << ": single frame " << single << " dB, averaged "
        << averaged << " dB";
  }
}
