// depth_to_normals: surface normals (and their confidence) of one depth image.
//
//   depth_to_normals --depth D.png|D.exr --camera-info CAM.yaml --output N.exr
//                    [--confidence C.exr] [--method NAME] [options]
//
// Exit codes: 0 success, 1 unusable input (files, sizes), 2 usage error
// (unknown option, missing or bad value). Errors are one line on stderr that
// starts with "depth_to_normals: error: ".
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <iostream>
#include <stdexcept>
#include <string>

#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"
#include "normal_fusion/solver_options.h"

namespace {

namespace nf = normal_fusion;
namespace nd = normal_fusion::depth;

constexpr int kExitInputError = 1;
constexpr int kExitUsageError = 2;

using UsageError = nf::cli::UsageError;

struct Options {
  std::string depth_path, camera_info_path, output_path, confidence_path;
  nd::DepthNormalSettings settings;
  bool help = false;
};

void printUsage(std::ostream& out) {
  const nd::DepthNormalSettings d;
  out << "Usage: depth_to_normals --depth D.png|D.exr --camera-info CAM.yaml\n"
         "                        --output N.exr [--confidence C.exr]\n"
         "                        [--method NAME] [options]\n"
         "\n"
         "Surface normals of a depth image (REP 118 units: a 16-bit PNG in\n"
         "millimetres, 0 = no depth, or a float EXR/PFM in metres, NaN = no\n"
         "depth), in the depth camera's optical frame, facing the camera, NaN\n"
         "where unknown. Writes --output (.exr or .pfm, x y z per pixel), a\n"
         "colour-coded picture beside it (same stem, .png) and, with\n"
         "--confidence, the confidence in [0, 1] (.exr or .pfm).\n"
         "\n"
         "Options (defaults in brackets):\n"
         "  --method NAME                central_difference | plane_fit ["
      << nd::toString(d.method) << "]\n"
      << "  --window-radius R            plane_fit window (2R+1)^2 ["
      << d.window_radius << "]\n"
      << "  --discontinuity-ratio X      relative depth jump of a "
         "discontinuity ["
      << d.discontinuity_ratio << "]\n"
      << "  --discontinuity-noise-sigmas K  noise part of the threshold ["
      << d.discontinuity_noise_sigmas << "]\n"
      << "  --noise-coefficient A        sigma_z = A z^2, 1/m ["
      << d.noise_coefficient << "]\n"
      << "  --normal-sigma-scale S0      confidence scale of sigma_n, rad ["
      << d.normal_sigma_scale << "]\n"
      << "  --edge-distance R            confidence ramp from an edge, "
         "pixels ["
      << d.edge_distance << "]\n"
      << "  --num-threads N              threads, 0 = all [" << d.num_threads
      << "] (was --threads)\n"
      << "  --help                       this text\n"
      << "\n"
      << "Exit codes: 0 success, 1 unusable input, 2 usage error.\n";
}

bool isFloatPath(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  return ext == ".exr" || ext == ".EXR" || ext == ".pfm" || ext == ".PFM";
}

double number(const std::string& option, const std::string& text) {
  try {
    return nf::cli::parseDouble(option, text);
  } catch (const nf::ParameterError& e) {
    throw UsageError(e.what());
  }
}

int integer(const std::string& option, const std::string& text) {
  const double v = number(option, text);
  if (v != static_cast<int>(v)) {
    throw UsageError(option + ": expected an integer, got '" + text + "'");
  }
  return static_cast<int>(v);
}

Options parseArguments(int argc, char** argv) {
  Options o;
  nd::DepthNormalSettings& s = o.settings;
  nf::cli::ArgumentCursor arguments(argc, argv);
  while (arguments.next()) {
    const std::string& option = arguments.option();
    if (option == "--help") {
      arguments.expectNoValue();
      o.help = true;
      continue;
    }
    const std::string value = arguments.value();
    if (option == "--depth") {
      o.depth_path = value;
    } else if (option == "--camera-info") {
      o.camera_info_path = value;
    } else if (option == "--output") {
      o.output_path = value;
    } else if (option == "--confidence") {
      o.confidence_path = value;
    } else if (option == "--method") {
      try {
        s.method = nd::normalMethodFromString(value);
      } catch (const nf::ParameterError& e) {
        throw UsageError(option + ": " + e.what());
      }
    } else if (option == "--window-radius") {
      s.window_radius = integer(option, value);
    } else if (option == "--discontinuity-ratio") {
      s.discontinuity_ratio = number(option, value);
    } else if (option == "--discontinuity-noise-sigmas") {
      s.discontinuity_noise_sigmas = number(option, value);
    } else if (option == "--noise-coefficient") {
      s.noise_coefficient = number(option, value);
    } else if (option == "--normal-sigma-scale") {
      s.normal_sigma_scale = number(option, value);
    } else if (option == "--edge-distance") {
      s.edge_distance = number(option, value);
    } else if (option == "--num-threads" || option == "--threads") {
      // --threads: the spelling before the options followed the parameter
      // names of the depth nodelet.
      if (option == "--threads") {
        std::cerr << "depth_to_normals: warning: --threads is deprecated; "
                     "use --num-threads\n";
      }
      s.num_threads = integer(option, value);
    } else {
      throw UsageError("unknown option '" + option + "' (see --help)");
    }
  }
  if (o.help) return o;
  if (o.depth_path.empty()) throw UsageError("missing --depth");
  if (o.camera_info_path.empty()) throw UsageError("missing --camera-info");
  if (o.output_path.empty()) throw UsageError("missing --output");
  if (!isFloatPath(o.output_path)) {
    throw UsageError("--output: expected a .exr or .pfm path, got '" +
                     o.output_path + "'");
  }
  if (!o.confidence_path.empty() && !isFloatPath(o.confidence_path)) {
    throw UsageError("--confidence: expected a .exr or .pfm path, got '" +
                     o.confidence_path + "'");
  }
  try {
    s.validate();
  } catch (const nf::ParameterError& e) {
    throw UsageError(e.what());
  }
  return o;
}

void run(const Options& o) {
  const nf::ScalarMap depth = nf::io::readDepthMap(o.depth_path);
  int width = 0, height = 0;
  const nf::CameraIntrinsics K =
      nf::io::readCameraInfo(o.camera_info_path, &width, &height);
  if (width != depth.width() || height != depth.height()) {
    throw nf::InputError("camera_info '" + o.camera_info_path + "' is for a " +
                         std::to_string(width) + "x" + std::to_string(height) +
                         " image, the depth '" + o.depth_path + "' is " +
                         std::to_string(depth.width()) + "x" +
                         std::to_string(depth.height()) +
                         ": expected the same size");
  }
  nf::NormalMap normals;
  nf::ScalarMap confidence;
  nd::depthToNormals(depth, K, o.settings, normals,
                     o.confidence_path.empty() ? nullptr : &confidence);
  nf::io::writeNormalMap(o.output_path, normals);
  nf::io::writeNormalPicture(
      std::filesystem::path(o.output_path).replace_extension(".png").string(),
      normals);
  if (!o.confidence_path.empty()) {
    nf::io::writeScalarMap(o.confidence_path, confidence);
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  try {
    options = parseArguments(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "depth_to_normals: error: " << e.what() << "\n";
    return kExitUsageError;
  }
  if (options.help) {
    printUsage(std::cout);
    return 0;
  }
  try {
    run(options);
  } catch (const std::exception& e) {
    std::cerr << "depth_to_normals: error: " << e.what() << "\n";
    return kExitInputError;
  }
  return 0;
}
