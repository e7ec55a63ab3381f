// evaluate's castle case: ViSP's synthetic Castle sequence, normals of its
// depth maps with depth-camera noise, ground truth from its model.
#include <algorithm>
#include <cmath>
#include <iostream>

#include "evaluate/evaluate.h"

namespace evaluate {

std::vector<int> castleFrames(const Options& options) {
  const std::vector<int> numbers = nf::castle::frameNumbers(options.castle_dir);
  const int count = std::min<int>(options.castle_frames, numbers.size());
  std::vector<int> frames;
  for (int k = 0; k < count; ++k) {
    const std::size_t at =
        count == 1
            ? 0
            : static_cast<std::size_t>(std::lround(
                  static_cast<double>(k) * (numbers.size() - 1) / (count - 1)));
    frames.push_back(numbers[at]);
  }
  return frames;
}

CastleOutcome runCastleCase(const Options& options, Timers* timers) {
  CastleOutcome outcome;
  if (!nf::castle::available(options.castle_dir)) {
    outcome.note = "skipped: the ViSP Castle-simu sequence is not at '" +
                   options.castle_dir +
                   "' (Debian package visp-images-data; scripts/setup.sh "
                   "installs it)";
    return outcome;
  }
  outcome.frames = castleFrames(options);
  const int count = static_cast<int>(outcome.frames.size());
  const std::vector<nf::castle::Face> model =
      nf::castle::loadModel(options.castle_dir);
  nf::castle::LoadSettings load;
  load.agreement_tolerance_m = options.castle_tolerance_m;
  CaseRunner runner({"depth normals"}, options, timers);
  for (int number : outcome.frames) {
    const nf::castle::Frame frame =
        nf::castle::loadFrame(options.castle_dir, number, model, load);
    outcome.agreement += frame.agreement / count;
    outcome.width += frame.image.width();
    outcome.height += frame.image.height();
    SceneData scene;
    scene.scene_id = number;
    scene.image = frame.image;
    scene.K = frame.K;
    scene.gt = frame.normals_gt;
    // Input: normals of the depth map with depth-camera noise.
    const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
        frame.depth, options.depth_sigma_at_1m, options.depth_step_m,
        options.depth_dropout, noiseSeed(options, 100 + number, 4, 0.0));
    const nf::NormalMap dense =
        nf::synthetic::normalsFromDepth(noisy_depth, frame.K);
    scene.inputs = {{"normals of noisy depth", dense}};
    scene.filter_inputs = {dense};
    scene.runs = {{"regularizer", {inputOf(dense)}}};
    const std::vector<nf::NormalMap> regularized = runner.addScene(scene);
    if (!outcome.example.taken) {
      Example& example = outcome.example;
      example.taken = true;
      example.tag = "castle_frame" + std::to_string(number);
      example.input_name = "normals of noisy depth";
      example.input_setting = "depth noise";
      example.image = frame.image;
      example.gt = frame.normals_gt;
      example.input = dense;
      example.regularizer = regularized.front();
    }
    std::cerr << "evaluate: castle frame " << number << " done\n";
  }
  outcome.width /= std::max(count, 1);
  outcome.height /= std::max(count, 1);
  outcome.ran = true;
  outcome.result =
      runner.finish("castle",
                    "ViSP Castle (synthetic RGB-D), normals of its depth maps "
                    "with depth-camera noise (" +
                        depthNoiseText(options) + ")");
  return outcome;
}

}  // namespace evaluate
