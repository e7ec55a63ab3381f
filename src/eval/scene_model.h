// The synthetic scenes' description (materials, solids, lighting) and the
// pieces of the ray caster shared by synthetic.cpp (scenes 0 - 2 and the
// renderer), scenes_textured.cpp and scenes_curved.cpp (the other scenes).
#pragma once

#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "eval/synthetic_internal.h"

namespace normal_fusion {
namespace synthetic {
namespace model {

using internal::add;
using internal::normalized;
using internal::scale;
using internal::sub;

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();
/// Smallest ray parameter accepted as a hit (metres of z-depth).
constexpr double kMinRayParameter = 1e-6;

using Rgb = std::array<double, 3>;

// ---------------------------------------------------------------------------
// Scene description.

enum class Pattern {
  kUniform,        ///< base colour everywhere
  kChecker,        ///< squares of side `period`, base and alt
  kStripes,        ///< bands of width `period` across u, base and alt
  kPosterStripes,  ///< base outside the rectangle; bands across v inside
  kPosterChecker,  ///< base outside the rectangle; squares inside
  kNoise,  ///< cells of side `period`, each a random mix of base and alt
};

/// Albedo as a function of 2-D surface coordinates (u, v) in metres.
struct Material {
  Pattern pattern = Pattern::kUniform;
  Rgb base{{0.7, 0.7, 0.7}};
  Rgb alt{{0.3, 0.3, 0.3}};
  Rgb accent{{0.5, 0.5, 0.5}};
  double period = 0.5;
  double u0 = 0.0, u1 = 0.0, v0 = 0.0, v1 = 0.0;  ///< poster rectangle
};

/// Axis-aligned room seen from inside; faces -x, +x, -y, +y, -z, +z.
struct Room {
  Vec3 lo{{0.0, -2.5, 0.0}};
  Vec3 hi{{6.0, 2.5, 2.8}};
  std::array<int, 6> material{{0, 0, 0, 0, 0, 0}};
};

/// A solid box turned by `yaw` (radians) about the vertical axis.
struct Box {
  Vec3 center;
  Vec3 half;
  double yaw = 0.0;
  int material = 0;
};

/// A solid vertical cylinder with flat caps.
struct Cylinder {
  double cx = 0.0, cy = 0.0, z0 = 0.0, z1 = 1.0, radius = 0.3;
  int material = 0;
};

struct Sphere {
  Vec3 center;
  double radius = 0.3;
  int material = 0;
};

/// A solid torus: the circle of radius `major` about `center` in the plane
/// normal to `axis` (unit), swept by a disc of radius `minor`.
struct Torus {
  Vec3 center;
  Vec3 axis{{0.0, 0.0, 1.0}};
  double major = 0.4, minor = 0.1;
  int material = 0;
};

/// Lambertian lighting: ambient + directional + point light with the soft
/// fall-off intensity / (d^2 + d0^2).
struct Lighting {
  double ambient = 0.25;
  Vec3 to_directional = normalized({{-0.5, 0.0, 0.8}});
  double directional = 0.45;
  Vec3 point_position{{2.5, 0.0, 2.2}};
  double point = 1.6;
  double point_falloff_d0 = 1.5;
};

struct Scene {
  Room room;
  std::vector<Box> boxes;
  std::vector<Cylinder> cylinders;
  std::vector<Sphere> spheres;
  std::vector<Torus> tori;
  std::vector<Material> materials;
  Lighting lighting;
  Vec3 camera_centre{{0.4, 0.0, 1.5}};
  double camera_yaw = 0.0;    ///< radians, positive turns left
  double camera_pitch = 0.0;  ///< radians, positive looks down
};

inline Material uniform(const Rgb& base) {
  Material m;
  m.base = base;
  return m;
}

inline Material patterned(Pattern pattern, const Rgb& base, const Rgb& alt,
                          double period) {
  Material m;
  m.pattern = pattern;
  m.base = base;
  m.alt = alt;
  m.period = period;
  return m;
}

inline Material poster(Pattern pattern, const Rgb& base, const Rgb& alt,
                       const Rgb& accent, double period, double u0, double u1,
                       double v0, double v1) {
  Material m = patterned(pattern, base, alt, period);
  m.accent = accent;
  m.u0 = u0;
  m.u1 = u1;
  m.v0 = v0;
  m.v1 = v1;
  return m;
}

inline int addMaterial(Scene* scene, const Material& m) {
  scene->materials.push_back(m);
  return static_cast<int>(scene->materials.size()) - 1;
}

/// A box standing on the floor (z = 0) with footprint centre (x, y).
inline Box floorBox(double x, double y, double hx, double hy, double hz,
                    double yaw, int material) {
  return Box{{{x, y, hz}}, {{hx, hy, hz}}, yaw, material};
}

// ---------------------------------------------------------------------------
// Ray casting. A ray is o + s d with d = R^T K^-1 (u, v, 1), so that the ray
// parameter s of a hit is its z-depth in the camera.

struct SurfaceHit {
  double s = kInf;
  Vec3 normal{{0.0, 0.0, 0.0}};  ///< world frame, unit
  double u = 0.0, v = 0.0;       ///< surface coordinates for the texture
  int material = 0;
};

/// Nearest hit of the ray o + s d with the torus that is nearer than hit->s.
void intersectTorus(const Torus& torus, const Vec3& o, const Vec3& d,
                    SurfaceHit* hit);

/// The textured scenes (kTexturedRoomScene, kTexturedCornerScene).
Scene makeTexturedScene(int scene_id);
/// The curved-object scenes (kCurvedLargeScene, kCurvedSmallScene).
Scene makeCurvedScene(int scene_id);

}  // namespace model
}  // namespace synthetic
}  // namespace normal_fusion
