// Depth to normals (depth.h): time per 640x480 frame per method (median of
// N runs, normals alone and with the confidence), and accuracy on the
// synthetic scenes with depth-camera noise (sigma_z = a z^2, 1 mm steps, a
// share of dropped pixels) against their exact normals. Not a test: timings
// depend on the machine and its load, which are printed.
//
//   bench_depth_normals [--runs N] [--threads T] [--width W --height H]

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "bench_util.h"
#include "eval/synthetic.h"
#include "normal_fusion/depth.h"
#include "normal_fusion/metrics.h"

namespace nf = normal_fusion;
namespace nd = normal_fusion::depth;
namespace nb = normal_fusion::bench;

namespace {

struct Variant {
  const char* label;
  nd::DepthNormalSettings settings;
};

std::vector<Variant> variants(int threads) {
  std::vector<Variant> out;
  nd::DepthNormalSettings s;
  s.num_threads = threads;
  s.method = nd::NormalMethod::kCentralDifference;
  out.push_back({"central_difference", s});
  s.method = nd::NormalMethod::kPlaneFit;
  for (int r : {1, 2, 3}) {
    s.window_radius = r;
    static const char* const kLabels[] = {
        "", "plane_fit r=1", "plane_fit r=2 (default)", "plane_fit r=3"};
    out.push_back({kLabels[r], s});
  }
  return out;
}

double minimum(const std::vector<double>& v) {
  return *std::min_element(v.begin(), v.end());
}

struct Options {
  int runs = 30, threads = 1, width = 640, height = 480;
};

/// Reads `--option value` pairs into `o`; false (after the usage) on an
/// unknown option.
bool parseOptions(int argc, char** argv, Options& o) {
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string option = argv[i];
    const int value = std::atoi(argv[i + 1]);
    if (option == "--runs") {
      o.runs = std::max(1, value);
    } else if (option == "--threads") {
      o.threads = std::max(1, value);
    } else if (option == "--width") {
      o.width = std::max(8, value);
    } else if (option == "--height") {
      o.height = std::max(8, value);
    } else {
      std::fprintf(stderr,
                   "usage: bench_depth_normals [--runs N] [--threads T] "
                   "[--width W --height H]\n");
      return false;
    }
  }
  return true;
}

/// Times every method on scene 2 with noisy depth (the content does not
/// change the work) and prints a row each.
void printTimings(const Options& o) {
  const nf::synthetic::Frame frame =
      nf::synthetic::renderScene(2, o.width, o.height);
  const nf::ScalarMap noisy =
      nf::synthetic::addDepthNoise(frame.depth, 0.0025, 0.001, 0.02, 1);
  std::printf("%-26s %14s %20s %10s %10s\n", "method", "normals (ms)",
              "normals+conf. (ms)", "min (ms)", "min (ms)");
  for (const Variant& v : variants(o.threads)) {
    nd::DepthNormalEstimator estimator(v.settings);
    nf::NormalMap normals;
    nf::ScalarMap confidence;
    double ms[2], best[2];
    for (int with_conf = 0; with_conf < 2; ++with_conf) {
      const std::vector<double> times = nb::timesMs(o.runs, [&] {
        estimator.compute(noisy, frame.K, normals,
                          with_conf ? &confidence : nullptr);
      });
      ms[with_conf] = nb::median(times);
      best[with_conf] = minimum(times);
    }
    std::printf("%-26s %14.2f %20.2f %10.2f %10.2f\n", v.label, ms[0], ms[1],
                best[0], best[1]);
  }
}

/// Sums over the scenes of one method and noise level.
struct AccuracySums {
  double mean = 0, med = 0, within = 0, coverage = 0, conf = 0;
  double mean_confident = 0, confident = 0;
  int scenes_confident = 0;
};

/// Adds one scene's errors (all pixels, and those the confidence trusts).
void addScene(const nf::NormalMap& normals, const nf::ScalarMap& confidence,
              const nf::NormalMap& normals_gt, AccuracySums& s) {
  const nf::AngularErrorStats e = nf::angularError(normals, normals_gt);
  s.mean += e.mean_deg;
  s.med += e.median_deg;
  s.within += e.within_11_25;
  s.coverage += static_cast<double>(e.pixel_count) / normals.pixelCount();
  double sum = 0.0;
  for (std::size_t i = 0; i < confidence.pixelCount(); ++i) {
    sum += confidence.data()[i];
  }
  s.conf += sum / confidence.pixelCount();
  nf::ScalarMap mask(confidence.width(), confidence.height(), 1, 0.0f);
  std::size_t trusted = 0;
  for (std::size_t i = 0; i < mask.pixelCount(); ++i) {
    const bool t = confidence.data()[i] >= 0.5f;
    mask.data()[i] = t ? 1.0f : 0.0f;
    trusted += t;
  }
  s.confident += static_cast<double>(trusted) / mask.pixelCount();
  if (trusted > 0) {
    s.mean_confident += nf::angularError(normals, normals_gt, mask).mean_deg;
    ++s.scenes_confident;
  }
}

/// Every scene, two noise levels and a = 0, 2 % dropout, 1 mm steps.
void printAccuracy(const Options& o) {
  std::printf(
      "\naccuracy against the exact normals (all scenes, %dx%d; pixels where "
      "both are valid; coverage = share of pixels with a normal)\n",
      o.width, o.height);
  std::printf(
      "(a = 0: the 1 mm steps alone; the estimator's noise_coefficient is "
      "set to a, or 0.001 for a = 0)\n");
  std::printf("%-26s %8s %10s %12s %12s %10s %10s %14s %10s\n", "method",
              "a (1/m)", "mean (deg)", "median (deg)", "<= 11.25 deg",
              "coverage", "mean conf.", "mean, c>=0.5", "c>=0.5");
  for (double a : {0.0, 0.001, 0.0025}) {
    for (const Variant& v : variants(o.threads)) {
      nd::DepthNormalSettings settings = v.settings;
      settings.noise_coefficient = a > 0.0 ? a : 0.001;
      nd::DepthNormalEstimator estimator(settings);
      AccuracySums s;
      for (int scene = 0; scene < nf::synthetic::kNumScenes; ++scene) {
        const nf::synthetic::Frame f =
            nf::synthetic::renderScene(scene, o.width, o.height);
        const nf::ScalarMap depth =
            nf::synthetic::addDepthNoise(f.depth, a, 0.001, 0.02, 10 + scene);
        nf::NormalMap normals;
        nf::ScalarMap confidence;
        estimator.compute(depth, f.K, normals, &confidence);
        addScene(normals, confidence, f.normals_gt, s);
      }
      const double n = nf::synthetic::kNumScenes;
      std::printf(
          "%-26s %8.4f %10.2f %12.2f %11.1f%% %9.1f%% %10.3f %14.2f %9.1f%%\n",
          v.label, a, s.mean / n, s.med / n, 100.0 * s.within / n,
          100.0 * s.coverage / n, s.conf / n,
          s.scenes_confident > 0 ? s.mean_confident / s.scenes_confident : 0.0,
          100.0 * s.confident / n);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (!parseOptions(argc, argv, o)) return 2;
  std::printf("%s\n", nb::machineLine().c_str());
  std::printf("frame %dx%d, %d thread(s), median of %d runs\n\n", o.width,
              o.height, o.threads, o.runs);
  printTimings(o);
  printAccuracy(o);
  return 0;
}
