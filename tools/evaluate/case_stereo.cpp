// evaluate's stereo cases: a rendered textured pair through OpenCV's
// semi-global matching, and Middlebury's Aloe pair with its ground truth.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <limits>

#include "evaluate/evaluate.h"

namespace evaluate {

const std::array<int, 3> kStereoScenes{{nf::synthetic::kTexturedRoomScene,
                                        nf::synthetic::kTexturedCornerScene,
                                        nf::synthetic::kCurvedLargeScene}};

namespace {

namespace syn = nf::synthetic;

/// The matcher's disparity error (pixels) behind the noise coefficient of
/// the depth normals: sigma_z = sigma_d z^2 / (f b).
constexpr double kDisparitySigmaPx = 0.3;
constexpr std::array<int, 3> kCorrelationLags{{1, 4, 16}};
constexpr int kCameraStream = 12;
/// The pair is matched at this multiple of the evaluated size, as a stereo
/// camera matches at its sensor's resolution; the disparity is reduced.
constexpr int kMatchScale = 2;

/// Plane-fit normals of stereo depth and their confidence, the noise
/// coefficient from f and b, s0 from the options.
nf::NormalMap stereoNormals(const Options& options,
                            const nf::ScalarMap& disparity,
                            const nf::CameraIntrinsics& K, double baseline_m,
                            nf::ScalarMap* confidence) {
  nf::depth::DepthNormalSettings settings;
  settings.method = nf::depth::NormalMethod::kPlaneFit;
  settings.noise_coefficient = kDisparitySigmaPx / (K.fx() * baseline_m);
  settings.normal_sigma_scale = options.confidence_sigma_scale;
  nf::NormalMap normals;
  nf::depth::depthToNormals(
      nf::stereo::depthFromDisparity(disparity, K.fx(), baseline_m), K,
      settings, normals, confidence);
  return normals;
}

/// A search range of whole 16-pixel blocks that covers the largest
/// disparity of the ground truth with a margin.
int searchRange(const nf::ScalarMap& disparity) {
  double largest = 0.0;
  for (std::size_t i = 0; i < disparity.pixelCount(); ++i) {
    const double d = disparity.data()[i];
    if (std::isfinite(d)) largest = std::max(largest, d);
  }
  return 16 * static_cast<int>(std::ceil((largest + 4.0) / 16.0));
}

double shareWithValue(const nf::ScalarMap& map) {
  std::size_t n = 0;
  for (std::size_t i = 0; i < map.pixelCount(); ++i) {
    if (std::isfinite(map.data()[i])) ++n;
  }
  return static_cast<double>(n) / static_cast<double>(map.pixelCount());
}

void takeExample(const std::string& tag, const std::string& setting,
                 const SceneData& scene, const nf::NormalMap& regularized,
                 Example* example) {
  example->taken = true;
  example->tag = tag;
  example->input_name = scene.inputs.front().first;
  example->input_setting = setting;
  example->image = scene.image;
  example->gt = scene.gt;
  example->input = scene.inputs.front().second;
  example->regularizer = regularized;
}

/// What whole-pixel steps and the plane fit leave in a ground truth made
/// like Aloe's: the textured room rendered at the full size, its disparity
/// (a baseline giving the same largest disparity) rounded to whole pixels,
/// reduced and fitted as Aloe's, against the room's exact normals (deg).
double quantizationFloorDeg(const nf::aloe::AloeSettings& settings, int width,
                            int height, double largest_full_px) {
  const int factor = settings.downscale;
  const syn::Frame full = syn::renderScene(syn::kTexturedRoomScene,
                                           factor * width, factor * height);
  const syn::Frame reduced =
      syn::renderScene(syn::kTexturedRoomScene, width, height);
  double z_min = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < full.depth.pixelCount(); ++i) {
    z_min = std::min(z_min, static_cast<double>(full.depth.data()[i]));
  }
  const double baseline = largest_full_px * z_min / full.K.fx();
  nf::ScalarMap steps =
      nf::stereo::disparityFromDepth(full.depth, full.K.fx(), baseline);
  for (std::size_t i = 0; i < steps.pixelCount(); ++i) {
    steps.data()[i] = std::round(steps.data()[i]);
  }
  const nf::NormalMap fitted = nf::aloe::normalsFromDisparity(
      nf::stereo::reduceDisparity(steps, factor), reduced.K, baseline,
      settings.gt_window_radius);
  return nf::angularError(fitted, reduced.normals_gt).mean_deg;
}

}  // namespace

StereoOutcome runStereoCase(const Options& options, Timers* timers) {
  StereoOutcome outcome;
  CaseRunner runner({"stereo normals"}, options, timers);
  const double b = options.stereo_baseline_m;
  for (int id : kStereoScenes) {
    const nf::stereo::StereoPair pair = nf::stereo::renderStereoPair(
        id, kMatchScale * options.width, kMatchScale * options.height, b);
    // The evaluated view: the left camera at the evaluated size.
    const syn::Frame left = syn::renderScene(id, options.width, options.height);
    const nf::CameraIntrinsics& K = left.K;
    nf::stereo::SgbmSettings sgbm;
    sgbm.num_disparities = searchRange(
        nf::stereo::disparityFromDepth(pair.left.depth, pair.left.K.fx(), b));
    const nf::ScalarMap disparity = nf::stereo::reduceDisparity(
        nf::stereo::sgbmDisparity(pair.left.image, pair.right.image, sgbm),
        kMatchScale);
    const nf::ScalarMap depth =
        nf::stereo::depthFromDisparity(disparity, K.fx(), b);
    const nf::ScalarMap camera_depth =
        syn::simulateDepthCamera(left, syn::structuredLightCamera(),
                                 noiseSeed(options, id, kCameraStream, 0.0));
    const double n = static_cast<double>(kStereoScenes.size());
    for (std::size_t k = 0; k < kCorrelationLags.size(); ++k) {
      outcome.correlation_stereo[k] +=
          nf::stereo::errorCorrelation(depth, left.depth, kCorrelationLags[k]) /
          n;
      outcome.correlation_camera[k] +=
          nf::stereo::errorCorrelation(camera_depth, left.depth,
                                       kCorrelationLags[k]) /
          n;
    }
    outcome.depth_share += shareWithValue(disparity) / n;
    nf::ScalarMap confidence;
    const nf::NormalMap input =
        stereoNormals(options, disparity, K, b, &confidence);
    SceneData scene;
    scene.scene_id = id;
    scene.image = left.image;
    scene.K = K;
    scene.gt = left.normals_gt;
    scene.inputs = {{"normals of SGBM depth (plane_fit)", input}};
    scene.filter_inputs = {input};
    scene.runs = runsWithConfidence(input, confidence);
    const std::vector<nf::NormalMap> regularized = runner.addScene(scene);
    if (!outcome.example.taken) {
      takeExample("stereo_scene" + std::to_string(id),
                  "SGBM, baseline " + fixed(b * 100.0, 0) + " cm", scene,
                  regularized.front(), &outcome.example);
    }
    std::cerr << "evaluate: stereo case, scene " << id << " done\n";
  }
  outcome.ran = true;
  outcome.result = finishWithConfidence(
      runner, "stereo",
      "Stereo: normals of OpenCV SGBM depth of a rendered pair (scenes " +
          std::to_string(kStereoScenes[0]) + ", " +
          std::to_string(kStereoScenes[1]) + ", " +
          std::to_string(kStereoScenes[2]) + ", baseline " +
          fixed(b * 100.0, 0) + " cm)");
  return outcome;
}

AloeOutcome runAloeCase(const Options& options, Timers* timers) {
  AloeOutcome outcome;
  nf::aloe::AloeSettings settings;
  settings.directory = options.aloe_dir;
  const nf::aloe::AloeData data = nf::aloe::load(settings);
  if (!data.found) {
    outcome.note = data.note;
    return outcome;
  }
  outcome.width = data.left.width();
  outcome.height = data.left.height();
  nf::stereo::SgbmSettings sgbm;
  sgbm.num_disparities = searchRange(data.disparity_gt);
  const nf::ScalarMap disparity =
      nf::stereo::sgbmDisparity(data.left, data.right, sgbm);
  nf::ScalarMap confidence;
  const nf::NormalMap input =
      stereoNormals(options, disparity, data.K, data.baseline_m, &confidence);
  // What the whole-pixel steps leave in the ground truth: its fit over a
  // window of half the size against the one used.
  const nf::NormalMap gt_small_window = nf::aloe::normalsFromDisparity(
      data.disparity_gt, data.K, data.baseline_m,
      std::max(1, settings.gt_window_radius / 2));
  outcome.gt_window_change_deg =
      nf::angularError(gt_small_window, data.normals_gt).mean_deg;
  double largest = 0.0;
  for (std::size_t i = 0; i < data.disparity_gt.pixelCount(); ++i) {
    const double d = data.disparity_gt.data()[i];
    if (std::isfinite(d)) largest = std::max(largest, d);
  }
  outcome.gt_floor_deg = quantizationFloorDeg(
      settings, outcome.width, outcome.height, largest * settings.downscale);
  std::size_t with_gt = 0, with_both = 0;
  outcome.depth_min_m = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < input.pixelCount(); ++i) {
    if (!validAt(data.normals_gt, i)) continue;
    ++with_gt;
    if (std::isfinite(disparity.data()[i])) ++with_both;
    const double z = data.depth_gt.data()[i];
    outcome.depth_min_m = std::min(outcome.depth_min_m, z);
    outcome.depth_max_m = std::max(outcome.depth_max_m, z);
  }
  outcome.gt_share = static_cast<double>(with_gt) / input.pixelCount();
  outcome.depth_share =
      with_gt > 0 ? static_cast<double>(with_both) / with_gt : 0.0;
  CaseRunner runner({"stereo normals"}, options, timers);
  SceneData scene;
  scene.scene_id = 0;
  scene.image = data.left;
  scene.K = data.K;
  scene.gt = data.normals_gt;
  scene.inputs = {{"normals of SGBM depth (plane_fit)", input}};
  scene.filter_inputs = {input};
  scene.runs = runsWithConfidence(input, confidence);
  const std::vector<nf::NormalMap> regularized = runner.addScene(scene);
  takeExample("aloe", "SGBM on the real pair", scene, regularized.front(),
              &outcome.example);
  outcome.ran = true;
  outcome.result = finishWithConfidence(
      runner, "aloe",
      "Real stereo: Middlebury Aloe, normals of OpenCV SGBM depth");
  std::cerr << "evaluate: aloe case done\n";
  return outcome;
}

}  // namespace evaluate
