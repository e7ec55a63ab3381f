// The curved-object scenes (cylinders, spheres and tori of several sizes)
// and the ray-torus intersection.
#include <algorithm>
#include <cmath>
#include <sstream>

#include "eval/scene_model.h"
#include "eval/synthetic.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace synthetic {
namespace model {
namespace {

/// Sphere-tracing steps before a ray counts as missing the torus.
constexpr int kMaxTorusSteps = 400;
/// Distance to the surface (metres) that counts as a hit.
constexpr double kTorusHitDistance = 1e-9;

/// Two unit vectors that complete `axis` to a right-handed frame.
void frameOf(const Vec3& axis, Vec3* e1, Vec3* e2) {
  const Vec3 helper =
      std::abs(axis[2]) < 0.9 ? Vec3{{0.0, 0.0, 1.0}} : Vec3{{1.0, 0.0, 0.0}};
  *e1 = normalized(cross(helper, axis));
  *e2 = cross(axis, *e1);
}

/// Signed distance to the torus of a point in its frame (axis = local z).
double torusDistance(const Vec3& p, double major, double minor) {
  const double rho = std::sqrt(p[0] * p[0] + p[1] * p[1]);
  const double a = rho - major;
  return std::sqrt(a * a + p[2] * p[2]) - minor;
}

/// A room with a random texture on its walls (stereo needs texture).
Scene curvedRoom() {
  Scene s;
  const int floor =
      addMaterial(&s, patterned(Pattern::kChecker, {{0.74, 0.70, 0.62}},
                                {{0.40, 0.36, 0.32}}, 0.25));
  const int walls =
      addMaterial(&s, patterned(Pattern::kNoise, {{0.82, 0.80, 0.76}},
                                {{0.42, 0.44, 0.48}}, 0.06));
  const int ceiling = addMaterial(&s, uniform({{0.90, 0.90, 0.88}}));
  s.room.material = {{walls, walls, walls, walls, floor, ceiling}};
  return s;
}

/// Large objects: 0.2 - 0.6 m.
Scene makeCurvedLarge() {
  Scene s = curvedRoom();
  const int clay = addMaterial(&s, uniform({{0.72, 0.50, 0.40}}));
  const int blue = addMaterial(&s, uniform({{0.30, 0.45, 0.72}}));
  const int banded =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.85, 0.80, 0.30}},
                                {{0.35, 0.30, 0.15}}, 0.1));
  const int speckled =
      addMaterial(&s, patterned(Pattern::kNoise, {{0.80, 0.78, 0.70}},
                                {{0.45, 0.40, 0.35}}, 0.04));
  s.cylinders.push_back(Cylinder{4.2, 1.2, 0.0, 1.0, 0.5, banded});
  s.spheres.push_back(Sphere{{{4.2, 1.2, 1.3}}, 0.3, blue});
  s.spheres.push_back(Sphere{{{3.6, -1.1, 0.6}}, 0.6, clay});
  // A torus lying on the floor and one standing, facing the camera.
  s.tori.push_back(
      Torus{{{2.5, 0.2, 0.18}}, {{0.0, 0.0, 1.0}}, 0.45, 0.18, speckled});
  s.tori.push_back(Torus{
      {{5.0, -0.1, 0.62}}, normalized({{1.0, 0.3, 0.0}}), 0.45, 0.17, clay});
  s.cylinders.push_back(Cylinder{5.3, -1.6, 0.0, 2.8, 0.25, speckled});
  s.camera_pitch = 12.0 * kPi / 180.0;
  return s;
}

/// Small objects on a table (0.04 - 0.2 m), seen from nearer.
Scene makeCurvedSmall() {
  Scene s = curvedRoom();
  const int table = addMaterial(&s, uniform({{0.55, 0.38, 0.24}}));
  const int white = addMaterial(&s, uniform({{0.85, 0.85, 0.85}}));
  const int red = addMaterial(&s, uniform({{0.70, 0.25, 0.22}}));
  const int teal = addMaterial(&s, uniform({{0.25, 0.55, 0.55}}));
  const int label =
      addMaterial(&s, patterned(Pattern::kStripes, {{0.90, 0.85, 0.40}},
                                {{0.25, 0.30, 0.60}}, 0.03));
  const double tx = 2.4, top_z = 0.72;
  s.boxes.push_back(Box{{{tx, 0.0, top_z}}, {{0.45, 0.7, 0.02}}, 0.0, table});
  for (int i = 0; i < 4; ++i) {
    const double lx = tx + ((i & 1) ? 0.4 : -0.4);
    const double ly = (i & 2) ? 0.64 : -0.64;
    s.boxes.push_back(
        floorBox(lx, ly, 0.03, 0.03, (top_z - 0.02) / 2.0, 0.0, table));
  }
  const double on = top_z + 0.02;
  s.cylinders.push_back(Cylinder{2.3, 0.3, on, on + 0.12, 0.04, label});
  s.cylinders.push_back(Cylinder{2.6, -0.35, on, on + 0.2, 0.07, white});
  s.spheres.push_back(Sphere{{{2.2, -0.1, on + 0.05}}, 0.05, red});
  s.spheres.push_back(Sphere{{{2.55, 0.05, on + 0.09}}, 0.09, teal});
  s.tori.push_back(
      Torus{{{2.1, 0.45, on + 0.025}}, {{0.0, 0.0, 1.0}}, 0.08, 0.025, red});
  s.tori.push_back(Torus{{{2.4, -0.5, on + 0.13}},
                         normalized({{1.0, -0.4, 0.0}}),
                         0.1,
                         0.03,
                         white});
  s.spheres.push_back(Sphere{{{3.4, 1.0, 0.2}}, 0.2, teal});
  s.cylinders.push_back(Cylinder{3.5, -1.0, 0.0, 0.5, 0.15, white});
  s.camera_centre = {{1.1, 0.0, 1.35}};
  s.camera_pitch = 28.0 * kPi / 180.0;
  return s;
}

}  // namespace

void intersectTorus(const Torus& torus, const Vec3& o, const Vec3& d,
                    SurfaceHit* hit) {
  Vec3 e1, e2;
  frameOf(torus.axis, &e1, &e2);
  const double length = std::sqrt(dot(d, d));
  const Vec3 rel = sub(o, torus.center);
  // Ray in the torus frame, unit direction: the distance bound is in metres.
  const Vec3 ol{{dot(rel, e1), dot(rel, e2), dot(rel, torus.axis)}};
  const Vec3 dl =
      scale(Vec3{{dot(d, e1), dot(d, e2), dot(d, torus.axis)}}, 1.0 / length);
  // The bounding sphere of radius major + minor limits the search.
  const double bound = torus.major + torus.minor;
  const double b = dot(ol, dl);
  const double c = dot(ol, ol) - bound * bound;
  const double disc = b * b - c;
  if (disc < 0.0) return;
  const double t_far = -b + std::sqrt(disc);
  double t = std::max(0.0, -b - std::sqrt(disc));
  if (t_far <= 0.0 || t / length >= hit->s) return;
  // Sphere tracing: the signed distance never overshoots the surface, so
  // the first root along the ray is found (the quartic's nearest root).
  bool found = false;
  for (int step = 0; step < kMaxTorusSteps && t <= t_far; ++step) {
    const double dist =
        torusDistance(add(ol, scale(dl, t)), torus.major, torus.minor);
    if (dist < kTorusHitDistance) {
      found = true;
      break;
    }
    t += dist;
  }
  const double s = t / length;
  if (!found || s <= kMinRayParameter || s >= hit->s) return;
  const Vec3 p = add(ol, scale(dl, t));
  const double rho = std::sqrt(p[0] * p[0] + p[1] * p[1]);
  // Normal: from the nearest point of the core circle to p.
  const Vec3 q{{p[0] * (1.0 - torus.major / rho),
                p[1] * (1.0 - torus.major / rho), p[2]}};
  const Vec3 n_local = normalized(q);
  hit->s = s;
  hit->normal = add(add(scale(e1, n_local[0]), scale(e2, n_local[1])),
                    scale(torus.axis, n_local[2]));
  hit->material = torus.material;
  hit->u = torus.major * std::atan2(p[1], p[0]);
  hit->v = torus.minor * std::atan2(p[2], rho - torus.major);
}

Scene makeCurvedScene(int scene_id) {
  if (scene_id == kCurvedLargeScene) return makeCurvedLarge();
  if (scene_id == kCurvedSmallScene) return makeCurvedSmall();
  std::ostringstream msg;
  msg << "makeCurvedScene: scene id " << scene_id << " is no curved scene";
  throw ParameterError(msg.str());
}

}  // namespace model
}  // namespace synthetic
}  // namespace normal_fusion
