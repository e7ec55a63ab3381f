// Files in and out: normal maps, images and camera_info YAML, with OpenCV's
// codecs and yaml-cpp. Every failure becomes an InputError naming the file.
#include "normal_fusion/io.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <vector>

#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace io {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

/// OpenCV (4.6) leaves its OpenEXR codec off unless OPENCV_IO_ENABLE_OPENEXR
/// is set before the codec is first used; a value the user set is kept.
void enableOpenExr() {
  static const bool enabled = [] {
    ::setenv("OPENCV_IO_ENABLE_OPENEXR", "1", 0);
    return true;
  }();
  (void)enabled;
}

/// Lower-case extension with its dot (".exr"), or "" when there is none.
std::string lowerExtension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) {
    return static_cast<char>(std::tolower(c));
  });
  return ext;
}

bool isFloatExtension(const std::string& path) {
  const std::string ext = lowerExtension(path);
  return ext == ".exr" || ext == ".pfm";
}

std::string depthName(int depth) {
  switch (depth) {
    case CV_8U:
      return "8-bit unsigned";
    case CV_8S:
      return "8-bit signed";
    case CV_16U:
      return "16-bit unsigned";
    case CV_16S:
      return "16-bit signed";
    case CV_32S:
      return "32-bit integer";
    case CV_32F:
      return "32-bit float";
    case CV_64F:
      return "64-bit float";
    case CV_16F:
      return "16-bit float";
    default:
      return "depth " + std::to_string(depth);
  }
}

[[noreturn]] void fail(const std::string& path, const std::string& problem) {
  throw InputError("'" + path + "': " + problem);
}

/// Reads a file as it is stored (depth and channel count kept).
cv::Mat readUnchanged(const std::string& path) {
  enableOpenExr();
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    fail(path, "no such file (expected a readable image file)");
  }
  cv::Mat mat;
  try {
    mat = cv::imread(path, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    fail(path, std::string("could not decode the image: ") + e.err);
  }
  if (mat.empty()) {
    fail(path,
         "could not decode the image (unknown or corrupt format, or a codec "
         "OpenCV was built without)");
  }
  return mat;
}

/// Throws unless the directory a file is to be written to exists (OpenCV
/// would only print a message and return false).
void checkDirectory(const std::string& path) {
  const std::filesystem::path parent =
      std::filesystem::path(path).parent_path();
  std::error_code ec;
  if (!parent.empty() && !std::filesystem::is_directory(parent, ec)) {
    fail(path, "cannot write: the directory '" + parent.string() +
                   "' does not exist");
  }
}

/// Writes a matrix; throws when OpenCV refuses or fails.
void writeMat(const std::string& path, const cv::Mat& mat,
              const std::vector<int>& params = {}) {
  enableOpenExr();
  checkDirectory(path);
  bool written = false;
  try {
    written = cv::imwrite(path, mat, params);
  } catch (const cv::Exception& e) {
    fail(path, std::string("could not write the image: ") + e.err);
  }
  if (!written) {
    fail(path,
         "could not write the image (check the directory and the extension)");
  }
}

/// Scale that maps the largest value of an integer depth to 1.
double unitScale(const cv::Mat& mat, const std::string& path,
                 const std::string& what) {
  if (mat.depth() == CV_8U) return 1.0 / 255.0;
  if (mat.depth() == CV_16U) return 1.0 / 65535.0;
  fail(path, "expected an 8- or 16-bit unsigned " + what + ", found " +
                 depthName(mat.depth()));
}

/// Copies an 8-bit picture (1 or 3 planes in [0, 1], R, G, B order) into a
/// cv::Mat in OpenCV's B, G, R order; NaN becomes 0.
cv::Mat toPicture(const ColorImage& image, const std::string& path) {
  if (image.empty() || (image.channels() != 1 && image.channels() != 3)) {
    std::ostringstream msg;
    msg << "expected a non-empty image with 1 or 3 planes to write, got "
        << image.width() << "x" << image.height() << " with "
        << image.channels() << " planes";
    fail(path, msg.str());
  }
  const int channels = image.channels();
  cv::Mat mat(image.height(), image.width(), CV_8UC(channels));
  for (int y = 0; y < image.height(); ++y) {
    std::uint8_t* row = mat.ptr<std::uint8_t>(y);
    for (int x = 0; x < image.width(); ++x) {
      for (int c = 0; c < channels; ++c) {
        const float v = image.at(c, y, x);
        // Plane c (R, G, B) goes to OpenCV channel channels-1-c (B, G, R).
        const float clamped = v == v ? std::clamp(v, 0.0f, 1.0f) : 0.0f;
        row[x * channels + (channels - 1 - c)] =
            static_cast<std::uint8_t>(std::lround(clamped * 255.0f));
      }
    }
  }
  return mat;
}

/// Checks that a float map about to be written has the expected plane count.
void checkFloatMap(const std::string& path, const PlanarImage& map,
                   int channels, const std::string& what) {
  if (map.empty() || map.channels() != channels) {
    std::ostringstream msg;
    msg << "expected a non-empty " << what << " with " << channels
        << " plane(s) to write, got " << map.width() << "x" << map.height()
        << " with " << map.channels() << " plane(s)";
    fail(path, msg.str());
  }
  if (!isFloatExtension(path)) {
    fail(path, "expected the extension .exr or .pfm for a float " + what +
                   ", found '" + lowerExtension(path) + "'");
  }
}

/// Writes planes as one float image, plane c to OpenCV channel c.
void writeFloatPlanes(const std::string& path, const PlanarImage& map) {
  std::vector<cv::Mat> planes;
  for (int c = 0; c < map.channels(); ++c) {
    planes.emplace_back(map.height(), map.width(), CV_32FC1,
                        const_cast<float*>(map.plane(c)));
  }
  cv::Mat mat;
  cv::merge(planes, mat);
  std::vector<int> params;
  if (lowerExtension(path) == ".exr") {
    params = {cv::IMWRITE_EXR_TYPE, cv::IMWRITE_EXR_TYPE_FLOAT};
  }
  writeMat(path, mat, params);
}

// ---- camera_info YAML ------------------------------------------------------

YAML::Node requireKey(const YAML::Node& parent, const std::string& key,
                      const std::string& context, const std::string& path) {
  if (!parent.IsMap() || !parent[key]) {
    fail(path, "camera_info: missing key '" + context + key + "'");
  }
  return parent[key];
}

template <typename T>
T readScalar(const YAML::Node& parent, const std::string& key,
             const std::string& context, const std::string& path,
             const std::string& expected) {
  const YAML::Node node = requireKey(parent, key, context, path);
  try {
    return node.as<T>();
  } catch (const YAML::Exception&) {
    fail(path, "camera_info: key '" + context + key + "': expected " +
                   expected + ", found '" + YAML::Dump(node) + "'");
  }
}

/// Reads {rows, cols, data} and checks its shape.
std::vector<double> readMatrix(const YAML::Node& root, const std::string& key,
                               int rows, int cols, const std::string& path) {
  const YAML::Node matrix = requireKey(root, key, "", path);
  const int found_rows =
      readScalar<int>(matrix, "rows", key + ".", path, "an integer");
  const int found_cols =
      readScalar<int>(matrix, "cols", key + ".", path, "an integer");
  const auto data = readScalar<std::vector<double>>(matrix, "data", key + ".",
                                                    path, "a list of numbers");
  if (found_rows != rows || found_cols != cols ||
      data.size() != static_cast<std::size_t>(rows * cols)) {
    std::ostringstream msg;
    msg << "camera_info: '" << key << "': expected " << rows << "x" << cols
        << " with " << rows * cols << " numbers, found " << found_rows << "x"
        << found_cols << " with " << data.size() << " numbers";
    fail(path, msg.str());
  }
  return data;
}

}  // namespace

NormalMap readNormalMap(const std::string& path) {
  const cv::Mat mat = readUnchanged(path);
  const int width = mat.cols;
  const int height = mat.rows;
  NormalMap normals(width, height, 3);
  if (mat.depth() == CV_32F || mat.depth() == CV_64F || mat.depth() == CV_16F) {
    if (mat.channels() != 3) {
      fail(path,
           "expected a float normal map with 3 channels (x, y, z), found " +
               std::to_string(mat.channels()));
    }
    cv::Mat mat_f;
    mat.convertTo(mat_f, CV_32F);
    for (int y = 0; y < height; ++y) {
      const float* row = mat_f.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        // Channel c of the file is component c of the normal (no BGR swap).
        for (int c = 0; c < 3; ++c) normals.at(c, y, x) = row[3 * x + c];
      }
    }
    return normals;
  }
  if (mat.channels() != 3 && mat.channels() != 4) {
    fail(path,
         "expected a colour-coded normal map with 3 channels (or 4, alpha "
         "ignored), found " +
             std::to_string(mat.channels()));
  }
  const double scale = unitScale(mat, path, "colour-coded normal map");
  cv::Mat mat_f;
  mat.convertTo(mat_f, CV_32F, scale);
  const int stride = mat.channels();
  for (int y = 0; y < height; ++y) {
    const float* row = mat_f.ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      const float* px = row + stride * x;
      // OpenCV stores B, G, R: x comes from R, y from G, z from B.
      const float r = px[2], g = px[1], b = px[0];
      if (r == 0.0f && g == 0.0f && b == 0.0f) {
        // Black marks a missing normal.
        for (int c = 0; c < 3; ++c) normals.at(c, y, x) = kNaN;
        continue;
      }
      // n = 2 c - 1, then normalized (undoes the quantization of the length).
      const float n[3] = {2.0f * r - 1.0f, 2.0f * g - 1.0f, 2.0f * b - 1.0f};
      const float len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
      for (int c = 0; c < 3; ++c) {
        normals.at(c, y, x) = len > 1e-6f ? n[c] / len : kNaN;
      }
    }
  }
  return normals;
}

void writeNormalMap(const std::string& path, const NormalMap& normals) {
  checkFloatMap(path, normals, 3, "normal map");
  writeFloatPlanes(path, normals);
}

ScalarMap readScalarMap(const std::string& path) {
  const cv::Mat mat = readUnchanged(path);
  if (mat.channels() != 1) {
    fail(path, "expected a single-channel (grey) scalar map, found " +
                   std::to_string(mat.channels()) + " channels");
  }
  cv::Mat mat_f;
  if (mat.depth() == CV_32F || mat.depth() == CV_64F || mat.depth() == CV_16F) {
    mat.convertTo(mat_f, CV_32F);
  } else {
    mat.convertTo(mat_f, CV_32F, unitScale(mat, path, "or float scalar map"));
  }
  ScalarMap values(mat.cols, mat.rows, 1);
  for (int y = 0; y < mat.rows; ++y) {
    std::copy_n(mat_f.ptr<float>(y), mat.cols, values.plane(0) + y * mat.cols);
  }
  return values;
}

void writeScalarMap(const std::string& path, const ScalarMap& values) {
  checkFloatMap(path, values, 1, "scalar map");
  writeFloatPlanes(path, values);
}

ScalarMap readDepthMap(const std::string& path) {
  const cv::Mat mat = readUnchanged(path);
  if (mat.channels() != 1) {
    fail(path, "expected a single-channel depth image, found " +
                   std::to_string(mat.channels()) + " channels");
  }
  ScalarMap depth_m;
  if (mat.depth() == CV_16U) {
    // REP 118 16UC1: millimetres, 0 = no depth.
    depth::depthFromMillimetres(mat.data, mat.cols, mat.rows, mat.step[0],
                                depth_m);
  } else if (mat.depth() == CV_32F || mat.depth() == CV_64F ||
             mat.depth() == CV_16F) {
    // REP 118 32FC1: metres; NaN, 0, negative, infinite = no depth.
    cv::Mat mat_f;
    mat.convertTo(mat_f, CV_32F);
    depth::depthFromMetres(mat_f.data, mat_f.cols, mat_f.rows, mat_f.step[0],
                           depth_m);
  } else {
    fail(path,
         "expected a 16-bit depth image in millimetres or a float one in "
         "metres, found " +
             depthName(mat.depth()));
  }
  return depth_m;
}

void writeDepthMap(const std::string& path, const ScalarMap& depth_m) {
  if (depth_m.empty() || depth_m.channels() != 1) {
    fail(path, "expected a non-empty depth map with 1 plane to write");
  }
  if (isFloatExtension(path)) {
    writeFloatPlanes(path, depth_m);
    return;
  }
  if (lowerExtension(path) != ".png") {
    fail(path,
         "expected the extension .png (16-bit millimetres), .exr or "
         ".pfm (float metres) for a depth map, found '" +
             lowerExtension(path) + "'");
  }
  cv::Mat mm(depth_m.height(), depth_m.width(), CV_16UC1);
  for (int y = 0; y < depth_m.height(); ++y) {
    auto* row = mm.ptr<std::uint16_t>(y);
    for (int x = 0; x < depth_m.width(); ++x) {
      // Metres to rounded millimetres; no depth (or out of range) = 0.
      const double v = std::round(depth_m.at(0, y, x) * 1000.0);
      row[x] = v >= 1.0 && v <= 65535.0 ? static_cast<std::uint16_t>(v) : 0;
    }
  }
  writeMat(path, mm);
}

ColorImage colorCode(const NormalMap& normals) {
  if (normals.channels() != 3) {
    throw InputError("colorCode: expected a normal map with 3 planes, got " +
                     std::to_string(normals.channels()));
  }
  ColorImage picture(normals.width(), normals.height(), 3, 0.0f);
  for (std::size_t i = 0; i < normals.pixelCount(); ++i) {
    const float nx = normals.plane(0)[i];
    const float ny = normals.plane(1)[i];
    const float nz = normals.plane(2)[i];
    if (!isValidNormal(nx, ny, nz)) continue;  // black = missing
    const float n[3] = {nx, ny, nz};
    for (int c = 0; c < 3; ++c) picture.plane(c)[i] = colorCodeComponent(n[c]);
  }
  return picture;
}

void writeNormalPicture(const std::string& path, const NormalMap& normals) {
  if (normals.empty() || normals.channels() != 3) {
    fail(path, "expected a non-empty normal map with 3 planes to write, got " +
                   std::to_string(normals.channels()) + " plane(s)");
  }
  writeMat(path, toPicture(colorCode(normals), path));
}

ColorImage readImage(const std::string& path) {
  const cv::Mat mat = readUnchanged(path);
  const int channels = mat.channels();
  if (channels != 1 && channels != 3 && channels != 4) {
    fail(path,
         "expected a grey (1 channel) or colour (3 or 4 channels) image, "
         "found " +
             std::to_string(channels) + " channels");
  }
  const double scale = unitScale(mat, path, "image");
  cv::Mat mat_f;
  mat.convertTo(mat_f, CV_32F, scale);
  const int planes = channels == 1 ? 1 : 3;
  ColorImage image(mat.cols, mat.rows, planes);
  for (int y = 0; y < mat.rows; ++y) {
    const float* row = mat_f.ptr<float>(y);
    for (int x = 0; x < mat.cols; ++x) {
      // OpenCV channel order B, G, R(, A) -> planes R, G, B; alpha dropped.
      for (int c = 0; c < planes; ++c) {
        image.at(c, y, x) = row[channels * x + (planes - 1 - c)];
      }
    }
  }
  return image;
}

void writeImage(const std::string& path, const ColorImage& image) {
  writeMat(path, toPicture(image, path));
}

void writeHeatmap(const std::string& path, const ScalarMap& values, double lo,
                  double hi) {
  if (values.empty() || values.channels() != 1) {
    fail(path,
         "expected a non-empty scalar map with 1 plane for a heatmap, got " +
             std::to_string(values.channels()) + " plane(s)");
  }
  if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi)) {
    std::ostringstream msg;
    msg << "heatmap range: expected finite lo < hi, got [" << lo << ", " << hi
        << "]";
    throw ParameterError(msg.str());
  }
  const int width = values.width();
  const int height = values.height();
  cv::Mat levels(height, width, CV_8UC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const double v = values.at(0, y, x);
      // t = (v - lo) / (hi - lo), clamped to [0, 1], quantized to 0..255.
      const double t =
          std::isnan(v) ? 0.0 : std::clamp((v - lo) / (hi - lo), 0.0, 1.0);
      levels.at<std::uint8_t>(y, x) =
          static_cast<std::uint8_t>(std::lround(t * 255.0));
    }
  }
  cv::Mat colours;
  cv::applyColorMap(levels, colours, cv::COLORMAP_INFERNO);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      if (std::isnan(values.at(0, y, x)))
        colours.at<cv::Vec3b>(y, x) = cv::Vec3b(0, 0, 0);
    }
  }
  writeMat(path, colours);
}

CameraIntrinsics readCameraInfo(const std::string& path, int* width,
                                int* height) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    fail(path, "no such file (expected a camera_info YAML file)");
  }
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    fail(path, std::string("camera_info: not valid YAML: ") + e.what());
  }
  if (!root.IsMap()) {
    fail(path,
         "camera_info: expected a YAML mapping with image_width, "
         "image_height and camera_matrix");
  }
  const int image_width =
      readScalar<int>(root, "image_width", "", path, "an integer");
  const int image_height =
      readScalar<int>(root, "image_height", "", path, "an integer");
  if (image_width <= 0 || image_height <= 0) {
    std::ostringstream msg;
    msg << "camera_info: expected a positive image size, found " << image_width
        << "x" << image_height;
    fail(path, msg.str());
  }
  const std::vector<double> data =
      readMatrix(root, "camera_matrix", 3, 3, path);
  CameraIntrinsics K;
  std::copy(data.begin(), data.end(), K.K.begin());
  try {
    K.validate();
  } catch (const InputError& e) {
    fail(path, e.what());
  }
  if (width != nullptr) *width = image_width;
  if (height != nullptr) *height = image_height;
  return K;
}

void writeCameraInfo(const std::string& path, const CameraIntrinsics& K,
                     int width, int height, const std::string& camera_name) {
  try {
    K.validate();
  } catch (const InputError& e) {
    fail(path, e.what());
  }
  if (width <= 0 || height <= 0) {
    std::ostringstream msg;
    msg << "camera_info: expected a positive image size, got " << width << "x"
        << height;
    fail(path, msg.str());
  }
  const auto matrix = [](YAML::Emitter& out, const char* key, int rows,
                         int cols, const std::vector<double>& data) {
    out << YAML::Key << key << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "rows" << YAML::Value << rows;
    out << YAML::Key << "cols" << YAML::Value << cols;
    out << YAML::Key << "data" << YAML::Value << YAML::Flow << data;
    out << YAML::EndMap;
  };
  const std::vector<double> k(K.K.begin(), K.K.end());
  // Rectified pinhole camera: no distortion, R = I, P = [K | 0].
  const std::vector<double> p = {k[0], k[1], k[2], 0.0,  k[3], k[4],
                                 k[5], 0.0,  k[6], k[7], k[8], 0.0};
  YAML::Emitter out;
  out.SetDoublePrecision(std::numeric_limits<double>::max_digits10);
  out << YAML::BeginMap;
  out << YAML::Key << "image_width" << YAML::Value << width;
  out << YAML::Key << "image_height" << YAML::Value << height;
  out << YAML::Key << "camera_name" << YAML::Value << camera_name;
  matrix(out, "camera_matrix", 3, 3, k);
  out << YAML::Key << "distortion_model" << YAML::Value << "plumb_bob";
  matrix(out, "distortion_coefficients", 1, 5, std::vector<double>(5, 0.0));
  matrix(out, "rectification_matrix", 3, 3, {1, 0, 0, 0, 1, 0, 0, 0, 1});
  matrix(out, "projection_matrix", 3, 4, p);
  out << YAML::EndMap;
  if (!out.good()) {
    fail(path, std::string("camera_info: could not format the YAML: ") +
                   out.GetLastError());
  }
  checkDirectory(path);
  std::ofstream file(path);
  file << out.c_str() << "\n";
  file.close();
  if (!file) fail(path, "could not write the camera_info file");
}

}  // namespace io
}  // namespace normal_fusion
