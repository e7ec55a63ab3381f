// fuse_normals: regularizes and fuses normal maps of one frame from files.
//
//   fuse_normals --image RGB.png --camera-info CAMERA.yaml --normals A.exr
//                [--normals B.exr ...] --output FUSED.exr [solver options]
//
// Exit codes: 0 success, 1 unusable input (files, sizes), 2 usage error
// (unknown option, missing or bad value). Errors are one line on stderr that
// starts with "fuse_normals: error: ".
#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"
#include "normal_fusion/settings.h"
#include "normal_fusion/settings_table.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/solver_options.h"
#include "normal_fusion/types.h"

namespace {

namespace nf = normal_fusion;

constexpr int kExitInputError = 1;
constexpr int kExitUsageError = 2;

/// A malformed command line: unknown option, missing or bad value.
using UsageError = nf::cli::UsageError;

/// One --normals argument with the per-input options that followed it.
struct InputSpec {
  std::string normals_path;
  std::string confidence_path;  ///< empty: confidence 1 everywhere
  double weight = 1.0;
  std::string orientation_name = "optical";
  nf::Orientation orientation;
};

struct Options {
  std::string image_path;
  std::string camera_info_path;
  std::string output_path;
  std::vector<InputSpec> inputs;
  nf::SolverSettings settings;
  bool help = false;
  bool print_markdown = false;  ///< print the settings table and exit
};

void printUsage(std::ostream& out) {
  const nf::SolverSettings d;
  out << "Usage: fuse_normals --image RGB.png --camera-info CAMERA.yaml\n"
         "                    --normals A.exr [input options]\n"
         "                    [--normals B.exr [input options] ...]\n"
         "                    --output FUSED.exr [solver options]\n"
         "\n"
         "Regularizes and fuses the normal maps of one frame, guided by its\n"
         "image. Writes the fused normals (float, x y z per pixel, camera\n"
         "optical frame) to --output (.exr or .pfm) and a colour-coded "
         "picture\n"
         "beside it (same stem, .png).\n"
         "\n"
         "Files:\n"
         "  --image PATH          guide image, 8/16-bit grey or colour\n"
         "  --camera-info PATH    ROS camera_calibration YAML of the image\n"
         "  --normals PATH        a normal map (.exr/.pfm float, or a colour-\n"
         "                        coded 8-bit .png); repeat for more inputs\n"
         "  --output PATH         fused normal map (.exr or .pfm)\n"
         "\n"
         "Input options (apply to the most recent --normals):\n"
         "  --weight W            global weight of this input (default 1)\n"
         "  --confidence PATH     per-pixel confidence in [0, 1], one channel\n"
         "  --orientation O       optical | optical_flipped | opengl | nine\n"
         "                        numbers of a signed permutation (row-major)\n"
         "\n"
         "Solver options (defaults in brackets):\n";
  nf::cli::printSolverOptions(out, d);
  out << "  --no-edges                      same as --edge-enabled off\n"
      << "  --print-settings-markdown       the solver settings' table of "
         "docs/parameters.md\n"
      << "  --help                          this text\n"
      << "\n"
      << "Exit codes: 0 success, 1 unusable input, 2 usage error.\n";
}

/// Strict number parsing, as a usage error.
double parseDouble(const std::string& option, const std::string& text) {
  try {
    return nf::cli::parseDouble(option, text);
  } catch (const nf::ParameterError& e) {
    throw UsageError(e.what());
  }
}

/// Runs a parser of settings.h, turning its ParameterError into a usage error.
template <typename Parse>
auto parseName(const std::string& option, const std::string& text, Parse parse)
    -> decltype(parse(text)) {
  try {
    return parse(text);
  } catch (const nf::ParameterError& e) {
    throw UsageError(option + ": " + e.what());
  }
}

bool hasFloatExtension(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  return ext == ".exr" || ext == ".EXR" || ext == ".pfm" || ext == ".PFM";
}

/// Applies one option that takes a value; `value()` reads it (inline or the
/// next argument).
template <typename Value>
void applyValueOption(const std::string& option, const Value& value,
                      Options& options) {
  const auto currentInput = [&]() -> InputSpec& {
    if (options.inputs.empty()) {
      throw UsageError(option + " must follow the --normals it applies to");
    }
    return options.inputs.back();
  };
  if (option == "--image") {
    options.image_path = value();
  } else if (option == "--camera-info") {
    options.camera_info_path = value();
  } else if (option == "--output") {
    options.output_path = value();
  } else if (option == "--normals") {
    InputSpec input;
    input.normals_path = value();
    options.inputs.push_back(input);
  } else if (option == "--weight") {
    InputSpec& input = currentInput();
    input.weight = parseDouble(option, value());
    if (input.weight < 0.0) {
      throw UsageError(option + ": expected a weight >= 0, got " +
                       std::to_string(input.weight));
    }
  } else if (option == "--confidence") {
    currentInput().confidence_path = value();
  } else if (option == "--orientation") {
    InputSpec& input = currentInput();
    input.orientation_name = value();
    input.orientation =
        parseName(option, input.orientation_name, nf::Orientation::fromString);
  } else if (nf::cli::isSolverOption(option)) {
    const std::string replacement = nf::cli::replacementOption(option);
    if (!replacement.empty()) {
      std::cerr << "fuse_normals: warning: " << option << " is deprecated; use "
                << replacement << "\n";
    }
    try {
      std::ostream no_warnings(nullptr);  // printed above, with the prefix
      nf::cli::applySolverOption(option, value(), options.settings,
                                 no_warnings);
    } catch (const nf::ParameterError& e) {
      throw UsageError(e.what());
    }
  } else {
    throw UsageError("unknown option '" + option + "' (see --help)");
  }
}

/// The files and settings a run needs, as usage errors.
void checkComplete(Options& options) {
  if (options.image_path.empty()) throw UsageError("missing --image");
  if (options.camera_info_path.empty()) {
    throw UsageError("missing --camera-info");
  }
  if (options.inputs.empty()) throw UsageError("missing --normals");
  if (options.output_path.empty()) throw UsageError("missing --output");
  if (!hasFloatExtension(options.output_path)) {
    throw UsageError("--output: expected a .exr or .pfm path, got '" +
                     options.output_path + "'");
  }
  try {
    options.settings.validate();
  } catch (const nf::ParameterError& e) {
    throw UsageError(std::string("solver settings: ") + e.what());
  }
}

Options parseArguments(int argc, char** argv) {
  Options options;
  nf::cli::ArgumentCursor arguments(argc, argv);
  while (arguments.next()) {
    const std::string& option = arguments.option();
    // Flags without a value.
    if (option == "--help" || option == "--no-edges" ||
        option == "--print-settings-markdown") {
      arguments.expectNoValue();
      if (option == "--help") options.help = true;
      if (option == "--print-settings-markdown") options.print_markdown = true;
      if (option == "--no-edges") options.settings.edges.enabled = false;
      continue;
    }
    applyValueOption(
        option, [&] { return arguments.value(); }, options);
  }
  if (options.help || options.print_markdown) return options;
  checkComplete(options);
  return options;
}

/// Sends stderr (file descriptor 2) to /dev/null while it lives: the image
/// codecs print their own diagnostics there (libpng, OpenCV), and the tool's
/// errors, which carry the same facts, must stay one line.
class SilencedStderr {
 public:
  SilencedStderr() {
    std::cerr.flush();
    std::fflush(stderr);
    saved_fd_ = ::dup(STDERR_FILENO);
    const int null_fd = ::open("/dev/null", O_WRONLY);
    if (saved_fd_ >= 0 && null_fd >= 0) ::dup2(null_fd, STDERR_FILENO);
    if (null_fd >= 0) ::close(null_fd);
  }
  ~SilencedStderr() {
    std::fflush(stderr);
    if (saved_fd_ >= 0) {
      ::dup2(saved_fd_, STDERR_FILENO);
      ::close(saved_fd_);
    }
  }
  SilencedStderr(const SilencedStderr&) = delete;
  SilencedStderr& operator=(const SilencedStderr&) = delete;

 private:
  int saved_fd_ = -1;
};

/// Fails before any work when the output cannot be written where asked.
void checkOutputDirectory(const std::string& output_path) {
  const std::filesystem::path parent =
      std::filesystem::path(output_path).parent_path();
  std::error_code ec;
  if (!parent.empty() && !std::filesystem::is_directory(parent, ec)) {
    throw nf::InputError("--output '" + output_path + "': the directory '" +
                         parent.string() + "' does not exist");
  }
}

std::string sizeText(int width, int height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

/// Throws InputError unless a map read from `path` has the image's size.
void checkSameSize(const std::string& what, const std::string& path,
                   const nf::PlanarImage& map, const nf::ColorImage& image,
                   const std::string& image_path) {
  if (map.sameSize(image)) return;
  std::string message = what + " '" + path + "' is " +
                        sizeText(map.width(), map.height()) + ", the image '" +
                        image_path + "' is " +
                        sizeText(image.width(), image.height());
  const bool same_aspect =
      static_cast<long long>(map.width()) * image.height() ==
      static_cast<long long>(map.height()) * image.width();
  if (same_aspect && map.width() < image.width()) {
    message +=
        ": lower-resolution inputs are not supported yet; resample them to "
        "the image size";
  } else {
    message += ": expected the same size";
  }
  throw nf::InputError(message);
}

/// Throws InputError unless K is a pinhole camera matrix that gives a
/// finite ray K^-1 (u, v, 1) for every pixel of a width x height image:
/// fx, fy > 0 and within [1e-6 * image size, 1e7] pixels, the principal
/// point within 100 image sizes of the image, last row (0, 0, 1). (The
/// library's CameraIntrinsics::validate() checks finiteness and
/// singularity only.)
void checkIntrinsics(const nf::CameraIntrinsics& K, int width, int height,
                     const std::string& path) {
  const std::string where = "camera_info '" + path + "': ";
  const auto number = [](double v) {
    std::ostringstream text;
    text << v;
    return text.str();
  };
  const double size = std::max(width, height);
  const double f_min = 1e-6 * size;
  const double f_max = 1e7;
  const std::pair<const char*, double> focal[] = {{"fx", K.fx()},
                                                  {"fy", K.fy()}};
  for (const auto& [name, f] : focal) {
    if (!(f > 0.0)) {
      throw nf::InputError(where + "focal length " + name + " = " + number(f) +
                           "; expected fx, fy > 0 (pixels)");
    }
    if (!(f >= f_min && f <= f_max)) {
      throw nf::InputError(where + "focal length " + name + " = " + number(f) +
                           " is out of range for a " + sizeText(width, height) +
                           " image; expected " + number(f_min) + " <= " + name +
                           " <= " + number(f_max) + " pixels");
    }
  }
  const std::tuple<const char*, double, int, const char*> centre[] = {
      {"cx", K.cx(), width, "widths"}, {"cy", K.cy(), height, "heights"}};
  for (const auto& [name, c, extent, unit] : centre) {
    const double lo = -100.0 * extent;
    const double hi = (extent - 1) + 100.0 * extent;
    if (!(c >= lo && c <= hi)) {
      throw nf::InputError(where + "principal point " + name + " = " +
                           number(c) + " is more than 100 image " + unit +
                           " outside the " + sizeText(width, height) +
                           " image; expected " + number(lo) + " <= " + name +
                           " <= " + number(hi));
    }
  }
  if (K.K[3] != 0.0 || K.K[6] != 0.0 || K.K[7] != 0.0 || K.K[8] != 1.0) {
    throw nf::InputError(
        where + "expected K = [fx s cx; 0 fy cy; 0 0 1], got " +
        "K[1][0] = " + number(K.K[3]) + ", last row (" + number(K.K[6]) + ", " +
        number(K.K[7]) + ", " + number(K.K[8]) + ")");
  }
  // The rays of the corners (the largest), as the solver has them (float).
  const std::array<double, 9> inv = K.inverse();
  for (const double u : {0.0, width - 1.0}) {
    for (const double v : {0.0, height - 1.0}) {
      for (int row = 0; row < 3; ++row) {
        const double r =
            inv[3 * row] * u + inv[3 * row + 1] * v + inv[3 * row + 2];
        if (!(std::abs(r) <= 1e30)) {
          throw nf::InputError(where + "K gives no finite ray for pixel (" +
                               number(u) + ", " + number(v) +
                               ") (skew s = " + number(K.K[1]) + ")");
        }
      }
    }
  }
}

nf::FusionProblem loadProblem(const Options& options) {
  nf::FusionProblem problem;
  problem.image = nf::io::readImage(options.image_path);
  int info_width = 0;
  int info_height = 0;
  problem.K = nf::io::readCameraInfo(options.camera_info_path, &info_width,
                                     &info_height);
  if (info_width != problem.image.width() ||
      info_height != problem.image.height()) {
    throw nf::InputError(
        "camera_info '" + options.camera_info_path + "' is for " +
        sizeText(info_width, info_height) + ", the image '" +
        options.image_path + "' is " +
        sizeText(problem.image.width(), problem.image.height()) +
        ": expected the same size");
  }
  checkIntrinsics(problem.K, info_width, info_height, options.camera_info_path);
  for (const InputSpec& spec : options.inputs) {
    nf::NormalInput input;
    input.normals = nf::io::readNormalMap(spec.normals_path);
    checkSameSize("normal map", spec.normals_path, input.normals, problem.image,
                  options.image_path);
    if (!spec.confidence_path.empty()) {
      input.confidence = nf::io::readScalarMap(spec.confidence_path);
      checkSameSize("confidence map", spec.confidence_path, input.confidence,
                    problem.image, options.image_path);
    }
    input.weight = spec.weight;
    input.orientation = spec.orientation;
    problem.inputs.push_back(std::move(input));
  }
  return problem;
}

void printReport(std::ostream& out, const Options& options,
                 const nf::FusionProblem& problem,
                 const nf::SolveReport& report,
                 const std::string& picture_path) {
  const auto yesNo = [](bool b) { return b ? "yes" : "no"; };
  out << "fuse_normals: fused " << report.num_inputs << " input(s) on a "
      << sizeText(problem.image.width(), problem.image.height()) << " image\n";
  for (std::size_t l = 0; l < options.inputs.size(); ++l) {
    const InputSpec& spec = options.inputs[l];
    out << "  input " << l << ":            " << spec.normals_path
        << " (weight " << spec.weight << ", orientation "
        << spec.orientation_name;
    if (!spec.confidence_path.empty()) {
      out << ", confidence " << spec.confidence_path;
    }
    out << ")\n";
  }
  out << "  outer iterations:   " << report.outer_iterations << " ("
      << report.rejected_outer_steps << " rejected)\n"
      << "  inner iterations:   " << report.inner_iterations
      << " at full size, " << report.coarse_inner_iterations
      << " on coarser levels (" << report.pyramid_levels
      << " pyramid level(s))\n"
      << "  energy:             " << std::setprecision(8)
      << report.initial_energy << " -> " << report.final_energy << "\n"
      << "  energy per step:   ";
  for (double e : report.energies) out << " " << std::setprecision(8) << e;
  out << "\n"
      << "  time:               " << std::fixed << std::setprecision(3)
      << report.seconds * 1000.0 << " ms\n"
      << std::defaultfloat
      << "  warm start:         " << yesNo(report.warm_started) << "\n"
      << "  converged:          " << yesNo(report.converged)
      << " (budget exhausted: " << yesNo(report.budget_exhausted) << ")\n"
      << "  valid pixels:       " << report.valid_pixels << "\n"
      << "  filled pixels:      " << report.filled_pixels << "\n"
      << "  output:             " << options.output_path << ", " << picture_path
      << "\n";
}

int run(int argc, char** argv) {
  const Options options = parseArguments(argc, argv);
  if (options.help) {
    printUsage(std::cout);
    return 0;
  }
  if (options.print_markdown) {
    nf::printSettingsMarkdown(std::cout, nf::solverSettingDescriptors(), true);
    return 0;
  }
  checkOutputDirectory(options.output_path);
  nf::FusionProblem problem;
  {
    const SilencedStderr silenced;
    problem = loadProblem(options);
  }
  nf::Solver solver(options.settings);
  nf::SolveReport report;
  const nf::NormalMap fused = solver.solve(problem, &report);
  const std::string picture_path = std::filesystem::path(options.output_path)
                                       .replace_extension(".png")
                                       .string();
  {
    const SilencedStderr silenced;
    nf::io::writeNormalMap(options.output_path, fused);
    nf::io::writeNormalPicture(picture_path, fused);
  }
  printReport(std::cout, options, problem, report, picture_path);
  return 0;
}

/// Prints one line: the message with line breaks replaced by spaces.
void printError(const std::string& message) {
  std::string line = message;
  for (char& c : line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  std::cerr << "fuse_normals: error: " << line << std::endl;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const UsageError& e) {
    printError(e.what());
    return kExitUsageError;
  } catch (const nf::ParameterError& e) {
    printError(e.what());
    return kExitUsageError;
  } catch (const nf::InputError& e) {
    printError(e.what());
    return kExitInputError;
  } catch (const std::bad_alloc&) {
    printError("out of memory");
    return kExitInputError;
  } catch (const std::exception& e) {
    printError(e.what());
    return kExitInputError;
  } catch (...) {
    printError("unexpected failure");
    return kExitInputError;
  }
}
