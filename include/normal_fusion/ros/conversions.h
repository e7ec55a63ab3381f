// Conversions between sensor_msgs and the library's types, with the checks at
// the boundary: every function throws normal_fusion::InputError whose message
// starts with the topic's name and says what was expected and what came.
#pragma once

#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/Header.h>

#include <cstdint>
#include <string>
#include <vector>

#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace node {

/// What the arrival checks bound.
struct MessageLimits {
  /// Most pixels an image may have (0 = no bound).
  std::uint64_t max_pixels = kDefaultMaxPixels;

  /// True when a width x height image is within max_pixels.
  bool allows(std::uint64_t width, std::uint64_t height) const {
    return max_pixels == 0 || width * height <= max_pixels;
  }
};

// The input checks are tables of named rules (conversions.cpp), applied in
// order; the first rule a message breaks throws InputError naming the topic.

/// Checks an image message's layout against its buffer: a known encoding, a
/// non-empty size of at most limits.max_pixels pixels, step >= width * bytes
/// per pixel, height * step == data.size(), little-endian multi-byte data.
void checkImageLayout(const sensor_msgs::Image& msg, const std::string& topic,
                      const MessageLimits& limits);

/// Checks a header: a non-zero, normalized stamp (nsec < 1e9).
void checkHeader(const std_msgs::Header& header, const std::string& topic);

/// The names of every input rule (header, image layout, camera_info), for the
/// tests that must cover each.
std::vector<std::string> inputRuleNames();

/// The guide image: rgb8, bgr8, rgba8, bgra8, rgb16, bgr16, rgba16, bgra16 ->
/// 3 planes R, G, B; mono8, 8UC1, mono16, 16UC1 -> 1 plane; values in [0, 1].
/// Reuses `image`'s buffer.
void imageFromMessage(const sensor_msgs::Image& msg, const std::string& topic,
                      ColorImage& image);

/// A normal map at the message's resolution. 32FC3: x, y, z per pixel, NaN or
/// a zero vector = missing; infinite values are an error; every other vector
/// must have |n| within 1 +- unit_tolerance (it is then normalized).
/// 8-bit colour coding (rgb8, 8UC3, bgr8, rgba8, bgra8): c = (n + 1) / 2 * 255
/// with x -> R, y -> G, z -> B, black = missing, normalized after decoding.
/// A map without any valid normal is an error.
void normalsFromMessage(const sensor_msgs::Image& msg, const std::string& topic,
                        double unit_tolerance, NormalMap& normals);

/// A confidence map (32FC1, values in [0, 1]; NaN reads as 0).
void confidenceFromMessage(const sensor_msgs::Image& msg,
                           const std::string& topic, ScalarMap& confidence);

/// K of a camera_info, checked: finite, fx, fy > 0, last row (0, 0, 1), the
/// camera_info's size equal to the image's (a size of 0 x 0 is accepted as
/// "not given"), and finite viewing rays at every pixel of the image
/// (CameraIntrinsics::validateForImage).
CameraIntrinsics intrinsicsFromCameraInfo(const sensor_msgs::CameraInfo& msg,
                                          const std::string& topic,
                                          int image_width, int image_height);

/// Resamples a map of any channel count to width x height. The aspect ratio
/// must be the image's (within 1 %); the topic names the map in the error.
/// Nearest: the source pixel under the target pixel's centre. Bilinear: the
/// valid source neighbours (normals: finite and non-zero; scalars: finite)
/// weighted bilinearly; normals are renormalized; NaN where none is valid.
/// Rows on `threads` threads (the same values on any count); `scratch`, if
/// given, holds the bilinear normals' masked copy of the source (reused
/// across calls).
void resampleMap(const PlanarImage& source, int width, int height,
                 Resampling method, bool is_normal_map,
                 const std::string& topic, PlanarImage& target, int threads = 1,
                 PlanarImage* scratch = nullptr);

/// The fused map as sensor_msgs/Image 32FC3 (x, y, z per pixel).
void normalsToMessage(const NormalMap& normals, const std_msgs::Header& header,
                      sensor_msgs::Image& msg);
/// The colour coding as rgb8: c = (n + 1) / 2 * 255, black where missing.
void normalsToVisMessage(const NormalMap& normals,
                         const std_msgs::Header& header,
                         sensor_msgs::Image& msg);

}  // namespace node
}  // namespace normal_fusion
