#include "normal_fusion/ros/pipeline.h"

#include <boost/make_shared.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/ros/conversions.h"

namespace normal_fusion {
namespace node {

TopicNames TopicNames::defaults(int num_inputs) {
  TopicNames names;
  for (int i = 0; i < num_inputs; ++i) {
    names.normals.push_back("normals_" + std::to_string(i));
    names.confidence.push_back("confidence_" + std::to_string(i));
  }
  return names;
}

std::vector<TopicRole> topicRoles(const NodeSettings& settings) {
  std::vector<TopicRole> roles;
  roles.push_back({TopicRole::kImage, -1, "image"});
  roles.push_back({TopicRole::kCameraInfo, -1, "camera_info"});
  for (int i = 0; i < settings.num_inputs; ++i) {
    roles.push_back({TopicRole::kNormals, i, "normals_" + std::to_string(i)});
  }
  for (int i = 0; i < settings.num_inputs; ++i) {
    if (settings.inputs[i].use_confidence) {
      roles.push_back(
          {TopicRole::kConfidence, i, "confidence_" + std::to_string(i)});
    }
  }
  if (settings.use_depth) roles.push_back({TopicRole::kDepth, -1, "depth"});
  return roles;
}

InputSet inputSetFrom(const std::vector<TopicRole>& roles,
                      const std::vector<QueuedMessage>& messages,
                      const std::vector<bool>& present, int num_inputs) {
  InputSet set;
  set.normals.resize(num_inputs);
  set.confidence.resize(num_inputs);
  std::vector<bool> wants_confidence(num_inputs, false);
  for (std::size_t j = 0; j < roles.size(); ++j) {
    const TopicRole& role = roles[j];
    if (role.kind == TopicRole::kConfidence)
      wants_confidence[role.input] = true;
    if (!present[j]) continue;
    switch (role.kind) {
      case TopicRole::kImage:
        set.image = messages[j].image;
        break;
      case TopicRole::kCameraInfo:
        set.camera_info = messages[j].info;
        break;
      case TopicRole::kNormals:
        set.normals[role.input] = messages[j].image;
        break;
      case TopicRole::kConfidence:
        set.confidence[role.input] = messages[j].image;
        break;
      case TopicRole::kDepth:
        set.depth = messages[j].image;
        break;
    }
  }
  // An input that takes a confidence is present only with it.
  for (int i = 0; i < num_inputs; ++i) {
    if (wants_confidence[i] && !set.confidence[i]) set.normals[i].reset();
    if (!set.normals[i]) set.confidence[i].reset();
  }
  return set;
}

std::vector<bool> requiredTopics(const std::vector<TopicRole>& roles,
                                 const NodeSettings& settings) {
  std::vector<bool> required;
  for (const TopicRole& role : roles) {
    required.push_back(
        role.kind != TopicRole::kDepth &&
        (role.input < 0 || !settings.inputs[role.input].optional));
  }
  return required;
}

TopicNames topicNamesOf(const std::vector<TopicRole>& roles, int num_inputs) {
  TopicNames names = TopicNames::defaults(num_inputs);
  for (const TopicRole& role : roles) {
    switch (role.kind) {
      case TopicRole::kImage:
        names.image = role.name;
        break;
      case TopicRole::kCameraInfo:
        names.camera_info = role.name;
        break;
      case TopicRole::kNormals:
        names.normals[role.input] = role.name;
        break;
      case TopicRole::kConfidence:
        names.confidence[role.input] = role.name;
        break;
      case TopicRole::kDepth:
        names.depth = role.name;
        break;
    }
  }
  return names;
}

void precheckMessage(const std::string& topic, const std_msgs::Header& header,
                     const sensor_msgs::Image* image,
                     const MessageLimits& limits) {
  checkHeader(header, topic);
  if (image != nullptr) checkImageLayout(*image, topic, limits);
}

double secondsBetween(const ros::Time& later, const ros::Time& earlier) {
  // In integer nanoseconds: ros::Duration throws beyond 2^31 s.
  return 1e-9 *
         static_cast<double>(static_cast<std::int64_t>(later.toNSec()) -
                             static_cast<std::int64_t>(earlier.toNSec()));
}

RotationLookup rotationLookupFromBuffer(const tf2::BufferCore& buffer,
                                        const std::string& fixed_frame) {
  const MotionLookup motion = motionLookupFromBuffer(buffer, fixed_frame);
  return [motion](const std::string& frame, const ros::Time& previous,
                  const ros::Time& current, std::array<double, 9>* R_cur_prev,
                  std::string* reason) {
    Pose T_cur_prev;
    if (!motion(frame, previous, current, &T_cur_prev, reason)) return false;
    *R_cur_prev = T_cur_prev.R;
    return true;
  };
}

MotionLookup motionLookupFromBuffer(const tf2::BufferCore& buffer,
                                    const std::string& fixed_frame) {
  return [&buffer, fixed_frame](
             const std::string& frame, const ros::Time& previous,
             const ros::Time& current, Pose* T_cur_prev, std::string* reason) {
    try {
      // X_cur = T X_prev: source frame at the previous stamp, target frame at
      // the current one, chained through the fixed frame.
      const geometry_msgs::TransformStamped T =
          buffer.lookupTransform(frame, current, frame, previous, fixed_frame);
      const auto& q = T.transform.rotation;
      const double n = std::sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
      if (!(n > 1e-9) || !std::isfinite(n)) {
        *reason = "the transform's quaternion is not a rotation";
        return false;
      }
      const double x = q.x / n, y = q.y / n, z = q.z / n, w = q.w / n;
      const auto& t = T.transform.translation;
      if (!std::isfinite(t.x) || !std::isfinite(t.y) || !std::isfinite(t.z)) {
        *reason = "the transform's translation is not finite";
        return false;
      }
      T_cur_prev->t = {{t.x, t.y, t.z}};
      // Unit quaternion to a row-major rotation matrix.
      T_cur_prev->R = {1 - 2 * (y * y + z * z), 2 * (x * y - z * w),
                       2 * (x * z + y * w),     2 * (x * y + z * w),
                       1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                       2 * (x * z - y * w),     2 * (y * z + x * w),
                       1 - 2 * (x * x + y * y)};
      return true;
    } catch (const std::exception& e) {
      *reason = e.what();
      return false;
    }
  };
}

namespace {

/// Inputs must be in the image's camera frame; an empty frame_id is taken as
/// "the same" (hand-written publishers often leave it empty).
void requireImageFrame(const std_msgs::Header& header,
                       const std::string& image_frame, const std::string& topic,
                       const char* what) {
  if (header.frame_id.empty() || image_frame.empty() ||
      header.frame_id == image_frame) {
    return;
  }
  throw InputError(topic + ": frame_id '" + header.frame_id +
                   "' differs from the image's '" + image_frame +
                   "'; expected " + what + " in the image's camera frame");
}

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start)
      .count();
}

}  // namespace

FusionPipeline::FusionPipeline(const NodeSettings& settings,
                               const TopicNames& topics)
    : settings_(settings),
      topics_(topics),
      fuser_(streamSettingsFrom(settings), topics.image) {
  const int L = settings_.num_inputs;
  if (static_cast<int>(topics_.normals.size()) < L ||
      static_cast<int>(topics_.confidence.size()) < L) {
    const TopicNames defaults = TopicNames::defaults(L);
    topics_.normals.resize(L);
    topics_.confidence.resize(L);
    for (int i = 0; i < L; ++i) {
      if (topics_.normals[i].empty()) topics_.normals[i] = defaults.normals[i];
      if (topics_.confidence[i].empty()) {
        topics_.confidence[i] = defaults.confidence[i];
      }
    }
  }
  raw_normals_.resize(L);
  raw_confidence_.resize(L);
}

void FusionPipeline::setSettings(const NodeSettings& settings) {
  if (settings.num_inputs != settings_.num_inputs) {
    throw ParameterError("num_inputs cannot change while running: expected " +
                         std::to_string(settings_.num_inputs) + ", got " +
                         std::to_string(settings.num_inputs));
  }
  fuser_.setSettings(streamSettingsFrom(settings));
  settings_ = settings;
}

void FusionPipeline::resetWarmStart() { fuser_.reset(); }

bool FusionPipeline::reserveFor(int width, int height, double* seconds) {
  const bool live =
      settings_.warm_start && settings_.solver.time_budget_ms > 0.0;
  MessageLimits limits;
  limits.max_pixels = static_cast<std::uint64_t>(settings_.max_pixels);
  if (!live || width < 2 || height < 2 ||
      !limits.allows(static_cast<std::uint64_t>(width),
                     static_cast<std::uint64_t>(height))) {
    return false;
  }
  *seconds =
      fuser_.reserve(width, height, settings_.num_inputs, settings_.use_depth);
  return true;
}

StreamSettings streamSettingsFrom(const NodeSettings& settings) {
  StreamSettings stream;
  stream.solver = settings.solver;
  stream.warm_start = settings.warm_start;
  stream.warm_start_max_gap = settings.warm_start_max_gap;
  stream.temporal = settings.temporal;
  return stream;
}

std::vector<std::uint8_t> FusionPipeline::convertSet(const InputSet& set) {
  // Threads of the inputs' resampling: the solver's (0 = all processors).
  const int conversion_threads =
      resolveThreadCount(settings_.solver.num_threads);
  const std::string& frame_id = set.image->header.frame_id;
  imageFromMessage(*set.image, topics_.image, problem_.image);
  const int W = problem_.image.width(), H = problem_.image.height();
  problem_.K =
      intrinsicsFromCameraInfo(*set.camera_info, topics_.camera_info, W, H);

  // Normal maps (resampled to the image where their size differs), absent
  // optional inputs as all-missing maps so that the input count stays fixed.
  const int L = settings_.num_inputs;
  problem_.inputs.resize(L);
  std::vector<std::uint8_t> present(L, 0);
  for (int i = 0; i < L; ++i) {
    NormalInput& input = problem_.inputs[i];
    const InputSettings& config = settings_.inputs[i];
    input.weight = config.weight;
    input.orientation = config.orientation;
    const sensor_msgs::ImageConstPtr normals_msg =
        i < static_cast<int>(set.normals.size()) ? set.normals[i] : nullptr;
    if (!normals_msg) {
      input.normals.resize(W, H, 3);
      input.normals.fill(std::numeric_limits<float>::quiet_NaN());
      input.confidence = ScalarMap();
      continue;
    }
    const std::string& topic = topics_.normals[i];
    requireImageFrame(normals_msg->header, frame_id, topic, "normals");
    if (static_cast<int>(normals_msg->width) == W &&
        static_cast<int>(normals_msg->height) == H) {
      normalsFromMessage(*normals_msg, topic, settings_.unit_tolerance,
                         input.normals);
    } else {
      normalsFromMessage(*normals_msg, topic, settings_.unit_tolerance,
                         raw_normals_[i]);
      resampleMap(raw_normals_[i], W, H, settings_.resampling, true, topic,
                  input.normals, conversion_threads, &resample_scratch_);
    }
    const sensor_msgs::ImageConstPtr confidence_msg =
        config.use_confidence && i < static_cast<int>(set.confidence.size())
            ? set.confidence[i]
            : nullptr;
    if (confidence_msg) {
      const std::string& ctopic = topics_.confidence[i];
      requireImageFrame(confidence_msg->header, frame_id, ctopic,
                        "the confidence");
      if (static_cast<int>(confidence_msg->width) == W &&
          static_cast<int>(confidence_msg->height) == H) {
        confidenceFromMessage(*confidence_msg, ctopic, input.confidence);
      } else {
        confidenceFromMessage(*confidence_msg, ctopic, raw_confidence_[i]);
        resampleMap(raw_confidence_[i], W, H, settings_.resampling, false,
                    ctopic, input.confidence, conversion_threads);
      }
    } else {
      input.confidence = ScalarMap();
    }
    present[i] = 1;
  }
  return present;
}

FrameRotation FusionPipeline::rotationFor(const CameraMotionLookup& motion,
                                          const std::string& frame_id,
                                          const ros::Time& stamp) const {
  if (settings_.fixed_frame.empty()) return FrameRotation::still();
  std::string unused;
  if (!(settings_.warm_start || settings_.temporal.enabled()) ||
      !fuser_.continuesStream(static_cast<std::int64_t>(stamp.toNSec()),
                              problem_.K, problem_.image.width(),
                              problem_.image.height(), settings_.num_inputs,
                              &unused)) {
    return FrameRotation::still();  // not used: the stream restarts
  }
  std::string why;
  if (!motion) {
    why = "no transform source";
  } else if (frame_id.empty()) {
    why = "the image has no frame_id";
  } else {
    ros::Time previous;
    previous.fromNSec(static_cast<std::uint64_t>(fuser_.previousStampNs()));
    if (motion.motion) {
      Pose T_cur_prev;
      if (motion.motion(frame_id, previous, stamp, &T_cur_prev, &why)) {
        return FrameRotation::knownMotion(T_cur_prev);
      }
    } else {
      std::array<double, 9> R_cur_prev{};
      if (motion.rotation(frame_id, previous, stamp, &R_cur_prev, &why)) {
        return FrameRotation::known(R_cur_prev);
      }
    }
  }
  return FrameRotation::unknown(why);
}

const ScalarMap* FusionPipeline::depthOf(const InputSet& set,
                                         std::string* error) {
  if (!settings_.use_depth || !set.depth) return nullptr;
  const sensor_msgs::Image& msg = *set.depth;
  const std::string consequence =
      "; the warm start of the next set follows the rotation alone";
  const std::string& image_frame = set.image->header.frame_id;
  if (!msg.header.frame_id.empty() && !image_frame.empty() &&
      msg.header.frame_id != image_frame) {
    *error = topics_.depth + ": frame_id '" + msg.header.frame_id +
             "' differs from the image's '" + image_frame +
             "'; expected the depth aligned with the image" + consequence;
    return nullptr;
  }
  if (static_cast<int>(msg.width) != problem_.image.width() ||
      static_cast<int>(msg.height) != problem_.image.height()) {
    *error = topics_.depth + ": the depth is " + std::to_string(msg.width) +
             "x" + std::to_string(msg.height) + ", the image " +
             std::to_string(problem_.image.width()) + "x" +
             std::to_string(problem_.image.height()) +
             "; expected the depth aligned with the image (same size)" +
             consequence;
    return nullptr;
  }
  try {
    if (msg.encoding == "16UC1" || msg.encoding == "mono16") {
      depth::depthFromMillimetres(msg.data.data(), msg.width, msg.height,
                                  msg.step, depth_m_);
    } else if (msg.encoding == "32FC1") {
      depth::depthFromMetres(msg.data.data(), msg.width, msg.height, msg.step,
                             depth_m_);
    } else {
      *error = topics_.depth + ": unsupported depth encoding '" + msg.encoding +
               "'; expected 16UC1 (millimetres) or 32FC1 (metres), REP 118" +
               consequence;
      return nullptr;
    }
  } catch (const Error& e) {
    *error = topics_.depth + ": " + e.what() + consequence;
    return nullptr;
  }
  return &depth_m_;
}

void FusionPipeline::process(const InputSet& set,
                             const CameraMotionLookup& motion, bool make_vis,
                             PipelineOutput* output) {
  const auto started = std::chrono::steady_clock::now();
  output->warning.clear();
  output->note.clear();
  output->error.clear();
  if (!set.image) throw InputError(topics_.image + ": no image in the set");
  if (!set.camera_info) {
    throw InputError(topics_.camera_info +
                     ": no camera_info for the image; expected one per image");
  }
  const sensor_msgs::Image& image_msg = *set.image;
  requireImageFrame(set.camera_info->header, image_msg.header.frame_id,
                    topics_.camera_info, "the camera_info");
  if (image_msg.width < 2 || image_msg.height < 2) {
    throw InputError(topics_.image + ": expected at least 2x2 pixels, got " +
                     std::to_string(image_msg.width) + "x" +
                     std::to_string(image_msg.height));
  }
  const std::vector<std::uint8_t> present = convertSet(set);
  if (std::find(present.begin(), present.end(), 1) == present.end()) {
    throw InputError(topics_.image +
                     ": the set holds no normal map; expected at least one");
  }

  const ros::Time stamp = image_msg.header.stamp;
  const FrameRotation frame_rotation =
      rotationFor(motion, image_msg.header.frame_id, stamp);
  const ScalarMap* depth_m = depthOf(set, &output->error);
  StreamResult result;
  fuser_.fuse(static_cast<std::int64_t>(stamp.toNSec()), problem_,
              frame_rotation, started, &result, depth_m);
  output->warning = result.warning;
  output->note = result.note;
  if (result.rotation_failed) {
    output->warning = "rotation of '" + image_msg.header.frame_id +
                      "' relative to fixed_frame '" + settings_.fixed_frame +
                      "' unknown (" + result.rotation_unknown +
                      "): " + result.rotation_consequence;
  }
  const auto encode_start = std::chrono::steady_clock::now();
  encodeOutputs(image_msg.header, make_vis, result, present, output);
  normal_fusion::FusionStats& stats = *output->stats;
  stats.encode_time = secondsSince(encode_start);
  stats.frame_time = fuser_.endFrame(stats.encode_time);
  stats.latency = stats.frame_time;
}

void FusionPipeline::encodeOutputs(const std_msgs::Header& header,
                                   bool make_vis, const StreamResult& result,
                                   const std::vector<std::uint8_t>& present,
                                   PipelineOutput* output) const {
  const NormalMap& fused = fuser_.fusedNormals();
  const SolveReport& report = fuser_.lastReport();
  output->fused = boost::make_shared<sensor_msgs::Image>();
  normalsToMessage(fused, header, *output->fused);
  output->fused_vis.reset();
  if (make_vis) {
    output->fused_vis = boost::make_shared<sensor_msgs::Image>();
    normalsToVisMessage(fused, header, *output->fused_vis);
  }
  auto stats = boost::make_shared<normal_fusion::FusionStats>();
  stats->header = header;
  stats->outer_iterations = report.outer_iterations;
  stats->inner_iterations = report.inner_iterations;
  stats->coarse_inner_iterations = report.coarse_inner_iterations;
  stats->pyramid_levels = report.pyramid_levels;
  stats->inconsistent_pixels = report.inconsistent_pixels;
  stats->refined_pixels = report.refined_pixels;
  stats->refine_iterations = report.refine_iterations;
  stats->initial_energy = report.initial_energy;
  stats->final_energy = report.final_energy;
  stats->solve_time = report.seconds;
  stats->prepare_time = report.prepare_seconds;
  stats->warm_start_time = report.warm_start_seconds;
  stats->refine_time = report.refine_seconds;
  stats->cold_start_budget_used = report.cold_start_budget_used;
  stats->input_average_time = result.average_seconds;
  stats->inputs_averaged = result.inputs_averaged;
  stats->warm_started = report.warm_started;
  stats->rotation_compensated = result.rotated && report.warm_started;
  stats->motion_compensated = result.motion_warped && report.warm_started;
  stats->converged = report.converged;
  stats->budget_exhausted = report.budget_exhausted;
  stats->inputs_present.assign(present.begin(), present.end());
  stats->valid_pixels = report.valid_pixels;
  stats->filled_pixels = report.filled_pixels;
  stats->frames_processed = fuser_.framesFused();
  stats->budget_reserve = result.budget_reserve_seconds;
  output->stats = stats;
}

}  // namespace node
}  // namespace normal_fusion
