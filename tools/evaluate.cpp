// evaluate: the paper's Fig. 6 experiment (PSNR against the noise level, the
// regularizer against the cross-bilateral baseline) and a fusion experiment
// (dense noisy + sparse accurate normals) on the synthetic scenes.
//
//   evaluate --output-dir DIR [--width 320 --height 240] [--scenes 0,1,2]
//            [--quick] [solver options]
//
// Writes DIR/results.md (the tables, also printed to stdout), DIR/results.csv
// (per scene), DIR/psnr_vs_sigma.png (the plot) and example pictures of one
// scene at sigma 0.5. Exit codes: 0 the regularizer is ahead of the best
// bilateral filter at every sigma, 1 it is not (the sigmas are printed),
// 2 usage error, 3 failure (unwritable output, library error).
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "normal_fusion/bilateral.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/settings.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/synthetic.h"
#include "normal_fusion/types.h"

namespace {

namespace nf = normal_fusion;
using Clock = std::chrono::steady_clock;

constexpr int kExitClaimFailed = 1;
constexpr int kExitUsageError = 2;
constexpr int kExitFailure = 3;

/// Half windows of the baseline and its two candidate spatial sigmas
/// (the paper's garbled fraction of w: 5w/3 or 3w/5).
constexpr std::array<int, 3> kHalfWindows{{3, 5, 7}};
constexpr int kNumSpatialChoices = 2;
constexpr int kNumBilateral = 3 * kNumSpatialChoices;
constexpr double kSigmaIntensity = 0.1;
/// The noise level of the example pictures.
constexpr double kExampleSigma = 0.5;
/// Range of the angular-error heat maps, degrees.
constexpr double kHeatmapMaxDeg = 45.0;

/// A malformed command line: unknown option, missing or bad value.
class UsageError : public std::runtime_error {
 public:
  explicit UsageError(const std::string& what) : std::runtime_error(what) {}
};

struct Options {
  std::string output_dir;
  int width = 320;
  int height = 240;
  bool size_given = false;
  bool quick = false;
  std::vector<int> scenes{0, 1, 2};
  std::vector<double> sigmas;  ///< empty: by --quick
  std::uint64_t seed = 2014;
  nf::SolverSettings settings;
  // Fusion experiment.
  bool fusion = true;
  double dense_sigma = 0.4;
  double depth_sigma_at_1m = 0.0015;
  double depth_dropout = 0.02;
  double sparse_density = 0.05;
  double sparse_sigma = 0.05;
  double sparse_weight = 1.0;
  bool help = false;
};

void printUsage(std::ostream& out) {
  const nf::SolverSettings d;
  const Options o;
  out << "Usage: evaluate --output-dir DIR [--width W --height H]\n"
         "                [--scenes 0,1,2] [--quick] [solver options]\n"
         "\n"
         "Runs the paper's Fig. 6 experiment on the synthetic scenes: paper\n"
         "noise of sigma 0.1 .. 0.9, the regularizer (one parameter set for\n"
         "every sigma) against the cross-bilateral filter (w = 3, 5, 7;\n"
         "sigma_S = 5w/3 or 3w/5; sigma_I = 0.1), PSNR averaged over the\n"
         "scenes; then a fusion experiment (dense noisy + sparse accurate).\n"
         "Writes DIR/results.md, DIR/results.csv, DIR/psnr_vs_sigma.png and\n"
         "example pictures of the first scene at sigma 0.5.\n"
         "\n"
         "Experiment:\n"
         "  --output-dir DIR      where the results go (created if missing)\n"
         "  --width N, --height N image size [320 x 240; 160 x 120 with "
         "--quick]\n"
         "  --scenes LIST         comma-separated scene ids in 0.."
      << nf::synthetic::kNumScenes - 1
      << " [0,1,2]\n"
         "  --sigmas LIST         noise levels [0.1,0.2,...,0.9; 0.1,0.5,0.9 "
         "with --quick]\n"
         "  --quick               small and fast: 160 x 120, three sigmas\n"
         "  --seed N              base seed of the noise ["
      << o.seed
      << "]\n"
         "  --no-fusion           skip the fusion experiment\n"
         "  --dense-sigma X       paper noise of the dense fusion input ["
      << o.dense_sigma << "]\n"
      << "  --depth-sigma X       depth noise at 1 m (metres, grows with z^2)\n"
         "                        of the depth-derived dense input ["
      << o.depth_sigma_at_1m << "]\n"
      << "  --depth-dropout X     share of missing depth pixels ["
      << o.depth_dropout << "]\n"
      << "  --sparse-density X    share of pixels in the sparse input ["
      << o.sparse_density << "]\n"
      << "  --sparse-sigma X      paper noise of the sparse input ["
      << o.sparse_sigma << "]\n"
      << "  --sparse-weight X     data weight of the sparse input when fused ["
      << o.sparse_weight << "]\n"
      << "\n"
         "Solver options (defaults in brackets):\n"
         "  --lambda X            data weight ["
      << d.lambda << "]\n"
      << "  --eps X               Huber threshold, 0 = plain TV ["
      << d.huber_eps << "]\n"
      << "  --penalty P           l2 | squared_l2 [" << nf::toString(d.penalty)
      << "]\n"
      << "  --visibility V        off | hard | soft ["
      << nf::toString(d.visibility) << "]\n"
      << "  --edge-alpha X        [" << d.edges.alpha << "]\n"
      << "  --edge-beta X         [" << d.edges.beta << "]\n"
      << "  --edge-wmin X         [" << d.edges.w_min << "]\n"
      << "  --edge-sigma X        [" << d.edges.smoothing_sigma << "]\n"
      << "  --edge-color C        luminance | color_max ["
      << nf::toString(d.edges.color_mode) << "]\n"
      << "  --edge-function F     exponential | rational ["
      << nf::toString(d.edges.function) << "]\n"
      << "  --no-edges            unguided TV (all edge weights 1)\n"
      << "  --inner-iterations N  iterations per outer step ["
      << d.inner_iterations << "]\n"
      << "  --max-outer N         majorize-minimize steps ["
      << d.max_outer_iterations << "]\n"
      << "  --max-iterations N    inner iterations in all ["
      << d.max_total_inner_iterations << "]\n"
      << "  --tolerance X         relative energy decrease to stop ["
      << d.relative_tolerance << "]\n"
      << "  --pyramid-levels N    1 = off, 0 = automatic [" << d.pyramid_levels
      << "]\n"
      << "  --preconditioning B   on | off ["
      << (d.preconditioning ? "on" : "off") << "]\n"
      << "  --threads N           solver and filter threads, 0 = all ["
      << d.num_threads << "]\n"
      << "  --backend B           fast | reference [" << nf::toString(d.backend)
      << "]\n"
      << "  --help                this text\n"
      << "\n"
      << "Exit codes: 0 the regularizer beats the best bilateral filter at\n"
         "every sigma, 1 it does not, 2 usage error, 3 failure.\n";
}

double parseDouble(const std::string& option, const std::string& text) {
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || !std::isfinite(value)) {
    throw UsageError(option + ": expected a finite number, got '" + text + "'");
  }
  return value;
}

int parseInt(const std::string& option, const std::string& text) {
  std::size_t used = 0;
  long value = 0;
  try {
    value = std::stol(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != text.size() || value < -2147483647L ||
      value > 2147483647L) {
    throw UsageError(option + ": expected an integer, got '" + text + "'");
  }
  return static_cast<int>(value);
}

std::vector<std::string> splitCommas(const std::string& option,
                                     const std::string& text) {
  std::vector<std::string> items;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) items.push_back(item);
  if (items.empty() || text.back() == ',') {
    throw UsageError(option + ": expected a comma-separated list, got '" +
                     text + "'");
  }
  return items;
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

void requireInRange(const std::string& option, double value, double lo,
                    double hi) {
  if (!(value >= lo && value <= hi)) {
    std::ostringstream msg;
    msg << option << ": expected a value in [" << lo << ", " << hi << "], got "
        << value;
    throw UsageError(msg.str());
  }
}

Options parseArguments(int argc, char** argv) {
  Options options;
  nf::SolverSettings& s = options.settings;
  bool width_given = false, height_given = false;
  for (int i = 1; i < argc; ++i) {
    std::string option = argv[i];
    std::string inline_value;
    bool has_inline_value = false;
    if (option.rfind("--", 0) != 0) {
      throw UsageError("unexpected argument '" + option +
                       "' (options start with --; see --help)");
    }
    const std::size_t equals = option.find('=');
    if (equals != std::string::npos) {
      inline_value = option.substr(equals + 1);
      option = option.substr(0, equals);
      has_inline_value = true;
    }
    // Flags without a value.
    if (option == "--help" || option == "--no-edges" || option == "--quick" ||
        option == "--no-fusion") {
      if (has_inline_value) throw UsageError(option + " takes no value");
      if (option == "--help") options.help = true;
      if (option == "--no-edges") s.edges.enabled = false;
      if (option == "--quick") options.quick = true;
      if (option == "--no-fusion") options.fusion = false;
      continue;
    }
    const auto value = [&]() -> std::string {
      if (has_inline_value) return inline_value;
      if (i + 1 >= argc) throw UsageError(option + " needs a value");
      return argv[++i];
    };
    if (option == "--output-dir") {
      options.output_dir = value();
    } else if (option == "--width") {
      options.width = parseInt(option, value());
      width_given = true;
    } else if (option == "--height") {
      options.height = parseInt(option, value());
      height_given = true;
    } else if (option == "--scenes") {
      options.scenes.clear();
      for (const std::string& item : splitCommas(option, value())) {
        const int id = parseInt(option, item);
        if (id < 0 || id >= nf::synthetic::kNumScenes) {
          throw UsageError(option + ": expected scene ids in 0.." +
                           std::to_string(nf::synthetic::kNumScenes - 1) +
                           ", got " + item);
        }
        if (std::find(options.scenes.begin(), options.scenes.end(), id) ==
            options.scenes.end()) {
          options.scenes.push_back(id);
        }
      }
    } else if (option == "--sigmas") {
      options.sigmas.clear();
      for (const std::string& item : splitCommas(option, value())) {
        const double sigma = parseDouble(option, item);
        requireInRange(option, sigma, 1e-6, 10.0);
        options.sigmas.push_back(sigma);
      }
    } else if (option == "--seed") {
      const int seed = parseInt(option, value());
      if (seed < 0) throw UsageError(option + ": expected a seed >= 0");
      options.seed = static_cast<std::uint64_t>(seed);
    } else if (option == "--dense-sigma") {
      options.dense_sigma = parseDouble(option, value());
      requireInRange(option, options.dense_sigma, 0.0, 10.0);
    } else if (option == "--depth-sigma") {
      options.depth_sigma_at_1m = parseDouble(option, value());
      requireInRange(option, options.depth_sigma_at_1m, 0.0, 1.0);
    } else if (option == "--depth-dropout") {
      options.depth_dropout = parseDouble(option, value());
      requireInRange(option, options.depth_dropout, 0.0, 1.0);
    } else if (option == "--sparse-density") {
      options.sparse_density = parseDouble(option, value());
      requireInRange(option, options.sparse_density, 0.0, 1.0);
    } else if (option == "--sparse-sigma") {
      options.sparse_sigma = parseDouble(option, value());
      requireInRange(option, options.sparse_sigma, 0.0, 10.0);
    } else if (option == "--sparse-weight") {
      options.sparse_weight = parseDouble(option, value());
      requireInRange(option, options.sparse_weight, 0.0, 1e6);
    } else if (option == "--lambda") {
      s.lambda = parseDouble(option, value());
    } else if (option == "--eps") {
      s.huber_eps = parseDouble(option, value());
    } else if (option == "--penalty") {
      s.penalty = parseName(option, value(), nf::parseDataPenalty);
    } else if (option == "--visibility") {
      s.visibility = parseName(option, value(), nf::parseVisibilityMode);
    } else if (option == "--edge-alpha") {
      s.edges.alpha = parseDouble(option, value());
    } else if (option == "--edge-beta") {
      s.edges.beta = parseDouble(option, value());
    } else if (option == "--edge-wmin") {
      s.edges.w_min = parseDouble(option, value());
    } else if (option == "--edge-sigma") {
      s.edges.smoothing_sigma = parseDouble(option, value());
    } else if (option == "--edge-color") {
      s.edges.color_mode = parseName(option, value(), nf::parseEdgeColorMode);
    } else if (option == "--edge-function") {
      s.edges.function =
          parseName(option, value(), nf::parseEdgeWeightFunction);
    } else if (option == "--inner-iterations") {
      s.inner_iterations = parseInt(option, value());
    } else if (option == "--max-outer") {
      s.max_outer_iterations = parseInt(option, value());
    } else if (option == "--max-iterations") {
      s.max_total_inner_iterations = parseInt(option, value());
    } else if (option == "--tolerance") {
      s.relative_tolerance = parseDouble(option, value());
    } else if (option == "--pyramid-levels") {
      s.pyramid_levels = parseInt(option, value());
    } else if (option == "--preconditioning") {
      const std::string text = value();
      if (text == "on" || text == "true" || text == "1") {
        s.preconditioning = true;
      } else if (text == "off" || text == "false" || text == "0") {
        s.preconditioning = false;
      } else {
        throw UsageError(option + ": expected on or off, got '" + text + "'");
      }
    } else if (option == "--threads") {
      s.num_threads = parseInt(option, value());
    } else if (option == "--backend") {
      s.backend = parseName(option, value(), nf::parseSolverBackend);
    } else {
      throw UsageError("unknown option '" + option + "' (see --help)");
    }
  }
  if (options.help) return options;
  if (options.output_dir.empty()) throw UsageError("missing --output-dir");
  if (options.quick) {
    if (!width_given) options.width = 160;
    if (!height_given) options.height = 120;
    if (options.sigmas.empty()) options.sigmas = {0.1, 0.5, 0.9};
  }
  if (options.sigmas.empty()) {
    for (int k = 1; k <= 9; ++k) options.sigmas.push_back(0.1 * k);
  }
  if (options.width < 16 || options.height < 16 || options.width > 8192 ||
      options.height > 8192) {
    throw UsageError("image size: expected 16..8192 x 16..8192, got " +
                     std::to_string(options.width) + " x " +
                     std::to_string(options.height));
  }
  try {
    s.validate();
  } catch (const nf::ParameterError& e) {
    throw UsageError(std::string("solver settings: ") + e.what());
  }
  return options;
}

std::string fixed(double value, int digits) {
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

std::string signedFixed(double value, int digits) {
  return (value >= 0.0 ? "+" : "") + fixed(value, digits);
}

// --- Scores -----------------------------------------------------------------

/// Accuracy of one map against the ground truth.
struct Score {
  double psnr_db = 0.0;
  nf::AngularErrorStats angles;
  double coverage = 0.0;  ///< share of the image's pixels evaluated
};

Score scoreOf(const nf::NormalMap& estimate, const nf::NormalMap& gt) {
  Score score;
  score.psnr_db = nf::psnr(estimate, gt);
  score.angles = nf::angularError(estimate, gt);
  score.coverage = static_cast<double>(score.angles.pixel_count) /
                   static_cast<double>(gt.pixelCount());
  return score;
}

/// Mean of scores over scenes (every field averaged).
Score meanOf(const std::vector<Score>& scores) {
  Score mean;
  if (scores.empty()) return mean;
  const double n = static_cast<double>(scores.size());
  for (const Score& s : scores) {
    mean.psnr_db += s.psnr_db / n;
    mean.angles.mean_deg += s.angles.mean_deg / n;
    mean.angles.median_deg += s.angles.median_deg / n;
    mean.angles.within_11_25 += s.angles.within_11_25 / n;
    mean.angles.within_22_5 += s.angles.within_22_5 / n;
    mean.angles.within_30 += s.angles.within_30 / n;
    mean.angles.pixel_count += s.angles.pixel_count;
    mean.coverage += s.coverage / n;
  }
  return mean;
}

nf::BilateralSettings bilateralSettings(int config, int num_threads) {
  nf::BilateralSettings settings;
  const int w = kHalfWindows[config / kNumSpatialChoices];
  settings.half_window = w;
  settings.sigma_spatial =
      config % kNumSpatialChoices == 0 ? 5.0 * w / 3.0 : 3.0 * w / 5.0;
  settings.sigma_intensity = kSigmaIntensity;
  settings.num_threads = num_threads;
  return settings;
}

std::string bilateralLabel(int config) {
  const int w = kHalfWindows[config / kNumSpatialChoices];
  return "w=" + std::to_string(w) +
         ", sigma_S=" + (config % kNumSpatialChoices == 0 ? "5w/3" : "3w/5");
}

/// Wall-clock seconds spent in one kind of work, and how often.
struct Timer {
  double seconds = 0.0;
  int calls = 0;
  double mean() const { return calls > 0 ? seconds / calls : 0.0; }
};

template <typename Work>
auto timed(Timer* timer, Work work) -> decltype(work()) {
  const auto start = Clock::now();
  auto result = work();
  timer->seconds += std::chrono::duration<double>(Clock::now() - start).count();
  ++timer->calls;
  return result;
}

/// Runs the regularizer (a fresh cold start) on the given inputs.
nf::NormalMap regularize(const nf::synthetic::Frame& frame,
                         std::vector<nf::NormalInput> inputs,
                         const nf::SolverSettings& settings, Timer* timer) {
  nf::FusionProblem problem;
  problem.image = frame.image;
  problem.K = frame.K;
  problem.inputs = std::move(inputs);
  nf::Solver solver(settings);
  return timed(timer, [&] { return solver.solve(problem); });
}

nf::NormalInput inputOf(const nf::NormalMap& normals, double weight = 1.0) {
  nf::NormalInput input;
  input.normals = normals;
  input.weight = weight;
  return input;
}

std::uint64_t noiseSeed(const Options& options, int scene, int stream,
                        double sigma) {
  return options.seed + 1000003ULL * static_cast<std::uint64_t>(scene + 1) +
         7919ULL * static_cast<std::uint64_t>(stream) +
         static_cast<std::uint64_t>(std::lround(1000.0 * sigma));
}

// --- Experiment (a): PSNR against sigma --------------------------------------

struct SigmaResult {
  double sigma = 0.0;
  std::vector<Score> noisy;                                 ///< per scene
  std::vector<Score> regularizer;                           ///< per scene
  std::array<std::vector<Score>, kNumBilateral> bilateral;  ///< per scene
  // Means over scenes, filled by summarize().
  Score noisy_mean, regularizer_mean;
  std::array<Score, kNumBilateral> bilateral_mean;
  std::array<int, 3> best_config_per_w{};  ///< better sigma_S for each w
  int best_config = 0;                     ///< best of all six
};

void summarize(SigmaResult* r) {
  r->noisy_mean = meanOf(r->noisy);
  r->regularizer_mean = meanOf(r->regularizer);
  for (int k = 0; k < kNumBilateral; ++k) {
    r->bilateral_mean[k] = meanOf(r->bilateral[k]);
  }
  // Each w at its better sigma_S (by PSNR over the scenes), then the best w.
  for (int wi = 0; wi < 3; ++wi) {
    int best = wi * kNumSpatialChoices;
    for (int j = 1; j < kNumSpatialChoices; ++j) {
      const int k = wi * kNumSpatialChoices + j;
      if (r->bilateral_mean[k].psnr_db > r->bilateral_mean[best].psnr_db) {
        best = k;
      }
    }
    r->best_config_per_w[wi] = best;
  }
  r->best_config = r->best_config_per_w[0];
  for (int k : r->best_config_per_w) {
    if (r->bilateral_mean[k].psnr_db >
        r->bilateral_mean[r->best_config].psnr_db) {
      r->best_config = k;
    }
  }
}

/// The maps of the example pictures.
struct Example {
  bool taken = false;
  int scene = 0;
  double sigma = 0.0;
  nf::ColorImage image;
  nf::NormalMap gt, noisy, regularizer;
  std::array<nf::NormalMap, kNumBilateral> bilateral;
};

std::vector<SigmaResult> runSigmaSweep(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Example* example, Timer* solver_timer, Timer* filter_timer) {
  // The example is the sigma nearest to 0.5 on the first scene.
  double example_sigma = options.sigmas.front();
  for (double sigma : options.sigmas) {
    if (std::fabs(sigma - kExampleSigma) <
        std::fabs(example_sigma - kExampleSigma)) {
      example_sigma = sigma;
    }
  }
  std::vector<SigmaResult> results;
  for (double sigma : options.sigmas) {
    SigmaResult r;
    r.sigma = sigma;
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const nf::synthetic::Frame& frame = frames[s];
      const int scene = options.scenes[s];
      // Noisy input: the paper's noise model.
      const nf::NormalMap noisy = nf::synthetic::addPaperNoise(
          frame.normals_gt, sigma, noiseSeed(options, scene, 0, sigma));
      r.noisy.push_back(scoreOf(noisy, frame.normals_gt));
      const bool keep = s == 0 && sigma == example_sigma;
      // Baseline: all six bilateral settings.
      for (int k = 0; k < kNumBilateral; ++k) {
        const nf::NormalMap filtered = timed(filter_timer, [&] {
          return nf::crossBilateralFilter(
              noisy, frame.image,
              bilateralSettings(k, options.settings.num_threads));
        });
        r.bilateral[k].push_back(scoreOf(filtered, frame.normals_gt));
        if (keep) example->bilateral[k] = filtered;
      }
      // The regularizer with one parameter set for every sigma.
      const nf::NormalMap regularized =
          regularize(frame, {inputOf(noisy)}, options.settings, solver_timer);
      r.regularizer.push_back(scoreOf(regularized, frame.normals_gt));
      if (keep) {
        example->taken = true;
        example->scene = scene;
        example->sigma = sigma;
        example->image = frame.image;
        example->gt = frame.normals_gt;
        example->noisy = noisy;
        example->regularizer = regularized;
      }
      std::cerr << "evaluate: scene " << scene << " sigma " << std::fixed
                << std::setprecision(2) << sigma << ": noisy "
                << r.noisy.back().psnr_db << " dB, regularizer "
                << r.regularizer.back().psnr_db << " dB\n"
                << std::defaultfloat;
    }
    summarize(&r);
    results.push_back(std::move(r));
  }
  return results;
}

// --- Experiment (b): fusion --------------------------------------------------

/// One row of the fusion table, scored per scene.
struct FusionRow {
  std::string method;
  std::vector<Score> scores;
};

struct FusionTable {
  std::string dense_name;
  std::vector<FusionRow> rows;
};

std::vector<FusionTable> runFusion(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Timer* solver_timer, Timer* filter_timer) {
  const std::vector<std::string> dense_names = {
      "paper noise sigma " + fixed(options.dense_sigma, 2),
      "normals from noisy depth (" +
          fixed(options.depth_sigma_at_1m * 1000.0, 2) + " mm at 1 m, " +
          fixed(options.depth_dropout * 100.0, 1) + " % dropout)"};
  std::vector<FusionTable> tables;
  for (std::size_t d = 0; d < dense_names.size(); ++d) {
    FusionTable table;
    table.dense_name = dense_names[d];
    for (const char* method :
         {"dense input", "sparse input", "bilateral on dense (best setting)",
          "dense alone, regularized", "sparse alone, regularized",
          "fused (sparse + dense)"}) {
      table.rows.push_back({method, {}});
    }
    std::array<std::vector<Score>, kNumBilateral> bilateral;
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const nf::synthetic::Frame& frame = frames[s];
      const nf::NormalMap& gt = frame.normals_gt;
      const int scene = options.scenes[s];
      // Dense input: paper noise, or normals of a noisy depth image.
      const nf::NormalMap dense =
          d == 0 ? nf::synthetic::addPaperNoise(
                       gt, options.dense_sigma,
                       noiseSeed(options, scene, 1, options.dense_sigma))
                 : nf::synthetic::normalsFromNoisyDepth(
                       frame, options.depth_sigma_at_1m, options.depth_dropout,
                       noiseSeed(options, scene, 2, 0.0));
      // Sparse input: few pixels, little noise (the same for both tables).
      const nf::NormalMap sparse = nf::synthetic::sparseAccurate(
          gt, options.sparse_density, options.sparse_sigma,
          noiseSeed(options, scene, 3, options.sparse_sigma));
      table.rows[0].scores.push_back(scoreOf(dense, gt));
      table.rows[1].scores.push_back(scoreOf(sparse, gt));
      for (int k = 0; k < kNumBilateral; ++k) {
        bilateral[k].push_back(scoreOf(
            timed(filter_timer,
                  [&] {
                    return nf::crossBilateralFilter(
                        dense, frame.image,
                        bilateralSettings(k, options.settings.num_threads));
                  }),
            gt));
      }
      table.rows[3].scores.push_back(scoreOf(
          regularize(frame, {inputOf(dense)}, options.settings, solver_timer),
          gt));
      table.rows[4].scores.push_back(scoreOf(
          regularize(frame, {inputOf(sparse)}, options.settings, solver_timer),
          gt));
      // Fused: the sparse, accurate input first (it initializes where given).
      table.rows[5].scores.push_back(scoreOf(
          regularize(frame,
                     {inputOf(sparse, options.sparse_weight), inputOf(dense)},
                     options.settings, solver_timer),
          gt));
      std::cerr << "evaluate: fusion, " << table.dense_name << ", scene "
                << scene << ": fused " << std::fixed << std::setprecision(2)
                << table.rows[5].scores.back().psnr_db << " dB\n"
                << std::defaultfloat;
    }
    // The baseline's setting with the best mean PSNR over the scenes.
    int best = 0;
    for (int k = 1; k < kNumBilateral; ++k) {
      if (meanOf(bilateral[k]).psnr_db > meanOf(bilateral[best]).psnr_db) {
        best = k;
      }
    }
    table.rows[2].method += " (" + bilateralLabel(best) + ")";
    table.rows[2].scores = bilateral[best];
    tables.push_back(std::move(table));
  }
  return tables;
}

// --- Output ------------------------------------------------------------------

std::string sigmaSLabel(int config) {
  return config % kNumSpatialChoices == 0 ? "5w/3" : "3w/5";
}

std::string psnrTable(const std::vector<SigmaResult>& results) {
  std::ostringstream out;
  out << "| sigma | noisy input | bilateral w=3 | bilateral w=5 | bilateral "
         "w=7 | regularizer | regularizer - best bilateral (dB) |\n"
         "|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const SigmaResult& r : results) {
    out << "| " << fixed(r.sigma, 2) << " | " << fixed(r.noisy_mean.psnr_db, 2);
    for (int k : r.best_config_per_w) {
      out << " | " << fixed(r.bilateral_mean[k].psnr_db, 2) << " ("
          << sigmaSLabel(k) << ")" << (k == r.best_config ? " *" : "");
    }
    const double gap =
        r.regularizer_mean.psnr_db - r.bilateral_mean[r.best_config].psnr_db;
    out << " | " << fixed(r.regularizer_mean.psnr_db, 2) << " | "
        << signedFixed(gap, 2) << " |\n";
  }
  return out.str();
}

std::string angleTable(const std::vector<SigmaResult>& results) {
  std::ostringstream out;
  out << "| sigma | noisy input | bilateral w=3 | bilateral w=5 | bilateral "
         "w=7 | regularizer | regularizer median | regularizer <= 11.25 deg |\n"
         "|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const SigmaResult& r : results) {
    out << "| " << fixed(r.sigma, 2) << " | "
        << fixed(r.noisy_mean.angles.mean_deg, 2);
    for (int k : r.best_config_per_w) {
      out << " | " << fixed(r.bilateral_mean[k].angles.mean_deg, 2);
    }
    out << " | " << fixed(r.regularizer_mean.angles.mean_deg, 2) << " | "
        << fixed(r.regularizer_mean.angles.median_deg, 2) << " | "
        << fixed(100.0 * r.regularizer_mean.angles.within_11_25, 1) << " % |\n";
  }
  return out.str();
}

std::string fusionTables(const std::vector<FusionTable>& tables) {
  std::ostringstream out;
  for (const FusionTable& table : tables) {
    out << "\nDense input: " << table.dense_name << "\n\n"
        << "| method | pixels scored | PSNR (dB) | mean (deg) | median (deg) "
           "| <= 11.25 deg | <= 22.5 deg | <= 30 deg |\n"
           "|---|---:|---:|---:|---:|---:|---:|---:|\n";
    for (const FusionRow& row : table.rows) {
      const Score m = meanOf(row.scores);
      out << "| " << row.method << " | " << fixed(100.0 * m.coverage, 1)
          << " % | " << fixed(m.psnr_db, 2) << " | "
          << fixed(m.angles.mean_deg, 2) << " | "
          << fixed(m.angles.median_deg, 2) << " | "
          << fixed(100.0 * m.angles.within_11_25, 1) << " % | "
          << fixed(100.0 * m.angles.within_22_5, 1) << " % | "
          << fixed(100.0 * m.angles.within_30, 1) << " % |\n";
    }
  }
  return out.str();
}

void writeCsv(const std::string& path, const Options& options,
              const std::vector<SigmaResult>& results,
              const std::vector<FusionTable>& tables) {
  std::ofstream out(path);
  if (!out) throw nf::InputError("cannot write '" + path + "'");
  out << "experiment,input,scene,sigma,method,psnr_db,mean_deg,median_deg,"
         "within_11_25,within_22_5,within_30,coverage\n";
  const auto row = [&](const std::string& experiment, const std::string& input,
                       int scene, double sigma, const std::string& method,
                       const Score& s) {
    out << experiment << ",\"" << input << "\"," << scene << "," << sigma
        << ",\"" << method << "\"," << std::setprecision(8) << s.psnr_db << ","
        << s.angles.mean_deg << "," << s.angles.median_deg << ","
        << s.angles.within_11_25 << "," << s.angles.within_22_5 << ","
        << s.angles.within_30 << "," << s.coverage << "\n";
  };
  for (const SigmaResult& r : results) {
    for (std::size_t s = 0; s < options.scenes.size(); ++s) {
      const int scene = options.scenes[s];
      row("sigma_sweep", "paper noise", scene, r.sigma, "noisy input",
          r.noisy[s]);
      for (int k = 0; k < kNumBilateral; ++k) {
        row("sigma_sweep", "paper noise", scene, r.sigma,
            "bilateral " + bilateralLabel(k), r.bilateral[k][s]);
      }
      row("sigma_sweep", "paper noise", scene, r.sigma, "regularizer",
          r.regularizer[s]);
    }
  }
  for (const FusionTable& table : tables) {
    for (const FusionRow& fusion_row : table.rows) {
      for (std::size_t s = 0; s < fusion_row.scores.size(); ++s) {
        row("fusion", table.dense_name, options.scenes[s], 0.0,
            fusion_row.method, fusion_row.scores[s]);
      }
    }
  }
  if (!out) throw nf::InputError("failed writing '" + path + "'");
}

/// One curve of the plot.
struct Series {
  std::string label;
  cv::Scalar colour;  ///< BGR
  int thickness;
  std::vector<double> psnr_db;
};

void drawText(cv::Mat* canvas, const std::string& text, cv::Point origin,
              double scale, const cv::Scalar& colour, int thickness = 1) {
  cv::putText(*canvas, text, origin, cv::FONT_HERSHEY_SIMPLEX, scale, colour,
              thickness, cv::LINE_AA);
}

/// PSNR against sigma for each method: axes, ticks, grid, legend.
void writePlot(const std::string& path, const std::vector<SigmaResult>& results,
               const Options& options) {
  std::vector<Series> series = {
      {"noisy input", cv::Scalar(140, 140, 140), 2, {}},
      {"bilateral w=3", cv::Scalar(200, 120, 30), 2, {}},
      {"bilateral w=5", cv::Scalar(60, 160, 40), 2, {}},
      {"bilateral w=7", cv::Scalar(30, 140, 230), 2, {}},
      {"regularizer", cv::Scalar(30, 30, 210), 3, {}}};
  std::vector<double> sigmas;
  for (const SigmaResult& r : results) {
    sigmas.push_back(r.sigma);
    series[0].psnr_db.push_back(r.noisy_mean.psnr_db);
    for (int wi = 0; wi < 3; ++wi) {
      series[1 + wi].psnr_db.push_back(
          r.bilateral_mean[r.best_config_per_w[wi]].psnr_db);
    }
    series[4].psnr_db.push_back(r.regularizer_mean.psnr_db);
  }
  // Data ranges, padded; y ticks on a step of 1, 2, 5 or 10 dB.
  double y_min = std::numeric_limits<double>::infinity();
  double y_max = -y_min;
  for (const Series& s : series) {
    for (double v : s.psnr_db) {
      if (!std::isfinite(v)) continue;
      y_min = std::min(y_min, v);
      y_max = std::max(y_max, v);
    }
  }
  if (!std::isfinite(y_min)) {
    y_min = 0.0;
    y_max = 1.0;
  }
  double step = 1.0;
  for (double candidate : {1.0, 2.0, 5.0, 10.0, 20.0}) {
    step = candidate;
    if ((y_max - y_min) / candidate <= 10.0) break;
  }
  y_min = std::floor(y_min / step) * step;
  y_max = std::ceil(y_max / step) * step;
  if (y_max <= y_min) y_max = y_min + step;
  const double x_min =
      std::max(0.0, *std::min_element(sigmas.begin(), sigmas.end()) - 0.05);
  const double x_max = *std::max_element(sigmas.begin(), sigmas.end()) + 0.05;

  const int width = 900, height = 600;
  const int left = 80, right = 30, top = 50, bottom = 70;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const cv::Scalar black(0, 0, 0), grid(225, 225, 225);
  const auto px = [&](double sigma) {
    return left +
           static_cast<int>(std::lround((sigma - x_min) / (x_max - x_min) *
                                        (width - left - right)));
  };
  const auto py = [&](double psnr_db) {
    return height - bottom -
           static_cast<int>(std::lround((psnr_db - y_min) / (y_max - y_min) *
                                        (height - top - bottom)));
  };
  // Grid and ticks: x at every sigma, y every `step` dB.
  for (double sigma : sigmas) {
    const int x = px(sigma);
    cv::line(canvas, {x, top}, {x, height - bottom}, grid, 1);
    cv::line(canvas, {x, height - bottom}, {x, height - bottom + 6}, black, 1);
    drawText(&canvas, fixed(sigma, 1), {x - 12, height - bottom + 24}, 0.5,
             black);
  }
  for (double v = y_min; v <= y_max + 1e-9; v += step) {
    const int y = py(v);
    cv::line(canvas, {left, y}, {width - right, y}, grid, 1);
    cv::line(canvas, {left - 6, y}, {left, y}, black, 1);
    drawText(&canvas, fixed(v, 0), {left - 40, y + 5}, 0.5, black);
  }
  // Axes.
  cv::line(canvas, {left, top}, {left, height - bottom}, black, 2);
  cv::line(canvas, {left, height - bottom}, {width - right, height - bottom},
           black, 2);
  drawText(&canvas, "noise sigma", {(width + left) / 2 - 50, height - 20}, 0.6,
           black);
  // The y label, drawn horizontally then turned by 90 degrees.
  cv::Mat label(30, 120, CV_8UC3, cv::Scalar(255, 255, 255));
  drawText(&label, "PSNR (dB)", {5, 22}, 0.6, black);
  cv::rotate(label, label, cv::ROTATE_90_COUNTERCLOCKWISE);
  label.copyTo(
      canvas(cv::Rect(8, (height - label.rows) / 2, label.cols, label.rows)));
  drawText(&canvas,
           "PSNR of the normals vs noise level (" +
               std::to_string(options.scenes.size()) + " scene(s), " +
               std::to_string(options.width) + "x" +
               std::to_string(options.height) + ")",
           {left, 32}, 0.65, black, 1);
  // Curves with markers.
  for (const Series& s : series) {
    for (std::size_t i = 0; i < sigmas.size(); ++i) {
      if (!std::isfinite(s.psnr_db[i])) continue;
      const cv::Point p(px(sigmas[i]), py(s.psnr_db[i]));
      cv::circle(canvas, p, 4, s.colour, cv::FILLED, cv::LINE_AA);
      if (i + 1 < sigmas.size() && std::isfinite(s.psnr_db[i + 1])) {
        cv::line(canvas, p, {px(sigmas[i + 1]), py(s.psnr_db[i + 1])}, s.colour,
                 s.thickness, cv::LINE_AA);
      }
    }
  }
  // Legend, top right.
  const int legend_w = 190, row_h = 24;
  const cv::Point corner(width - right - legend_w - 10, top + 10);
  cv::rectangle(canvas,
                cv::Rect(corner.x, corner.y, legend_w,
                         row_h * static_cast<int>(series.size()) + 10),
                cv::Scalar(255, 255, 255), cv::FILLED);
  cv::rectangle(canvas,
                cv::Rect(corner.x, corner.y, legend_w,
                         row_h * static_cast<int>(series.size()) + 10),
                black, 1);
  for (std::size_t i = 0; i < series.size(); ++i) {
    const int y = corner.y + 18 + row_h * static_cast<int>(i);
    cv::line(canvas, {corner.x + 10, y - 5}, {corner.x + 45, y - 5},
             series[i].colour, series[i].thickness, cv::LINE_AA);
    cv::circle(canvas, {corner.x + 27, y - 5}, 4, series[i].colour, cv::FILLED,
               cv::LINE_AA);
    drawText(&canvas, series[i].label, {corner.x + 55, y}, 0.5, black);
  }
  if (!cv::imwrite(path, canvas)) {
    throw nf::InputError("cannot write '" + path + "'");
  }
}

std::vector<std::string> writeExamples(const std::string& dir,
                                       const Example& example,
                                       const SigmaResult& result) {
  std::vector<std::string> files;
  if (!example.taken) return files;
  const std::string stem = (std::filesystem::path(dir) /
                            ("example_scene" + std::to_string(example.scene) +
                             "_sigma" + fixed(example.sigma, 2) + "_"))
                               .string();
  const nf::NormalMap& bilateral = example.bilateral[result.best_config];
  const auto add = [&](const std::string& name) {
    files.push_back(stem + name);
    return stem + name;
  };
  nf::io::writeImage(add("image.png"), example.image);
  nf::io::writeNormalPicture(add("gt.png"), example.gt);
  nf::io::writeNormalPicture(add("noisy.png"), example.noisy);
  nf::io::writeNormalPicture(add("bilateral_best.png"), bilateral);
  nf::io::writeNormalPicture(add("regularizer.png"), example.regularizer);
  // Angular error in degrees, mapped from [0, 45].
  nf::io::writeHeatmap(add("error_bilateral_best.png"),
                       nf::angularErrorMap(bilateral, example.gt), 0.0,
                       kHeatmapMaxDeg);
  nf::io::writeHeatmap(add("error_regularizer.png"),
                       nf::angularErrorMap(example.regularizer, example.gt),
                       0.0, kHeatmapMaxDeg);
  return files;
}

std::string cpuModel() {
  std::ifstream cpuinfo("/proc/cpuinfo");
  std::string line;
  while (std::getline(cpuinfo, line)) {
    if (line.rfind("model name", 0) == 0) {
      const std::size_t colon = line.find(':');
      if (colon != std::string::npos) return line.substr(colon + 2);
    }
  }
  return "unknown CPU";
}

std::string settingsText(const nf::SolverSettings& s) {
  std::ostringstream out;
  out << "lambda " << s.lambda << ", eps " << s.huber_eps << ", penalty "
      << nf::toString(s.penalty) << ", visibility "
      << nf::toString(s.visibility) << ", edges "
      << (s.edges.enabled ? "on" : "off") << " (alpha " << s.edges.alpha
      << ", beta " << s.edges.beta << ", w_min " << s.edges.w_min << ", sigma "
      << s.edges.smoothing_sigma << ", " << nf::toString(s.edges.color_mode)
      << ", " << nf::toString(s.edges.function) << "), " << s.inner_iterations
      << " inner x <= " << s.max_outer_iterations
      << " outer, <= " << s.max_total_inner_iterations
      << " inner in all, tolerance " << s.relative_tolerance
      << ", pyramid levels " << s.pyramid_levels << ", preconditioning "
      << (s.preconditioning ? "on" : "off") << ", backend "
      << nf::toString(s.backend);
  return out.str();
}

int run(int argc, char** argv) {
  const auto start = Clock::now();
  const Options options = parseArguments(argc, argv);
  if (options.help) {
    printUsage(std::cout);
    return 0;
  }
  std::error_code ec;
  std::filesystem::create_directories(options.output_dir, ec);
  if (!std::filesystem::is_directory(options.output_dir)) {
    throw nf::InputError("--output-dir '" + options.output_dir +
                         "': cannot create the directory");
  }

  // Ground truth of every scene.
  std::vector<nf::synthetic::Frame> frames;
  for (int scene : options.scenes) {
    frames.push_back(
        nf::synthetic::renderScene(scene, options.width, options.height));
  }
  Timer solver_timer, filter_timer;
  Example example;
  std::vector<SigmaResult> results =
      runSigmaSweep(options, frames, &example, &solver_timer, &filter_timer);
  std::vector<FusionTable> fusion;
  if (options.fusion) {
    fusion = runFusion(options, frames, &solver_timer, &filter_timer);
  }

  // The claim: ahead of the best bilateral filter at every sigma.
  std::vector<std::string> failures;
  for (const SigmaResult& r : results) {
    const double best = r.bilateral_mean[r.best_config].psnr_db;
    if (!(r.regularizer_mean.psnr_db > best)) {
      failures.push_back(
          "sigma " + fixed(r.sigma, 2) + ": regularizer " +
          fixed(r.regularizer_mean.psnr_db, 2) + " dB, best bilateral (" +
          bilateralLabel(r.best_config) + ") " + fixed(best, 2) + " dB");
    }
  }

  // Output files.
  const std::filesystem::path dir(options.output_dir);
  const std::string plot_path = (dir / "psnr_vs_sigma.png").string();
  const std::string csv_path = (dir / "results.csv").string();
  const std::string md_path = (dir / "results.md").string();
  writePlot(plot_path, results, options);
  writeCsv(csv_path, options, results, fusion);
  const SigmaResult* example_result = nullptr;
  for (const SigmaResult& r : results) {
    if (example.taken && r.sigma == example.sigma) example_result = &r;
  }
  std::vector<std::string> example_files;
  if (example_result != nullptr) {
    example_files = writeExamples(options.output_dir, example, *example_result);
  }
  const double total_seconds =
      std::chrono::duration<double>(Clock::now() - start).count();

  std::ostringstream md;
  md << "# normal_fusion evaluation on synthetic scenes\n\n"
     << "- scenes: ";
  for (std::size_t s = 0; s < options.scenes.size(); ++s) {
    md << (s ? "," : "") << options.scenes[s];
  }
  md << " at " << options.width << "x" << options.height << ", noise seed "
     << options.seed << "\n"
     << "- regularizer: " << settingsText(options.settings)
     << " (one parameter set for every sigma)\n"
     << "- bilateral baseline: cross-bilateral filter guided by the image "
        "luminance, sigma_I = "
     << kSigmaIntensity
     << ", w = 3, 5, 7 each at the better of sigma_S = 5w/3, 3w/5 (shown in "
        "brackets); * marks the best of all six\n"
     << "- machine: " << cpuModel() << ", "
     << std::thread::hardware_concurrency() << " hardware thread(s), "
     << (options.settings.num_threads > 0
             ? std::to_string(options.settings.num_threads)
             : std::string("all"))
     << " used\n"
     << "- time: " << fixed(total_seconds, 1) << " s in all; regularizer "
     << fixed(solver_timer.mean(), 3) << " s per solve (" << solver_timer.calls
     << " solves), bilateral " << fixed(filter_timer.mean(), 3)
     << " s per filter (" << filter_timer.calls << " filters)\n\n"
     << "## PSNR (dB) against the noise level, mean over the scenes\n\n"
     << psnrTable(results) << "\n"
     << "## Mean angular error (deg), same settings\n\n"
     << angleTable(results) << "\n";
  if (failures.empty()) {
    md << "The regularizer is ahead of the best bilateral filter at every "
          "sigma.\n";
  } else {
    md << "The regularizer is NOT ahead of the best bilateral filter at:\n\n";
    for (const std::string& f : failures) md << "- " << f << "\n";
  }
  if (options.fusion) {
    md << "\n## Fusion: dense noisy + sparse accurate (density "
       << options.sparse_density << ", sigma " << options.sparse_sigma
       << ", weight " << options.sparse_weight << "), mean over the scenes\n\n"
       << "Pixels scored: the share of pixels valid in the map (inputs are "
          "scored only where they hold a normal).\n"
       << fusionTables(fusion);
  }
  md << "\n## Files\n\n- " << plot_path << "\n- " << csv_path << "\n";
  for (const std::string& f : example_files) md << "- " << f << "\n";

  std::cout << md.str();
  std::ofstream md_file(md_path);
  md_file << md.str();
  if (!md_file) throw nf::InputError("cannot write '" + md_path + "'");
  std::cout << "\nevaluate: wrote " << md_path << "\n";
  if (!failures.empty()) {
    for (const std::string& f : failures) {
      std::cerr << "evaluate: regularizer not ahead of the best bilateral "
                   "filter at "
                << f << "\n";
    }
    return kExitClaimFailed;
  }
  return 0;
}

void printError(const std::string& message) {
  std::string line = message;
  for (char& c : line) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  std::cerr << "evaluate: error: " << line << std::endl;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const UsageError& e) {
    printError(e.what());
    return kExitUsageError;
  } catch (const std::exception& e) {
    printError(e.what());
    return kExitFailure;
  } catch (...) {
    printError("unexpected failure");
    return kExitFailure;
  }
}
