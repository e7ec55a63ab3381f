// ViSP's synthetic "Castle" RGB-D sequence (Debian package visp-images-data,
// folder ViSP-images/mbt-depth/Castle-simu) as an evaluation case: the depth
// maps, the grey images, the ground-truth camera poses and the piecewise
// planar model, and from them exact ground-truth normals.
//
// Files of the sequence (checked against the files and against ViSP's own
// reader, testGenericTracker.cpp):
//  - Images/Image_NNNN.pgm: 640 x 480 grey image of the colour camera;
//  - Depth/Depth_NNNN.bin: uint32 LE height, uint32 LE width, then
//    height * width uint16 LE depths, kDepthScaleM metres per unit, 0 = none;
//  - CameraPose/Camera_NNN.txt: the 4 x 4 pose c_M_o of the colour camera
//    (object point X_o maps to X_c = R X_o + t), row-major text;
//  - Config/chateau.xml, chateau_depth.xml: intrinsics (px, py, u0, v0) of
//    the colour and depth cameras;
//  - Models/chateau.wrl (the rendered castle, VRML 2) and Models/cube.cao
//    (the textured cube, placed in the object frame by kCubeToObject).
// The depth camera sits 5 cm beside the colour camera:
// X_depth = X_color + (kDepthFromColorXM, 0, 0).
#pragma once

#include <array>
#include <string>
#include <vector>

#include "eval/synthetic.h"
#include "normal_fusion/geometry.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace castle {

/// Where Debian's visp-images-data package installs the sequence.
constexpr const char* kDefaultDirectory =
    "/usr/share/visp-images-data/ViSP-images/mbt-depth/Castle-simu";

/// Metres per unit of the 16-bit depth files (ViSP's reader of the sequence).
constexpr double kDepthScaleM = 0.000030518;

/// x offset of the depth camera in the colour camera's frame, metres:
/// d_M_c is a pure translation (kDepthFromColorXM, 0, 0).
constexpr double kDepthFromColorXM = -0.05;

/// A planar polygon of the model, vertices in the object frame (metres).
struct Face {
  std::vector<std::array<double, 3>> vertices_obj;
};

/// True when `dir` holds the sequence (Images, Depth, CameraPose, Config and
/// Models/chateau.wrl, Models/cube.cao).
bool available(const std::string& dir = kDefaultDirectory);

/// Frame numbers N for which image, depth and pose files all exist, ascending.
std::vector<int> frameNumbers(const std::string& dir = kDefaultDirectory);

/// Reads a depth file: z-depth in metres (value * scale_m), NaN where the file
/// holds 0. Throws InputError for a missing, truncated or oversized file.
/// The castel sequence's depth files have the same layout.
ScalarMap readDepth(const std::string& path, double scale_m = kDepthScaleM);

/// Reads a 4 x 4 homogeneous pose (16 numbers, row-major). Throws InputError
/// when a number is missing, the last row is not (0, 0, 0, 1) or the rotation
/// is not one (isRotation).
synthetic::Pose readPose(const std::string& path);

/// Reads px, py, u0, v0 of the <camera> element of a ViSP tracker XML file.
/// Throws InputError when one is missing or not a positive number (u0, v0 may
/// be any finite number).
CameraIntrinsics readIntrinsics(const std::string& xml_path);

/// Faces of the IndexedFaceSets of a VRML 2 file whose shapes are given in
/// the file's root frame (chateau.wrl has no shape transforms). Degenerate
/// polygons (fewer than 3 vertices, zero area) are dropped. Throws InputError.
std::vector<Face> readVrmlFaces(const std::string& path);

/// Faces ("face points") of a ViSP .cao file (V1), with its load("...")
/// files, each vertex mapped by T_obj_file (default: identity). Throws
/// InputError.
std::vector<Face> readCaoFaces(const std::string& path,
                               const synthetic::Pose& T_obj_file = {});

/// Placement of cube.cao in the object frame, as ViSP's tracker test of the
/// sequence loads it.
synthetic::Pose cubeToObject();

/// The whole scene: the faces of chateau.wrl and of cube.cao (placed).
std::vector<Face> loadModel(const std::string& dir = kDefaultDirectory);

/// Ray casts the faces seen by a camera with pose T_cam_obj and intrinsics K
/// (pixel centres at integer coordinates): per pixel the z-depth of the
/// nearest face and its unit normal in the camera frame, turned to face the
/// camera; NaN where no face is hit.
void renderModel(const std::vector<Face>& faces,
                 const synthetic::Pose& T_cam_obj, const CameraIntrinsics& K,
                 int width, int height, ScalarMap* depth_cam,
                 NormalMap* normals_cam);

struct LoadSettings {
  /// Ground truth is kept where the model's depth and the file's depth differ
  /// by at most this (metres); elsewhere the model does not explain the depth
  /// map (silhouettes, parts missing from the model) and it is NaN.
  /// The file's depth deviates from the model by up to about 1.5 mm inside
  /// faces (along the renderer's triangle seams and on slanted faces), while
  /// silhouettes differ by centimetres.
  double agreement_tolerance_m = 0.003;
  /// Maps are cropped to the box of the pixels with depth, grown by this many
  /// pixels (clamped to the image); < 0 keeps the full image.
  int crop_margin = 16;
};

/// One frame of the sequence in the depth camera's pixels.
struct Frame {
  int number = 0;
  /// The colour camera's image (1 plane, [0, 1]) sampled (bilinear) where
  /// each depth pixel's 3D point projects (no occlusion test); pixels without
  /// depth get the median of the colour pixels no depth point reaches.
  ColorImage image;
  ScalarMap depth;       ///< z-depth in metres, NaN where none
  NormalMap normals_gt;  ///< model normals where the model agrees with depth
  CameraIntrinsics K;    ///< of the depth camera, after cropping
  synthetic::Pose T_depth_obj;  ///< pose of the depth camera
  int crop_x = 0, crop_y = 0;   ///< top-left corner of the crop in the file
  double agreement = 0.0;  ///< share of the pixels with depth that got ground
                           ///< truth
};

/// Loads frame `number` with ground-truth normals rendered from `faces`.
/// Throws InputError for missing or malformed files.
Frame loadFrame(const std::string& dir, int number,
                const std::vector<Face>& faces,
                const LoadSettings& settings = LoadSettings());

}  // namespace castle

/// ViSP's real "castel" RGB-D sequence of an Intel SR300 (visp-images-data,
/// ViSP-images/mbt-depth/castel), read with castle's readers: castel/
/// image_NNNN.pgm (640 x 480 grey), castel/depth_image_NNNN.bin (castle's
/// depth layout, kDepthScaleM metres per unit), chateau.xml and
/// chateau_depth.xml (intrinsics of the colour and depth cameras) and
/// depth_M_color.txt (the 4 x 4 pose of the colour camera in the depth
/// camera: X_depth = depth_M_color X_color).
namespace castel {

/// Where Debian's visp-images-data package installs the sequence.
constexpr const char* kDefaultDirectory =
    "/usr/share/visp-images-data/ViSP-images/mbt-depth/castel";

/// Metres per unit of the SR300 depth files of this sequence.
constexpr double kDepthScaleM = 0.000124986647;

}  // namespace castel
}  // namespace normal_fusion
