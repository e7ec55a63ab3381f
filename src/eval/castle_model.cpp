// The Castle model's files (VRML 2 and ViSP .cao) and their ray casting.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "eval/castle.h"
#include "eval/castle_internal.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/geometry.h"

namespace normal_fusion {
namespace castle {
namespace {

namespace fs = std::filesystem;
using internal::between;
using internal::numbersIn;
using internal::readText;

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

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

/// The plane n . X = d of a polygon in the camera frame and the two axes of
/// its inside test in 2D (the axis along which the normal is largest
/// dropped).
struct FacePlane {
  Vec3 n{{0.0, 0.0, 0.0}};
  double d = 0.0;
  int ax = 0, ay = 1;
  std::vector<std::array<double, 2>> polygon_2d;
};

/// False for a degenerate polygon.
bool planeOf(const std::vector<Vec3>& polygon_cam, FacePlane* plane) {
  Vec3 n = newellNormal(polygon_cam);
  const double length = std::sqrt(dot(n, n));
  if (length < 1e-12) return false;
  for (double& c : n) c /= length;
  Vec3 centroid{0.0, 0.0, 0.0};
  for (const Vec3& v : polygon_cam) {
    for (int c = 0; c < 3; ++c) centroid[c] += v[c] / polygon_cam.size();
  }
  plane->n = n;
  plane->d = dot(n, centroid);
  int drop = 0;
  for (int c = 1; c < 3; ++c) {
    if (std::fabs(n[c]) > std::fabs(n[drop])) drop = c;
  }
  plane->ax = drop == 0 ? 1 : 0;
  plane->ay = drop == 2 ? 1 : 2;
  plane->polygon_2d.clear();
  for (const Vec3& v : polygon_cam) {
    plane->polygon_2d.push_back({v[plane->ax], v[plane->ay]});
  }
  return true;
}

/// Pixel box of a polygon: its projected vertices when all lie in front of
/// the camera, else the whole image.
void pixelBox(const std::vector<Vec3>& polygon_cam, const CameraIntrinsics& K,
              int width, int height, int* u_lo, int* u_hi, int* v_lo,
              int* v_hi) {
  *u_lo = 0, *u_hi = width - 1, *v_lo = 0, *v_hi = height - 1;
  double pu_lo = 1e300, pu_hi = -1e300, pv_lo = 1e300, pv_hi = -1e300;
  for (const Vec3& v : polygon_cam) {
    if (v[2] <= 1e-9) return;
    const double pu = (K.K[0] * v[0] + K.K[1] * v[1]) / v[2] + K.K[2];
    const double pv = K.K[4] * v[1] / v[2] + K.K[5];
    pu_lo = std::min(pu_lo, pu);
    pu_hi = std::max(pu_hi, pu);
    pv_lo = std::min(pv_lo, pv);
    pv_hi = std::max(pv_hi, pv);
  }
  *u_lo = std::max(*u_lo, static_cast<int>(std::floor(pu_lo)));
  *u_hi = std::min(*u_hi, static_cast<int>(std::ceil(pu_hi)));
  *v_lo = std::max(*v_lo, static_cast<int>(std::floor(pv_lo)));
  *v_hi = std::min(*v_hi, static_cast<int>(std::ceil(pv_hi)));
}

/// Even-odd crossing test of a point against a 2D polygon.
bool inside(const std::vector<std::array<double, 2>>& polygon_2d, double px,
            double py) {
  bool in = false;
  for (std::size_t i = 0, j = polygon_2d.size() - 1; i < polygon_2d.size();
       j = i++) {
    const auto& a = polygon_2d[i];
    const auto& b = polygon_2d[j];
    if ((a[1] > py) != (b[1] > py) &&
        px < (b[0] - a[0]) * (py - a[1]) / (b[1] - a[1]) + a[0]) {
      in = !in;
    }
  }
  return in;
}

/// Casts the rays of the pixel box through one face, keeping the nearest
/// hit per pixel.
void renderFace(const std::vector<Vec3>& polygon_cam, const FacePlane& plane,
                const CameraIntrinsics& K, const Mat3& K_inv,
                ScalarMap* depth_cam, NormalMap* normals_cam) {
  int u_lo, u_hi, v_lo, v_hi;
  pixelBox(polygon_cam, K, depth_cam->width(), depth_cam->height(), &u_lo,
           &u_hi, &v_lo, &v_hi);
  const Vec3& n = plane.n;
  for (int y = v_lo; y <= v_hi; ++y) {
    for (int x = u_lo; x <= u_hi; ++x) {
      // Ray r = K^-1 (x, y, 1); hit X = t r with n . X = d.
      const Vec3 r = multiply(
          K_inv, Vec3{{static_cast<double>(x), static_cast<double>(y), 1.0}});
      const double n_dot_r = dot(n, r);
      if (std::fabs(n_dot_r) < 1e-12) continue;
      const double t = plane.d / n_dot_r;
      const Vec3 X{t * r[0], t * r[1], t * r[2]};
      if (!(X[2] > 0.0)) continue;
      const float z_old = depth_cam->at(0, y, x);
      if (!std::isnan(z_old) && X[2] >= z_old) continue;
      if (!inside(plane.polygon_2d, X[plane.ax], X[plane.ay])) continue;
      // Unit normal turned towards the camera: n . r <= 0.
      const double sign = n_dot_r > 0.0 ? -1.0 : 1.0;
      depth_cam->at(0, y, x) = static_cast<float>(X[2]);
      for (int c = 0; c < 3; ++c) {
        normals_cam->at(c, y, x) = static_cast<float>(sign * n[c]);
      }
    }
  }
}

}  // namespace

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
    p = transformPoint(T_obj_file, file);
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
  T.R = {{-1, 0, 0, 0, 0, 1, 0, 1, 0}};
  T.t = {{-0.2, 0.12, -0.15}};
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
  const Mat3 K_inv = K.inverse();
  depth_cam->resize(width, height, 1);
  depth_cam->fill(kNaN);
  normals_cam->resize(width, height, 3);
  normals_cam->fill(kNaN);
  std::vector<Vec3> polygon_cam;
  FacePlane plane;
  for (const Face& face : faces) {
    polygon_cam.clear();
    for (const Vec3& v : face.vertices_obj) {
      polygon_cam.push_back(transformPoint(T_cam_obj, v));
    }
    if (!planeOf(polygon_cam, &plane)) continue;
    renderFace(polygon_cam, plane, K, K_inv, depth_cam, normals_cam);
  }
}

}  // namespace castle
}  // namespace normal_fusion
