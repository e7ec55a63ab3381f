// evaluate's cases on the synthetic scenes: the paper's noise (Fig. 6),
// normals of a noisy depth map, and a dense input fused with a sparse one.
#include <cmath>
#include <iostream>

#include "evaluate/evaluate.h"

namespace evaluate {

std::vector<CaseResult> runPaperCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Example* example, Timers* timers) {
  // The example is the sigma nearest to 0.5 on the first scene.
  double example_sigma = options.sigmas.front();
  for (double sigma : options.sigmas) {
    if (std::fabs(sigma - kExampleSigma) <
        std::fabs(example_sigma - kExampleSigma)) {
      example_sigma = sigma;
    }
  }
  std::vector<CaseResult> results;
  for (double sigma : options.sigmas) {
    CaseRunner runner({"noisy input"}, options, timers);
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const nf::synthetic::Frame& frame = frames[s];
      SceneData scene;
      scene.scene_id = options.scenes[s];
      scene.image = frame.image;
      scene.K = frame.K;
      scene.gt = frame.normals_gt;
      // Noisy input: the paper's noise model.
      const nf::NormalMap noisy = nf::synthetic::addPaperNoise(
          frame.normals_gt, sigma,
          noiseSeed(options, scene.scene_id, 0, sigma));
      scene.inputs = {{"noisy input", noisy}};
      scene.filter_inputs = {noisy};
      scene.runs = {{"regularizer", {inputOf(noisy)}}};
      const std::vector<nf::NormalMap> regularized = runner.addScene(scene);
      if (s == 0 && sigma == example_sigma) {
        example->taken = true;
        example->tag = "scene" + std::to_string(scene.scene_id) + "_sigma" +
                       fixed(sigma, 2);
        example->input_name = "noisy input";
        example->input_setting = "sigma " + fixed(sigma, 2);
        example->sigma = sigma;
        example->image = frame.image;
        example->gt = frame.normals_gt;
        example->input = noisy;
        example->regularizer = regularized.front();
      }
    }
    CaseResult result = runner.finish("paper sigma " + fixed(sigma, 2),
                                      "Paper noise, sigma " + fixed(sigma, 2));
    result.sigma = sigma;
    const Row& reg = result.rows[result.regularizer_row];
    std::cerr << "evaluate: paper sigma " << fixed(sigma, 2) << ": noisy "
              << fixed(result.rows[0].mean.valid.psnr_db, 2)
              << " dB, regularizer " << fixed(reg.mean.valid.psnr_db, 2)
              << " dB\n";
    results.push_back(std::move(result));
  }
  return results;
}

/// Normals of a noisy depth map of each scene (the depth case's input and
/// the fusion's depth-derived dense input).
nf::NormalMap depthInput(const Options& options,
                         const nf::synthetic::Frame& frame, int scene) {
  const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
      frame.depth, options.depth_sigma_at_1m, options.depth_step_m,
      options.depth_dropout, noiseSeed(options, scene, 2, 0.0));
  return nf::synthetic::normalsFromDepth(noisy_depth, frame.K);
}

std::string depthNoiseText(const Options& options) {
  return fixed(options.depth_sigma_at_1m * 1000.0, 2) +
         " mm at 1 m growing with z^2, " +
         fixed(options.depth_step_m * 1000.0, 2) + " mm steps, " +
         fixed(options.depth_dropout * 100.0, 1) + " % dropout";
}

CaseResult runDepthCase(const Options& options,
                        const std::vector<nf::synthetic::Frame>& frames,
                        Timers* timers) {
  CaseRunner runner({"depth normals"}, options, timers);
  for (std::size_t s = 0; s < frames.size(); ++s) {
    SceneData scene;
    scene.scene_id = options.scenes[s];
    scene.image = frames[s].image;
    scene.K = frames[s].K;
    scene.gt = frames[s].normals_gt;
    const nf::NormalMap dense = depthInput(options, frames[s], scene.scene_id);
    scene.inputs = {{"normals of noisy depth", dense}};
    scene.filter_inputs = {dense};
    scene.runs = {{"regularizer", {inputOf(dense)}}};
    runner.addScene(scene);
    std::cerr << "evaluate: depth case, scene " << scene.scene_id << " done\n";
  }
  return runner.finish("depth", "Normals of a noisy depth map (" +
                                    depthNoiseText(options) + ")");
}

std::vector<CaseResult> runFusionCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Timers* timers) {
  std::vector<CaseResult> results;
  for (int d = 0; d < 2; ++d) {
    const std::string dense_name =
        d == 0 ? "paper noise sigma " + fixed(options.dense_sigma, 2)
               : "normals of noisy depth";
    // The filters take one map: the dense one, the sparse one, or both
    // merged (the sparse normal where there is one).
    CaseRunner runner({"dense", "sparse", "merged"}, options, timers);
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const nf::synthetic::Frame& frame = frames[s];
      const nf::NormalMap& gt = frame.normals_gt;
      SceneData scene;
      scene.scene_id = options.scenes[s];
      scene.image = frame.image;
      scene.K = frame.K;
      scene.gt = gt;
      const nf::NormalMap dense =
          d == 0
              ? nf::synthetic::addPaperNoise(
                    gt, options.dense_sigma,
                    noiseSeed(options, scene.scene_id, 1, options.dense_sigma))
              : depthInput(options, frame, scene.scene_id);
      // Sparse input: few pixels, little noise (the same for both inputs).
      const nf::NormalMap sparse = nf::synthetic::sparseAccurate(
          gt, options.sparse_density, options.sparse_sigma,
          noiseSeed(options, scene.scene_id, 3, options.sparse_sigma));
      nf::NormalMap merged = dense;
      for (std::size_t i = 0; i < sparse.pixelCount(); ++i) {
        if (!validAt(sparse, i)) continue;
        for (int c = 0; c < 3; ++c) {
          merged.plane(c)[i] = sparse.plane(c)[i];
        }
      }
      scene.inputs = {{"dense input (" + dense_name + ")", dense},
                      {"sparse input", sparse}};
      scene.filter_inputs = {dense, sparse, merged};
      // Fused: the sparse, accurate input first (it initializes where given).
      scene.runs = {{"regularizer, dense alone", {inputOf(dense)}},
                    {"regularizer, sparse alone", {inputOf(sparse)}},
                    {"regularizer, fused (sparse + dense)",
                     {inputOf(sparse, options.sparse_weight), inputOf(dense)}}};
      runner.addScene(scene);
      std::cerr << "evaluate: fusion with " << dense_name << ", scene "
                << scene.scene_id << " done\n";
    }
    results.push_back(runner.finish(
        "fusion, " + dense_name,
        "Fusion: dense " + dense_name + " + sparse accurate (density " +
            fixed(options.sparse_density, 2) + ", sigma " +
            fixed(options.sparse_sigma, 2) + ", weight " +
            fixed(options.sparse_weight, 2) + ")"));
  }
  return results;
}

}  // namespace evaluate
