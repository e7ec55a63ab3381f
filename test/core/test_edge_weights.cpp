// The edge weights of the smoothness term: Sobel and forward differences,
// luminance and colour, the exponential against the double exp.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace {

/// The paper-style weights: Gaussian pre-smoothing, Sobel, luminance.
EdgeWeightSettings sobelSettings() {
  EdgeWeightSettings settings;
  settings.gradient = EdgeGradient::kSobel;
  settings.smoothing_sigma = 1.2;
  settings.alpha = 10.0;
  settings.w_min = 0.01;
  settings.color_mode = EdgeColorMode::kLuminance;
  return settings;
}

TEST(EdgeWeights, FlatImageGivesOneAndEdgesGiveLess) {
  ColorImage flat(20, 10, 1, 0.5f);
  EdgeWeightSettings settings = sobelSettings();
  const PlanarImage w_flat = computeEdgeWeights(flat, settings);
  for (std::size_t i = 0; i < w_flat.pixelCount() * 2; ++i) {
    EXPECT_FLOAT_EQ(w_flat.data()[i], 1.0f);
  }
  ColorImage step(20, 10, 3, 0.0f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) {
      for (int c = 0; c < 3; ++c) step.at(c, y, x) = 1.0f;  // black to white
    }
  }
  const PlanarImage w = computeEdgeWeights(step, settings);
  EXPECT_LT(w.at(0, 5, 9), 0.1f);   // across the step
  EXPECT_GT(w.at(1, 5, 9), 0.99f);  // along it
  EXPECT_GT(w.at(0, 5, 1), 0.99f);  // far from it
  EXPECT_GE(w.at(0, 5, 9), settings.w_min);
  // A step in green alone: the colour gradient sees full contrast, the
  // luminance only 0.587 of it.
  ColorImage green(20, 10, 3, 0.0f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) green.at(1, y, x) = 1.0f;
  }
  const PlanarImage w_lum = computeEdgeWeights(green, settings);
  settings.color_mode = EdgeColorMode::kColorMax;
  const PlanarImage w_max = computeEdgeWeights(green, settings);
  EXPECT_NEAR(w_max.at(0, 5, 9), w.at(0, 5, 9), 1e-6);
  EXPECT_LT(w_max.at(0, 5, 9), 0.5f * w_lum.at(0, 5, 9));
  settings.enabled = false;
  EXPECT_FLOAT_EQ(computeEdgeWeights(step, settings).at(0, 5, 9), 1.0f);
}

/// The exponential weights (computed with a float exp) against the double
/// exp of the same differences: within 2e-7 relative wherever the weight is
/// above 0.05, the floor everywhere else.
TEST(EdgeWeights, ExponentialMatchesTheDoubleExp) {
  const int W = 800, H = 2;
  ColorImage ramp(W, H, 1, 0.0f);
  // Differences 0, 0.0005, 0.001, ...: weights from 1 down to the floor.
  for (int y = 0; y < H; ++y) {
    float value = 0.0f;
    for (int x = 0; x < W; ++x) {
      ramp.at(0, y, x) = value;
      value += 0.0005f * x;
    }
  }
  EdgeWeightSettings settings;  // exponential, beta 1, forward differences
  settings.w_min = 0.01;
  const PlanarImage w = computeEdgeWeights(ramp, settings);
  int checked = 0, floored = 0;
  for (int x = 0; x + 1 < W; ++x) {
    const float g = std::abs(ramp.at(0, 0, x + 1) - ramp.at(0, 0, x));
    const double expected = std::exp(-settings.alpha * static_cast<double>(g));
    if (expected >= 0.05) {
      EXPECT_NEAR(w.at(0, 0, x), expected, 2e-7 * expected) << "g " << g;
      ++checked;
    } else if (expected < settings.w_min) {
      EXPECT_EQ(w.at(0, 0, x), static_cast<float>(settings.w_min));
      ++floored;
    }
  }
  EXPECT_GT(checked, 100);
  EXPECT_GT(floored, 100);
}

TEST(EdgeWeights, ForwardDifferencesMarkExactlyTheLinkAcrossAnEdge) {
  ColorImage step(20, 10, 3, 0.2f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) step.at(1, y, x) = 0.8f;  // green step
  }
  EdgeWeightSettings settings;  // defaults: forward differences, colour max
  ASSERT_EQ(settings.gradient, EdgeGradient::kForwardDifference);
  const PlanarImage w = computeEdgeWeights(step, settings);
  // Only the link between columns 9 and 10 is cut (down to the floor).
  EXPECT_FLOAT_EQ(w.at(0, 5, 9), static_cast<float>(settings.w_min));
  EXPECT_FLOAT_EQ(w.at(0, 5, 8), 1.0f);
  EXPECT_FLOAT_EQ(w.at(0, 5, 10), 1.0f);
  EXPECT_FLOAT_EQ(w.at(1, 5, 9), 1.0f);  // along the edge
  // A faint step (0.02) keeps most of the weight: exp(-alpha * 0.02).
  ColorImage faint(20, 10, 1, 0.5f);
  for (int y = 0; y < 10; ++y) {
    for (int x = 10; x < 20; ++x) faint.at(0, y, x) = 0.52f;
  }
  EXPECT_NEAR(computeEdgeWeights(faint, settings).at(0, 5, 9),
              std::exp(-settings.alpha * 0.02), 1e-4);
  EXPECT_GT(std::exp(-settings.alpha * 0.02), settings.w_min);
  // The luminance sees 0.587 of the green step: a higher weight.
  settings.color_mode = EdgeColorMode::kLuminance;
  settings.w_min = 0.0;
  settings.alpha = 5.0;
  const float w_lum = computeEdgeWeights(step, settings).at(0, 5, 9);
  settings.color_mode = EdgeColorMode::kColorMax;
  const float w_max = computeEdgeWeights(step, settings).at(0, 5, 9);
  EXPECT_NEAR(w_max, std::exp(-5.0 * 0.6), 1e-4);
  EXPECT_NEAR(w_lum, std::exp(-5.0 * 0.6 * 0.587), 1e-3);
}

/// The one pass per row of the forward differences (the default) against
/// the passes over whole planes: the same weights, bit for bit, for one and
/// three channels, both weight functions, on a random image with a NaN.
TEST(EdgeWeights, OnePassMatchesThePassByPassOracle) {
  std::mt19937 random(7);
  std::uniform_real_distribution<float> value(0.0f, 1.0f);
  for (int channels : {1, 3}) {
    ColorImage image(37, 23, channels, 0.0f);
    for (std::size_t i = 0; i < image.pixelCount() * channels; ++i) {
      image.data()[i] = value(random);
    }
    image.at(0, 5, 7) = std::numeric_limits<float>::quiet_NaN();
    for (EdgeWeightFunction function :
         {EdgeWeightFunction::kExponential, EdgeWeightFunction::kRational}) {
      for (double beta : {1.0, 0.7}) {
        EdgeWeightSettings settings;
        ASSERT_EQ(settings.gradient, EdgeGradient::kForwardDifference);
        settings.function = function;
        settings.beta = beta;
        internal::EdgeWeightScratch scratch;
        PlanarImage one_pass, oracle;
        internal::computeEdgeWeightsInto(image, settings, one_pass, scratch, 2);
        internal::computeEdgeWeightsPassByPass(image, settings, oracle, scratch,
                                               1);
        ASSERT_EQ(one_pass.pixelCount(), oracle.pixelCount());
        int differing = 0;
        for (std::size_t i = 0; i < 2 * oracle.pixelCount(); ++i) {
          const float a = one_pass.data()[i], b = oracle.data()[i];
          differing += !(a == b || (std::isnan(a) && std::isnan(b)));
        }
        EXPECT_EQ(differing, 0) << channels << " channels, beta " << beta;
      }
    }
  }
}

}  // namespace
}  // namespace normal_fusion
