// The textured scenes: strong textures on planar faces (checkerboards of
// several cell sizes, posters, a high-contrast random texture) beside
// creases of weak contrast, where an image edge is no geometric edge and a
// geometric edge shows almost no image edge.
#include <sstream>

#include "eval/scene_model.h"
#include "eval/synthetic.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace synthetic {
namespace model {
namespace {

const Rgb kWhite{{0.86, 0.86, 0.84}};
const Rgb kBlack{{0.10, 0.10, 0.12}};

/// A textured room seen along its length, slightly downwards.
Scene makeTexturedRoom() {
  Scene s;
  const int floor = addMaterial(
      &s, patterned(Pattern::kChecker, kWhite, {{0.22, 0.20, 0.18}}, 0.3));
  const int back =
      addMaterial(&s, patterned(Pattern::kNoise, kWhite, kBlack, 0.05));
  const int left =
      addMaterial(&s, patterned(Pattern::kChecker, {{0.80, 0.72, 0.50}},
                                {{0.20, 0.26, 0.45}}, 0.12));
  const int right =
      addMaterial(&s, poster(Pattern::kPosterChecker, {{0.70, 0.72, 0.66}},
                             kBlack, kWhite, 0.05, 1.6, 4.0, 0.7, 2.1));
  const int ceiling = addMaterial(&s, uniform({{0.90, 0.90, 0.88}}));
  const int near = addMaterial(&s, uniform({{0.70, 0.70, 0.70}}));
  s.room.material = {{near, back, right, left, floor, ceiling}};
  const int clay = addMaterial(&s, uniform({{0.66, 0.52, 0.40}}));
  const int small_checker = addMaterial(
      &s, patterned(Pattern::kChecker, kWhite, {{0.55, 0.12, 0.10}}, 0.05));
  const int noise =
      addMaterial(&s, patterned(Pattern::kNoise, {{0.90, 0.85, 0.60}},
                                {{0.15, 0.25, 0.30}}, 0.03));
  const int posters =
      addMaterial(&s, poster(Pattern::kPosterStripes, {{0.62, 0.62, 0.66}},
                             {{0.85, 0.80, 0.25}}, {{0.15, 0.20, 0.55}}, 0.04,
                             0.1, 0.5, 0.2, 0.8));
  // Turned by 45 degrees on the light's plane y = 0, one albedo: their
  // front faces meet at creases of almost no contrast.
  s.boxes.push_back(floorBox(2.8, 0.0, 0.35, 0.35, 0.35, kPi / 4, clay));
  s.boxes.push_back(floorBox(4.9, 0.0, 0.3, 0.3, 0.8, kPi / 4, clay));
  // Textured faces: image edges without geometric edges.
  s.boxes.push_back(floorBox(3.6, 1.3, 0.4, 0.35, 0.45, 0.2, small_checker));
  s.boxes.push_back(floorBox(3.9, -1.4, 0.35, 0.45, 0.6, -0.25, noise));
  s.boxes.push_back(floorBox(2.4, -0.9, 0.02, 0.3, 0.5, 0.0, posters));
  s.camera_pitch = 11.0 * kPi / 180.0;
  return s;
}

/// A room corner seen at an angle, walls and floor textured.
Scene makeTexturedCorner() {
  Scene s;
  const int floor =
      addMaterial(&s, patterned(Pattern::kChecker, {{0.80, 0.78, 0.72}},
                                {{0.30, 0.28, 0.26}}, 0.05));
  const int back =
      addMaterial(&s, poster(Pattern::kPosterStripes, {{0.78, 0.76, 0.70}},
                             {{0.20, 0.30, 0.60}}, {{0.90, 0.70, 0.20}}, 0.08,
                             -2.3, -0.5, 0.6, 2.2));
  const int right =
      addMaterial(&s, patterned(Pattern::kNoise, kWhite, kBlack, 0.1));
  const int left = addMaterial(&s, uniform({{0.70, 0.74, 0.78}}));
  const int ceiling = addMaterial(&s, uniform({{0.92, 0.92, 0.90}}));
  const int near = addMaterial(&s, uniform({{0.70, 0.70, 0.70}}));
  s.room.material = {{near, back, right, left, floor, ceiling}};
  const int stone = addMaterial(&s, uniform({{0.60, 0.60, 0.58}}));
  const int checker =
      addMaterial(&s, patterned(Pattern::kChecker, {{0.85, 0.85, 0.30}},
                                {{0.20, 0.20, 0.20}}, 0.12));
  const int noise =
      addMaterial(&s, patterned(Pattern::kNoise, {{0.85, 0.60, 0.55}},
                                {{0.20, 0.15, 0.35}}, 0.04));
  s.boxes.push_back(floorBox(3.4, 0.0, 0.3, 0.3, 0.45, kPi / 4, stone));
  s.boxes.push_back(floorBox(4.6, -1.2, 0.45, 0.35, 0.35, 0.35, checker));
  s.boxes.push_back(floorBox(3.0, -1.6, 0.3, 0.3, 0.7, -0.2, noise));
  s.boxes.push_back(floorBox(5.3, -0.3, 0.35, 0.35, 0.3, kPi / 4, stone));
  s.camera_centre = {{0.8, 1.2, 1.3}};
  s.camera_yaw = -30.0 * kPi / 180.0;
  s.camera_pitch = 14.0 * kPi / 180.0;
  return s;
}

}  // namespace

Scene makeTexturedScene(int scene_id) {
  if (scene_id == kTexturedRoomScene) return makeTexturedRoom();
  if (scene_id == kTexturedCornerScene) return makeTexturedCorner();
  std::ostringstream msg;
  msg << "makeTexturedScene: scene id " << scene_id << " is no textured scene";
  throw ParameterError(msg.str());
}

}  // namespace model
}  // namespace synthetic
}  // namespace normal_fusion
