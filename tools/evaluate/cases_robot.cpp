// evaluate's cases of what robots feed the fusion: textured scenes, curved
// objects, and normals of structured-light and time-of-flight depth as a
// driver user computes them.
#include <iostream>
#include <string>
#include <utility>

#include "evaluate/evaluate.h"

namespace evaluate {
namespace {

namespace syn = nf::synthetic;

/// Noise streams of these cases (see noiseSeed), apart from the others'.
constexpr int kCameraStream = 10;
constexpr int kCurvedPaperStream = 11;

constexpr std::array<int, 2> kTexturedScenes{
    {syn::kTexturedRoomScene, syn::kTexturedCornerScene}};
constexpr std::array<int, 2> kCurvedScenes{
    {syn::kCurvedLargeScene, syn::kCurvedSmallScene}};

std::vector<syn::Frame> renderAll(const Options& options,
                                  const std::array<int, 2>& ids) {
  std::vector<syn::Frame> frames;
  for (int id : ids) {
    frames.push_back(syn::renderScene(id, options.width, options.height));
  }
  return frames;
}

/// A scene of one input; `confidence` (when given) adds the regularizer run
/// with it.
SceneData sceneOf(int id, const syn::Frame& frame, const std::string& name,
                  const nf::NormalMap& input,
                  const nf::ScalarMap* confidence = nullptr) {
  SceneData scene;
  scene.scene_id = id;
  scene.image = frame.image;
  scene.K = frame.K;
  scene.gt = frame.normals_gt;
  scene.inputs = {{name, input}};
  scene.filter_inputs = {input};
  scene.runs =
      confidence != nullptr
          ? runsWithConfidence(input, *confidence)
          : std::vector<std::pair<std::string, std::vector<nf::NormalInput>>>{
                {"regularizer", {inputOf(input)}}};
  return scene;
}

std::string methodName(nf::depth::NormalMethod method) {
  return nf::depth::toString(method);
}

}  // namespace

const char* const kConfidenceRun = "regularizer, with confidence";

std::vector<std::pair<std::string, std::vector<nf::NormalInput>>>
runsWithConfidence(const nf::NormalMap& normals,
                   const nf::ScalarMap& confidence) {
  nf::NormalInput weighted = inputOf(normals);
  weighted.confidence = confidence;
  return {{"regularizer", {inputOf(normals)}}, {kConfidenceRun, {weighted}}};
}

CaseResult finishWithConfidence(CaseRunner& runner, const std::string& id,
                                const std::string& title) {
  CaseResult result = runner.finish(id, title);
  // The runs are the last rows: plain, then with confidence.
  result.confidence_row = result.regularizer_row;
  result.regularizer_row -= 1;
  return result;
}

nf::NormalMap cameraNormals(const Options& options, const syn::Frame& frame,
                            const syn::DepthCameraModel& camera,
                            nf::depth::NormalMethod method, std::uint64_t seed,
                            nf::ScalarMap* confidence) {
  const nf::ScalarMap depth = syn::simulateDepthCamera(frame, camera, seed);
  nf::depth::DepthNormalSettings settings;
  settings.method = method;
  settings.noise_coefficient = camera.noise_coefficient;
  settings.normal_sigma_scale = options.confidence_sigma_scale;
  nf::NormalMap normals;
  nf::depth::depthToNormals(depth, frame.K, settings, normals, confidence);
  return normals;
}

std::string cameraText(const syn::DepthCameraModel& camera) {
  return camera.name + ": sigma_z = " + fixed(camera.noise_coefficient, 4) +
         " z^2, " + fixed(camera.quantization_m * 1000.0, 0) +
         " mm steps, flying pixels at " + percent(camera.flying_share) +
         " of the depth-edge pixels, " + percent(camera.random_dropout) +
         " random dropout, lost at grazing angles (|n.v| < " +
         fixed(camera.grazing_cos, 2) + ") and on dark surfaces (luminance < " +
         fixed(camera.dark_luminance, 2) + ")";
}

std::vector<CaseResult> runTexturedCase(const Options& options,
                                        Example* example, Timers* timers) {
  const std::vector<syn::Frame> frames = renderAll(options, kTexturedScenes);
  const syn::DepthCameraModel camera = syn::structuredLightCamera();
  std::vector<CaseResult> results;
  for (nf::depth::NormalMethod method :
       {nf::depth::NormalMethod::kPlaneFit,
        nf::depth::NormalMethod::kCentralDifference}) {
    const std::string name = "normals of depth (" + methodName(method) + ")";
    CaseRunner runner({"depth normals"}, options, timers);
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const int id = kTexturedScenes[s];
      nf::ScalarMap confidence;
      const nf::NormalMap input = cameraNormals(
          options, frames[s], camera, method,
          noiseSeed(options, id, kCameraStream, 0.0), &confidence);
      const std::vector<nf::NormalMap> regularized =
          runner.addScene(sceneOf(id, frames[s], name, input, &confidence));
      if (s == 0 && method == nf::depth::NormalMethod::kPlaneFit) {
        example->taken = true;
        example->tag = "textured_scene" + std::to_string(id);
        example->input_name = name;
        example->input_setting = camera.name + " depth";
        example->image = frames[s].image;
        example->gt = frames[s].normals_gt;
        example->input = input;
        example->regularizer = regularized.front();
        example->normals_panel = true;
      }
    }
    results.push_back(finishWithConfidence(
        runner, "textured, " + methodName(method),
        "Textured scenes " + std::to_string(kTexturedScenes[0]) + ", " +
            std::to_string(kTexturedScenes[1]) + ": " + name + ", " +
            camera.name + " camera"));
    std::cerr << "evaluate: textured case, " << methodName(method) << " done\n";
  }
  return results;
}

std::vector<CaseResult> runCurvedCase(const Options& options, Timers* timers) {
  const std::vector<syn::Frame> frames = renderAll(options, kCurvedScenes);
  const syn::DepthCameraModel camera = syn::structuredLightCamera();
  std::vector<CaseResult> results;
  for (int input_kind = 0; input_kind < 2; ++input_kind) {
    const std::string name =
        input_kind == 0 ? "paper noise sigma " + fixed(options.curved_sigma, 2)
                        : "normals of depth (plane_fit)";
    CaseRunner runner({"input"}, options, timers);
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const int id = kCurvedScenes[s];
      // Only the depth normals have a producer's confidence.
      nf::ScalarMap confidence;
      const nf::NormalMap input =
          input_kind == 0
              ? syn::addPaperNoise(frames[s].normals_gt, options.curved_sigma,
                                   noiseSeed(options, id, kCurvedPaperStream,
                                             options.curved_sigma))
              : cameraNormals(options, frames[s], camera,
                              nf::depth::NormalMethod::kPlaneFit,
                              noiseSeed(options, id, kCameraStream, 0.0),
                              &confidence);
      runner.addScene(sceneOf(id, frames[s], name, input,
                              input_kind == 0 ? nullptr : &confidence));
    }
    const std::string id =
        "curved, " + std::string(input_kind == 0 ? "paper noise" : "depth");
    const std::string title =
        "Curved objects (scenes " + std::to_string(kCurvedScenes[0]) + ", " +
        std::to_string(kCurvedScenes[1]) + "): " + name +
        (input_kind == 0 ? "" : ", " + camera.name + " camera");
    results.push_back(input_kind == 0
                          ? runner.finish(id, title)
                          : finishWithConfidence(runner, id, title));
    std::cerr << "evaluate: curved case, " << name << " done\n";
  }
  return results;
}

std::vector<CaseResult> runDepthCameraCase(
    const Options& options, const std::vector<syn::Frame>& frames,
    Timers* timers) {
  std::vector<CaseResult> results;
  for (const syn::DepthCameraModel& camera :
       {syn::structuredLightCamera(), syn::timeOfFlightCamera()}) {
    for (nf::depth::NormalMethod method :
         {nf::depth::NormalMethod::kCentralDifference,
          nf::depth::NormalMethod::kPlaneFit}) {
      const std::string name = "normals of depth (" + methodName(method) + ")";
      CaseRunner runner({"depth normals"}, options, timers);
      for (std::size_t s = 0; s < frames.size(); ++s) {
        const int id = options.scenes[s];
        nf::ScalarMap confidence;
        const nf::NormalMap input = cameraNormals(
            options, frames[s], camera, method,
            noiseSeed(options, id, kCameraStream, 0.0), &confidence);
        runner.addScene(sceneOf(id, frames[s], name, input, &confidence));
      }
      results.push_back(
          finishWithConfidence(runner, camera.name + ", " + methodName(method),
                               "Depth camera, " + camera.name + ": " + name));
      std::cerr << "evaluate: depth-camera case, " << camera.name << ", "
                << methodName(method) << " done\n";
    }
  }
  return results;
}

}  // namespace evaluate
