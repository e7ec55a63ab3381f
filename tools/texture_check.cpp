// texture_check: how the dynamic guidance (docs/method.md) treats texture and
// creases, on small scenes made here: a plane and a room corner under a
// checkerboard (or a uniform image), with the paper's noise on the normals or
// with normals of noisy depth. Prints one markdown table row per scene and
// setting: PSNR, mean angular error overall, inside the checker cells,
// within 1 px of a texture edge and within 2 px of the crease, and the time.
//
//   texture_check [--size WxH] [--cell N] [--guidance LIST]
//                 [--guidance-deg LIST] [--runs N] [solver options]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "normal_fusion/depth.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/solver_options.h"

namespace {

namespace nf = normal_fusion;
constexpr double kPi = 3.14159265358979323846;

struct Options {
  int width = 320, height = 240, cell = 16, runs = 3;
  std::vector<double> guidance{0.0, 0.25, 0.5, 1.0};
  std::vector<double> degrees{10.0, 20.0, 40.0};
  nf::SolverSettings settings;
};

/// One scene: the problem, its ground truth and the masks of the metrics.
struct Scene {
  std::string name;
  nf::FusionProblem problem;
  nf::NormalMap gt;
  nf::ScalarMap inside, border, crease;
};

std::vector<double> parseList(const std::string& option,
                              const std::string& text) {
  std::vector<double> values;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    values.push_back(nf::cli::parseDouble(option, item));
  }
  return values;
}

/// The unit normal of the plane turned `deg` degrees about the vertical axis
/// from facing the camera.
std::vector<float> turned(double deg) {
  return {static_cast<float>(std::sin(deg * kPi / 180.0)), 0.0f,
          static_cast<float>(-std::cos(deg * kPi / 180.0))};
}

/// The scene's geometry: a plane turned 30 degrees (`corner` false) or a room
/// corner, two walls at 90 degrees meeting 2 m ahead in the middle column;
/// `depth_noise`: normals of noisy depth (sigma_z = 0.0025 z^2, plane fit),
/// else the paper's noise at `sigma`.
Scene makeScene(const Options& o, const std::string& name, bool corner,
                bool textured, bool depth_noise, double sigma) {
  const int W = o.width, H = o.height;
  Scene s;
  s.name = name;
  nf::FusionProblem& p = s.problem;
  p.K = nf::CameraIntrinsics(0.9 * W, 0.9 * W, (W - 1) / 2.0, (H - 1) / 2.0);
  p.image = nf::ColorImage(W, H, 1);
  s.gt.resize(W, H, 3);
  nf::ScalarMap depth(W, H, 1);
  for (nf::ScalarMap* m : {&s.inside, &s.border, &s.crease}) m->resize(W, H, 1);
  const std::vector<float> left = turned(corner ? 45.0 : 30.0);
  const std::vector<float> right = turned(corner ? -45.0 : 30.0);
  std::mt19937_64 rng(17);
  std::normal_distribution<double> unit(0.0, 1.0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      // Ray r = K^-1 (x, y, 1); the visible wall of a corner is the nearer.
      const double r[3] = {(x - p.K.cx()) / p.K.fx(), (y - p.K.cy()) / p.K.fy(),
                           1.0};
      double z = 1e30;
      const std::vector<float>* normal = &left;
      for (const std::vector<float>* n : {&left, &right}) {
        // Planes through (0, 0, 2): n . P = 2 n_z, z = 2 n_z / (n . r).
        const double zn =
            2.0 * (*n)[2] / ((*n)[0] * r[0] + (*n)[1] * r[1] + (*n)[2] * r[2]);
        if (zn > 0.0 && zn < z) {
          z = zn;
          normal = n;
        }
      }
      for (int c = 0; c < 3; ++c) s.gt.at(c, y, x) = (*normal)[c];
      depth.at(0, y, x) = static_cast<float>(z + 0.0025 * z * z * unit(rng));
      const int cx = x % o.cell, cy = y % o.cell;
      const bool dark = ((x / o.cell) + (y / o.cell)) % 2 == 0;
      p.image.at(0, y, x) = !textured ? 0.5f : dark ? 0.2f : 0.8f;
      const bool edge = (cx == 0 && x > 0) || (cx == o.cell - 1 && x + 1 < W) ||
                        (cy == 0 && y > 0) || (cy == o.cell - 1 && y + 1 < H);
      s.border.at(0, y, x) = edge ? 1.0f : 0.0f;
      s.inside.at(0, y, x) = edge ? 0.0f : 1.0f;
      s.crease.at(0, y, x) =
          corner && std::abs(x - W / 2 + 0.5) < 2.0 ? 1.0f : 0.0f;
    }
  }
  nf::NormalInput input;
  if (depth_noise) {
    nf::depth::depthToNormals(depth, p.K, nf::depth::DepthNormalSettings(),
                              input.normals);
  } else {
    input.normals.resize(W, H, 3);
    std::normal_distribution<float> noise(0.0f, static_cast<float>(sigma));
    for (std::size_t i = 0; i < s.gt.pixelCount(); ++i) {
      float v[3];
      for (int c = 0; c < 3; ++c) v[c] = s.gt.plane(c)[i] + noise(rng);
      const float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int c = 0; c < 3; ++c) input.normals.plane(c)[i] = v[c] / len;
    }
  }
  p.inputs.push_back(input);
  return s;
}

std::string metric(const nf::NormalMap& n, const nf::NormalMap& gt,
                   const nf::ScalarMap& mask) {
  for (std::size_t i = 0; i < mask.pixelCount(); ++i) {
    if (mask.data()[i] > 0.5f) {
      char text[32];
      std::snprintf(text, sizeof(text), "%.2f",
                    nf::angularError(n, gt, mask).mean_deg);
      return text;
    }
  }
  return "-";
}

/// One row: the scene solved `runs` times with `settings` (median time).
void printRow(const Scene& s, const nf::SolverSettings& settings, int runs,
              const std::string& label) {
  std::vector<double> seconds;
  nf::NormalMap n;
  for (int k = 0; k < runs; ++k) {
    nf::SolveReport report;
    n = nf::Solver(settings).solve(s.problem, &report);
    seconds.push_back(report.seconds);
  }
  std::sort(seconds.begin(), seconds.end());
  std::printf(
      "| %s | %s | %.2f | %.2f | %s | %s | %s | %.3f |\n", s.name.c_str(),
      label.c_str(), nf::psnr(n, s.gt), nf::angularError(n, s.gt).mean_deg,
      metric(n, s.gt, s.inside).c_str(), metric(n, s.gt, s.border).c_str(),
      metric(n, s.gt, s.crease).c_str(), seconds[seconds.size() / 2]);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--help") {
      std::cout << "Usage: texture_check [--size WxH] [--cell N] [--guidance "
                   "LIST] [--guidance-deg LIST] [--runs N] [solver options]\n"
                   "Defaults: --size 320x240 --cell 16 --guidance "
                   "0,0.25,0.5,1 --guidance-deg 10,20,40 --runs 3\n\n";
      nf::cli::printSolverOptions(std::cout, nf::SolverSettings());
      std::exit(0);
    }
    if (i + 1 >= argc) throw nf::ParameterError(arg + ": missing value");
    const std::string value = argv[++i];
    if (arg == "--size") {
      if (std::sscanf(value.c_str(), "%dx%d", &o.width, &o.height) != 2) {
        throw nf::ParameterError("--size: expected WxH, got " + value);
      }
    } else if (arg == "--cell") {
      o.cell = nf::cli::parseInt(arg, value);
    } else if (arg == "--runs") {
      o.runs = std::max(1, nf::cli::parseInt(arg, value));
    } else if (arg == "--guidance") {
      o.guidance = parseList(arg, value);
    } else if (arg == "--guidance-deg") {
      o.degrees = parseList(arg, value);
    } else if (nf::cli::isSolverOption(arg)) {
      nf::cli::applySolverOption(arg, value, o.settings);
    } else {
      throw nf::ParameterError("unknown option " + arg);
    }
  }
  o.settings.validate();
  return o;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    const Options o = parse(argc, argv);
    const std::vector<Scene> scenes = {
        makeScene(o, "plane, paper noise 0.3", false, true, false, 0.3),
        makeScene(o, "plane, paper noise 0.5", false, true, false, 0.5),
        makeScene(o, "plane, depth noise", false, true, true, 0.0),
        makeScene(o, "plane, depth noise, uniform image", false, false, true,
                  0.0),
        makeScene(o, "corner, depth noise", true, true, true, 0.0),
        makeScene(o, "corner, depth noise, uniform image", true, false, true,
                  0.0),
        makeScene(o, "corner, paper noise 0.3", true, true, false, 0.3),
    };
    std::printf(
        "| scene | dynamic_guidance / deg | PSNR (dB) | mean (deg) | inside "
        "cells | texture edges | crease | seconds |\n"
        "|---|---|---:|---:|---:|---:|---:|---:|\n");
    for (const Scene& s : scenes) {
      for (double mu : o.guidance) {
        for (double deg : mu > 0.0 ? o.degrees : std::vector<double>{0.0}) {
          nf::SolverSettings settings = o.settings;
          settings.dynamic_guidance = mu;
          if (mu > 0.0) settings.dynamic_guidance_deg = deg;
          char label[32] = "off";
          if (mu > 0.0)
            std::snprintf(label, sizeof(label), "%.2f / %.0f", mu, deg);
          printRow(s, settings, o.runs, label);
        }
      }
    }
  } catch (const std::exception& e) {
    std::cerr << "texture_check: error: " << e.what() << "\n";
    return 2;
  }
  return 0;
}
