// The paper's claim (its Fig. 6): on synthetic scenes with its noise model, the
// regularizer with one parameter set (the library's defaults) beats the best
// cross-bilateral filter (w = 3, 5, 7; sigma_S = 5w/3 or 3w/5; sigma_I = 0.1)
// in PSNR at every noise level.
#include <gtest/gtest.h>

#include <algorithm>

#include "eval/synthetic.h"
#include "normal_fusion/bilateral.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {
namespace {

constexpr int kWidth = 256;
constexpr int kHeight = 192;

double bestBilateralPsnr(const NormalMap& noisy,
                         const synthetic::Frame& frame) {
  double best = -1e9;
  for (int w : {3, 5, 7}) {
    for (double sigma_spatial : {5.0 * w / 3.0, 3.0 * w / 5.0}) {
      BilateralSettings settings;
      settings.half_window = w;
      settings.sigma_spatial = sigma_spatial;
      settings.sigma_intensity = 0.1;
      best = std::max(best,
                      psnr(crossBilateralFilter(noisy, frame.image, settings),
                           frame.normals_gt));
    }
  }
  return best;
}

TEST(PaperClaim, RegularizerBeatsTheBestBilateralFilterAtEveryNoiseLevel) {
  std::vector<synthetic::Frame> frames;
  for (int scene = 0; scene < synthetic::kNumScenes; ++scene) {
    frames.push_back(synthetic::renderScene(scene, kWidth, kHeight));
  }
  const SolverSettings defaults;  // one parameter set for every sigma
  for (double sigma : {0.1, 0.3, 0.5, 0.7, 0.9}) {
    double psnr_regularizer = 0.0, psnr_bilateral = 0.0, psnr_noisy = 0.0;
    for (std::size_t scene = 0; scene < frames.size(); ++scene) {
      const synthetic::Frame& frame = frames[scene];
      const NormalMap noisy = synthetic::addPaperNoise(
          frame.normals_gt, sigma,
          1000 + 10 * scene + static_cast<int>(10 * sigma));
      FusionProblem problem;
      problem.image = frame.image;
      problem.K = frame.K;
      NormalInput input;
      input.normals = noisy;
      problem.inputs = {input};
      Solver solver(defaults);
      psnr_regularizer += psnr(solver.solve(problem), frame.normals_gt);
      psnr_bilateral += bestBilateralPsnr(noisy, frame);
      psnr_noisy += psnr(noisy, frame.normals_gt);
    }
    const double n = static_cast<double>(frames.size());
    RecordProperty("sigma_" + std::to_string(static_cast<int>(100 * sigma)),
                   std::to_string(psnr_regularizer / n) + " vs " +
                       std::to_string(psnr_bilateral / n));
    EXPECT_GT(psnr_regularizer / n, psnr_bilateral / n) << "sigma " << sigma;
    EXPECT_GT(psnr_bilateral / n, psnr_noisy / n) << "sigma " << sigma;
  }
}

}  // namespace
}  // namespace normal_fusion
