#include "normal_fusion/ros/pipeline.h"

#include <boost/make_shared.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>

#include "normal_fusion/detail/previous_pixel.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/ros/conversions.h"
#include "normal_fusion/warp.h"

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
    required.push_back(role.input < 0 || !settings.inputs[role.input].optional);
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
  return [&buffer, fixed_frame](
             const std::string& frame, const ros::Time& previous,
             const ros::Time& current, std::array<double, 9>* R_cur_prev,
             std::string* reason) {
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
      // Unit quaternion to a row-major rotation matrix.
      *R_cur_prev = {1 - 2 * (y * y + z * z), 2 * (x * y - z * w),
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

/// The number of pixels of `normals` that are not finite unit vectors.
std::size_t nonUnitPixels(const NormalMap& normals) {
  std::size_t bad = 0;
  const std::size_t n = normals.pixelCount();
  const float* x = normals.plane(0);
  const float* y = normals.plane(1);
  const float* z = normals.plane(2);
  for (std::size_t i = 0; i < n; ++i) {
    const float length2 = x[i] * x[i] + y[i] * y[i] + z[i] * z[i];
    // NaN fails the comparison and counts as bad.
    bad += !(std::abs(length2 - 1.0f) <= 1e-3f);
  }
  return bad;
}

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start)
      .count();
}

}  // namespace

FusionPipeline::FusionPipeline(const NodeSettings& settings,
                               const TopicNames& topics)
    : settings_(settings), topics_(topics), solver_(settings.solver) {
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
  solver_.setSettings(settings.solver);
  settings_ = settings;
}

void FusionPipeline::resetWarmStart() {
  has_previous_ = false;
  state_.clear();
  temporal_.reset();
  averages_current_ = false;
}

bool FusionPipeline::canWarmStart(const CameraIntrinsics& K,
                                  const ros::Time& stamp,
                                  std::string* reason) const {
  if (!has_previous_) {
    *reason = "no previous frame";
    return false;
  }
  if (!state_.compatible(problem_.image.width(), problem_.image.height(),
                         settings_.num_inputs)) {
    *reason = "the image size changed";
    return false;
  }
  for (int i = 0; i < 9; ++i) {
    if (std::abs(K.K[i] - previous_K_.K[i]) >
        1e-9 * std::max(1.0, std::abs(previous_K_.K[i]))) {
      *reason = "K changed";
      return false;
    }
  }
  // The gap the previous set's own processing opened does not count: after
  // a long solve (a stream's converged start) the next set solved is the
  // newest, its stamp that much later.
  const double gap = secondsBetween(stamp, previous_stamp_);
  if (gap > settings_.warm_start_max_gap + previous_seconds_) {
    std::ostringstream text;
    text << "stamp gap " << gap << " s exceeds warm_start_max_gap plus the "
         << "previous set's processing (" << previous_seconds_ << " s)";
    *reason = text.str();
    return false;
  }
  return true;
}

void FusionPipeline::process(const InputSet& set,
                             const RotationLookup& rotation, bool make_vis,
                             PipelineOutput* output) {
  const auto started = std::chrono::steady_clock::now();
  output->warning.clear();
  // Threads of the inputs' resampling: the solver's (0 = all processors).
  const int conversion_threads =
      resolveThreadCount(settings_.solver.num_threads);
  if (!set.image) throw InputError(topics_.image + ": no image in the set");
  if (!set.camera_info) {
    throw InputError(topics_.camera_info +
                     ": no camera_info for the image; expected one per image");
  }
  const sensor_msgs::Image& image_msg = *set.image;
  const std::string& frame_id = image_msg.header.frame_id;
  const ros::Time stamp = image_msg.header.stamp;
  requireImageFrame(set.camera_info->header, frame_id, topics_.camera_info,
                    "the camera_info");
  if (image_msg.width < 2 || image_msg.height < 2) {
    throw InputError(topics_.image + ": expected at least 2x2 pixels, got " +
                     std::to_string(image_msg.width) + "x" +
                     std::to_string(image_msg.height));
  }

  // Guide image and intrinsics.
  imageFromMessage(image_msg, topics_.image, problem_.image);
  const int W = problem_.image.width(), H = problem_.image.height();
  problem_.K =
      intrinsicsFromCameraInfo(*set.camera_info, topics_.camera_info, W, H);

  // Normal maps (resampled to the image where their size differs), absent
  // optional inputs as all-missing maps so that the input count stays fixed.
  const int L = settings_.num_inputs;
  problem_.inputs.resize(L);
  std::vector<std::uint8_t> present(L, 0);
  int present_count = 0;
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
    ++present_count;
  }
  if (present_count == 0) {
    throw InputError(topics_.image +
                     ": the set holds no normal map; expected at least one");
  }

  // Warm start: from the previous result when it fits, rotated when asked.
  bool warm = false, rotated = false;
  if (has_previous_ && stamp < previous_stamp_) {
    std::ostringstream text;
    text << "time went backwards by " << secondsBetween(previous_stamp_, stamp)
         << " s (a bag loop or a restarted player): warm start reset";
    output->warning = text.str();
    resetWarmStart();
  }
  std::string reason;
  // A warm start wanted but the previous map unusable (no previous frame,
  // another size or K, too long a gap): the stream (re)starts here. Its cold
  // start is solved under cold_start_budget_ms (the solver's rule for a warm
  // start asked for without a usable state), since the warm frames after it
  // carry its map on. A rotation that cannot be looked up is a one-frame
  // failure instead: that frame is cold-started under the frame budget.
  // The inputs' temporal averages follow the same stream: carried by the
  // same rotation, restarted where the warm start would be.
  bool stream_start = false;
  output->note.clear();
  const bool averaging = settings_.temporal.enabled();
  bool continuous = false;  // this set continues the previous set's stream
  if (settings_.warm_start || averaging) {
    continuous = canWarmStart(problem_.K, stamp, &reason);
    if (!continuous && settings_.warm_start) {
      stream_start = true;
      state_.clear();
    }
  }
  std::array<double, 9> R_cur_prev{};
  if (continuous && !settings_.fixed_frame.empty()) {
    std::string why;
    if (!rotation) {
      why = "no transform source";
    } else if (frame_id.empty()) {
      why = "the image has no frame_id";
    } else if (rotation(frame_id, previous_stamp_, stamp, &R_cur_prev, &why)) {
      try {
        if (settings_.warm_start) {
          // With the local refinement the duals are reset (as good, and
          // cheaper: see DualWarp).
          warpStateByRotation(state_, problem_.K, R_cur_prev, warp_scratch_,
                              solver_.settings().num_threads,
                              solver_.settings().warm_refine_iterations > 0
                                  ? DualWarp::kReset
                                  : DualWarp::kRotate);
        } else {
          internal::checkRotation(R_cur_prev, "the transform");
        }
        rotated = true;
      } catch (const Error& e) {
        why = e.what();
      }
    }
    if (!rotated) {
      output->warning = "rotation of '" + frame_id +
                        "' relative to fixed_frame '" + settings_.fixed_frame +
                        "' unknown (" + why + "): ";
      if (settings_.warm_start) output->warning += "cold start";
      if (settings_.warm_start && averaging) output->warning += ", ";
      if (averaging) output->warning += "input averages restarted";
    }
  }
  // Aligned with the previous set: by the rotation, or assumed still when no
  // fixed_frame is given.
  const bool aligned = continuous && (settings_.fixed_frame.empty() || rotated);
  warm = settings_.warm_start && aligned;
  double average_seconds = 0.0;
  // This set's samples join the previous sets' averages (else they restart).
  const bool joined = averaging && aligned && averages_current_;
  if (averaging) {
    const auto average_start = std::chrono::steady_clock::now();
    // A new stream, or averages left from before averaging was last turned
    // off (stale): they restart with this set.
    if (!joined) temporal_.reset();
    try {
      temporal_.apply(problem_.inputs, problem_.K,
                      rotated ? &R_cur_prev : nullptr, settings_.temporal,
                      conversion_threads);
    } catch (...) {
      resetWarmStart();
      throw;
    }
    averages_current_ = true;
    average_seconds = std::chrono::duration<double>(
                          std::chrono::steady_clock::now() - average_start)
                          .count();
  } else {
    averages_current_ = false;
  }

  try {
    // time_budget_ms covers the whole frame: conversion, warp, solve and the
    // outputs' encoding, whose time (as the last frames took) is set aside
    // by starting the budget that much earlier.
    const auto reserve =
        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
            std::chrono::duration<double>(encode_estimate_s_));
    solver_.setBudgetStart(started - reserve);
    solver_.solve(problem_, state_, warm || stream_start, report_);
    if (report_.cancelled) throw Cancelled(topics_.image + ": solve cancelled");
    // The warp's buffers, sized with the state (allocates on the first frame
    // of a size only).
    warp_scratch_.resize(state_.normals.width(), state_.normals.height(),
                         static_cast<int>(state_.dual_data.size()));
  } catch (...) {
    resetWarmStart();
    throw;
  }
  if (stream_start) {
    std::ostringstream text;
    text << "stream (re)started (" << reason << "): cold start in "
         << std::lround(1e3 * report_.seconds) << " ms, "
         << report_.inner_iterations + report_.coarse_inner_iterations
         << " inner iterations";
    if (report_.cold_start_budget_used) {
      const double budget = solver_.settings().cold_start_budget_ms;
      text << " under cold_start_budget_ms ";
      if (budget > 0.0) {
        text << "(" << budget << " ms)";
      } else {
        text << "(none: the iteration caps)";
      }
      text << " instead of time_budget_ms ("
           << solver_.settings().time_budget_ms << " ms)";
    }
    output->note = text.str();
  }
  const std::size_t bad_pixels = nonUnitPixels(state_.normals);
  if (bad_pixels > 0) {
    // Never published: fused_normals promises a unit normal at every pixel.
    resetWarmStart();
    std::ostringstream text;
    text << topics_.image << ": the solve gave " << bad_pixels << " of "
         << state_.normals.pixelCount()
         << " pixels without a finite unit normal (K, the inputs or the "
            "settings are degenerate); frame skipped, stream reset";
    throw Error(text.str());
  }
  has_previous_ = true;
  previous_stamp_ = stamp;
  previous_K_ = problem_.K;
  ++frames_processed_;

  // Outputs with the image's header.
  const auto encode_start = std::chrono::steady_clock::now();
  output->fused = boost::make_shared<sensor_msgs::Image>();
  normalsToMessage(state_.normals, image_msg.header, *output->fused);
  output->fused_vis.reset();
  if (make_vis) {
    output->fused_vis = boost::make_shared<sensor_msgs::Image>();
    normalsToVisMessage(state_.normals, image_msg.header, *output->fused_vis);
  }
  auto stats = boost::make_shared<normal_fusion::FusionStats>();
  stats->header = image_msg.header;
  stats->outer_iterations = report_.outer_iterations;
  stats->inner_iterations = report_.inner_iterations;
  stats->coarse_inner_iterations = report_.coarse_inner_iterations;
  stats->pyramid_levels = report_.pyramid_levels;
  stats->inconsistent_pixels = report_.inconsistent_pixels;
  stats->refined_pixels = report_.refined_pixels;
  stats->refine_iterations = report_.refine_iterations;
  stats->initial_energy = report_.initial_energy;
  stats->final_energy = report_.final_energy;
  stats->solve_time = report_.seconds;
  stats->prepare_time = report_.prepare_seconds;
  stats->warm_start_time = report_.warm_start_seconds;
  stats->refine_time = report_.refine_seconds;
  stats->cold_start_budget_used = report_.cold_start_budget_used;
  stats->input_average_time = average_seconds;
  stats->inputs_averaged = joined;
  stats->warm_started = report_.warm_started;
  stats->rotation_compensated = rotated && report_.warm_started;
  stats->converged = report_.converged;
  stats->budget_exhausted = report_.budget_exhausted;
  stats->inputs_present.assign(present.begin(), present.end());
  stats->valid_pixels = report_.valid_pixels;
  stats->filled_pixels = report_.filled_pixels;
  stats->frames_processed = frames_processed_;
  stats->encode_time = secondsSince(encode_start);
  // A slow running estimate: one frame's hiccup does not halve the next
  // frame's solve.
  encode_estimate_s_ = frames_processed_ == 1 ? stats->encode_time
                                              : 0.8 * encode_estimate_s_ +
                                                    0.2 * stats->encode_time;
  stats->frame_time = secondsSince(started);
  stats->latency = stats->frame_time;
  previous_seconds_ = stats->frame_time;
  output->stats = stats;
}

}  // namespace node
}  // namespace normal_fusion
