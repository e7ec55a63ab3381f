// Registration of depth normals into the colour image (registration.h),
// against a two-camera rig that renders planes, a sphere and a box exactly in
// both cameras: the registered normals equal the colour camera's, the nearer
// surface wins, unreached pixels are unknown, identity is the identity.
#include "normal_fusion/registration.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"

namespace nf = normal_fusion;
namespace nd = normal_fusion::depth;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr int kW = 160, kH = 120;

struct V3 {
  double x, y, z;
};
V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
V3 operator-(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
V3 operator*(double s, V3 a) { return {s * a.x, s * a.y, s * a.z}; }
double dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
V3 unit(V3 a) { return (1.0 / std::sqrt(dot(a, a))) * a; }
V3 rotate(const std::array<double, 9>& R, V3 a) {
  return {R[0] * a.x + R[1] * a.y + R[2] * a.z,
          R[3] * a.x + R[4] * a.y + R[5] * a.z,
          R[6] * a.x + R[7] * a.y + R[8] * a.z};
}
std::array<double, 9> transposed(const std::array<double, 9>& R) {
  return {R[0], R[3], R[6], R[1], R[4], R[7], R[2], R[5], R[8]};
}

/// R_y(b) R_x(a).
std::array<double, 9> rotationYX(double a, double b) {
  const double ca = std::cos(a), sa = std::sin(a);
  const double cb = std::cos(b), sb = std::sin(b);
  return {cb, sb * sa, sb * ca, 0, ca, -sa, -sb, cb * sa, cb * ca};
}

/// Surfaces in the depth camera's frame (the rig's world).
struct Scene {
  struct Plane {
    V3 n;
    double d;  ///< n . X = d
  };
  struct Sphere {
    V3 c;
    double r;
  };
  struct Box {
    V3 lo, hi;
  };
  std::vector<Plane> planes;
  std::vector<Sphere> spheres;
  std::vector<Box> boxes;

  /// Nearest hit of o + s dir (s > 0): s, the normal, the object's index.
  double hit(V3 o, V3 dir, V3* n, int* id) const {
    double best = kInf;
    int index = 0;
    for (const Plane& p : planes) {
      const double s = (p.d - dot(p.n, o)) / dot(p.n, dir);
      if (s > 0 && s < best) best = s, *n = p.n, *id = index;
      ++index;
    }
    for (const Sphere& q : spheres) {
      const V3 oc = o - q.c;
      const double b = dot(oc, dir), a = dot(dir, dir);
      const double disc = b * b - a * (dot(oc, oc) - q.r * q.r);
      const double s = disc >= 0 ? (-b - std::sqrt(disc)) / a : -1;
      if (s > 0 && s < best) {
        best = s, *n = unit(o + s * dir - q.c), *id = index;
      }
      ++index;
    }
    for (const Box& b : boxes) {
      double s_in = -kInf, s_out = kInf;
      V3 n_in{0, 0, 0};
      const double os[3] = {o.x, o.y, o.z}, ds[3] = {dir.x, dir.y, dir.z};
      const double los[3] = {b.lo.x, b.lo.y, b.lo.z};
      const double his[3] = {b.hi.x, b.hi.y, b.hi.z};
      for (int k = 0; k < 3; ++k) {
        double s0 = (los[k] - os[k]) / ds[k], s1 = (his[k] - os[k]) / ds[k];
        double sign = -1;
        if (s0 > s1) std::swap(s0, s1), sign = 1;
        if (s0 > s_in) {
          s_in = s0;
          n_in = {0, 0, 0};
          (k == 0 ? n_in.x : k == 1 ? n_in.y : n_in.z) = sign;
        }
        s_out = std::min(s_out, s1);
      }
      if (s_in <= s_out && s_in > 0 && s_in < best) {
        best = s_in, *n = n_in, *id = index;
      }
      ++index;
    }
    return best;
  }
};

/// What one camera of the rig sees exactly.
struct View {
  nf::ScalarMap depth;  ///< z in the camera, NaN where nothing
  nf::NormalMap normals;
  std::vector<int> id;  ///< object per pixel, -1 nothing
};

/// The scene through a camera at T_cam_world (p_cam = R p_world + t).
View render(const Scene& scene, const nf::CameraIntrinsics& K, int W, int H,
            const nd::RigidTransform& T_cam_world) {
  const std::array<double, 9> Rt = transposed(T_cam_world.R);
  const V3 t{T_cam_world.t[0], T_cam_world.t[1], T_cam_world.t[2]};
  const V3 centre = -1.0 * rotate(Rt, t);
  View view{nf::ScalarMap(W, H, 1, NAN), nf::NormalMap(W, H, 3, NAN),
            std::vector<int>(static_cast<std::size_t>(W) * H, -1)};
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const V3 ray_cam{(u - K.cx()) / K.fx(), (v - K.cy()) / K.fy(), 1.0};
      V3 n_world{0, 0, 0};
      int id = -1;
      // The ray is scaled to z = 1 in the camera, so s is the depth.
      const double s = scene.hit(centre, rotate(Rt, ray_cam), &n_world, &id);
      if (!std::isfinite(s)) continue;
      V3 n_cam = rotate(T_cam_world.R, n_world);
      if (dot(n_cam, ray_cam) > 0) n_cam = -1.0 * n_cam;
      view.depth.at(0, v, u) = static_cast<float>(s);
      view.normals.at(0, v, u) = static_cast<float>(n_cam.x);
      view.normals.at(1, v, u) = static_cast<float>(n_cam.y);
      view.normals.at(2, v, u) = static_cast<float>(n_cam.z);
      view.id[static_cast<std::size_t>(v) * W + u] = id;
    }
  }
  return view;
}

nf::CameraIntrinsics cameraK(double f = 150.0) {
  return nf::CameraIntrinsics(f, f, (kW - 1) / 2.0, (kH - 1) / 2.0);
}

/// The depth camera `baseline` metres to the colour camera's left, turned a
/// little (1 degree about x, 2 about y).
nd::RigidTransform rig(double baseline, bool rotated = true) {
  nd::RigidTransform T;
  if (rotated) T.R = rotationYX(kPi / 180.0, 2.0 * kPi / 180.0);
  T.t = {-baseline, 0.0, 0.0};
  return T;
}

/// atan2(|a x b|, a . b): accurate for small angles, unlike acos.
double angleBetween(const nf::NormalMap& a, const nf::NormalMap& b, int x,
                    int y) {
  const V3 p{a.at(0, y, x), a.at(1, y, x), a.at(2, y, x)};
  const V3 q{b.at(0, y, x), b.at(1, y, x), b.at(2, y, x)};
  const V3 c{p.y * q.z - p.z * q.y, p.z * q.x - p.x * q.z,
             p.x * q.y - p.y * q.x};
  return std::atan2(std::sqrt(dot(c, c)), dot(p, q));
}

/// True when the pixel and every pixel within `r` show the same object.
bool interior(const View& view, int x, int y, int r) {
  const int id = view.id[static_cast<std::size_t>(y) * kW + x];
  if (id < 0) return false;
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      const int xx = x + dx, yy = y + dy;
      if (xx < 0 || yy < 0 || xx >= kW || yy >= kH) return false;
      if (view.id[static_cast<std::size_t>(yy) * kW + xx] != id) return false;
    }
  }
  return true;
}

/// How the depth camera sees the colour pixel's exact surface point.
enum class Sight { kOutside, kSeen, kHidden };

Sight depthSight(const View& rgb, const View& dep, const nd::RigidTransform& T,
                 int x, int y) {
  const nf::CameraIntrinsics K = cameraK();
  const double z = rgb.depth.at(0, y, x);
  if (!std::isfinite(z)) return Sight::kOutside;
  const V3 P_rgb{(x - K.cx()) / K.fx() * z, (y - K.cy()) / K.fy() * z, z};
  const V3 P_dep = rotate(transposed(T.R), P_rgb - V3{T.t[0], T.t[1], T.t[2]});
  const double u = K.fx() * P_dep.x / P_dep.z + K.cx();
  const double v = K.fy() * P_dep.y / P_dep.z + K.cy();
  if (!(u >= 3 && v >= 3 && u <= kW - 4 && v <= kH - 4)) return Sight::kOutside;
  const float z_seen = dep.depth.at(0, static_cast<int>(std::lround(v)),
                                    static_cast<int>(std::lround(u)));
  if (std::abs(z_seen - P_dep.z) < 0.02 * P_dep.z) return Sight::kSeen;
  return z_seen < P_dep.z ? Sight::kHidden : Sight::kOutside;
}

bool seenByDepth(const View& rgb, const View& dep, const nd::RigidTransform& T,
                 int x, int y) {
  return depthSight(rgb, dep, T, x, y) == Sight::kSeen;
}

struct Result {
  nf::NormalMap normals;
  nf::ScalarMap confidence, depth;
};

/// Registers the depth camera's exact normals (confidence 0.5) into the
/// colour camera.
Result registerView(const View& dep, const nd::RigidTransform& T,
                    nd::Splat splat, const nf::CameraIntrinsics& K_rgb) {
  nf::ScalarMap confidence(kW, kH, 1, 0.5f);
  Result r;
  nd::RegistrationSettings settings;
  settings.splat = splat;
  nd::registerNormals(dep.depth, dep.normals, &confidence, cameraK(),
                      nd::TargetCamera{K_rgb, kW, kH}, T, settings, r.normals,
                      &r.confidence, &r.depth);
  return r;
}

/// Largest angle (radians) between the registered and the exact colour
/// normals on the interior pixels both cameras see; counts them and those of
/// them that got a normal.
double maxError(const View& rgb, const View& dep, const nd::RigidTransform& T,
                const Result& r, int* seen, int* reached,
                double (*scale)(const View&, int, int) = nullptr) {
  double worst = 0;
  *seen = *reached = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      if (!interior(rgb, x, y, 2) || !seenByDepth(rgb, dep, T, x, y)) continue;
      ++*seen;
      if (!std::isfinite(r.normals.at(0, y, x))) continue;
      ++*reached;
      const double error = angleBetween(r.normals, rgb.normals, x, y);
      worst = std::max(worst, scale ? error / scale(rgb, x, y) : error);
    }
  }
  return worst;
}

Scene tiltedPlane() {
  Scene scene;
  scene.planes.push_back({unit({0.3, -0.2, -1.0}), -1.5});
  return scene;
}

Scene sphereBeforePlane() {
  Scene scene;
  scene.planes.push_back({unit({0.1, 0.0, -1.0}), -2.0});
  scene.spheres.push_back({{0.05, 0.02, 1.2}, 0.25});
  return scene;
}

}  // namespace

TEST(Registration, PlaneGivesTheColourCamerasNormals) {
  const Scene scene = tiltedPlane();
  for (double baseline : {0.025, 0.05}) {
    for (nd::Splat splat : {nd::Splat::k2x2, nd::Splat::kNearest}) {
      const nd::RigidTransform T = rig(baseline);
      const View dep = render(scene, cameraK(), kW, kH, nd::RigidTransform());
      const View rgb = render(scene, cameraK(), kW, kH, T);
      const Result r = registerView(dep, T, splat, cameraK());
      int seen = 0, reached = 0;
      const double worst = maxError(rgb, dep, T, r, &seen, &reached);
      SCOPED_TRACE(baseline);
      EXPECT_GT(seen, kW * kH / 2);
      EXPECT_LT(worst, 1e-5);
      // The 2x2 footprint closes the cracks of a grid as fine as the depth's.
      if (splat == nd::Splat::k2x2) {
        EXPECT_EQ(reached, seen);
      } else {
        EXPECT_GT(reached, seen * 3 / 4);
      }
    }
  }
}

TEST(Registration, TransposedRotationIsCaughtByThePlaneBound) {
  // The bound above fails for R^T, so the test tells R from R^T.
  const Scene scene = tiltedPlane();
  const nd::RigidTransform T = rig(0.05);
  nd::RigidTransform wrong = T;
  wrong.R = transposed(T.R);
  const View dep = render(scene, cameraK(), kW, kH, nd::RigidTransform());
  const View rgb = render(scene, cameraK(), kW, kH, T);
  const Result r = registerView(dep, wrong, nd::Splat::k2x2, cameraK());
  int seen = 0, reached = 0;
  EXPECT_GT(maxError(rgb, dep, T, r, &seen, &reached), 1e-2);
}

TEST(Registration, SphereGivesTheColourCamerasNormals) {
  const Scene scene = sphereBeforePlane();
  for (double baseline : {0.025, 0.05}) {
    const nd::RigidTransform T = rig(baseline);
    const View dep = render(scene, cameraK(), kW, kH, nd::RigidTransform());
    const View rgb = render(scene, cameraK(), kW, kH, T);
    const Result r = registerView(dep, T, nd::Splat::k2x2, cameraK());
    int seen = 0, reached = 0;
    // In units of the turn of the sphere's normal over one colour pixel,
    // z / (f r |n . v|): a 2x2 footprint shows a point at most 1.5 pixels off.
    const auto pixel_turn = [](const View& view, int x, int y) {
      if (view.id[static_cast<std::size_t>(y) * kW + x] != 1) return 1e-5;
      const nf::CameraIntrinsics K = cameraK();
      const V3 ray = unit({(x - K.cx()) / K.fx(), (y - K.cy()) / K.fy(), 1.0});
      const V3 n{view.normals.at(0, y, x), view.normals.at(1, y, x),
                 view.normals.at(2, y, x)};
      return view.depth.at(0, y, x) / (K.fx() * 0.25 * std::abs(dot(n, ray)));
    };
    EXPECT_LT(maxError(rgb, dep, T, r, &seen, &reached, pixel_turn), 1.5);
    EXPECT_EQ(reached, seen);
    int sphere_pixels = 0;
    for (int i : rgb.id) sphere_pixels += i == 1;
    EXPECT_GT(sphere_pixels, 2000);
  }
}

TEST(Registration, NearerSurfaceWinsAndTheShadowIsUnknown) {
  // A box 0.5 m away in front of a wall at 2 m; either side of the baseline,
  // so that the hidden wall points come before and after the box's.
  Scene scene;
  scene.planes.push_back({{0, 0, -1}, -2.0});
  // Edges off the pixel centres of both cameras, so no ray grazes one.
  scene.boxes.push_back({{-0.071, -0.047, 0.5}, {0.073, 0.052, 0.6}});
  for (double baseline : {0.05, -0.05}) {
    for (nd::Splat splat : {nd::Splat::k2x2, nd::Splat::kNearest}) {
      SCOPED_TRACE(baseline);
      const nd::RigidTransform T = rig(baseline, false);
      const View dep = render(scene, cameraK(), kW, kH, nd::RigidTransform());
      const View rgb = render(scene, cameraK(), kW, kH, T);
      const Result r = registerView(dep, T, splat, cameraK());
      int box = 0, shadow = 0;
      for (int y = 0; y < kH; ++y) {
        for (int x = 0; x < kW; ++x) {
          const int id = rgb.id[static_cast<std::size_t>(y) * kW + x];
          if (id == 1 && interior(rgb, x, y, 1)) {
            // The box's front, not the wall behind it.
            ++box;
            EXPECT_NEAR(r.depth.at(0, y, x), 0.5, 1e-4);
            EXPECT_NEAR(r.normals.at(2, y, x), -1.0, 1e-6);
          }
          // Wall the depth camera cannot see (the box hides it): unknown,
          // away from the shadow's edge for the 2x2 footprint.
          const bool hidden = [&] {
            if (x < 1 || y < 1 || x >= kW - 1 || y >= kH - 1) return false;
            for (int dy = -1; dy <= 1; ++dy) {
              for (int dx = -1; dx <= 1; ++dx) {
                if (rgb.id[static_cast<std::size_t>(y + dy) * kW + x + dx] !=
                        0 ||
                    depthSight(rgb, dep, T, x + dx, y + dy) != Sight::kHidden)
                  return false;
              }
            }
            return true;
          }();
          if (hidden) {
            ++shadow;
            EXPECT_TRUE(std::isnan(r.normals.at(0, y, x))) << x << " " << y;
            EXPECT_EQ(r.confidence.at(0, y, x), 0.0f);
            EXPECT_TRUE(std::isnan(r.depth.at(0, y, x)));
          }
        }
      }
      EXPECT_GT(box, 800);
      EXPECT_GT(shadow, 150);
    }
  }
}

TEST(Registration, IdentityWithTheSameCameraIsTheIdentity) {
  const Scene scene = sphereBeforePlane();
  const View dep = render(scene, cameraK(), kW, kH, nd::RigidTransform());
  nf::ScalarMap confidence(kW, kH, 1);
  for (std::size_t i = 0; i < confidence.pixelCount(); ++i) {
    confidence.data()[i] = static_cast<float>(i % 97) / 97.0f;
  }
  nd::RegistrationSettings settings;
  settings.splat = nd::Splat::kNearest;
  nf::NormalMap normals;
  nf::ScalarMap confidence_rgb, depth_rgb;
  nd::registerNormals(dep.depth, dep.normals, &confidence, cameraK(),
                      nd::TargetCamera{cameraK(), kW, kH}, nd::RigidTransform(),
                      settings, normals, &confidence_rgb, &depth_rgb);
  for (std::size_t i = 0; i < dep.depth.pixelCount(); ++i) {
    ASSERT_EQ(depth_rgb.data()[i], dep.depth.data()[i]) << i;
    ASSERT_EQ(confidence_rgb.data()[i], confidence.data()[i]) << i;
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(normals.plane(c)[i], dep.normals.plane(c)[i]) << i;
    }
  }
}

TEST(Registration, PixelsNoDepthPixelReachesAreUnknown) {
  // A wider colour camera sees beyond the depth camera's edges, and a block
  // without depth leaves its image in the colour camera empty.
  const Scene scene = tiltedPlane();
  const nd::RigidTransform T = rig(0.05);
  View dep = render(scene, cameraK(), kW, kH, nd::RigidTransform());
  for (int y = 40; y < 80; ++y) {
    for (int x = 60; x < 100; ++x) dep.depth.at(0, y, x) = NAN;
  }
  const nf::CameraIntrinsics K_wide = cameraK(100.0);
  const Result r = registerView(dep, T, nd::Splat::kNearest, K_wide);
  int unknown = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      // Back into the depth camera through the plane: a pixel without depth?
      const V3 ray{(x - K_wide.cx()) / K_wide.fx(),
                   (y - K_wide.cy()) / K_wide.fy(), 1.0};
      const std::array<double, 9> Rt = transposed(T.R);
      const V3 centre = -1.0 * rotate(Rt, {T.t[0], T.t[1], T.t[2]});
      V3 n{0, 0, 0};
      int id = -1;
      const double s = scene.hit(centre, rotate(Rt, ray), &n, &id);
      const V3 P = centre + s * rotate(Rt, ray);
      const double u = 150.0 * P.x / P.z + (kW - 1) / 2.0;
      const double v = 150.0 * P.y / P.z + (kH - 1) / 2.0;
      const bool outside = u < -1 || v < -1 || u > kW || v > kH;
      const bool in_hole = u > 61 && u < 98 && v > 41 && v < 78;
      if (!outside && !in_hole) continue;
      ++unknown;
      EXPECT_TRUE(std::isnan(r.normals.at(0, y, x))) << x << " " << y;
      EXPECT_EQ(r.confidence.at(0, y, x), 0.0f);
      EXPECT_TRUE(std::isnan(r.depth.at(0, y, x)));
    }
  }
  EXPECT_GT(unknown, 2000);
}

TEST(Registration, NormalsAreTurnedToFaceTheColourCamera) {
  // One point on the depth camera's axis with a normal across the ray: seen
  // from a colour camera 5 cm to its left it faces away unless flipped.
  nf::ScalarMap depth(1, 1, 1, 1.0f);
  nf::NormalMap normals(1, 1, 3, 0.0f);
  normals.at(0, 0, 0) = 1.0f;
  nd::RigidTransform T;
  T.t = {0.05, 0.0, 0.0};
  const nd::TargetCamera rgb{nf::CameraIntrinsics(100, 100, 5, 0), 11, 1};
  nf::NormalMap out;
  nd::RegistrationSettings settings;
  settings.splat = nd::Splat::kNearest;
  nd::registerNormals(depth, normals, nullptr, nf::CameraIntrinsics(1, 1, 0, 0),
                      rgb, T, settings, out, nullptr);
  EXPECT_EQ(out.at(0, 0, 10), -1.0f);
  settings.face_camera = false;
  nd::registerNormals(depth, normals, nullptr, nf::CameraIntrinsics(1, 1, 0, 0),
                      rgb, T, settings, out, nullptr);
  EXPECT_EQ(out.at(0, 0, 10), 1.0f);
}

TEST(Registration, BadInputThrows) {
  nf::ScalarMap depth(4, 4, 1, 1.0f);
  nf::NormalMap normals(4, 4, 3, 0.0f), out;
  const nd::TargetCamera rgb{nf::CameraIntrinsics(4, 4, 2, 2), 4, 4};
  const nf::CameraIntrinsics K(4, 4, 2, 2);
  nf::NormalMap small(3, 4, 3, 0.0f);
  EXPECT_THROW(
      nd::registerNormals(depth, small, nullptr, K, rgb, {}, {}, out, nullptr),
      nf::InputError);
  nf::ScalarMap confidence;
  EXPECT_THROW(nd::registerNormals(depth, normals, nullptr, K, rgb, {}, {}, out,
                                   &confidence),
               nf::InputError);
  EXPECT_THROW(
      nd::registerNormals(depth, normals, nullptr, K, nd::TargetCamera{K, 0, 4},
                          {}, {}, out, nullptr),
      nf::InputError);
  nf::CameraIntrinsics skewed = K;
  skewed.K[1] = 0.5;
  EXPECT_THROW(nd::registerNormals(depth, normals, nullptr, skewed, rgb, {}, {},
                                   out, nullptr),
               nf::InputError);
  nd::RigidTransform mirror;
  mirror.R[0] = -1.0;
  EXPECT_THROW(nd::registerNormals(depth, normals, nullptr, K, rgb, mirror, {},
                                   out, nullptr),
               nf::ParameterError);
  nd::RigidTransform scaled;
  scaled.R[4] = 1.1;
  EXPECT_THROW(nd::registerNormals(depth, normals, nullptr, K, rgb, scaled, {},
                                   out, nullptr),
               nf::ParameterError);
  EXPECT_THROW(nd::splatFromString("3x3"), nf::ParameterError);
  EXPECT_EQ(nd::splatFromString(nd::toString(nd::Splat::kNearest)),
            nd::Splat::kNearest);
}
