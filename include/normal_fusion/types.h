// Basic image and camera types of the normal_fusion library (no ROS, no
// OpenCV).
#pragma once

#include <array>
#include <cstddef>
#include <cstdlib>
#include <new>
#include <string>
#include <vector>

#include "normal_fusion/geometry.h"

namespace normal_fusion {

/// Allocator that aligns every buffer to 64 bytes (one cache line, one AVX-512
/// register), so that vectorised kernels may use aligned loads on plane starts.
template <typename T>
struct AlignedAllocator {
  using value_type = T;
  static constexpr std::size_t kAlignment = 64;
  AlignedAllocator() noexcept = default;
  template <typename U>
  AlignedAllocator(const AlignedAllocator<U>&) noexcept {}  // NOLINT
  T* allocate(std::size_t n) {
    const std::size_t bytes =
        ((n * sizeof(T) + kAlignment - 1) / kAlignment) * kAlignment;
    void* p = std::aligned_alloc(kAlignment, bytes == 0 ? kAlignment : bytes);
    if (p == nullptr) throw std::bad_alloc();
    return static_cast<T*>(p);
  }
  void deallocate(T* p, std::size_t) noexcept { std::free(p); }
  template <typename U>
  bool operator==(const AlignedAllocator<U>&) const noexcept {
    return true;
  }
  template <typename U>
  bool operator!=(const AlignedAllocator<U>&) const noexcept {
    return false;
  }
};

/// A float image stored as `channels` contiguous planes of width*height values
/// each (plane-major, then row-major). Plane c, pixel (x, y) lives at
/// data()[c * width * height + y * width + x].
class PlanarImage {
 public:
  PlanarImage() = default;
  PlanarImage(int width, int height, int channels, float fill = 0.0f);

  /// Sets the size; contents are then unspecified. Reallocates when the new
  /// size exceeds the capacity, and when it is below a quarter of it: a
  /// buffer sized for a much larger frame gives its memory back. The same
  /// size never reallocates (a stream of frames of one size allocates once).
  void resize(int width, int height, int channels);
  /// The same, but never gives memory back: for a buffer that smaller sizes
  /// reuse in turn (the levels of one pyramid), sized for the largest of them
  /// by resize() first.
  void resizeKeepingCapacity(int width, int height, int channels);
  /// Bytes of memory the buffer holds (its capacity, not its size).
  std::size_t bytesHeld() const { return data_.capacity() * sizeof(float); }
  void fill(float value);

  int width() const { return width_; }
  int height() const { return height_; }
  int channels() const { return channels_; }
  std::size_t pixelCount() const {
    return static_cast<std::size_t>(width_) * static_cast<std::size_t>(height_);
  }
  bool empty() const { return data_.empty(); }
  bool sameSize(const PlanarImage& other) const {
    return width_ == other.width_ && height_ == other.height_;
  }

  float* plane(int c) { return data_.data() + c * pixelCount(); }
  const float* plane(int c) const { return data_.data() + c * pixelCount(); }
  float* data() { return data_.data(); }
  const float* data() const { return data_.data(); }

  float& at(int c, int y, int x) {
    return data_[c * pixelCount() + static_cast<std::size_t>(y) * width_ + x];
  }
  float at(int c, int y, int x) const {
    return data_[c * pixelCount() + static_cast<std::size_t>(y) * width_ + x];
  }

 private:
  int width_ = 0;
  int height_ = 0;
  int channels_ = 0;
  std::vector<float, AlignedAllocator<float>> data_;
};

/// Three planes x, y, z of unit normals in the camera optical frame
/// (x right, y down, z forward). NaN or (0,0,0) marks a missing normal.
using NormalMap = PlanarImage;
/// One plane of scalars (confidence, weights).
using ScalarMap = PlanarImage;
/// The guide image: one plane (grey) or three planes (R, G, B), values in [0,
/// 1].
using ColorImage = PlanarImage;

/// True when the pixel holds an observation: finite and not the zero vector.
inline bool isValidNormal(float x, float y, float z) {
  const float s = x * x + y * y + z * z;
  return s > 1e-12f && s < 1e30f && x == x && y == y && z == z;
}

/// Pinhole intrinsics K (row-major 3x3), pixel centres at integer (u, v), as in
/// sensor_msgs/CameraInfo. The ray of pixel (u, v) is r = K^-1 (u, v, 1)^T.
struct CameraIntrinsics {
  Mat3 K = kIdentity3;

  CameraIntrinsics() = default;
  CameraIntrinsics(double fx, double fy, double cx, double cy)
      : K{{fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0}} {}

  double fx() const { return K[0]; }
  double fy() const { return K[4]; }
  double cx() const { return K[2]; }
  double cy() const { return K[5]; }

  /// Throws InputError when K has non-finite entries or is singular.
  void validate() const;
  /// validate(), and the viewing rays K^-1 (u, v, 1) of the corners of a
  /// width x height image no farther than 89.99 degrees off the optical axis
  /// (|x / z|, |y / z| <= 1e4), so that every pixel's ray stays finite in
  /// single precision. Throws InputError saying which bound failed.
  void validateForImage(int width, int height) const;
  /// K^-1 (row-major). Calls validate().
  Mat3 inverse() const;
  /// Intrinsics of the same camera at an image scaled by (sx, sy), with the
  /// pixel-centre convention kept: u' = sx (u + 0.5) - 0.5.
  CameraIntrinsics scaled(double sx, double sy) const;
};

/// A 3x3 matrix that maps a producer's normal to the optical frame on input.
/// Presets: "optical" (identity), "optical_flipped" (normals pointing away from
/// the camera: -I), "opengl" (x right, y up, z backward: diag(1, -1, -1)).
struct Orientation {
  std::array<float, 9> M{{1, 0, 0, 0, 1, 0, 0, 0, 1}};

  static Orientation optical();
  static Orientation opticalFlipped();
  static Orientation opengl();
  /// Parses a preset name, or nine comma- or space-separated numbers forming a
  /// signed permutation matrix. Throws ParameterError otherwise.
  static Orientation fromString(const std::string& text);
  /// Throws ParameterError unless M is a signed permutation matrix.
  void validate() const;
};

}  // namespace normal_fusion
