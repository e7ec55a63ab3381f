// One synchronized set of messages in, the fused map and its statistics out:
// the part of the node that the nodelet and fuse_bag share. Converts the
// messages, looks up the camera's rotation and encodes the outputs; the
// stream's policy and state are the library's StreamFuser. No subscriptions,
// no threads.
#pragma once

#include <normal_fusion/FusionStats.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2/buffer_core.h>

#include <array>
#include <cstddef>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "normal_fusion/ros/conversions.h"
#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/stream_fuser.h"

namespace normal_fusion {
namespace node {

/// Names of the input topics, for error messages (resolved names).
struct TopicNames {
  std::string image = "image";
  std::string camera_info = "camera_info";
  std::string depth = "depth";          ///< with use_depth
  std::vector<std::string> normals;     ///< normals_0 .. normals_{N-1}
  std::vector<std::string> confidence;  ///< confidence_0 .. confidence_{N-1}

  /// The default relative names for `num_inputs` inputs.
  static TopicNames defaults(int num_inputs);
};

/// One synchronized set. `normals` has one entry per input (null = an optional
/// input that is absent from this set); `confidence` likewise (null = not
/// used or absent).
struct InputSet {
  sensor_msgs::ImageConstPtr image;
  sensor_msgs::CameraInfoConstPtr camera_info;
  std::vector<sensor_msgs::ImageConstPtr> normals;
  std::vector<sensor_msgs::ImageConstPtr> confidence;
  /// With use_depth: the depth aligned with the image (null = absent).
  sensor_msgs::ImageConstPtr depth;
};

/// What the synchronizer queues per topic: an image or a camera_info.
struct QueuedMessage {
  sensor_msgs::ImageConstPtr image;
  sensor_msgs::CameraInfoConstPtr info;
};

/// Which input a synchronizer topic is.
struct TopicRole {
  enum Kind { kImage, kCameraInfo, kNormals, kConfidence, kDepth } kind;
  int input = -1;    ///< normals / confidence: the input index
  std::string name;  ///< resolved topic name
};

/// The synchronizer topics for the settings: image, camera_info, normals_i,
/// confidence_i of the inputs that use one, then depth with use_depth. Names
/// are relative.
std::vector<TopicRole> topicRoles(const NodeSettings& settings);

/// Which topics a set needs: image, camera_info and the inputs (with their
/// confidence) that are not optional. The depth is optional: a set without
/// it is warm-started by the rotation alone.
std::vector<bool> requiredTopics(const std::vector<TopicRole>& roles,
                                 const NodeSettings& settings);

/// The roles' names as the pipeline reports them (confidence topics of
/// inputs without one get the default name).
TopicNames topicNamesOf(const std::vector<TopicRole>& roles, int num_inputs);

/// The checks a message gets on arrival, before it may join a set: a non-zero,
/// normalized stamp and, for images, a layout that matches the buffer and a
/// size within the limits. Throws InputError naming the topic.
void precheckMessage(const std::string& topic, const std_msgs::Header& header,
                     const sensor_msgs::Image* image,
                     const MessageLimits& limits = MessageLimits());

/// later - earlier in seconds, for any two valid stamps (no overflow).
double secondsBetween(const ros::Time& later, const ros::Time& earlier);

/// Builds the pipeline's input set from a synchronized set.
InputSet inputSetFrom(const std::vector<TopicRole>& roles,
                      const std::vector<QueuedMessage>& messages,
                      const std::vector<bool>& present, int num_inputs);

/// Looks up the rotation R_cur_prev of the camera frame `frame` between the
/// stamps `previous` and `current` (X_cur = R_cur_prev X_prev, row-major).
/// Returns false with a reason when it is not known.
using RotationLookup =
    std::function<bool(const std::string& frame, const ros::Time& previous,
                       const ros::Time& current,
                       std::array<double, 9>* R_cur_prev, std::string* reason)>;

/// A lookup in a tf2 buffer: the transform of `frame` at `previous` into
/// `frame` at `current` through `fixed_frame`, its rotation part. The buffer
/// must outlive the returned function.
RotationLookup rotationLookupFromBuffer(const tf2::BufferCore& buffer,
                                        const std::string& fixed_frame);

/// Looks up the full motion T_cur_prev of the camera frame `frame` between
/// the stamps (X_cur = R X_prev + t, t in metres). Returns false with a
/// reason when it is not known.
using MotionLookup = std::function<bool(
    const std::string& frame, const ros::Time& previous,
    const ros::Time& current, Pose* T_cur_prev, std::string* reason)>;

/// The same lookup as rotationLookupFromBuffer, with its translation.
MotionLookup motionLookupFromBuffer(const tf2::BufferCore& buffer,
                                    const std::string& fixed_frame);

/// Where process() gets the camera's motion from: a rotation lookup (the
/// translation unknown: the warm start follows the rotation alone), a full
/// motion lookup (with use_depth and a depth, the warm start follows the
/// full motion), or nothing (no compensation).
struct CameraMotionLookup {
  CameraMotionLookup() = default;
  CameraMotionLookup(std::nullptr_t) {}      // NOLINT: no lookup
  CameraMotionLookup(RotationLookup lookup)  // NOLINT: implicit on purpose
      : rotation(std::move(lookup)) {}
  CameraMotionLookup(MotionLookup lookup)  // NOLINT: implicit on purpose
      : motion(std::move(lookup)) {}
  explicit operator bool() const {
    return static_cast<bool>(rotation) || static_cast<bool>(motion);
  }

  RotationLookup rotation;
  MotionLookup motion;  ///< used when set
};

/// The stream settings in `settings` (solver, warm start, temporal
/// averaging).
StreamSettings streamSettingsFrom(const NodeSettings& settings);

/// What one processed set gives.
struct PipelineOutput {
  sensor_msgs::ImagePtr fused;      ///< 32FC3, the image's header
  sensor_msgs::ImagePtr fused_vis;  ///< rgb8; null unless requested
  normal_fusion::FusionStatsPtr stats;
  /// Something the caller should log (e.g. the rotation lookup failed and the
  /// frame was cold-started); empty when all went as asked.
  std::string warning;
  /// An input the set could do without was refused (e.g. a depth of another
  /// size than the image: the warm start followed the rotation alone); worth
  /// an error line, the frame was fused.
  std::string error;
  /// Worth an info line: the stream (re)started here with a cold start, why,
  /// and under which budget; empty otherwise.
  std::string note;
};

class FusionPipeline {
 public:
  FusionPipeline(const NodeSettings& settings, const TopicNames& topics);

  /// New settings (already corrected by settingsFromParameters); take effect
  /// on the next set. The input count must stay the same.
  void setSettings(const NodeSettings& settings);
  const NodeSettings& settings() const { return settings_; }

  /// Converts, checks, solves (warm-started when allowed) and encodes one
  /// set. Throws InputError naming the topic and the problem, or
  /// ParameterError; the warm-start state is then dropped. `motion` may be
  /// empty (no rotation compensation).
  void process(const InputSet& set, const CameraMotionLookup& motion,
               bool make_vis, PipelineOutput* output);

  /// Forgets the previous frame: the next set cold-starts.
  void resetWarmStart();

  /// Before the first set, from its camera_info: reserves the stream's
  /// buffers for `width` x `height` sets (StreamFuser::reserve()) when the
  /// stream is live (warm starts under a time budget), so that its first
  /// frames keep the budget. Returns false, doing nothing, when it is not
  /// live or the size is one no set may have (below 2x2, above max_pixels);
  /// else the seconds it took in *seconds.
  bool reserveFor(int width, int height, double* seconds);

  /// From any thread: the solve under way (and every later one) stops within
  /// an inner iteration block; process() then throws Cancelled. For shutdown.
  void requestCancel() noexcept { fuser_.requestCancel(); }

  std::uint64_t framesProcessed() const { return fuser_.framesFused(); }
  const SolveReport& lastReport() const { return fuser_.lastReport(); }
  /// The fused normals of the last set (valid after process()).
  const NormalMap& fusedNormals() const { return fuser_.fusedNormals(); }

 private:
  /// Fills problem_ from the set (guide image, K, the inputs resampled to
  /// the image); returns which inputs are present.
  std::vector<std::uint8_t> convertSet(const InputSet& set);
  /// The camera's rotation since the previous set, looked up only when the
  /// set continues the stream with a fixed_frame given.
  FrameRotation rotationFor(const CameraMotionLookup& motion,
                            const std::string& frame_id,
                            const ros::Time& stamp) const;
  /// With use_depth, the set's depth in metres for the stream (null: none,
  /// or refused with the reason in *error).
  const ScalarMap* depthOf(const InputSet& set, std::string* error);
  /// Encodes the outputs and fills the statistics.
  void encodeOutputs(const std_msgs::Header& header, bool make_vis,
                     const StreamResult& result,
                     const std::vector<std::uint8_t>& present,
                     PipelineOutput* output) const;

  NodeSettings settings_;
  TopicNames topics_;
  StreamFuser fuser_;
  FusionProblem problem_;
  std::vector<NormalMap> raw_normals_;     ///< per input, as received
  std::vector<ScalarMap> raw_confidence_;  ///< per input, as received
  PlanarImage resample_scratch_;  ///< resampleMap()'s masked source copy
  ScalarMap depth_m_;             ///< the set's depth, metres
};

}  // namespace node
}  // namespace normal_fusion
