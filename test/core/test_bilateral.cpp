// Tests of the cross-bilateral baseline filter.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "normal_fusion/bilateral.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"

namespace normal_fusion {
namespace {

constexpr double kPi = 3.14159265358979323846;
using Vec3 = std::array<double, 3>;

Vec3 normalized(const Vec3& v) {
  const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  return {v[0] / len, v[1] / len, v[2] / len};
}

Vec3 normalAt(const NormalMap& map, int y, int x) {
  return {map.at(0, y, x), map.at(1, y, x), map.at(2, y, x)};
}

void setNormal(NormalMap* map, int y, int x, const Vec3& n) {
  for (int c = 0; c < 3; ++c) map->at(c, y, x) = static_cast<float>(n[c]);
}

bool valid(const NormalMap& map, int y, int x) {
  return isValidNormal(map.at(0, y, x), map.at(1, y, x), map.at(2, y, x));
}

double angleDeg(const Vec3& a, const Vec3& b) {
  const Vec3 c = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                  a[0] * b[1] - a[1] * b[0]};
  const double sine = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
  const double cosine = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  return std::atan2(sine, cosine) * 180.0 / kPi;
}

NormalMap constantMap(int W, int H, const Vec3& n) {
  NormalMap map(W, H, 3);
  for (int c = 0; c < 3; ++c) {
    for (std::size_t i = 0; i < map.pixelCount(); ++i) {
      map.plane(c)[i] = static_cast<float>(n[c]);
    }
  }
  return map;
}

/// Uniform random grey values in [0, 1].
ColorImage texturedGuide(int W, int H, std::uint64_t seed) {
  ColorImage guide(W, H, 1);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> dist(0.0f, 1.0f);
  for (std::size_t i = 0; i < guide.pixelCount(); ++i)
    guide.data()[i] = dist(rng);
  return guide;
}

/// The paper's noise model: n' = (n + N(0, sigma^2 I)) normalized.
NormalMap addNoise(const NormalMap& n, double sigma, std::uint64_t seed) {
  NormalMap out(n.width(), n.height(), 3);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> dist(0.0, sigma);
  for (int y = 0; y < n.height(); ++y) {
    for (int x = 0; x < n.width(); ++x) {
      const Vec3 v = normalAt(n, y, x);
      setNormal(
          &out, y, x,
          normalized({v[0] + dist(rng), v[1] + dist(rng), v[2] + dist(rng)}));
    }
  }
  return out;
}

BilateralSettings settingsOf(int half_window, double sigma_spatial,
                             double sigma_intensity = 0.1) {
  BilateralSettings settings;
  settings.half_window = half_window;
  settings.sigma_spatial = sigma_spatial;
  settings.sigma_intensity = sigma_intensity;
  return settings;
}

const Vec3 kLeft = normalized({0.6, 0.1, -1.0});
const Vec3 kRight = normalized({-0.7, -0.2, -1.0});

/// Two planes meeting at column W/2, the guide bright left, dark right.
void stepScene(int W, int H, NormalMap* normals, ColorImage* guide) {
  normals->resize(W, H, 3);
  guide->resize(W, H, 1);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool left = x < W / 2;
      setNormal(normals, y, x, left ? kLeft : kRight);
      guide->at(0, y, x) = left ? 0.8f : 0.3f;
    }
  }
}

TEST(CrossBilateral, ConstantMapStaysConstant) {
  const Vec3 n = normalized({0.3, -0.2, -0.9});
  const NormalMap input = constantMap(37, 23, n);
  const NormalMap output =
      crossBilateralFilter(input, texturedGuide(37, 23, 5), settingsOf(5, 3.0));
  ASSERT_EQ(output.channels(), 3);
  ASSERT_TRUE(output.sameSize(input));
  for (int y = 0; y < 23; ++y) {
    for (int x = 0; x < 37; ++x) {
      ASSERT_TRUE(valid(output, y, x)) << y << "," << x;
      for (int c = 0; c < 3; ++c) {
        ASSERT_NEAR(output.at(c, y, x), n[c], 1e-6) << y << "," << x;
      }
    }
  }
}

TEST(CrossBilateral, StepEdgeInImageAndNormalsIsPreserved) {
  const int W = 40, H = 30;
  NormalMap input;
  ColorImage guide;
  stepScene(W, H, &input, &guide);
  const NormalMap output =
      crossBilateralFilter(input, guide, settingsOf(7, 35.0 / 3.0));
  for (int y = 0; y < H; ++y) {
    // Two columns from the edge on either side.
    EXPECT_LT(angleDeg(normalAt(output, y, W / 2 - 2), kLeft), 0.1) << y;
    EXPECT_LT(angleDeg(normalAt(output, y, W / 2 + 1), kRight), 0.1) << y;
  }
  // The same window without the guide's say (huge sigma_I) blurs the edge.
  const NormalMap blurred =
      crossBilateralFilter(input, guide, settingsOf(7, 35.0 / 3.0, 1e3));
  EXPECT_GT(angleDeg(normalAt(blurred, H / 2, W / 2 - 2), kLeft), 5.0);
}

TEST(CrossBilateral, NoiseOnPlanarRegionIsReduced) {
  const int W = 64, H = 48;
  const NormalMap gt = constantMap(W, H, normalized({0.2, -0.3, -1.0}));
  const NormalMap noisy = addNoise(gt, 0.2, 42);
  ColorImage guide(W, H, 1, 0.5f);
  const NormalMap output =
      crossBilateralFilter(noisy, guide, settingsOf(3, 5.0));
  // A 7 x 7 window of nearly equal weights averages about 49 samples: the MSE
  // falls by far more than the factor 4 (6 dB) asked here.
  EXPECT_GT(psnr(output, gt), psnr(noisy, gt) + 6.0);
  EXPECT_LT(angularError(output, gt).mean_deg,
            0.5 * angularError(noisy, gt).mean_deg);
}

TEST(CrossBilateral, NoiseReducedOnBothSidesOfAnEdge) {
  const int W = 60, H = 40;
  NormalMap gt;
  ColorImage guide;
  stepScene(W, H, &gt, &guide);
  const NormalMap noisy = addNoise(gt, 0.15, 7);
  const NormalMap output =
      crossBilateralFilter(noisy, guide, settingsOf(5, 3.0));
  EXPECT_GT(psnr(output, gt), psnr(noisy, gt) + 6.0);
  // The columns next to the edge improve too: the filter does not mix sides.
  ScalarMap edge_columns(W, H, 1, 0.0f);
  for (int y = 0; y < H; ++y) {
    for (int x = W / 2 - 2; x <= W / 2 + 1; ++x)
      edge_columns.at(0, y, x) = 1.0f;
  }
  EXPECT_GT(psnr(output, gt, edge_columns),
            psnr(noisy, gt, edge_columns) + 3.0);
}

TEST(CrossBilateral, MissingPixelsAreFilledFromValidNeighbours) {
  const int W = 30, H = 20;
  const Vec3 n = normalized({-0.1, 0.4, -1.0});
  NormalMap input = constantMap(W, H, n);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int y = 8; y < 11; ++y) {
    for (int x = 12; x < 15; ++x) setNormal(&input, y, x, {nan, nan, nan});
  }
  setNormal(&input, 2, 3, {0.0, 0.0, 0.0});
  setNormal(&input, 0, 0, {nan, 0.0, 0.0});
  const NormalMap output = crossBilateralFilter(
      input, ColorImage(W, H, 1, 0.5f), settingsOf(3, 2.0));
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      ASSERT_TRUE(valid(output, y, x)) << y << "," << x;
      EXPECT_LT(angleDeg(normalAt(output, y, x), n), 1e-3) << y << "," << x;
    }
  }
}

TEST(CrossBilateral, PixelsWithoutValidNeighbourStayMissing) {
  const int W = 30, H = 20;
  const Vec3 n = normalized({0.0, 0.0, -1.0});
  NormalMap input = constantMap(W, H, n);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // A 9 x 9 hole: its centre is 4 pixels from any valid pixel.
  for (int y = 5; y < 14; ++y) {
    for (int x = 10; x < 19; ++x) setNormal(&input, y, x, {nan, nan, nan});
  }
  const NormalMap output = crossBilateralFilter(
      input, ColorImage(W, H, 1, 0.5f), settingsOf(3, 2.0));
  EXPECT_FALSE(valid(output, 9, 14));  // centre: no valid pixel within 3
  EXPECT_FALSE(valid(output, 8, 13));
  EXPECT_TRUE(valid(output, 9, 11));  // 2 columns into the hole: filled
  EXPECT_TRUE(valid(output, 5, 14));  // the hole's top row: filled

  const NormalMap all_missing = crossBilateralFilter(
      NormalMap(8, 8, 3, nan), ColorImage(8, 8, 1, 0.5f), settingsOf(3, 2.0));
  for (int y = 0; y < 8; ++y) {
    for (int x = 0; x < 8; ++x) EXPECT_FALSE(valid(all_missing, y, x));
  }
}

TEST(CrossBilateral, OutputHasUnitLength) {
  const int W = 33, H = 21;
  // Non-unit, noisy input: the filter normalizes what it reads and writes.
  NormalMap input =
      addNoise(constantMap(W, H, normalized({0.1, 0.1, -1.0})), 0.6, 3);
  for (std::size_t i = 0; i < input.pixelCount() * 3; ++i)
    input.data()[i] *= 2.5f;
  const NormalMap output =
      crossBilateralFilter(input, texturedGuide(W, H, 11), settingsOf(5, 3.0));
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const Vec3 v = normalAt(output, y, x);
      ASSERT_NEAR(std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), 1.0,
                  1e-5);
    }
  }
}

TEST(CrossBilateral, ColourGuideUsesLuminance) {
  const int W = 24, H = 18;
  const NormalMap input =
      addNoise(constantMap(W, H, normalized({0, 0, -1})), 0.3, 9);
  const ColorImage grey = texturedGuide(W, H, 21);
  // R = G = B = grey has luminance (0.299 + 0.587 + 0.114) grey = grey.
  ColorImage colour(W, H, 3);
  for (int c = 0; c < 3; ++c) {
    for (std::size_t i = 0; i < grey.pixelCount(); ++i) {
      colour.plane(c)[i] = grey.data()[i];
    }
  }
  const NormalMap from_grey =
      crossBilateralFilter(input, grey, settingsOf(3, 2.0));
  const NormalMap from_colour =
      crossBilateralFilter(input, colour, settingsOf(3, 2.0));
  for (std::size_t i = 0; i < input.pixelCount() * 3; ++i) {
    ASSERT_NEAR(from_grey.data()[i], from_colour.data()[i], 1e-5);
  }
  // A colour edge of equal luminance is no edge; one of unequal luminance is.
  NormalMap step;
  ColorImage step_grey;
  stepScene(W, H, &step, &step_grey);
  // Left white (Y = 1), right pure blue (Y = 0.114): an edge in luminance.
  ColorImage white_blue(W, H, 3, 0.0f);
  // Left grey 0.299, right pure red (both Y = 0.299): no edge in luminance.
  ColorImage grey_red(W, H, 3, 0.0f);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool left = x < W / 2;
      for (int c = 0; c < 3; ++c) {
        white_blue.at(c, y, x) = left || c == 2 ? 1.0f : 0.0f;
        grey_red.at(c, y, x) = left ? 0.299f : (c == 0 ? 1.0f : 0.0f);
      }
    }
  }
  const NormalMap kept =
      crossBilateralFilter(step, white_blue, settingsOf(5, 3.0));
  EXPECT_LT(angleDeg(normalAt(kept, H / 2, W / 2 - 2), kLeft), 0.1);
  const NormalMap mixed =
      crossBilateralFilter(step, grey_red, settingsOf(5, 3.0));
  EXPECT_GT(angleDeg(normalAt(mixed, H / 2, W / 2 - 2), kLeft), 5.0);
}

TEST(CrossBilateral, ThreadCountDoesNotChangeTheResult) {
  const int W = 50, H = 37;
  const NormalMap input =
      addNoise(constantMap(W, H, normalized({0, 0.2, -1})), 0.4, 13);
  const ColorImage guide = texturedGuide(W, H, 17);
  BilateralSettings one = settingsOf(4, 3.0);
  one.num_threads = 1;
  BilateralSettings two = one;
  two.num_threads = 2;
  const NormalMap a = crossBilateralFilter(input, guide, one);
  const NormalMap b = crossBilateralFilter(input, guide, two);
  for (std::size_t i = 0; i < input.pixelCount() * 3; ++i) {
    ASSERT_EQ(a.data()[i], b.data()[i]);
  }
}

TEST(CrossBilateral, BadInputsThrow) {
  const NormalMap normals = constantMap(10, 8, {0, 0, -1});
  const ColorImage guide(10, 8, 1, 0.5f);
  EXPECT_THROW(
      crossBilateralFilter(normals, ColorImage(10, 7, 1), settingsOf(3, 2.0)),
      InputError);
  EXPECT_THROW(
      crossBilateralFilter(normals, ColorImage(10, 8, 2), settingsOf(3, 2.0)),
      InputError);
  EXPECT_THROW(
      crossBilateralFilter(ScalarMap(10, 8, 1), guide, settingsOf(3, 2.0)),
      InputError);
  EXPECT_THROW(crossBilateralFilter(normals, guide, settingsOf(-1, 2.0)),
               ParameterError);
  EXPECT_THROW(crossBilateralFilter(normals, guide, settingsOf(3, 0.0)),
               ParameterError);
  EXPECT_THROW(crossBilateralFilter(normals, guide, settingsOf(3, 2.0, 0.0)),
               ParameterError);
  EXPECT_THROW(
      crossBilateralFilter(normals, guide, settingsOf(3, std::nan(""))),
      ParameterError);
  BilateralSettings negative_threads = settingsOf(3, 2.0);
  negative_threads.num_threads = -2;
  EXPECT_THROW(crossBilateralFilter(normals, guide, negative_threads),
               ParameterError);
}

}  // namespace
}  // namespace normal_fusion
