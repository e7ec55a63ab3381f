// Synthetic indoor-like scenes (a small ray caster) and noise models.
#include "eval/synthetic.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "eval/scene_model.h"
#include "eval/synthetic_internal.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace synthetic {

using namespace internal;  // NOLINT: the helpers shared with the noise models
using namespace model;  // NOLINT: the scene description shared with the scenes

namespace {

/// Scene 0: room with boxes.
Scene makeRoomWithBoxes() {
  Scene s;
  const int floor =
      addMaterial(&s, patterned(Pattern::kChecker, {{0.78, 0.74, 0.66}},
                                {{0.36, 0.33, 0.30}}, 0.5));
  const int back =
      addMaterial(&s, poster(Pattern::kPosterStripes, {{0.82, 0.82, 0.78}},
                             {{0.20, 0.38, 0.70}}, {{0.85, 0.62, 0.20}}, 0.12,
                             -1.2, 0.4, 0.9, 2.0));
  const int left =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.72, 0.62, 0.50}},
                                {{0.50, 0.56, 0.62}}, 0.4));
  const int right = addMaterial(&s, uniform({{0.64, 0.70, 0.60}}));
  const int ceiling = addMaterial(&s, uniform({{0.90, 0.90, 0.88}}));
  const int near =
      addMaterial(&s, poster(Pattern::kPosterChecker, {{0.75, 0.75, 0.75}},
                             {{0.45, 0.30, 0.25}}, {{0.60, 0.45, 0.35}}, 0.3,
                             -0.5, 0.5, 0.0, 2.0));
  s.room.material = {{near, back, right, left, floor, ceiling}};
  const int wood = addMaterial(&s, uniform({{0.62, 0.46, 0.30}}));
  const int green = addMaterial(&s, uniform({{0.30, 0.52, 0.36}}));
  const int grey = addMaterial(&s, uniform({{0.56, 0.56, 0.62}}));
  // Turned by 45 degrees on the light's plane y = 0: its front faces share
  // albedo and light, so their common edge has almost no contrast.
  s.boxes.push_back(floorBox(3.3, 0.0, 0.4, 0.4, 0.5, kPi / 4, wood));
  s.boxes.push_back(floorBox(4.5, 1.4, 0.5, 0.35, 0.35, 0.0, green));
  s.boxes.push_back(floorBox(5.3, -1.6, 0.4, 0.5, 0.9, 0.17, grey));
  s.camera_pitch = 10.0 * kPi / 180.0;
  return s;
}

/// Scene 1: room with cylinders and spheres, and a pedestal box.
Scene makeRoomWithCylinders() {
  Scene s;
  const int floor =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.66, 0.50, 0.34}},
                                {{0.52, 0.38, 0.24}}, 0.25));
  const int back =
      addMaterial(&s, patterned(Pattern::kChecker, {{0.88, 0.88, 0.86}},
                                {{0.55, 0.65, 0.72}}, 0.3));
  const int left =
      addMaterial(&s, poster(Pattern::kPosterStripes, {{0.70, 0.72, 0.66}},
                             {{0.80, 0.30, 0.25}}, {{0.25, 0.25, 0.30}}, 0.15,
                             1.5, 3.5, 0.8, 1.9));
  const int right = addMaterial(&s, uniform({{0.72, 0.66, 0.58}}));
  const int ceiling = addMaterial(&s, uniform({{0.92, 0.92, 0.92}}));
  const int near = addMaterial(&s, uniform({{0.70, 0.70, 0.70}}));
  s.room.material = {{near, back, right, left, floor, ceiling}};
  const int clay = addMaterial(&s, uniform({{0.72, 0.50, 0.40}}));
  const int pillar = addMaterial(&s, uniform({{0.80, 0.80, 0.76}}));
  const int blue = addMaterial(&s, uniform({{0.30, 0.45, 0.72}}));
  const int banded =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.85, 0.80, 0.30}},
                                {{0.35, 0.30, 0.15}}, 0.08));
  const int stone = addMaterial(&s, uniform({{0.58, 0.58, 0.55}}));
  s.cylinders.push_back(Cylinder{3.8, 0.9, 0.0, 1.1, 0.35, clay});
  s.cylinders.push_back(Cylinder{5.0, -1.5, 0.0, 2.8, 0.3, pillar});
  s.spheres.push_back(Sphere{{{3.0, -0.9, 0.4}}, 0.4, blue});
  s.spheres.push_back(Sphere{{{3.8, 0.9, 1.35}}, 0.25, banded});
  // Pedestal turned by 45 degrees on the light's plane y = 0 (weak edge).
  s.boxes.push_back(floorBox(4.4, 0.0, 0.3, 0.3, 0.35, kPi / 4, stone));
  s.spheres.push_back(Sphere{{{4.4, 0.0, 0.95}}, 0.25, blue});
  s.camera_yaw = 4.0 * kPi / 180.0;
  s.camera_pitch = 9.0 * kPi / 180.0;
  return s;
}

/// Scene 2: cluttered mix: table with boxes and a sphere, rotated box, spheres.
Scene makeClutteredRoom() {
  Scene s;
  const int floor =
      addMaterial(&s, poster(Pattern::kPosterChecker, {{0.60, 0.60, 0.58}},
                             {{0.75, 0.25, 0.20}}, {{0.90, 0.85, 0.70}}, 0.2,
                             1.8, 3.6, -2.0, -0.4));
  const int back =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.80, 0.78, 0.70}},
                                {{0.62, 0.70, 0.78}}, 0.3));
  const int left = addMaterial(&s, uniform({{0.70, 0.74, 0.78}}));
  const int right =
      addMaterial(&s, poster(Pattern::kPosterChecker, {{0.76, 0.72, 0.66}},
                             {{0.15, 0.15, 0.18}}, {{0.92, 0.92, 0.92}}, 0.1,
                             2.0, 3.2, 1.0, 1.8));
  const int ceiling = addMaterial(&s, uniform({{0.92, 0.92, 0.90}}));
  const int near = addMaterial(&s, uniform({{0.70, 0.70, 0.70}}));
  s.room.material = {{near, back, right, left, floor, ceiling}};
  const int table = addMaterial(&s, uniform({{0.55, 0.38, 0.24}}));
  const int red = addMaterial(&s, uniform({{0.70, 0.25, 0.22}}));
  const int books =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.20, 0.35, 0.60}},
                                {{0.85, 0.80, 0.60}}, 0.04));
  const int crate = addMaterial(&s, uniform({{0.66, 0.56, 0.40}}));
  const int white = addMaterial(&s, uniform({{0.85, 0.85, 0.85}}));
  const int teal = addMaterial(&s, uniform({{0.25, 0.55, 0.55}}));
  // Table: top slab and four legs.
  const double tx = 3.8, ty = 1.2, top_z = 0.74;
  s.boxes.push_back(Box{{{tx, ty, top_z}}, {{0.5, 0.8, 0.03}}, 0.0, table});
  for (int i = 0; i < 4; ++i) {
    const double lx = tx + ((i & 1) ? 0.44 : -0.44);
    const double ly = ty + ((i & 2) ? 0.74 : -0.74);
    s.boxes.push_back(
        floorBox(lx, ly, 0.03, 0.03, (top_z - 0.03) / 2.0, 0.0, table));
  }
  const double on_table = top_z + 0.03;
  s.boxes.push_back(
      Box{{{3.7, 1.55, on_table + 0.12}}, {{0.15, 0.2, 0.12}}, 0.0, red});
  s.boxes.push_back(
      Box{{{3.9, 0.8, on_table + 0.08}}, {{0.12, 0.16, 0.08}}, 0.5, books});
  s.spheres.push_back(Sphere{{{3.6, 1.0, on_table + 0.12}}, 0.12, white});
  // Crate turned by 45 degrees on the light's plane y = 0 (weak edge).
  s.boxes.push_back(floorBox(2.9, 0.0, 0.3, 0.3, 0.3, kPi / 4, crate));
  s.spheres.push_back(Sphere{{{3.4, -1.2, 0.35}}, 0.35, teal});
  s.spheres.push_back(Sphere{{{4.8, -0.6, 0.25}}, 0.25, red});
  s.boxes.push_back(floorBox(5.2, -1.8, 0.3, 0.4, 0.6, -0.3, white));
  s.camera_yaw = 6.0 * kPi / 180.0;
  s.camera_pitch = 13.0 * kPi / 180.0;
  return s;
}

Scene makeScene(int scene_id) {
  switch (scene_id) {
    case 0:
      return makeRoomWithBoxes();
    case 1:
      return makeRoomWithCylinders();
    case 2:
      return makeClutteredRoom();
    case kTexturedRoomScene:
    case kTexturedCornerScene:
      return makeTexturedScene(scene_id);
    case kCurvedLargeScene:
    case kCurvedSmallScene:
      return makeCurvedScene(scene_id);
    default: {
      std::ostringstream msg;
      msg << "synthetic scene id " << scene_id << ": expected 0.."
          << kNumSceneIds - 1;
      throw ParameterError(msg.str());
    }
  }
}

/// R_cam_world of a camera looking along world +x turned by yaw (left) and
/// pitch (down): its rows are the camera's right, down and forward axes.
std::array<double, 9> rotationFromYawPitch(double yaw, double pitch) {
  const Vec3 forward{{std::cos(pitch) * std::cos(yaw),
                      std::cos(pitch) * std::sin(yaw), -std::sin(pitch)}};
  const Vec3 right{{std::sin(yaw), -std::cos(yaw), 0.0}};
  // down = forward x right completes the right-handed frame (x right, y down).
  const Vec3 down = cross(forward, right);
  return {{right[0], right[1], right[2], down[0], down[1], down[2], forward[0],
           forward[1], forward[2]}};
}

Pose poseFromCentre(const std::array<double, 9>& R_cam_world,
                    const Vec3& centre_world) {
  Pose pose;
  pose.R = R_cam_world;
  // t = -R C maps the camera centre to the camera origin.
  const Vec3 t = scale(multiply(R_cam_world, centre_world), -1.0);
  pose.t = {{t[0], t[1], t[2]}};
  return pose;
}

void intersectRoom(const Room& room, const Vec3& o, const Vec3& d,
                   SurfaceHit* hit) {
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.0) continue;
    // The ray leaves the room through the far plane of each axis.
    const bool positive = d[a] > 0.0;
    const double s = ((positive ? room.hi[a] : room.lo[a]) - o[a]) / d[a];
    if (s <= kMinRayParameter || s >= hit->s) continue;
    hit->s = s;
    hit->normal = {{0.0, 0.0, 0.0}};
    hit->normal[a] = positive ? -1.0 : 1.0;
    hit->material = room.material[2 * a + (positive ? 1 : 0)];
    const int a1 = a == 0 ? 1 : 0;
    const int a2 = a == 2 ? 1 : 2;
    hit->u = o[a1] + s * d[a1];
    hit->v = o[a2] + s * d[a2];
  }
}

void intersectBox(const Box& box, const Vec3& o, const Vec3& d,
                  SurfaceHit* hit) {
  const double c = std::cos(box.yaw), sn = std::sin(box.yaw);
  // Ray in the box frame: x_local = Rz(-yaw) (x - centre).
  const Vec3 rel = sub(o, box.center);
  const Vec3 ol{{c * rel[0] + sn * rel[1], -sn * rel[0] + c * rel[1], rel[2]}};
  const Vec3 dl{{c * d[0] + sn * d[1], -sn * d[0] + c * d[1], d[2]}};
  // Slab test: the entry is the latest of the three slab entries.
  double s_near = -kInf, s_far = kInf;
  int axis_near = -1;
  for (int a = 0; a < 3; ++a) {
    if (dl[a] == 0.0) {
      if (std::abs(ol[a]) > box.half[a]) return;
      continue;
    }
    const double s1 = (-box.half[a] - ol[a]) / dl[a];
    const double s2 = (box.half[a] - ol[a]) / dl[a];
    const double s_in = std::min(s1, s2);
    if (s_in > s_near) {
      s_near = s_in;
      axis_near = a;
    }
    s_far = std::min(s_far, std::max(s1, s2));
  }
  if (axis_near < 0 || s_near > s_far || s_near <= kMinRayParameter ||
      s_near >= hit->s) {
    return;
  }
  Vec3 normal_local{{0.0, 0.0, 0.0}};
  normal_local[axis_near] = dl[axis_near] > 0.0 ? -1.0 : 1.0;
  hit->s = s_near;
  // Normal back to the world: Rz(yaw) n_local.
  hit->normal = {{c * normal_local[0] - sn * normal_local[1],
                  sn * normal_local[0] + c * normal_local[1], normal_local[2]}};
  hit->material = box.material;
  const int a1 = axis_near == 0 ? 1 : 0;
  const int a2 = axis_near == 2 ? 1 : 2;
  hit->u = ol[a1] + s_near * dl[a1] + box.half[a1];
  hit->v = ol[a2] + s_near * dl[a2] + box.half[a2];
}

void intersectCylinder(const Cylinder& cyl, const Vec3& o, const Vec3& d,
                       SurfaceHit* hit) {
  const double dx = o[0] - cyl.cx, dy = o[1] - cyl.cy;
  // Side: |(o + s d - axis)_xy|^2 = r^2, the nearer root.
  const double a = d[0] * d[0] + d[1] * d[1];
  if (a > 0.0) {
    const double b = 2.0 * (dx * d[0] + dy * d[1]);
    const double c = dx * dx + dy * dy - cyl.radius * cyl.radius;
    const double disc = b * b - 4.0 * a * c;
    if (disc >= 0.0) {
      const double s = (-b - std::sqrt(disc)) / (2.0 * a);
      const double z = o[2] + s * d[2];
      if (s > kMinRayParameter && s < hit->s && z >= cyl.z0 && z <= cyl.z1) {
        const double px = dx + s * d[0], py = dy + s * d[1];
        hit->s = s;
        hit->normal = {{px / cyl.radius, py / cyl.radius, 0.0}};
        hit->material = cyl.material;
        hit->u = cyl.radius * std::atan2(py, px);
        hit->v = z;
      }
    }
  }
  // Caps: the planes z = z0 and z = z1 inside the radius.
  if (d[2] == 0.0) return;
  for (const double z_cap : {cyl.z0, cyl.z1}) {
    const double s = (z_cap - o[2]) / d[2];
    if (s <= kMinRayParameter || s >= hit->s) continue;
    const double px = dx + s * d[0], py = dy + s * d[1];
    if (px * px + py * py > cyl.radius * cyl.radius) continue;
    hit->s = s;
    hit->normal = {{0.0, 0.0, z_cap == cyl.z1 ? 1.0 : -1.0}};
    hit->material = cyl.material;
    hit->u = px;
    hit->v = py;
  }
}

void intersectSphere(const Sphere& sphere, const Vec3& o, const Vec3& d,
                     SurfaceHit* hit) {
  const Vec3 rel = sub(o, sphere.center);
  // |rel + s d|^2 = r^2, the nearer root.
  const double a = dot(d, d);
  const double b = 2.0 * dot(rel, d);
  const double c = dot(rel, rel) - sphere.radius * sphere.radius;
  const double disc = b * b - 4.0 * a * c;
  if (disc < 0.0) return;
  const double s = (-b - std::sqrt(disc)) / (2.0 * a);
  if (s <= kMinRayParameter || s >= hit->s) return;
  const Vec3 p = add(rel, scale(d, s));
  hit->s = s;
  hit->normal = scale(p, 1.0 / sphere.radius);
  hit->material = sphere.material;
  hit->u = sphere.radius * std::atan2(p[1], p[0]);
  hit->v = p[2];
}

/// Nearest surface along the ray; s = inf when none.
SurfaceHit trace(const Scene& scene, const Vec3& o, const Vec3& d) {
  SurfaceHit hit;
  intersectRoom(scene.room, o, d, &hit);
  for (const Box& box : scene.boxes) intersectBox(box, o, d, &hit);
  for (const Cylinder& cyl : scene.cylinders) {
    intersectCylinder(cyl, o, d, &hit);
  }
  for (const Sphere& sphere : scene.spheres) {
    intersectSphere(sphere, o, d, &hit);
  }
  for (const Torus& torus : scene.tori) intersectTorus(torus, o, d, &hit);
  return hit;
}

inline bool oddCell(double u, double period) {
  return (static_cast<long long>(std::floor(u / period)) & 1LL) != 0;
}

/// A value in [0, 1] per cell (i, j): one of four levels from a hash, so
/// neighbouring cells differ strongly (a high-contrast random texture).
double cellNoise(double u, double v, double period) {
  const auto i = static_cast<std::uint64_t>(
      static_cast<std::int64_t>(std::floor(u / period)));
  const auto j = static_cast<std::uint64_t>(
      static_cast<std::int64_t>(std::floor(v / period)));
  // SplitMix64's finalizer of the cell index.
  std::uint64_t h = i * 0x9E3779B97F4A7C15ULL ^ (j + 0x632BE59BD9B4E019ULL);
  h = (h ^ (h >> 30)) * 0xBF58476D1CE4E5B9ULL;
  h = (h ^ (h >> 27)) * 0x94D049BB133111EBULL;
  h ^= h >> 31;
  return static_cast<double>(h & 3ULL) / 3.0;
}

Rgb albedo(const Material& m, double u, double v) {
  const bool inside = u >= m.u0 && u <= m.u1 && v >= m.v0 && v <= m.v1;
  switch (m.pattern) {
    case Pattern::kUniform:
      return m.base;
    case Pattern::kChecker:
      return oddCell(u, m.period) != oddCell(v, m.period) ? m.alt : m.base;
    case Pattern::kStripes:
      return oddCell(u, m.period) ? m.alt : m.base;
    case Pattern::kPosterStripes:
      if (!inside) return m.base;
      return oddCell(v - m.v0, m.period) ? m.accent : m.alt;
    case Pattern::kPosterChecker:
      if (!inside) return m.base;
      return oddCell(u - m.u0, m.period) != oddCell(v - m.v0, m.period)
                 ? m.accent
                 : m.alt;
    case Pattern::kNoise: {
      const double h = cellNoise(u, v, m.period);
      return {{m.alt[0] + h * (m.base[0] - m.alt[0]),
               m.alt[1] + h * (m.base[1] - m.alt[1]),
               m.alt[2] + h * (m.base[2] - m.alt[2])}};
    }
  }
  return m.base;
}

/// Lambertian radiance factor at point p with unit normal n (facing the
/// viewer).
double irradiance(const Lighting& light, const Vec3& p, const Vec3& n) {
  // Directional term: max(0, n . l).
  const double directional =
      light.directional * std::max(0.0, dot(n, light.to_directional));
  // Point term: max(0, n . (P - p) / |P - p|) I / (|P - p|^2 + d0^2).
  const Vec3 to_point = sub(light.point_position, p);
  const double dist2 = dot(to_point, to_point);
  const double cosine = std::max(0.0, dot(n, to_point) / std::sqrt(dist2));
  const double point =
      light.point * cosine /
      (dist2 + light.point_falloff_d0 * light.point_falloff_d0);
  return light.ambient + directional + point;
}

void requireRotation(const Pose& pose) {
  const auto& R = pose.R;
  for (double r : R) requireFinite("pose rotation entry", r);
  for (double t : pose.t) requireFinite("pose translation entry", t);
  if (!isRotation(R)) throw ParameterError(notRotationMessage("pose"));
}

Frame renderPrepared(const Scene& scene, int width, int height,
                     const Pose& pose) {
  requireSize(width, height);
  requireRotation(pose);
  const auto& R = pose.R;
  // Camera centre in the world: C = -R^T t.
  const Vec3 t{{pose.t[0], pose.t[1], pose.t[2]}};
  const Vec3 centre = scale(multiplyTransposed(R, t), -1.0);
  for (int a = 0; a < 3; ++a) {
    if (!(centre[a] > scene.room.lo[a] && centre[a] < scene.room.hi[a])) {
      std::ostringstream msg;
      msg << "pose: camera centre (" << centre[0] << ", " << centre[1] << ", "
          << centre[2] << ") lies outside the room [" << scene.room.lo[0]
          << ", " << scene.room.hi[0] << "] x [" << scene.room.lo[1] << ", "
          << scene.room.hi[1] << "] x [" << scene.room.lo[2] << ", "
          << scene.room.hi[2] << "]; expected a camera inside it";
      throw ParameterError(msg.str());
    }
  }

  Frame frame;
  frame.K = CameraIntrinsics(0.9 * width, 0.9 * width, (width - 1) / 2.0,
                             (height - 1) / 2.0);
  frame.pose = pose;
  frame.image = ColorImage(width, height, 3);
  frame.normals_gt = NormalMap(width, height, 3);
  frame.depth = ScalarMap(width, height, 1);
  const std::array<double, 9> K_inv = frame.K.inverse();

#pragma omp parallel for schedule(dynamic, 4)
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      // Ray of the pixel centre in the camera, then in the world.
      const Vec3 ray_cam = multiply(
          K_inv, Vec3{{static_cast<double>(x), static_cast<double>(y), 1.0}});
      const Vec3 ray_world = multiplyTransposed(R, ray_cam);
      SurfaceHit hit = trace(scene, centre, ray_world);
      if (!std::isfinite(hit.s)) {
        for (int c = 0; c < 3; ++c) {
          frame.image.at(c, y, x) = 0.0f;
          frame.normals_gt.at(c, y, x) = kMissing;
        }
        frame.depth.at(0, y, x) = kMissing;
        continue;
      }
      // Orient the normal towards the viewer: n . d <= 0.
      if (dot(hit.normal, ray_world) > 0.0) hit.normal = scale(hit.normal, -1);
      const Vec3 point = add(centre, scale(ray_world, hit.s));
      const Rgb rho =
          albedo(scene.materials[static_cast<std::size_t>(hit.material)], hit.u,
                 hit.v);
      const double light = irradiance(scene.lighting, point, hit.normal);
      // Camera-frame normal: n_cam = R n_world.
      const Vec3 normal_cam = multiply(R, hit.normal);
      for (int c = 0; c < 3; ++c) {
        frame.image.at(c, y, x) =
            static_cast<float>(std::min(1.0, std::max(0.0, rho[c] * light)));
        frame.normals_gt.at(c, y, x) = static_cast<float>(normal_cam[c]);
      }
      frame.depth.at(0, y, x) = static_cast<float>(hit.s);
    }
  }
  return frame;
}

}  // namespace

Pose defaultPose(int scene_id) {
  const Scene scene = makeScene(scene_id);
  return poseFromCentre(
      rotationFromYawPitch(scene.camera_yaw, scene.camera_pitch),
      scene.camera_centre);
}

Frame renderScene(int scene_id, int width, int height) {
  return renderScene(scene_id, width, height, defaultPose(scene_id));
}

Frame renderScene(int scene_id, int width, int height, const Pose& pose) {
  return renderPrepared(makeScene(scene_id), width, height, pose);
}

Frame renderUntextured(int scene_id, int width, int height, const Pose& pose) {
  Scene scene = makeScene(scene_id);
  for (Material& m : scene.materials) m = uniform(m.base);
  return renderPrepared(scene, width, height, pose);
}

std::vector<Frame> renderSequence(int scene_id, int width, int height,
                                  int num_frames, double degrees_per_frame,
                                  double fps) {
  const Scene scene = makeScene(scene_id);
  requireSize(width, height);
  if (num_frames < 1) {
    std::ostringstream msg;
    msg << "renderSequence: num_frames = " << num_frames
        << ": expected at least 1";
    throw ParameterError(msg.str());
  }
  requireFinite("renderSequence: degrees_per_frame", degrees_per_frame);
  requireFinite("renderSequence: fps", fps);
  if (!(fps > 0.0)) {
    std::ostringstream msg;
    msg << "renderSequence: fps = " << fps << ": expected > 0";
    throw ParameterError(msg.str());
  }
  constexpr double kStepM = 0.0025;
  constexpr double kCircleRadiusM = 0.25;
  std::vector<Frame> frames;
  frames.reserve(static_cast<std::size_t>(num_frames));
  for (int k = 0; k < num_frames; ++k) {
    // Pan: yaw grows by degrees_per_frame about the world's vertical axis.
    const double yaw = scene.camera_yaw + k * degrees_per_frame * kPi / 180.0;
    // Circle through the default centre: C_k = C_0 + rho (1 - cos phi, sin
    // phi).
    const double phi = k * kStepM / kCircleRadiusM;
    const Vec3 centre =
        add(scene.camera_centre, {{kCircleRadiusM * (1.0 - std::cos(phi)),
                                   kCircleRadiusM * std::sin(phi), 0.0}});
    frames.push_back(renderPrepared(
        scene, width, height,
        poseFromCentre(rotationFromYawPitch(yaw, scene.camera_pitch), centre)));
    frames.back().stamp = k / fps;
  }
  return frames;
}

Pose relativePose(const Pose& cur, const Pose& prev) {
  Pose T_cur_prev;
  T_cur_prev.R = relativeRotation(cur, prev);
  const Vec3 Rt = multiply(T_cur_prev.R, prev.t);
  for (int r = 0; r < 3; ++r) T_cur_prev.t[r] = cur.t[r] - Rt[r];
  return T_cur_prev;
}

std::vector<Frame> renderTranslation(int scene_id, int width, int height,
                                     int num_frames, const Vec3& step_cam,
                                     double fps) {
  const Scene scene = makeScene(scene_id);
  requireSize(width, height);
  if (num_frames < 1 || !(fps > 0.0)) {
    std::ostringstream msg;
    msg << "renderTranslation: num_frames = " << num_frames << ", fps = " << fps
        << ": expected at least 1 and > 0";
    throw ParameterError(msg.str());
  }
  for (double v : step_cam) requireFinite("renderTranslation: step_cam", v);
  requireFinite("renderTranslation: fps", fps);
  const Pose start = defaultPose(scene_id);
  std::vector<Frame> frames;
  for (int k = 0; k < num_frames; ++k) {
    // X_cam_k = X_cam_0 - k step_cam: the camera centre moves by +k step.
    Pose pose = start;
    for (int r = 0; r < 3; ++r) pose.t[r] -= k * step_cam[r];
    frames.push_back(renderPrepared(scene, width, height, pose));
    frames.back().stamp = k / fps;
  }
  return frames;
}

}  // namespace synthetic
}  // namespace normal_fusion
