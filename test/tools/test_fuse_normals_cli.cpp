// The fuse_normals command-line tool, run as a process on small files:
// outputs on success, exit codes and one-line errors on bad input or usage.
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "normal_fusion/io.h"
#include "normal_fusion/types.h"

#ifndef FUSE_NORMALS_BIN
#define FUSE_NORMALS_BIN ""
#endif

namespace normal_fusion {
namespace {

namespace fs = std::filesystem;

constexpr int kWidth = 32;
constexpr int kHeight = 24;
constexpr char kErrorPrefix[] = "fuse_normals: error: ";

struct RunResult {
  int exit_code = -1;  ///< -1 when the process did not exit normally (crash)
  std::string out;
  std::string err;
};

std::string readFile(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

/// Quotes one argument for /bin/sh.
std::string shellQuote(const std::string& arg) {
  std::string quoted = "'";
  for (char c : arg) {
    if (c == '\'') {
      quoted += "'\\''";
    } else {
      quoted += c;
    }
  }
  return quoted + "'";
}

/// Angle in degrees between two unit vectors.
double angleDeg(const float a[3], const float b[3]) {
  const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  return std::acos(std::max(-1.0, std::min(1.0, dot))) * 180.0 /
         3.14159265358979323846;
}

/// A 32 x 24 view of one plane facing the camera, written to a temp dir:
/// image.png (colour), camera.yaml, noisy.exr (noisy normals with a hole),
/// flipped.exr (noisy normals pointing away from the camera), confidence.png.
class FuseNormalsCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern =
        (fs::temp_directory_path() / "nf_cli_XXXXXX").string();
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
    binary_ = FUSE_NORMALS_BIN;
    ASSERT_FALSE(binary_.empty())
        << "FUSE_NORMALS_BIN is not defined at compile time";
    ASSERT_TRUE(fs::exists(binary_)) << "no fuse_normals binary at " << binary_;

    const float len = std::sqrt(0.3f * 0.3f + 0.2f * 0.2f + 1.0f);
    plane_normal_[0] = 0.3f / len;
    plane_normal_[1] = -0.2f / len;
    plane_normal_[2] = -1.0f / len;

    ColorImage image(kWidth, kHeight, 3);
    for (int y = 0; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) {
        image.at(0, y, x) = 0.2f + 0.6f * x / (kWidth - 1);
        image.at(1, y, x) = 0.5f;
        image.at(2, y, x) = 0.2f + 0.6f * y / (kHeight - 1);
      }
    }
    io::writeImage(path("image.png"), image);
    io::writeCameraInfo(path("camera.yaml"),
                        CameraIntrinsics(30.0, 30.0, 15.5, 11.5), kWidth,
                        kHeight);

    noisy_ = noisyPlane(1, 1.0f);
    // A 4 x 4 hole of missing normals.
    for (int y = 10; y < 14; ++y) {
      for (int x = 6; x < 10; ++x) {
        for (int c = 0; c < 3; ++c) noisy_.at(c, y, x) = NAN;
      }
    }
    io::writeNormalMap(path("noisy.exr"), noisy_);
    io::writeNormalMap(path("flipped.exr"), noisyPlane(2, -1.0f));
    io::writeImage(path("confidence.png"),
                   ColorImage(kWidth, kHeight, 1, 0.8f));
  }

  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  std::string path(const std::string& name) const {
    return (dir_ / name).string();
  }

  /// sign * plane normal plus Gaussian noise (sigma 0.1), normalized.
  NormalMap noisyPlane(unsigned seed, float sign) const {
    NormalMap n(kWidth, kHeight, 3);
    std::mt19937 rng(seed);
    std::normal_distribution<float> noise(0.0f, 0.1f);
    for (std::size_t i = 0; i < n.pixelCount(); ++i) {
      float v[3];
      for (int c = 0; c < 3; ++c) v[c] = sign * plane_normal_[c] + noise(rng);
      const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int c = 0; c < 3; ++c) n.plane(c)[i] = v[c] / len;
    }
    return n;
  }

  /// Mean angle in degrees to the plane normal over the valid pixels.
  double meanAngleToPlane(const NormalMap& n) const {
    double sum = 0.0;
    int count = 0;
    for (std::size_t i = 0; i < n.pixelCount(); ++i) {
      const float v[3] = {n.plane(0)[i], n.plane(1)[i], n.plane(2)[i]};
      if (!isValidNormal(v[0], v[1], v[2])) continue;
      sum += angleDeg(v, plane_normal_);
      ++count;
    }
    return count > 0 ? sum / count : 180.0;
  }

  RunResult runTool(const std::vector<std::string>& args) const {
    std::string command = shellQuote(binary_);
    for (const std::string& arg : args) command += " " + shellQuote(arg);
    const fs::path out = dir_ / "stdout.txt";
    const fs::path err = dir_ / "stderr.txt";
    command +=
        " >" + shellQuote(out.string()) + " 2>" + shellQuote(err.string());
    const int status = std::system(command.c_str());
    RunResult result;
    if (status != -1 && WIFEXITED(status))
      result.exit_code = WEXITSTATUS(status);
    result.out = readFile(out);
    result.err = readFile(err);
    return result;
  }

  /// The base command line: image, camera_info and output in the temp dir.
  std::vector<std::string> baseArgs() const {
    return {"--image",           path("image.png"), "--camera-info",
            path("camera.yaml"), "--output",        path("fused.exr")};
  }

  fs::path dir_;
  std::string binary_;
  float plane_normal_[3] = {0.0f, 0.0f, -1.0f};
  NormalMap noisy_;
};

/// The error contract: exactly one line on stderr, with the tool's prefix.
void expectOneLineError(const RunResult& result, const std::string& needle) {
  EXPECT_EQ(result.err.rfind(kErrorPrefix, 0), 0u) << "stderr: " << result.err;
  ASSERT_FALSE(result.err.empty());
  EXPECT_EQ(result.err.back(), '\n');
  EXPECT_EQ(std::count(result.err.begin(), result.err.end(), '\n'), 1)
      << "stderr: " << result.err;
  EXPECT_NE(result.err.find(needle), std::string::npos)
      << "stderr: " << result.err;
}

void expectUnitLength(const NormalMap& n) {
  ASSERT_EQ(n.channels(), 3);
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    const double len2 = n.plane(0)[i] * n.plane(0)[i] +
                        n.plane(1)[i] * n.plane(1)[i] +
                        n.plane(2)[i] * n.plane(2)[i];
    ASSERT_NEAR(len2, 1.0, 1e-4) << "pixel " << i;
  }
}

TEST_F(FuseNormalsCliTest, FusesOneInputAndWritesExrAndPng) {
  std::vector<std::string> args = baseArgs();
  args.insert(args.end(), {"--normals", path("noisy.exr")});
  const RunResult result = runTool(args);
  ASSERT_EQ(result.exit_code, 0) << "stderr: " << result.err;
  EXPECT_TRUE(result.err.empty()) << result.err;
  ASSERT_TRUE(fs::exists(path("fused.exr")));
  ASSERT_TRUE(fs::exists(path("fused.png")));

  const NormalMap fused = io::readNormalMap(path("fused.exr"));
  ASSERT_EQ(fused.width(), kWidth);
  ASSERT_EQ(fused.height(), kHeight);
  // Every pixel, the hole included, holds a unit normal.
  expectUnitLength(fused);
  // The regularizer removes noise from a single plane.
  EXPECT_LT(meanAngleToPlane(fused), meanAngleToPlane(noisy_));

  // The picture is the colour coding of the float map.
  const NormalMap picture = io::readNormalMap(path("fused.png"));
  ASSERT_TRUE(picture.sameSize(fused));
  const double bound = 2.0 * std::sqrt(3.0) / 255.0;  // see test_io
  for (std::size_t i = 0; i < fused.pixelCount(); ++i) {
    double dist2 = 0.0;
    for (int c = 0; c < 3; ++c) {
      const double d = picture.plane(c)[i] - fused.plane(c)[i];
      dist2 += d * d;
    }
    ASSERT_LE(std::sqrt(dist2), bound) << "pixel " << i;
  }

  // The report names the counts a user looks for.
  EXPECT_NE(result.out.find("fused 1 input(s)"), std::string::npos)
      << result.out;
  EXPECT_NE(result.out.find("outer iterations"), std::string::npos);
  EXPECT_NE(result.out.find("filled pixels:      16"), std::string::npos)
      << result.out;
}

TEST_F(FuseNormalsCliTest, PerInputOptionsReachTheSolver) {
  // Only a flipped input: without its orientation the result would face away.
  std::vector<std::string> args = baseArgs();
  args.insert(args.end(), {"--normals", path("flipped.exr"), "--orientation",
                           "optical_flipped", "--num-threads", "1"});
  RunResult result = runTool(args);
  ASSERT_EQ(result.exit_code, 0) << "stderr: " << result.err;
  NormalMap fused = io::readNormalMap(path("fused.exr"));
  expectUnitLength(fused);
  EXPECT_LT(meanAngleToPlane(fused), meanAngleToPlane(noisy_));

  // Two inputs with weights, a confidence map and a matrix orientation.
  args = baseArgs();
  args.insert(args.end(),
              {"--normals", path("noisy.exr"), "--weight", "1.0",
               "--confidence", path("confidence.png"), "--normals",
               path("flipped.exr"), "--orientation=-1 0 0 0 -1 0 0 0 -1",
               "--weight", "0.5", "--lambda", "2", "--backend", "reference"});
  result = runTool(args);
  ASSERT_EQ(result.exit_code, 0) << "stderr: " << result.err;
  fused = io::readNormalMap(path("fused.exr"));
  expectUnitLength(fused);
  EXPECT_LT(meanAngleToPlane(fused), meanAngleToPlane(noisy_));
  EXPECT_NE(result.out.find("fused 2 input(s)"), std::string::npos)
      << result.out;
}

TEST_F(FuseNormalsCliTest, MismatchedSizesAreInputErrors) {
  io::writeNormalMap(path("wide.exr"), NormalMap(kWidth + 8, kHeight, 3, 0.0f));
  std::vector<std::string> args = baseArgs();
  args.insert(args.end(), {"--normals", path("wide.exr")});
  RunResult result = runTool(args);
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "wide.exr");
  EXPECT_FALSE(fs::exists(path("fused.exr")));

  // Same aspect ratio, half the resolution: rejected with its own reason.
  io::writeNormalMap(path("half.exr"),
                     NormalMap(kWidth / 2, kHeight / 2, 3, 0.0f));
  args = baseArgs();
  args.insert(args.end(), {"--normals", path("half.exr")});
  result = runTool(args);
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "lower-resolution");

  // camera_info for another image size.
  io::writeCameraInfo(path("vga.yaml"), CameraIntrinsics(500, 500, 320, 240),
                      640, 480);
  result =
      runTool({"--image", path("image.png"), "--camera-info", path("vga.yaml"),
               "--normals", path("noisy.exr"), "--output", path("fused.exr")});
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "640x480");

  // A confidence map of another size.
  io::writeImage(path("small_conf.png"), ColorImage(8, 8, 1, 1.0f));
  args = baseArgs();
  args.insert(args.end(), {"--normals", path("noisy.exr"), "--confidence",
                           path("small_conf.png")});
  result = runTool(args);
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "small_conf.png");
}

TEST_F(FuseNormalsCliTest, BadFilesAreInputErrors) {
  std::vector<std::string> args = baseArgs();
  args.insert(args.end(), {"--normals", path("missing.exr")});
  RunResult result = runTool(args);
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "missing.exr");

  std::ofstream(path("garbage.yaml")) << "image_width: [\n";
  result = runTool({"--image", path("image.png"), "--camera-info",
                    path("garbage.yaml"), "--normals", path("noisy.exr"),
                    "--output", path("fused.exr")});
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "garbage.yaml");

  // Grey image as normals: wrong channel count.
  args = baseArgs();
  args.insert(args.end(), {"--normals", path("confidence.png")});
  result = runTool(args);
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "confidence.png");

  // A truncated PNG (the codec's own complaint must not reach stderr).
  const std::string png = readFile(path("image.png"));
  std::ofstream(path("truncated.png"), std::ios::binary)
      << png.substr(0, png.size() / 2);
  result = runTool({"--image", path("truncated.png"), "--camera-info",
                    path("camera.yaml"), "--normals", path("noisy.exr"),
                    "--output", path("fused.exr")});
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "truncated.png");

  // An output directory that does not exist.
  result = runTool({"--image", path("image.png"), "--camera-info",
                    path("camera.yaml"), "--normals", path("noisy.exr"),
                    "--output", path("no_dir/fused.exr")});
  EXPECT_EQ(result.exit_code, 1);
  expectOneLineError(result, "no_dir");
}

TEST_F(FuseNormalsCliTest, AbsurdIntrinsicsAreInputErrors) {
  // camera_info files written as text: the values are ones a writer that
  // validates K may refuse.
  const auto cameraInfo = [&](const std::string& name, const std::string& fx,
                              const std::string& fy, const std::string& cx,
                              const std::string& cy) {
    std::ofstream(path(name))
        << "image_width: " << kWidth << "\nimage_height: " << kHeight
        << "\ncamera_matrix:\n  rows: 3\n  cols: 3\n  data: [" << fx << ", 0, "
        << cx << ", 0, " << fy << ", " << cy << ", 0, 0, 1]\n";
    return path(name);
  };
  struct Case {
    std::string camera_info, needle;
  };
  const std::vector<Case> cases = {
      {cameraInfo("negative_fx.yaml", "-30", "30", "15.5", "11.5"),
       "focal length fx = -30"},
      {cameraInfo("negative_fy.yaml", "30", "-30", "15.5", "11.5"),
       "focal length fy = -30"},
      {cameraInfo("negative_both.yaml", "-30", "-30", "15.5", "11.5"),
       "focal length fx = -30"},
      {cameraInfo("tiny_f.yaml", "1e-150", "1e-150", "15.5", "11.5"),
       "focal length fx = 1e-150"},
      {cameraInfo("tiny_fx.yaml", "1e-150", "30", "15.5", "11.5"),
       "fx = 1e-150"},
      {cameraInfo("huge_f.yaml", "1e30", "1e30", "15.5", "11.5"),
       "focal length fx = 1e+30"},
      {cameraInfo("far_cx.yaml", "30", "30", "1e30", "11.5"),
       "principal point cx = 1e+30"},
      {cameraInfo("far_cy.yaml", "30", "30", "15.5", "-1e30"),
       "principal point cy = -1e+30"},
      {cameraInfo("far_cy_small.yaml", "30", "30", "15.5", "5000"),
       "principal point cy = 5000"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.camera_info);
    fs::remove(path("fused.exr"));
    const RunResult result = runTool(
        {"--image", path("image.png"), "--camera-info", c.camera_info,
         "--normals", path("noisy.exr"), "--output", path("fused.exr")});
    EXPECT_EQ(result.exit_code, 1);
    expectOneLineError(result, c.needle);
    EXPECT_NE(result.err.find(c.camera_info), std::string::npos) << result.err;
    EXPECT_FALSE(fs::exists(path("fused.exr")));
  }
  // Unusual but sound intrinsics still work: a principal point outside the
  // image (a crop), a long focal length.
  for (const std::string& file :
       {cameraInfo("crop.yaml", "30", "30", "-200", "300"),
        cameraInfo("tele.yaml", "1e6", "1e6", "15.5", "11.5")}) {
    SCOPED_TRACE(file);
    std::vector<std::string> args = {
        "--image",  path("image.png"), "--camera-info", file,
        "--output", path("fused.exr"), "--normals",     path("noisy.exr")};
    const RunResult result = runTool(args);
    EXPECT_EQ(result.exit_code, 0) << result.err;
  }
}

TEST_F(FuseNormalsCliTest, UsageErrorsExitWithTwo) {
  const std::vector<std::string> input = {"--normals", path("noisy.exr")};
  const auto withInput = [&](std::vector<std::string> extra) {
    std::vector<std::string> args = baseArgs();
    args.insert(args.end(), input.begin(), input.end());
    args.insert(args.end(), extra.begin(), extra.end());
    return args;
  };
  struct Case {
    std::vector<std::string> args;
    std::string needle;
  };
  const std::vector<Case> cases = {
      {withInput({"--frobnicate"}), "--frobnicate"},
      {withInput({"--lambda", "abc"}), "--lambda"},
      {withInput({"--lambda", "-1"}), "lambda"},
      {withInput({"--inner-iterations", "2.5"}), "--inner-iterations"},
      {withInput({"--penalty", "l7"}), "--penalty"},
      {withInput({"--visibility", "sometimes"}), "--visibility"},
      {withInput({"--orientation", "sideways"}), "--orientation"},
      {withInput({"--weight", "-2"}), "--weight"},
      {withInput({"--relative-tolerance"}), "needs a value"},
      {withInput({"stray"}), "stray"},
      {{"--weight", "2", "--image", path("image.png")}, "--normals"},
      {{"--image", path("image.png"), "--camera-info", path("camera.yaml"),
        "--output", path("fused.exr")},
       "--normals"},
      {{"--image", path("image.png"), "--camera-info", path("camera.yaml"),
        "--normals", path("noisy.exr"), "--output", path("fused.png")},
       ".exr or .pfm"},
      {{}, "--image"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(testing::PrintToString(c.args));
    const RunResult result = runTool(c.args);
    EXPECT_EQ(result.exit_code, 2);
    expectOneLineError(result, c.needle);
  }
  EXPECT_FALSE(fs::exists(path("fused.exr")));
}

TEST_F(FuseNormalsCliTest, OldOptionSpellingsStillWorkAndNameTheNewOnes) {
  std::vector<std::string> args = baseArgs();
  args.insert(args.end(), {"--normals", path("noisy.exr"), "--eps", "0.01",
                           "--threads", "1"});
  const RunResult result = runTool(args);
  ASSERT_EQ(result.exit_code, 0) << "stderr: " << result.err;
  EXPECT_EQ(result.err,
            "fuse_normals: warning: --eps is deprecated; use --huber-eps\n"
            "fuse_normals: warning: --threads is deprecated; use "
            "--num-threads\n");
  EXPECT_TRUE(fs::exists(path("fused.exr")));
}

TEST_F(FuseNormalsCliTest, PrintsTheSettingsTableOfTheDocs) {
  const RunResult result = runTool({"--print-settings-markdown"});
  EXPECT_EQ(result.exit_code, 0);
  EXPECT_EQ(result.out.rfind("| parameter | option |", 0), 0u) << result.out;
  EXPECT_NE(result.out.find("| `huber_eps` | `--huber-eps` | 0 |"),
            std::string::npos)
      << result.out;
  EXPECT_TRUE(result.err.empty());
}

TEST_F(FuseNormalsCliTest, HelpPrintsUsage) {
  const RunResult result = runTool({"--help"});
  EXPECT_EQ(result.exit_code, 0);
  EXPECT_NE(result.out.find("Usage: fuse_normals"), std::string::npos);
  EXPECT_NE(result.out.find("--edge-function"), std::string::npos);
  EXPECT_TRUE(result.err.empty());
}

}  // namespace
}  // namespace normal_fusion
