// Files in and out: normal maps (EXR, PFM, colour-coded PNG), images,
// camera_info YAML.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

#include "normal_fusion/types.h"

namespace normal_fusion {
namespace io {

/// Reads a normal map. Float files (.exr, .pfm): three channels x, y, z in the
/// order OpenCV's imread returns them (no BGR/RGB swap), NaN = missing.
/// 8-bit files (.png and others): colour-coded, c = (n + 1) / 2 * 255 with
/// x -> R, y -> G, z -> B, black (0,0,0) = missing; decoded vectors are
/// normalized. 16-bit colour-coded files are read alike (c / 65535); an alpha
/// channel is ignored. Throws InputError with the path and the problem.
NormalMap readNormalMap(const std::string& path);

/// Writes a float normal map (.exr or .pfm by extension; NaN kept). Throws
/// InputError for another extension, a map without 3 planes or a failed write.
void writeNormalMap(const std::string& path, const NormalMap& normals);

/// Reads a one-channel scalar map (confidence, weights): float files (.exr,
/// .pfm) as stored, 8- or 16-bit grey images scaled to [0, 1]. Throws
/// InputError.
ScalarMap readScalarMap(const std::string& path);
/// Writes a one-plane float map (.exr or .pfm by extension). Throws InputError.
void writeScalarMap(const std::string& path, const ScalarMap& values);

/// Reads a depth image into metres (REP 118 units): 16-bit unsigned (PNG)
/// in millimetres with 0 = no depth, or float (.exr, .pfm) in metres with
/// NaN, 0, negative and infinite values = no depth; NaN where missing.
/// Throws InputError for another pixel type or more than one channel.
ScalarMap readDepthMap(const std::string& path);
/// Writes a depth map in metres: .png as 16-bit millimetres (rounded; no
/// depth and values beyond 65.535 m as 0), .exr / .pfm as float metres (NaN
/// kept). Throws InputError.
void writeDepthMap(const std::string& path, const ScalarMap& depth_m);

/// The colour code of one component of a unit normal: c = (n + 1) / 2,
/// clamped to [0, 1]; x -> R, y -> G, z -> B, black where the normal is
/// missing. Inline, without OpenCV, so that every picture of normals (files,
/// the nodes' visualisation) codes them alike.
inline float colorCodeComponent(float n) {
  return std::clamp(0.5f * (n + 1.0f), 0.0f, 1.0f);
}
/// The same code in 8 bits: round(255 c).
inline std::uint8_t colorCodeByte(float n) {
  return static_cast<std::uint8_t>(std::lround(colorCodeComponent(n) * 255.0f));
}

/// Colour coding of a normal map (colorCodeComponent): 3 planes R, G, B in
/// [0, 1], black where missing.
ColorImage colorCode(const NormalMap& normals);
/// Writes the colour-coded picture (8-bit PNG).
void writeNormalPicture(const std::string& path, const NormalMap& normals);

/// Reads an 8- or 16-bit grey or colour image into planes in [0, 1]
/// (3 planes R, G, B for colour, 1 plane for grey; alpha dropped).
/// Throws InputError.
ColorImage readImage(const std::string& path);
/// Writes a 1- or 3-plane [0, 1] image as 8-bit (PNG by extension); values
/// are clamped to [0, 1], NaN is written as 0.
void writeImage(const std::string& path, const ColorImage& image);
/// Writes a scalar map as a false-colour picture with values mapped from
/// [lo, hi] (NaN black), for error images. Colour map: OpenCV's INFERNO.
/// Throws ParameterError unless lo < hi (both finite), InputError otherwise.
void writeHeatmap(const std::string& path, const ScalarMap& values, double lo,
                  double hi);

/// Reads intrinsics from a camera_info YAML in the ROS camera_calibration
/// format (camera_matrix: {rows: 3, cols: 3, data: [...]}, image_width,
/// image_height). The other keys of the format are optional on input. Throws
/// InputError for a missing file or key, a wrong shape, a non-positive size
/// or a singular or non-finite K.
CameraIntrinsics readCameraInfo(const std::string& path, int* width = nullptr,
                                int* height = nullptr);
/// Writes the same format for a rectified pinhole camera: plumb_bob with zero
/// distortion, R = I, P = [K | 0]. Throws InputError for a bad K or size.
void writeCameraInfo(const std::string& path, const CameraIntrinsics& K,
                     int width, int height,
                     const std::string& camera_name = "camera");

}  // namespace io
}  // namespace normal_fusion
