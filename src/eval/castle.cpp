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

#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"

namespace normal_fusion {
namespace castle {
namespace {

namespace fs = std::filesystem;
using Vec3 = std::array<double, 3>;

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

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("castle: cannot open '" + path + "'");
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

double dot(const Vec3& a, const Vec3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/// X' = R X + t of a pose.
Vec3 transform(const synthetic::Pose& T, const Vec3& X) {
  const auto& R = T.R_cam_world;
  return {R[0] * X[0] + R[1] * X[1] + R[2] * X[2] + T.t_cam_world[0],
          R[3] * X[0] + R[4] * X[1] + R[5] * X[2] + T.t_cam_world[1],
          R[6] * X[0] + R[7] * X[1] + R[8] * X[2] + T.t_cam_world[2]};
}

/// Newell's normal of a polygon: its direction is the plane normal, its
/// length twice the area.
Vec3 newellNormal(const std::vector<Vec3>& polygon) {
  Vec3 n{0.0, 0.0, 0.0};
  for (std::size_t i = 0; i < polygon.size(); ++i) {
    const Vec3& a = polygon[i];
    const Vec3& b = polygon[(i + 1) % polygon.size()];
    n[0] += (a[1] - b[1]) * (a[2] + b[2]);
    n[1] += (a[2] - b[2]) * (a[0] + b[0]);
    n[2] += (a[0] - b[0]) * (a[1] + b[1]);
  }
  return n;
}

bool isDegenerate(const std::vector<Vec3>& polygon) {
  if (polygon.size() < 3) return true;
  const Vec3 n = newellNormal(polygon);
  return std::sqrt(dot(n, n)) < 1e-12;
}

/// Numbers of a text, separators being anything that cannot start a number.
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

/// Removes '#' comments up to the end of each line.
std::string stripComments(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  bool in_comment = false;
  for (char c : text) {
    if (c == '#') in_comment = true;
    if (c == '\n') in_comment = false;
    if (!in_comment) out.push_back(c);
  }
  return out;
}

/// The text between `open` (searched from `from`) and the next `close`.
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

/// One face of a polygon list, checked and kept unless degenerate.
void addFace(const std::vector<Vec3>& points, const std::vector<int>& indices,
             const std::string& path, std::vector<Face>* faces) {
  Face face;
  for (int index : indices) {
    if (index < 0 || index >= static_cast<int>(points.size())) {
      throw InputError("castle: '" + path + "': vertex index " +
                       std::to_string(index) + " outside 0.." +
                       std::to_string(points.size()) + "-1");
    }
    face.vertices_obj.push_back(points[index]);
  }
  if (!isDegenerate(face.vertices_obj)) faces->push_back(std::move(face));
}

/// Token stream of a .cao file: comments removed, name=... tokens skipped.
class CaoTokens {
 public:
  explicit CaoTokens(const std::string& path) : path_(path) {
    std::istringstream in(stripComments(readText(path)));
    std::string token;
    while (in >> token) {
      if (token.find('=') == std::string::npos) tokens_.push_back(token);
    }
  }
  bool done() const { return next_ >= tokens_.size(); }
  const std::string& peek() const { return tokens_[next_]; }
  std::string take() {
    if (done()) throw InputError("castle: '" + path_ + "': truncated");
    return tokens_[next_++];
  }
  double number() {
    const std::string token = take();
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    if (end == token.c_str() || *end != '\0' || !std::isfinite(v)) {
      throw InputError("castle: '" + path_ + "': expected a number, got '" +
                       token + "'");
    }
    return v;
  }
  int count() {
    const double v = number();
    if (v < 0 || v != std::floor(v) || v > 1e7) {
      throw InputError("castle: '" + path_ + "': expected a count, got " +
                       std::to_string(v));
    }
    return static_cast<int>(v);
  }

 private:
  std::string path_;
  std::vector<std::string> tokens_;
  std::size_t next_ = 0;
};

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
    for (int c = 0; c < 3; ++c) pose.R_cam_world[3 * r + c] = m[4 * r + c];
    pose.t_cam_world[r] = m[4 * r + 3];
  }
  // R R^T = I within the precision of the file.
  const auto& R = pose.R_cam_world;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) {
      const double rr = R[3 * a] * R[3 * b] + R[3 * a + 1] * R[3 * b + 1] +
                        R[3 * a + 2] * R[3 * b + 2];
      if (std::fabs(rr - (a == b ? 1.0 : 0.0)) > 1e-4) {
        throw InputError("castle: '" + path +
                         "': the rotation is not orthonormal");
      }
    }
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

std::vector<Face> readVrmlFaces(const std::string& path) {
  const std::string text = stripComments(readText(path));
  std::vector<Face> faces;
  std::size_t at = 0;
  for (;;) {
    const std::size_t set = text.find("IndexedFaceSet", at);
    if (set == std::string::npos) break;
    std::string points_text, index_text;
    std::size_t after_points = 0;
    if (!between(text, "point", "]", set, &points_text, &after_points) ||
        !between(text, "coordIndex", "]", after_points, &index_text, &at)) {
      throw InputError("castle: '" + path +
                       "': an IndexedFaceSet without point or coordIndex");
    }
    // Points: x y z triples.
    const std::vector<double> xyz = numbersIn(points_text);
    if (xyz.size() % 3 != 0) {
      throw InputError("castle: '" + path + "': expected x y z triples");
    }
    std::vector<Vec3> points;
    for (std::size_t i = 0; i < xyz.size(); i += 3) {
      points.push_back({xyz[i], xyz[i + 1], xyz[i + 2]});
    }
    // Polygons: indices ended by -1.
    std::vector<int> polygon;
    for (double v : numbersIn(index_text)) {
      if (v < 0) {
        addFace(points, polygon, path, &faces);
        polygon.clear();
      } else {
        polygon.push_back(static_cast<int>(v));
      }
    }
    if (!polygon.empty()) addFace(points, polygon, path, &faces);
  }
  if (faces.empty()) {
    throw InputError("castle: '" + path + "': no faces in the VRML file");
  }
  return faces;
}

std::vector<Face> readCaoFaces(const std::string& path,
                               const synthetic::Pose& T_obj_file) {
  CaoTokens tokens(path);
  if (tokens.done() || tokens.take() != "V1") {
    throw InputError("castle: '" + path + "': expected a V1 .cao file");
  }
  std::vector<Face> faces;
  // load("file") lines: faces of other files, relative to this one.
  while (!tokens.done() && tokens.peek().rfind("load(", 0) == 0) {
    const std::string token = tokens.take();
    const std::size_t a = token.find('"'), b = token.rfind('"');
    if (a == std::string::npos || b <= a) {
      throw InputError("castle: '" + path + "': malformed " + token);
    }
    const std::string loaded =
        (fs::path(path).parent_path() / token.substr(a + 1, b - a - 1))
            .string();
    for (Face& face : readCaoFaces(loaded, T_obj_file)) {
      faces.push_back(std::move(face));
    }
  }
  // Points.
  std::vector<Vec3> points(tokens.count());
  for (Vec3& p : points) {
    Vec3 file{tokens.number(), tokens.number(), tokens.number()};
    p = transform(T_obj_file, file);
  }
  // Segments (two indices each) and faces made of segments: not surfaces
  // this case needs; skipped.
  const int num_segments = tokens.count();
  for (int i = 0; i < 2 * num_segments; ++i) tokens.number();
  const int num_segment_faces = tokens.count();
  for (int i = 0; i < num_segment_faces; ++i) {
    const int n = tokens.count();
    for (int k = 0; k < n; ++k) tokens.number();
  }
  // Faces made of points.
  const int num_point_faces = tokens.count();
  for (int i = 0; i < num_point_faces; ++i) {
    std::vector<int> indices(tokens.count());
    for (int& index : indices) index = tokens.count();
    addFace(points, indices, path, &faces);
  }
  return faces;
}

synthetic::Pose cubeToObject() {
  // x' = -x - 0.2, y' = z + 0.12, z' = y - 0.15 (ViSP testGenericTracker).
  synthetic::Pose T;
  T.R_cam_world = {{-1, 0, 0, 0, 0, 1, 0, 1, 0}};
  T.t_cam_world = {{-0.2, 0.12, -0.15}};
  return T;
}

std::vector<Face> loadModel(const std::string& dir) {
  std::vector<Face> faces =
      readVrmlFaces((fs::path(dir) / "Models/chateau.wrl").string());
  for (Face& face : readCaoFaces((fs::path(dir) / "Models/cube.cao").string(),
                                 cubeToObject())) {
    faces.push_back(std::move(face));
  }
  return faces;
}

void renderModel(const std::vector<Face>& faces,
                 const synthetic::Pose& T_cam_obj, const CameraIntrinsics& K,
                 int width, int height, ScalarMap* depth_cam,
                 NormalMap* normals_cam) {
  if (width < 1 || height < 1) {
    throw InputError("castle: render size expected >= 1 x 1, got " +
                     std::to_string(width) + " x " + std::to_string(height));
  }
  const std::array<double, 9> K_inv = K.inverse();
  depth_cam->resize(width, height, 1);
  depth_cam->fill(kNaN);
  normals_cam->resize(width, height, 3);
  normals_cam->fill(kNaN);
  std::vector<Vec3> polygon_cam;
  std::vector<std::array<double, 2>> polygon_2d;
  for (const Face& face : faces) {
    polygon_cam.clear();
    for (const Vec3& v : face.vertices_obj) {
      polygon_cam.push_back(transform(T_cam_obj, v));
    }
    // Plane n . X = d through the polygon (camera frame).
    Vec3 n = newellNormal(polygon_cam);
    const double length = std::sqrt(dot(n, n));
    if (length < 1e-12) continue;
    for (double& c : n) c /= length;
    Vec3 centroid{0.0, 0.0, 0.0};
    for (const Vec3& v : polygon_cam) {
      for (int c = 0; c < 3; ++c) centroid[c] += v[c] / polygon_cam.size();
    }
    const double d = dot(n, centroid);
    // Inside test in 2D: drop the axis along which the normal is largest.
    int drop = 0;
    for (int c = 1; c < 3; ++c) {
      if (std::fabs(n[c]) > std::fabs(n[drop])) drop = c;
    }
    const int ax = drop == 0 ? 1 : 0, ay = drop == 2 ? 1 : 2;
    polygon_2d.clear();
    for (const Vec3& v : polygon_cam) polygon_2d.push_back({v[ax], v[ay]});
    // Pixel box: the projected vertices when all lie in front, else all.
    int u_lo = 0, u_hi = width - 1, v_lo = 0, v_hi = height - 1;
    bool in_front = true;
    double pu_lo = 1e300, pu_hi = -1e300, pv_lo = 1e300, pv_hi = -1e300;
    for (const Vec3& v : polygon_cam) {
      if (v[2] <= 1e-9) {
        in_front = false;
        break;
      }
      const double pu = (K.K[0] * v[0] + K.K[1] * v[1]) / v[2] + K.K[2];
      const double pv = K.K[4] * v[1] / v[2] + K.K[5];
      pu_lo = std::min(pu_lo, pu);
      pu_hi = std::max(pu_hi, pu);
      pv_lo = std::min(pv_lo, pv);
      pv_hi = std::max(pv_hi, pv);
    }
    if (in_front) {
      u_lo = std::max(u_lo, static_cast<int>(std::floor(pu_lo)));
      u_hi = std::min(u_hi, static_cast<int>(std::ceil(pu_hi)));
      v_lo = std::max(v_lo, static_cast<int>(std::floor(pv_lo)));
      v_hi = std::min(v_hi, static_cast<int>(std::ceil(pv_hi)));
    }
    for (int y = v_lo; y <= v_hi; ++y) {
      for (int x = u_lo; x <= u_hi; ++x) {
        // Ray r = K^-1 (x, y, 1); hit X = t r with n . X = d.
        const Vec3 r{K_inv[0] * x + K_inv[1] * y + K_inv[2],
                     K_inv[3] * x + K_inv[4] * y + K_inv[5],
                     K_inv[6] * x + K_inv[7] * y + K_inv[8]};
        const double n_dot_r = dot(n, r);
        if (std::fabs(n_dot_r) < 1e-12) continue;
        const double t = d / n_dot_r;
        const Vec3 X{t * r[0], t * r[1], t * r[2]};
        if (!(X[2] > 0.0)) continue;
        const float z_old = depth_cam->at(0, y, x);
        if (!std::isnan(z_old) && X[2] >= z_old) continue;
        // Even-odd crossing test of the hit point against the polygon.
        const double px = X[ax], py = X[ay];
        bool inside = false;
        for (std::size_t i = 0, j = polygon_2d.size() - 1;
             i < polygon_2d.size(); j = i++) {
          const auto& a = polygon_2d[i];
          const auto& b = polygon_2d[j];
          if ((a[1] > py) != (b[1] > py) &&
              px < (b[0] - a[0]) * (py - a[1]) / (b[1] - a[1]) + a[0]) {
            inside = !inside;
          }
        }
        if (!inside) continue;
        // Unit normal turned towards the camera: n . r <= 0.
        const double sign = n_dot_r > 0.0 ? -1.0 : 1.0;
        depth_cam->at(0, y, x) = static_cast<float>(X[2]);
        for (int c = 0; c < 3; ++c) {
          normals_cam->at(c, y, x) = static_cast<float>(sign * n[c]);
        }
      }
    }
  }
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
  const int W = depth.width(), H = depth.height();

  // Depth camera pose: d_M_o = d_M_c c_M_o, d_M_c a translation along x.
  synthetic::Pose T_depth_obj = T_color_obj;
  T_depth_obj.t_cam_world[0] += kDepthFromColorXM;

  // Model depth and normals; ground truth where the model explains the depth.
  ScalarMap model_depth;
  NormalMap model_normals;
  renderModel(faces, T_depth_obj, K_depth, W, H, &model_depth, &model_normals);
  NormalMap normals_gt(W, H, 3, kNaN);
  int with_depth = 0, agreeing = 0;
  int x_lo = W, x_hi = -1, y_lo = H, y_hi = -1;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float z = depth.at(0, y, x);
      if (std::isnan(z)) continue;
      ++with_depth;
      x_lo = std::min(x_lo, x);
      x_hi = std::max(x_hi, x);
      y_lo = std::min(y_lo, y);
      y_hi = std::max(y_hi, y);
      const float z_model = model_depth.at(0, y, x);
      if (!(std::fabs(z_model - z) <= settings.agreement_tolerance_m)) {
        continue;
      }
      ++agreeing;
      for (int c = 0; c < 3; ++c) {
        normals_gt.at(c, y, x) = model_normals.at(c, y, x);
      }
    }
  }

  // Guide: the colour image sampled where each depth pixel's point projects
  // (X_c = X_d - (kDepthFromColorXM, 0, 0), pinhole K_color).
  const std::array<double, 9> K_depth_inv = K_depth.inverse();
  const int W_color = image_color.width(), H_color = image_color.height();
  const auto project = [&](int x, int y, double z, double* u, double* v) {
    const double X =
        z * (K_depth_inv[0] * x + K_depth_inv[1] * y + K_depth_inv[2]) -
        kDepthFromColorXM;
    const double Y =
        z * (K_depth_inv[3] * x + K_depth_inv[4] * y + K_depth_inv[5]);
    *u = (K_color.K[0] * X + K_color.K[1] * Y) / z + K_color.K[2];
    *v = K_color.K[4] * Y / z + K_color.K[5];
  };
  // Colour pixels no depth point reaches (3 x 3 footprint): the background
  // as the colour camera sees it.
  std::vector<unsigned char> reached(image_color.pixelCount(), 0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
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

  Frame frame;
  frame.number = number;
  frame.T_depth_obj = T_depth_obj;
  frame.agreement =
      with_depth > 0 ? static_cast<double>(agreeing) / with_depth : 0.0;
  frame.K = K_depth;
  if (settings.crop_margin < 0 || with_depth == 0) {
    frame.image = image;
    frame.depth = depth;
    frame.normals_gt = normals_gt;
    return frame;
  }
  // Crop to the pixels with depth, grown by the margin; K follows.
  const int m = settings.crop_margin;
  frame.crop_x = std::max(0, x_lo - m);
  frame.crop_y = std::max(0, y_lo - m);
  const int crop_w = std::min(W - 1, x_hi + m) - frame.crop_x + 1;
  const int crop_h = std::min(H - 1, y_hi + m) - frame.crop_y + 1;
  frame.image = crop(image, frame.crop_x, frame.crop_y, crop_w, crop_h);
  frame.depth = crop(depth, frame.crop_x, frame.crop_y, crop_w, crop_h);
  frame.normals_gt =
      crop(normals_gt, frame.crop_x, frame.crop_y, crop_w, crop_h);
  frame.K.K[2] -= frame.crop_x;
  frame.K.K[5] -= frame.crop_y;
  return frame;
}

}  // namespace castle
}  // namespace normal_fusion
