// The Castle sequence's frames: depth, image, pose and intrinsics files, and
// the ground truth rendered from the model (castle_model.cpp).
#include "eval/castle.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "eval/castle_internal.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/geometry.h"
#include "normal_fusion/io.h"

namespace normal_fusion {
namespace castle {
namespace internal {

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("castle: cannot open '" + path + "'");
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

std::vector<double> numbersIn(const std::string& text) {
  std::vector<double> values;
  const char* p = text.c_str();
  const char* end = p + text.size();
  while (p < end) {
    if (std::isdigit(static_cast<unsigned char>(*p)) || *p == '-' ||
        *p == '+' || *p == '.') {
      char* next = nullptr;
      const double v = std::strtod(p, &next);
      if (next != p) {
        values.push_back(v);
        p = next;
        continue;
      }
    }
    ++p;
  }
  return values;
}

bool between(const std::string& text, const std::string& open,
             const std::string& close, std::size_t from, std::string* inner,
             std::size_t* after) {
  const std::size_t a = text.find(open, from);
  if (a == std::string::npos) return false;
  const std::size_t b = text.find(close, a + open.size());
  if (b == std::string::npos) return false;
  *inner = text.substr(a + open.size(), b - a - open.size());
  if (after != nullptr) *after = b + close.size();
  return true;
}

}  // namespace internal

namespace {

namespace fs = std::filesystem;
using internal::between;
using internal::numbersIn;
using internal::readText;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
/// Largest side of a depth file we accept (guards against a corrupt header).
constexpr std::uint32_t kMaxDepthSide = 16384;

std::string numbered(const std::string& dir, const char* pattern, int number) {
  char name[64];
  std::snprintf(name, sizeof(name), pattern, number);
  return (fs::path(dir) / name).string();
}

std::string imagePath(const std::string& dir, int n) {
  return numbered(dir, "Images/Image_%04d.pgm", n);
}
std::string depthPath(const std::string& dir, int n) {
  return numbered(dir, "Depth/Depth_%04d.bin", n);
}
std::string posePath(const std::string& dir, int n) {
  return numbered(dir, "CameraPose/Camera_%03d.txt", n);
}

/// Bilinear sample of plane 0 at (u, v), clamped to the image.
float bilinear(const ColorImage& image, double u, double v) {
  const int W = image.width(), H = image.height();
  u = std::min(std::max(u, 0.0), W - 1.0);
  v = std::min(std::max(v, 0.0), H - 1.0);
  const int x0 = std::min(static_cast<int>(u), W - 2 < 0 ? 0 : W - 2);
  const int y0 = std::min(static_cast<int>(v), H - 2 < 0 ? 0 : H - 2);
  const int x1 = std::min(x0 + 1, W - 1), y1 = std::min(y0 + 1, H - 1);
  const double fx = u - x0, fy = v - y0;
  const double top = (1 - fx) * image.at(0, y0, x0) + fx * image.at(0, y0, x1);
  const double bottom =
      (1 - fx) * image.at(0, y1, x0) + fx * image.at(0, y1, x1);
  return static_cast<float>((1 - fy) * top + fy * bottom);
}

PlanarImage crop(const PlanarImage& image, int x0, int y0, int width,
                 int height) {
  PlanarImage out(width, height, image.channels());
  for (int c = 0; c < image.channels(); ++c) {
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        out.at(c, y, x) = image.at(c, y0 + y, x0 + x);
      }
    }
  }
  return out;
}

/// The model's normals where its depth agrees with the file's, and the box
/// of the pixels with depth.
struct GroundTruth {
  NormalMap normals;
  int with_depth = 0, agreeing = 0;
  int x_lo = 0, x_hi = -1, y_lo = 0, y_hi = -1;
};

GroundTruth groundTruth(const ScalarMap& depth, const ScalarMap& model_depth,
                        const NormalMap& model_normals, double tolerance_m) {
  const int W = depth.width(), H = depth.height();
  GroundTruth truth;
  truth.normals = NormalMap(W, H, 3, kNaN);
  truth.x_lo = W;
  truth.y_lo = H;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float z = depth.at(0, y, x);
      if (std::isnan(z)) continue;
      ++truth.with_depth;
      truth.x_lo = std::min(truth.x_lo, x);
      truth.x_hi = std::max(truth.x_hi, x);
      truth.y_lo = std::min(truth.y_lo, y);
      truth.y_hi = std::max(truth.y_hi, y);
      const float z_model = model_depth.at(0, y, x);
      if (!(std::fabs(z_model - z) <= tolerance_m)) continue;
      ++truth.agreeing;
      for (int c = 0; c < 3; ++c) {
        truth.normals.at(c, y, x) = model_normals.at(c, y, x);
      }
    }
  }
  return truth;
}

/// Where depth pixel (x, y) at depth z projects in the colour image
/// (X_c = X_d - (kDepthFromColorXM, 0, 0), pinhole K_color).
struct ColorProjection {
  Mat3 K_depth_inv;
  CameraIntrinsics K_color;

  void operator()(int x, int y, double z, double* u, double* v) const {
    const Mat3& Ki = K_depth_inv;
    const double X = z * (Ki[0] * x + Ki[1] * y + Ki[2]) - kDepthFromColorXM;
    const double Y = z * (Ki[3] * x + Ki[4] * y + Ki[5]);
    *u = (K_color.K[0] * X + K_color.K[1] * Y) / z + K_color.K[2];
    *v = K_color.K[4] * Y / z + K_color.K[5];
  }
};

/// Colour pixels no depth point reaches (3 x 3 footprint): the background
/// as the colour camera sees it.
std::vector<unsigned char> reachedPixels(const ScalarMap& depth,
                                         const ColorProjection& project,
                                         int W_color, int H_color) {
  std::vector<unsigned char> reached(
      static_cast<std::size_t>(W_color) * H_color, 0);
  for (int y = 0; y < depth.height(); ++y) {
    for (int x = 0; x < depth.width(); ++x) {
      const float z = depth.at(0, y, x);
      if (std::isnan(z)) continue;
      double u = 0.0, v = 0.0;
      project(x, y, z, &u, &v);
      const int cu = static_cast<int>(std::lround(u));
      const int cv = static_cast<int>(std::lround(v));
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          if (cu + dx < 0 || cu + dx >= W_color || cv + dy < 0 ||
              cv + dy >= H_color) {
            continue;
          }
          reached[static_cast<std::size_t>(cv + dy) * W_color + cu + dx] = 1;
        }
      }
    }
  }
  return reached;
}

/// The guide: the colour camera's image sampled where each depth pixel's
/// point projects.
ColorImage guideImage(const ScalarMap& depth, const ColorImage& image_color,
                      const CameraIntrinsics& K_depth,
                      const CameraIntrinsics& K_color) {
  const int W = depth.width(), H = depth.height();
  const ColorProjection project{K_depth.inverse(), K_color};
  const int W_color = image_color.width(), H_color = image_color.height();
  const std::vector<unsigned char> reached =
      reachedPixels(depth, project, W_color, H_color);
  ColorImage image(W, H, image_color.channels());
  ColorImage plane(W_color, H_color, 1);
  std::vector<float> background;
  for (int c = 0; c < image_color.channels(); ++c) {
    std::copy(image_color.plane(c), image_color.plane(c) + plane.pixelCount(),
              plane.plane(0));
    // Pixels without depth get the median background intensity (sampling
    // them at some depth would copy objects seen beside them).
    background.clear();
    for (std::size_t i = 0; i < reached.size(); ++i) {
      if (!reached[i]) background.push_back(plane.data()[i]);
    }
    float background_value = 0.0f;
    if (!background.empty()) {
      auto mid = background.begin() + background.size() / 2;
      std::nth_element(background.begin(), mid, background.end());
      background_value = *mid;
    }
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        const float z = depth.at(0, y, x);
        if (std::isnan(z)) {
          image.at(c, y, x) = background_value;
          continue;
        }
        double u = 0.0, v = 0.0;
        project(x, y, z, &u, &v);
        image.at(c, y, x) = bilinear(plane, u, v);
      }
    }
  }
  return image;
}

}  // namespace

bool available(const std::string& dir) {
  const fs::path root(dir);
  std::error_code ec;
  for (const char* sub : {"Images", "Depth", "CameraPose", "Config"}) {
    if (!fs::is_directory(root / sub, ec)) return false;
  }
  for (const char* file : {"Models/chateau.wrl", "Models/cube.cao",
                           "Config/chateau.xml", "Config/chateau_depth.xml"}) {
    if (!fs::is_regular_file(root / file, ec)) return false;
  }
  return !frameNumbers(dir).empty();
}

std::vector<int> frameNumbers(const std::string& dir) {
  std::vector<int> numbers;
  std::error_code ec;
  if (!fs::is_directory(fs::path(dir) / "Depth", ec)) return numbers;
  for (const auto& entry :
       fs::directory_iterator(fs::path(dir) / "Depth", ec)) {
    const std::string name = entry.path().filename().string();
    int n = 0;
    char tail = 0;
    if (std::sscanf(name.c_str(), "Depth_%d.bi%c", &n, &tail) != 2 ||
        tail != 'n' || name != fs::path(depthPath(dir, n)).filename()) {
      continue;
    }
    if (fs::is_regular_file(imagePath(dir, n), ec) &&
        fs::is_regular_file(posePath(dir, n), ec)) {
      numbers.push_back(n);
    }
  }
  std::sort(numbers.begin(), numbers.end());
  return numbers;
}

ScalarMap readDepth(const std::string& path, double scale_m) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("castle: cannot open depth file '" + path + "'");
  // Header: height, width as little-endian uint32.
  unsigned char header[8];
  if (!in.read(reinterpret_cast<char*>(header), 8)) {
    throw InputError("castle: '" + path + "': expected an 8-byte header");
  }
  const auto le32 = [&](int at) {
    return static_cast<std::uint32_t>(header[at]) |
           static_cast<std::uint32_t>(header[at + 1]) << 8 |
           static_cast<std::uint32_t>(header[at + 2]) << 16 |
           static_cast<std::uint32_t>(header[at + 3]) << 24;
  };
  const std::uint32_t height = le32(0), width = le32(4);
  if (height == 0 || width == 0 || height > kMaxDepthSide ||
      width > kMaxDepthSide) {
    throw InputError("castle: '" + path + "': expected a size in 1.." +
                     std::to_string(kMaxDepthSide) + ", got " +
                     std::to_string(width) + " x " + std::to_string(height));
  }
  const std::size_t count = static_cast<std::size_t>(width) * height;
  std::vector<unsigned char> raw(2 * count);
  if (!in.read(reinterpret_cast<char*>(raw.data()),
               static_cast<std::streamsize>(raw.size()))) {
    throw InputError("castle: '" + path + "': expected " +
                     std::to_string(2 * count) + " bytes of depth after the " +
                     "header, the file is shorter");
  }
  ScalarMap depth(static_cast<int>(width), static_cast<int>(height), 1);
  float* z = depth.plane(0);
  for (std::size_t i = 0; i < count; ++i) {
    // uint16 little-endian; 0 means no depth.
    const unsigned value = raw[2 * i] | (raw[2 * i + 1] << 8);
    z[i] = value == 0 ? kNaN : static_cast<float>(value * scale_m);
  }
  return depth;
}

synthetic::Pose readPose(const std::string& path) {
  const std::vector<double> m = numbersIn(readText(path));
  if (m.size() < 16) {
    throw InputError("castle: '" + path + "': expected 16 numbers of a 4x4 " +
                     "pose, got " + std::to_string(m.size()));
  }
  if (std::fabs(m[12]) > 1e-9 || std::fabs(m[13]) > 1e-9 ||
      std::fabs(m[14]) > 1e-9 || std::fabs(m[15] - 1.0) > 1e-9) {
    throw InputError("castle: '" + path + "': expected (0 0 0 1) as last row");
  }
  synthetic::Pose pose;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) pose.R[3 * r + c] = m[4 * r + c];
    pose.t[r] = m[4 * r + 3];
  }
  if (!isRotation(pose.R)) {
    throw InputError(notRotationMessage("castle: '" + path + "'"));
  }
  return pose;
}

CameraIntrinsics readIntrinsics(const std::string& xml_path) {
  const std::string text = readText(xml_path);
  std::string camera;
  if (!between(text, "<camera>", "</camera>", 0, &camera, nullptr)) {
    throw InputError("castle: '" + xml_path + "': no <camera> element");
  }
  const auto value = [&](const std::string& tag, bool positive) {
    std::string inner;
    if (!between(camera, "<" + tag + ">", "</" + tag + ">", 0, &inner,
                 nullptr)) {
      throw InputError("castle: '" + xml_path + "': no <" + tag +
                       "> in <camera>");
    }
    const std::vector<double> v = numbersIn(inner);
    if (v.size() != 1 || !std::isfinite(v[0]) || (positive && v[0] <= 0.0)) {
      throw InputError("castle: '" + xml_path + "': <" + tag + "> expected " +
                       (positive ? "a positive number" : "a number") +
                       ", got '" + inner + "'");
    }
    return v[0];
  };
  return CameraIntrinsics(value("px", true), value("py", true),
                          value("u0", false), value("v0", false));
}

Frame loadFrame(const std::string& dir, int number,
                const std::vector<Face>& faces, const LoadSettings& settings) {
  if (!(settings.agreement_tolerance_m >= 0.0)) {
    throw ParameterError("castle: agreement_tolerance_m expected >= 0, got " +
                         std::to_string(settings.agreement_tolerance_m));
  }
  const ScalarMap depth = readDepth(depthPath(dir, number));
  const ColorImage image_color = io::readImage(imagePath(dir, number));
  if (image_color.channels() != 1 && image_color.channels() != 3) {
    throw InputError("castle: expected a grey or colour image");
  }
  const synthetic::Pose T_color_obj = readPose(posePath(dir, number));
  const CameraIntrinsics K_color =
      readIntrinsics((fs::path(dir) / "Config/chateau.xml").string());
  const CameraIntrinsics K_depth =
      readIntrinsics((fs::path(dir) / "Config/chateau_depth.xml").string());

  // Depth camera pose: d_M_o = d_M_c c_M_o, d_M_c a translation along x.
  synthetic::Pose T_depth_obj = T_color_obj;
  T_depth_obj.t[0] += kDepthFromColorXM;

  // Model depth and normals; ground truth where the model explains the depth.
  ScalarMap model_depth;
  NormalMap model_normals;
  renderModel(faces, T_depth_obj, K_depth, depth.width(), depth.height(),
              &model_depth, &model_normals);
  const GroundTruth truth = groundTruth(depth, model_depth, model_normals,
                                        settings.agreement_tolerance_m);
  const ColorImage image = guideImage(depth, image_color, K_depth, K_color);

  Frame frame;
  frame.number = number;
  frame.T_depth_obj = T_depth_obj;
  frame.agreement = truth.with_depth > 0
                        ? static_cast<double>(truth.agreeing) / truth.with_depth
                        : 0.0;
  frame.K = K_depth;
  if (settings.crop_margin < 0 || truth.with_depth == 0) {
    frame.image = image;
    frame.depth = depth;
    frame.normals_gt = truth.normals;
    return frame;
  }
  // Crop to the pixels with depth, grown by the margin; K follows.
  const int W = depth.width(), H = depth.height();
  const int m = settings.crop_margin;
  frame.crop_x = std::max(0, truth.x_lo - m);
  frame.crop_y = std::max(0, truth.y_lo - m);
  const int crop_w = std::min(W - 1, truth.x_hi + m) - frame.crop_x + 1;
  const int crop_h = std::min(H - 1, truth.y_hi + m) - frame.crop_y + 1;
  frame.image = crop(image, frame.crop_x, frame.crop_y, crop_w, crop_h);
  frame.depth = crop(depth, frame.crop_x, frame.crop_y, crop_w, crop_h);
  frame.normals_gt =
      crop(truth.normals, frame.crop_x, frame.crop_y, crop_w, crop_h);
  frame.K.K[2] -= frame.crop_x;
  frame.K.K[5] -= frame.crop_y;
  return frame;
}

}  // namespace castle
}  // namespace normal_fusion
