#include "normal_fusion/ros/conversions.h"

#include <cv_bridge/cv_bridge.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>

#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"

namespace normal_fusion {
namespace node {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// What an encoding holds: channel count, bytes per channel, float or not, and
/// where R, G, B sit (for 3- and 4-channel encodings).
struct EncodingInfo {
  int channels = 0;
  int bytes_per_channel = 0;
  bool is_float = false;
  int r = 0, g = 1, b = 2;
};

bool lookupEncoding(const std::string& encoding, EncodingInfo* info) {
  struct Entry {
    const char* name;
    EncodingInfo info;
  };
  static const Entry kEntries[] = {
      {"rgb8", {3, 1, false, 0, 1, 2}},   {"bgr8", {3, 1, false, 2, 1, 0}},
      {"rgba8", {4, 1, false, 0, 1, 2}},  {"bgra8", {4, 1, false, 2, 1, 0}},
      {"rgb16", {3, 2, false, 0, 1, 2}},  {"bgr16", {3, 2, false, 2, 1, 0}},
      {"rgba16", {4, 2, false, 0, 1, 2}}, {"bgra16", {4, 2, false, 2, 1, 0}},
      {"mono8", {1, 1, false, 0, 0, 0}},  {"8UC1", {1, 1, false, 0, 0, 0}},
      {"mono16", {1, 2, false, 0, 0, 0}}, {"16UC1", {1, 2, false, 0, 0, 0}},
      {"8UC3", {3, 1, false, 0, 1, 2}},   {"32FC3", {3, 4, true, 0, 1, 2}},
      {"32FC1", {1, 4, true, 0, 0, 0}},
  };
  for (const Entry& entry : kEntries) {
    if (encoding == entry.name) {
      *info = entry.info;
      return true;
    }
  }
  return false;
}

std::string sizeText(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

/// A checked view of the message as a cv::Mat (no copy).
cv::Mat viewOf(const sensor_msgs::Image& msg, const std::string& topic) {
  checkImageLayout(msg, topic, MessageLimits{0});
  try {
    return cv_bridge::toCvShare(msg, nullptr)->image;
  } catch (const cv_bridge::Exception& e) {
    throw InputError(topic + ": cannot read encoding '" + msg.encoding +
                     "': " + e.what());
  }
}

void requireEncoding(const sensor_msgs::Image& msg, const std::string& topic,
                     std::initializer_list<const char*> accepted) {
  for (const char* name : accepted) {
    if (msg.encoding == name) return;
  }
  std::string list;
  for (const char* name : accepted) list += std::string(" ") + name;
  throw InputError(topic + ": unsupported encoding '" + msg.encoding +
                   "'; expected one of" + list);
}

}  // namespace

namespace {

/// One rule of the arrival checks: empty when the message passes, else what
/// was expected and what came (without the topic, which the caller adds).
template <typename Subject>
struct Rule {
  const char* name;
  std::string (*check)(const Subject&, const MessageLimits&);
};

std::string checkStampZero(const std_msgs::Header& h, const MessageLimits&) {
  return h.stamp.isZero() ? "the stamp is zero; expected the capture time"
                          : std::string();
}

std::string checkStampNormalized(const std_msgs::Header& h,
                                 const MessageLimits&) {
  if (h.stamp.nsec < 1000000000u) return std::string();
  return "stamp nsec = " + std::to_string(h.stamp.nsec) +
         " is not normalized; expected nsec < 1000000000";
}

const Rule<std_msgs::Header> kHeaderRules[] = {
    {"stamp zero", checkStampZero},
    {"stamp normalized", checkStampNormalized},
};

std::string checkEncoding(const sensor_msgs::Image& msg, const MessageLimits&) {
  EncodingInfo info;
  return lookupEncoding(msg.encoding, &info)
             ? std::string()
             : "unsupported encoding '" + msg.encoding + "'";
}

std::string checkMinimumSize(const sensor_msgs::Image& msg,
                             const MessageLimits&) {
  if (msg.width == 0 || msg.height == 0) {
    return "expected a non-empty image, got " + sizeText(msg.width, msg.height);
  }
  return std::string();
}

std::string checkMaximumSize(const sensor_msgs::Image& msg,
                             const MessageLimits& limits) {
  if (limits.allows(msg.width, msg.height)) return std::string();
  const std::uint64_t pixels =
      static_cast<std::uint64_t>(msg.width) * msg.height;
  std::ostringstream text;
  text << "a " << msg.width << "x" << msg.height << " image (" << pixels
       << " pixels) is larger than max_pixels = " << limits.max_pixels
       << "; frame refused before any allocation";
  return text.str();
}

std::string checkStep(const sensor_msgs::Image& msg, const MessageLimits&) {
  EncodingInfo info;
  lookupEncoding(msg.encoding, &info);
  const std::uint64_t row_bytes = static_cast<std::uint64_t>(msg.width) *
                                  info.channels * info.bytes_per_channel;
  if (msg.step >= row_bytes) return std::string();
  std::ostringstream text;
  text << "step " << msg.step << " is shorter than a row of " << msg.width
       << " " << msg.encoding << " pixels (" << row_bytes << " bytes)";
  return text.str();
}

std::string checkDataSize(const sensor_msgs::Image& msg, const MessageLimits&) {
  const std::uint64_t expected =
      static_cast<std::uint64_t>(msg.height) * msg.step;
  if (expected == msg.data.size()) return std::string();
  std::ostringstream text;
  text << "expected height * step = " << msg.height << " * " << msg.step
       << " = " << expected << " bytes of data, got " << msg.data.size();
  return text.str();
}

std::string checkEndianness(const sensor_msgs::Image& msg,
                            const MessageLimits&) {
  EncodingInfo info;
  lookupEncoding(msg.encoding, &info);
  if (!msg.is_bigendian || info.bytes_per_channel == 1) return std::string();
  return "big-endian " + msg.encoding +
         " data is not supported; expected little-endian";
}

// In this order: each rule may rely on the ones before it (a known encoding,
// a size within the limits).
const Rule<sensor_msgs::Image> kImageRules[] = {
    {"encoding", checkEncoding},        {"minimum size", checkMinimumSize},
    {"maximum size", checkMaximumSize}, {"step", checkStep},
    {"data size", checkDataSize},       {"endianness", checkEndianness},
};

template <typename Subject, std::size_t N>
void applyRules(const Rule<Subject> (&rules)[N], const Subject& subject,
                const MessageLimits& limits, const std::string& topic) {
  for (const Rule<Subject>& rule : rules) {
    const std::string problem = rule.check(subject, limits);
    if (!problem.empty()) throw InputError(topic + ": " + problem);
  }
}

}  // namespace

void checkImageLayout(const sensor_msgs::Image& msg, const std::string& topic,
                      const MessageLimits& limits) {
  applyRules(kImageRules, msg, limits, topic);
}

void checkHeader(const std_msgs::Header& header, const std::string& topic) {
  applyRules(kHeaderRules, header, MessageLimits(), topic);
}

void imageFromMessage(const sensor_msgs::Image& msg, const std::string& topic,
                      ColorImage& image) {
  requireEncoding(msg, topic,
                  {"rgb8", "bgr8", "rgba8", "bgra8", "mono8", "mono16", "8UC1",
                   "16UC1", "rgb16", "bgr16", "rgba16", "bgra16"});
  const cv::Mat view = viewOf(msg, topic);
  EncodingInfo info;
  lookupEncoding(msg.encoding, &info);
  const int W = static_cast<int>(msg.width), H = static_cast<int>(msg.height);
  const int planes = info.channels == 1 ? 1 : 3;
  image.resize(W, H, planes);
  const int source_channel[3] = {info.r, info.g, info.b};
  for (int y = 0; y < H; ++y) {
    for (int c = 0; c < planes; ++c) {
      float* out = image.plane(c) + static_cast<std::size_t>(y) * W;
      const int sc = source_channel[c];
      if (info.bytes_per_channel == 1) {
        const std::uint8_t* row = view.ptr<std::uint8_t>(y);
        // 8-bit value to [0, 1].
        for (int x = 0; x < W; ++x) {
          out[x] = row[x * info.channels + sc] * (1.0f / 255.0f);
        }
      } else {
        const std::uint16_t* row = view.ptr<std::uint16_t>(y);
        // 16-bit value to [0, 1].
        for (int x = 0; x < W; ++x) {
          out[x] = row[x * info.channels + sc] * (1.0f / 65535.0f);
        }
      }
    }
  }
}

namespace {

/// What decoding a normal map found, for the errors after it.
struct DecodeCounts {
  long valid = 0, non_unit = 0, infinite = 0;
  int first_x = -1, first_y = -1;  ///< the first non-unit normal
  float first_length = 0.0f;
};

/// Decodes one row of a 32FC3 map: NaN = missing, unit length within the
/// tolerance normalized exactly, infinite or non-unit values counted.
void decodeFloatRow(const float* row, int W, int y, double unit_tolerance,
                    float* nx, float* ny, float* nz, DecodeCounts& counts) {
  for (int x = 0; x < W; ++x) {
    const float v[3] = {row[3 * x], row[3 * x + 1], row[3 * x + 2]};
    float out[3] = {kNaN, kNaN, kNaN};
    if (std::isinf(v[0]) || std::isinf(v[1]) || std::isinf(v[2])) {
      ++counts.infinite;
    } else if (isValidNormal(v[0], v[1], v[2])) {
      const float length = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      if (std::abs(length - 1.0f) > unit_tolerance) {
        if (counts.non_unit++ == 0) {
          counts.first_x = x;
          counts.first_y = y;
          counts.first_length = length;
        }
      } else {
        // Unit length within the tolerance: normalize exactly.
        for (int c = 0; c < 3; ++c) out[c] = v[c] / length;
        ++counts.valid;
      }
    }
    nx[x] = out[0];
    ny[x] = out[1];
    nz[x] = out[2];
  }
}

/// Decodes one row of a colour-coded 8-bit map: black = missing.
void decodeByteRow(const std::uint8_t* row, int W, const EncodingInfo& info,
                   float* nx, float* ny, float* nz, DecodeCounts& counts) {
  for (int x = 0; x < W; ++x) {
    const std::uint8_t* p = row + x * info.channels;
    const int r = p[info.r], g = p[info.g], b = p[info.b];
    float out[3] = {kNaN, kNaN, kNaN};
    if (r != 0 || g != 0 || b != 0) {
      // Decode n = c / 255 * 2 - 1, then normalize.
      const float v[3] = {r * (2.0f / 255.0f) - 1.0f,
                          g * (2.0f / 255.0f) - 1.0f,
                          b * (2.0f / 255.0f) - 1.0f};
      const float length = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      if (length > 1e-3f) {
        for (int c = 0; c < 3; ++c) out[c] = v[c] / length;
        ++counts.valid;
      }
    }
    nx[x] = out[0];
    ny[x] = out[1];
    nz[x] = out[2];
  }
}

void throwOnDecodeProblems(const DecodeCounts& counts, int W, int H,
                           double unit_tolerance, const std::string& topic) {
  if (counts.infinite > 0) {
    throw InputError(topic + ": " + std::to_string(counts.infinite) +
                     " pixels hold infinite values; expected finite x, y, z "
                     "(NaN = missing)");
  }
  if (counts.non_unit > 0) {
    std::ostringstream text;
    text << topic << ": " << counts.non_unit << " of " << W * H
         << " normals are not unit vectors (|n| = " << counts.first_length
         << " at (" << counts.first_x << ", " << counts.first_y
         << ")); expected |n| within 1 +- " << unit_tolerance;
    throw InputError(text.str());
  }
  if (counts.valid == 0) {
    throw InputError(topic + ": no valid normal in the " + sizeText(W, H) +
                     " map (all NaN or zero); expected at least one");
  }
}

}  // namespace

void normalsFromMessage(const sensor_msgs::Image& msg, const std::string& topic,
                        double unit_tolerance, NormalMap& normals) {
  requireEncoding(msg, topic,
                  {"32FC3", "rgb8", "8UC3", "bgr8", "rgba8", "bgra8"});
  const cv::Mat view = viewOf(msg, topic);
  EncodingInfo info;
  lookupEncoding(msg.encoding, &info);
  const int W = static_cast<int>(msg.width), H = static_cast<int>(msg.height);
  normals.resize(W, H, 3);
  DecodeCounts counts;
  for (int y = 0; y < H; ++y) {
    const std::size_t row_start = static_cast<std::size_t>(y) * W;
    float* nx = normals.plane(0) + row_start;
    float* ny = normals.plane(1) + row_start;
    float* nz = normals.plane(2) + row_start;
    if (info.is_float) {
      decodeFloatRow(view.ptr<float>(y), W, y, unit_tolerance, nx, ny, nz,
                     counts);
    } else {
      decodeByteRow(view.ptr<std::uint8_t>(y), W, info, nx, ny, nz, counts);
    }
  }
  throwOnDecodeProblems(counts, W, H, unit_tolerance, topic);
}

void confidenceFromMessage(const sensor_msgs::Image& msg,
                           const std::string& topic, ScalarMap& confidence) {
  requireEncoding(msg, topic, {"32FC1"});
  const cv::Mat view = viewOf(msg, topic);
  const int W = static_cast<int>(msg.width), H = static_cast<int>(msg.height);
  confidence.resize(W, H, 1);
  long outside = 0;
  float first_bad = 0.0f;
  for (int y = 0; y < H; ++y) {
    const float* row = view.ptr<float>(y);
    float* out = confidence.plane(0) + static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) {
      const float c = row[x];
      if (std::isnan(c)) {
        out[x] = 0.0f;
      } else if (c < 0.0f || c > 1.0f) {
        if (outside++ == 0) first_bad = c;
        out[x] = 0.0f;
      } else {
        out[x] = c;
      }
    }
  }
  if (outside > 0) {
    std::ostringstream text;
    text << topic << ": " << outside
         << " confidence values outside [0, 1] (e.g. " << first_bad
         << "); expected values in [0, 1]";
    throw InputError(text.str());
  }
}

namespace {

/// A camera_info with the size of the image it must describe.
struct CameraInfoForImage {
  const sensor_msgs::CameraInfo& msg;
  int width, height;
};

std::string checkKFinite(const CameraInfoForImage& c, const MessageLimits&) {
  for (int i = 0; i < 9; ++i) {
    if (!std::isfinite(c.msg.K[i])) {
      return "K[" + std::to_string(i) + "] is not finite; expected a finite K";
    }
  }
  return std::string();
}

std::string checkKShape(const CameraInfoForImage& c, const MessageLimits&) {
  const auto& K = c.msg.K;
  if (K[0] > 0.0 && K[4] > 0.0 && K[8] == 1.0 && K[6] == 0.0 && K[7] == 0.0) {
    return std::string();
  }
  std::ostringstream text;
  text << "expected K with fx, fy > 0 and last row (0, 0, 1), got"
       << " fx = " << K[0] << ", fy = " << K[4] << ", last row (" << K[6]
       << ", " << K[7] << ", " << K[8] << ")";
  return text.str();
}

std::string checkInfoSize(const CameraInfoForImage& c, const MessageLimits&) {
  if ((c.msg.width == 0 && c.msg.height == 0) ||
      (static_cast<int>(c.msg.width) == c.width &&
       static_cast<int>(c.msg.height) == c.height)) {
    return std::string();
  }
  return "camera_info is for a " + sizeText(c.msg.width, c.msg.height) +
         " image; expected the image's size " + sizeText(c.width, c.height);
}

std::string checkKRays(const CameraInfoForImage& c, const MessageLimits&) {
  CameraIntrinsics K;
  for (int i = 0; i < 9; ++i) K.K[i] = c.msg.K[i];
  try {
    K.validateForImage(c.width, c.height);
  } catch (const Error& e) {
    return e.what();
  }
  return std::string();
}

const Rule<CameraInfoForImage> kCameraInfoRules[] = {
    {"K finite", checkKFinite},
    {"K shape", checkKShape},
    {"camera_info size", checkInfoSize},
    {"K rays", checkKRays},
};

}  // namespace

CameraIntrinsics intrinsicsFromCameraInfo(const sensor_msgs::CameraInfo& msg,
                                          const std::string& topic,
                                          int image_width, int image_height) {
  applyRules(kCameraInfoRules,
             CameraInfoForImage{msg, image_width, image_height},
             MessageLimits(), topic);
  CameraIntrinsics K;
  for (int i = 0; i < 9; ++i) K.K[i] = msg.K[i];
  return K;
}

void normalsToMessage(const NormalMap& normals, const std_msgs::Header& header,
                      sensor_msgs::Image& msg) {
  const int W = normals.width(), H = normals.height();
  msg.header = header;
  msg.width = W;
  msg.height = H;
  msg.encoding = "32FC3";
  msg.is_bigendian = 0;
  msg.step = static_cast<std::uint32_t>(W * 3 * sizeof(float));
  msg.data.resize(static_cast<std::size_t>(msg.step) * H);
  const std::size_t n = normals.pixelCount();
  float pixel[3];
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) pixel[c] = normals.plane(c)[i];
    std::memcpy(&msg.data[i * sizeof(pixel)], pixel, sizeof(pixel));
  }
}

void normalsToVisMessage(const NormalMap& normals,
                         const std_msgs::Header& header,
                         sensor_msgs::Image& msg) {
  const int W = normals.width(), H = normals.height();
  msg.header = header;
  msg.width = W;
  msg.height = H;
  msg.encoding = "rgb8";
  msg.is_bigendian = 0;
  msg.step = static_cast<std::uint32_t>(W * 3);
  msg.data.resize(static_cast<std::size_t>(msg.step) * H);
  const std::size_t n = normals.pixelCount();
  for (std::size_t i = 0; i < n; ++i) {
    const float x = normals.plane(0)[i], y = normals.plane(1)[i],
                z = normals.plane(2)[i];
    const bool ok = isValidNormal(x, y, z);
    const float v[3] = {x, y, z};
    for (int c = 0; c < 3; ++c) {
      // The library's colour code; black where missing.
      msg.data[3 * i + c] = ok ? io::colorCodeByte(v[c]) : 0;
    }
  }
}

std::vector<std::string> inputRuleNames() {
  std::vector<std::string> names;
  for (const auto& rule : kHeaderRules) names.push_back(rule.name);
  for (const auto& rule : kImageRules) names.push_back(rule.name);
  for (const auto& rule : kCameraInfoRules) names.push_back(rule.name);
  return names;
}

}  // namespace node
}  // namespace normal_fusion
