// evaluate: accuracy of the regularizer against the paper's cross-bilateral
// baseline and against the edge-aware filters people use today (OpenCV
// ximgproc: joint bilateral, guided, fast global smoother, domain transform),
// each filter at its best setting of a small grid for each case.
//
//   evaluate --output-dir DIR [--cases paper,depth,fusion,castle,stream]
//            [--width 320 --height 240] [--scenes 0,1,2] [--quick]
//            [solver options]
//
// Cases: "paper" (the paper's Fig. 6: paper noise of sigma 0.1 .. 0.9 on the
// synthetic scenes), "depth" (normals of a noisy depth map: structured noise,
// dropout), "fusion" (a dense noisy input with a sparse accurate one) and
// "castle" (ViSP's synthetic Castle sequence: normals of its depth maps with
// depth-camera noise, ground truth from its piecewise-planar model) and
// "stream" (consecutive frames of a moving camera, new noise in each: each
// frame solved alone, the warm-started stream, and both on the inputs
// averaged over time; a synthetic sequence and Castle's frames).
//
// Writes DIR/results.md (the tables, also printed to stdout),
// DIR/results.csv (per scene), DIR/filter_grid.csv (every filter setting),
// DIR/psnr_vs_sigma.png (the plot), the error pictures of every method on
// one scene at sigma 0.5 and their panel. Exit codes: 0 the regularizer is
// ahead of the best bilateral filter at every sigma of the paper case, 1 it
// is not (the sigmas are printed), 2 usage error, 3 failure (unwritable
// output, library error). The comparison with the ximgproc filters is
// reported, not part of the exit code.
#include <algorithm>
#include <array>
#include <cctype>
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
#include "eval/castle.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"
#include "normal_fusion/metrics.h"
#include "eval/peers.h"
#include "normal_fusion/settings.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/solver_options.h"
#include "eval/synthetic.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/types.h"
#include "normal_fusion/warp.h"

namespace {

namespace nf = normal_fusion;
namespace peers = normal_fusion::peers;
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
/// Family index of the paper's bilateral filter; peers follow from 1.
constexpr int kBilateralFamily = 0;

/// A malformed command line: unknown option, missing or bad value.
class UsageError : public std::runtime_error {
 public:
  explicit UsageError(const std::string& what) : std::runtime_error(what) {}
};

struct Options {
  std::string output_dir;
  int width = 320;
  int height = 240;
  bool quick = false;
  std::vector<int> scenes{0, 1, 2};
  std::vector<double> sigmas;  ///< empty: by --quick
  std::uint64_t seed = 2014;
  nf::SolverSettings settings;
  // Cases.
  bool run_paper = true;
  bool run_depth = true;
  bool run_fusion = true;
  bool run_castle = true;
  bool run_stream = true;
  // Depth-camera noise (depth and castle cases, depth input of the fusion).
  double depth_sigma_at_1m = 0.0015;
  double depth_dropout = 0.02;
  double depth_step_m = nf::synthetic::kDepthQuantizationM;
  // Fusion.
  double dense_sigma = 0.4;
  double sparse_density = 0.05;
  double sparse_sigma = 0.05;
  double sparse_weight = 1.0;
  // Castle.
  std::string castle_dir = nf::castle::kDefaultDirectory;
  int castle_frames = 5;  ///< 0: by --quick
  double castle_tolerance_m = nf::castle::LoadSettings().agreement_tolerance_m;
  // Streams.
  int stream_frames = 12;  ///< per sequence; 0: by --quick
  double stream_sigma = 0.4;
  nf::TemporalSettings temporal{20, 45.0};
  bool help = false;
};

void printUsage(std::ostream& out) {
  const Options o;
  out << "Usage: evaluate --output-dir DIR [--cases "
         "paper,depth,fusion,castle]\n"
         "                [--width W --height H] [--scenes 0,1,2] [--quick]\n"
         "                [solver options]\n"
         "\n"
         "Compares the regularizer (one parameter set for every case) with "
         "the\n"
         "paper's cross-bilateral filter (w = 3, 5, 7; sigma_S = 5w/3 or "
         "3w/5;\n"
         "sigma_I = 0.1) and with OpenCV ximgproc's joint bilateral, guided,\n"
         "fast global smoother and domain-transform filters, each filter at\n"
         "its best setting (by PSNR, mean over the scenes) for each case.\n"
         "Metrics: PSNR and angular error on pixels where the input and the\n"
         "ground truth are valid, and separately on pixels the input misses.\n"
         "Writes DIR/results.md, DIR/results.csv, DIR/filter_grid.csv,\n"
         "DIR/psnr_vs_sigma.png and error pictures of the first scene at\n"
         "sigma 0.5 (DIR/errors_scene<N>_sigma0.50.png and one per method).\n"
         "\n"
         "Experiment:\n"
         "  --output-dir DIR      where the results go (created if missing)\n"
         "  --cases LIST          any of paper, depth, fusion, castle [all]\n"
         "  --width N, --height N synthetic image size [320 x 240; 160 x 120 "
         "with --quick]\n"
         "  --scenes LIST         comma-separated scene ids in 0.."
      << nf::synthetic::kNumScenes - 1
      << " [0,1,2]\n"
         "  --sigmas LIST         noise levels of the paper case "
         "[0.1,0.2,...,0.9;\n"
         "                        0.1,0.5,0.9 with --quick]\n"
         "  --quick               small and fast: 160 x 120, three sigmas, "
         "two\n"
         "                        castle frames\n"
         "  --seed N              base seed of the noise ["
      << o.seed
      << "]\n"
         "  --no-fusion           same as leaving fusion out of --cases\n"
         "  --depth-sigma X       depth noise at 1 m (metres, grows with z^2) ["
      << o.depth_sigma_at_1m << "]\n"
      << "  --depth-dropout X     share of missing depth pixels ["
      << o.depth_dropout << "]\n"
      << "  --depth-step X        depth quantization step, metres (0: none) ["
      << o.depth_step_m << "]\n"
      << "  --dense-sigma X       paper noise of the dense fusion input ["
      << o.dense_sigma << "]\n"
      << "  --sparse-density X    share of pixels in the sparse input ["
      << o.sparse_density << "]\n"
      << "  --sparse-sigma X      paper noise of the sparse input ["
      << o.sparse_sigma << "]\n"
      << "  --sparse-weight X     data weight of the sparse input when fused ["
      << o.sparse_weight << "]\n"
      << "  --castle-dir DIR      ViSP's Castle-simu folder [" << o.castle_dir
      << "]\n"
      << "  --castle-frames N     frames used, evenly spaced ["
      << o.castle_frames << "; 2 with --quick]\n"
      << "  --castle-tolerance X  model vs depth agreement for ground truth, "
         "metres ["
      << o.castle_tolerance_m << "]\n"
      << "\n"
         "Solver options (defaults in brackets):\n";
  nf::cli::printSolverOptions(out, nf::SolverSettings());
  out << "  --stream-frames N     consecutive frames of each stream sequence ["
      << o.stream_frames << "; 5 with --quick]\n"
      << "  --stream-sigma X      paper noise of the streams' first input ["
      << o.stream_sigma << "]\n"
      << "  --temporal-frames N   the streams' temporal averaging (0 or 1: "
         "off) ["
      << o.temporal.frames << "]\n"
      << "  --temporal-gate-deg X its gate [" << o.temporal.gate_degrees
      << "]\n";
  out << "  --no-edges            same as --edges off\n"
         "  --help                this text\n"
         "\n"
         "Exit codes: 0 the regularizer beats the best bilateral filter at\n"
         "every sigma of the paper case, 1 it does not, 2 usage error,\n"
         "3 failure. The ximgproc comparison does not change the exit code.\n";
}

double parseDouble(const std::string& option, const std::string& text) {
  try {
    return nf::cli::parseDouble(option, text);
  } catch (const nf::ParameterError& e) {
    throw UsageError(e.what());
  }
}

int parseInt(const std::string& option, const std::string& text) {
  try {
    return nf::cli::parseInt(option, text);
  } catch (const nf::ParameterError& e) {
    throw UsageError(e.what());
  }
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
  bool width_given = false, height_given = false, frames_given = false;
  bool stream_frames_given = false;
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
      if (option == "--no-fusion") options.run_fusion = false;
      continue;
    }
    const auto value = [&]() -> std::string {
      if (has_inline_value) return inline_value;
      if (i + 1 >= argc) throw UsageError(option + " needs a value");
      return argv[++i];
    };
    if (nf::cli::isSolverOption(option)) {
      try {
        nf::cli::applySolverOption(option, value(), s);
      } catch (const nf::ParameterError& e) {
        throw UsageError(e.what());
      }
    } else if (option == "--output-dir") {
      options.output_dir = value();
    } else if (option == "--cases") {
      options.run_paper = options.run_depth = options.run_fusion =
          options.run_castle = options.run_stream = false;
      for (const std::string& item : splitCommas(option, value())) {
        if (item == "paper") {
          options.run_paper = true;
        } else if (item == "depth") {
          options.run_depth = true;
        } else if (item == "fusion") {
          options.run_fusion = true;
        } else if (item == "castle") {
          options.run_castle = true;
        } else if (item == "stream") {
          options.run_stream = true;
        } else {
          throw UsageError(option +
                           ": expected paper, depth, fusion, castle or "
                           "stream, got '" +
                           item + "'");
        }
      }
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
    } else if (option == "--depth-step") {
      options.depth_step_m = parseDouble(option, value());
      requireInRange(option, options.depth_step_m, 0.0, 1.0);
    } else if (option == "--sparse-density") {
      options.sparse_density = parseDouble(option, value());
      requireInRange(option, options.sparse_density, 0.0, 1.0);
    } else if (option == "--sparse-sigma") {
      options.sparse_sigma = parseDouble(option, value());
      requireInRange(option, options.sparse_sigma, 0.0, 10.0);
    } else if (option == "--sparse-weight") {
      options.sparse_weight = parseDouble(option, value());
      requireInRange(option, options.sparse_weight, 0.0, 1e6);
    } else if (option == "--castle-dir") {
      options.castle_dir = value();
    } else if (option == "--castle-frames") {
      options.castle_frames = parseInt(option, value());
      requireInRange(option, options.castle_frames, 1, 1000);
      frames_given = true;
    } else if (option == "--castle-tolerance") {
      options.castle_tolerance_m = parseDouble(option, value());
      requireInRange(option, options.castle_tolerance_m, 0.0, 1.0);
    } else if (option == "--stream-frames") {
      options.stream_frames = parseInt(option, value());
      requireInRange(option, options.stream_frames, 2, 1000);
      stream_frames_given = true;
    } else if (option == "--stream-sigma") {
      options.stream_sigma = parseDouble(option, value());
      requireInRange(option, options.stream_sigma, 0.0, 10.0);
    } else if (option == "--temporal-frames") {
      options.temporal.frames = parseInt(option, value());
      requireInRange(option, options.temporal.frames, 0, 100000);
    } else if (option == "--temporal-gate-deg") {
      options.temporal.gate_degrees = parseDouble(option, value());
      requireInRange(option, options.temporal.gate_degrees, 0.1, 180.0);
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
    if (!frames_given) options.castle_frames = 2;
    if (!stream_frames_given) options.stream_frames = 5;
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
  if (std::isnan(value)) return "-";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

std::string signedFixed(double value, int digits) {
  return (value >= 0.0 ? "+" : "") + fixed(value, digits);
}

std::string percent(double share) { return fixed(100.0 * share, 1) + " %"; }

// --- Scores -----------------------------------------------------------------

/// Accuracy of one map against the ground truth on one set of pixels.
struct Score {
  bool empty = true;  ///< no pixel evaluated (the metrics are then NaN)
  double psnr_db = std::numeric_limits<double>::quiet_NaN();
  nf::AngularErrorStats angles;
  /// Share of the set's pixels (with ground truth) that the map holds.
  double produced = 0.0;
};

/// Scores on the two pixel sets of a case: where an input holds a normal
/// ("valid") and where none does ("fill-in").
struct SplitScore {
  Score valid;
  Score fill;
};

bool validAt(const nf::NormalMap& normals, std::size_t i) {
  const std::size_t n = normals.pixelCount();
  const float x = normals.data()[i], y = normals.data()[n + i],
              z = normals.data()[2 * n + i];
  return std::isfinite(x) && std::isfinite(y) && std::isfinite(z) &&
         nf::isValidNormal(x, y, z);
}

/// Scores `estimate` on the pixels of `mask` (> 0.5) with ground truth.
Score scoreOn(const nf::NormalMap& estimate, const nf::NormalMap& gt,
              const nf::ScalarMap& mask) {
  Score score;
  std::size_t in_set = 0, evaluated = 0;
  for (std::size_t i = 0; i < gt.pixelCount(); ++i) {
    if (!(mask.data()[i] > 0.5f) || !validAt(gt, i)) continue;
    ++in_set;
    if (validAt(estimate, i)) ++evaluated;
  }
  score.produced =
      in_set > 0 ? static_cast<double>(evaluated) / static_cast<double>(in_set)
                 : 0.0;
  if (evaluated == 0) return score;
  score.empty = false;
  score.psnr_db = nf::psnr(estimate, gt, mask);
  score.angles = nf::angularError(estimate, gt, mask);
  return score;
}

/// Mean over scenes: metrics over the scenes where the map has pixels,
/// the produced share over all scenes.
Score meanOf(const std::vector<Score>& scores) {
  Score mean;
  mean.psnr_db = 0.0;
  int used = 0;
  for (const Score& s : scores) {
    mean.produced += s.produced / static_cast<double>(scores.size());
    if (s.empty) continue;
    ++used;
    mean.psnr_db += s.psnr_db;
    mean.angles.mean_deg += s.angles.mean_deg;
    mean.angles.median_deg += s.angles.median_deg;
    mean.angles.within_11_25 += s.angles.within_11_25;
    mean.angles.within_22_5 += s.angles.within_22_5;
    mean.angles.within_30 += s.angles.within_30;
    mean.angles.pixel_count += s.angles.pixel_count;
  }
  if (used == 0) {
    Score none;
    none.produced = mean.produced;
    return none;
  }
  mean.empty = false;
  mean.psnr_db /= used;
  mean.angles.mean_deg /= used;
  mean.angles.median_deg /= used;
  mean.angles.within_11_25 /= used;
  mean.angles.within_22_5 /= used;
  mean.angles.within_30 /= used;
  return mean;
}

SplitScore meanOf(const std::vector<SplitScore>& scores) {
  std::vector<Score> valid, fill;
  for (const SplitScore& s : scores) {
    valid.push_back(s.valid);
    fill.push_back(s.fill);
  }
  return {meanOf(valid), meanOf(fill)};
}

/// PSNR used to rank methods; an empty score ranks last.
double rankOf(const Score& score) {
  return score.empty ? -std::numeric_limits<double>::infinity() : score.psnr_db;
}

/// Filter settings that leave more than this share of the pixels without a
/// normal (normalized convolution that does not reach) rank after all that
/// do not: they would be scored on the easy pixels only.
constexpr double kMinProducedShare = 0.9;

/// How many times a filter's grid is extended past the edge its best
/// setting lies on (see CaseRunner::extendGrids).
constexpr int kMaxGridExtensions = 2;

/// True when setting a ranks above setting b.
bool ranksAbove(const Score& a, const Score& b) {
  const bool a_dense = a.produced >= kMinProducedShare;
  const bool b_dense = b.produced >= kMinProducedShare;
  if (a_dense != b_dense) return a_dense;
  return rankOf(a) > rankOf(b);
}

// --- Timing
// -------------------------------------------------------------------

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

/// Timers of the solver and of each filter family.
struct Timers {
  Timer solver;
  std::vector<Timer> filters;  ///< by family
};

// --- Filters: the paper's bilateral and the ximgproc peers
// ---------------------

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

std::string sigmaSLabel(int config) {
  return config % kNumSpatialChoices == 0 ? "5w/3" : "3w/5";
}

std::string bilateralLabel(int config) {
  const int w = kHalfWindows[config / kNumSpatialChoices];
  return "w=" + std::to_string(w) + ", sigma_S=" + sigmaSLabel(config);
}

int numFamilies() { return 1 + static_cast<int>(peers::allPeers().size()); }

std::string familyName(int family) {
  return family == kBilateralFamily
             ? std::string("bilateral (paper)")
             : peers::name(peers::allPeers()[family - 1]);
}

/// One setting of one filter on one of the case's filter inputs.
struct Candidate {
  int family = kBilateralFamily;
  int variant = 0;  ///< index into the case's filter inputs
  int bilateral_config = 0;
  peers::PeerSetting peer;
  bool beyond_grid = false;  ///< added past the edge of the filter's grid
};

std::string candidateLabel(const Candidate& c,
                           const std::vector<std::string>& variant_names) {
  std::string label = c.family == kBilateralFamily
                          ? bilateralLabel(c.bilateral_config)
                          : c.peer.label();
  if (variant_names.size() > 1) {
    label = "on " + variant_names[c.variant] + ", " + label;
  }
  if (c.beyond_grid) label += " (beyond the grid)";
  return label;
}

/// Every setting of every filter on every filter input.
std::vector<Candidate> allCandidates(int num_variants) {
  std::vector<Candidate> candidates;
  for (int v = 0; v < num_variants; ++v) {
    for (int k = 0; k < kNumBilateral; ++k) {
      Candidate c;
      c.family = kBilateralFamily;
      c.variant = v;
      c.bilateral_config = k;
      candidates.push_back(c);
    }
    const std::vector<peers::PeerFilter> filters = peers::allPeers();
    for (std::size_t f = 0; f < filters.size(); ++f) {
      for (const peers::PeerSetting& setting :
           peers::settingsGrid(filters[f])) {
        Candidate c;
        c.family = static_cast<int>(f) + 1;
        c.variant = v;
        c.peer = setting;
        candidates.push_back(c);
      }
    }
  }
  return candidates;
}

nf::NormalMap applyCandidate(const Candidate& c, const nf::NormalMap& input,
                             const nf::ColorImage& image, int num_threads) {
  if (c.family == kBilateralFamily) {
    return nf::crossBilateralFilter(
        input, image, bilateralSettings(c.bilateral_config, num_threads));
  }
  return peers::applyPeer(input, image, c.peer);
}

// --- Cases
// --------------------------------------------------------------------

/// Runs the regularizer (a fresh cold start) on the given inputs.
nf::NormalMap regularize(const nf::ColorImage& image,
                         const nf::CameraIntrinsics& K,
                         std::vector<nf::NormalInput> inputs,
                         const nf::SolverSettings& settings, Timer* timer) {
  nf::FusionProblem problem;
  problem.image = image;
  problem.K = K;
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

/// One scene (or frame) of a case: ground truth, guide and inputs.
struct SceneData {
  int scene_id = 0;
  nf::ColorImage image;
  nf::CameraIntrinsics K;
  nf::NormalMap gt;
  /// The inputs as given, each scored as a row of its own.
  std::vector<std::pair<std::string, nf::NormalMap>> inputs;
  /// What the filters may take, one per variant of the case.
  std::vector<nf::NormalMap> filter_inputs;
  /// Regularizer runs: a row name and the data terms.
  std::vector<std::pair<std::string, std::vector<nf::NormalInput>>> runs;
};

/// One row of a case's table.
struct Row {
  std::string method;
  std::string setting;  ///< empty for inputs and the regularizer
  std::vector<SplitScore> scenes;
  SplitScore mean;
};

struct CaseResult {
  std::string id;           ///< short name: "paper sigma 0.50", "depth", ...
  std::string title;        ///< heading of its tables
  double sigma = 0.0;       ///< paper case only
  bool has_fill = false;    ///< some pixels with ground truth lack every input
  double fill_share = 0.0;  ///< their share of the pixels with ground truth
  std::vector<std::string> variant_names;
  std::vector<int> scene_ids;  ///< scene ids (castle: frame numbers)
  std::vector<Row> rows;  ///< inputs, best of each filter, regularizer runs
  int num_inputs = 0;
  int first_filter_row = 0;     ///< bilateral, then the peers
  int regularizer_row = 0;      ///< the run the summary compares
  std::vector<Candidate> best;  ///< per family
  std::vector<Candidate> candidates;
  std::vector<SplitScore> candidate_means;
};

/// Accumulates the scores of one case over its scenes.
class CaseRunner {
 public:
  CaseRunner(std::vector<std::string> variant_names, const Options& options,
             Timers* timers)
      : variant_names_(std::move(variant_names)),
        options_(options),
        timers_(timers),
        candidates_(allCandidates(static_cast<int>(variant_names_.size()))),
        candidate_scores_(candidates_.size()) {}

  /// Scores the inputs, every filter setting and the regularizer runs on one
  /// scene; the regularized maps are returned (for pictures).
  std::vector<nf::NormalMap> addScene(const SceneData& scene) {
    const std::size_t n = scene.gt.pixelCount();
    // Pixels with some input ("valid") and with none ("fill-in").
    nf::ScalarMap valid(scene.gt.width(), scene.gt.height(), 1, 0.0f);
    nf::ScalarMap fill(scene.gt.width(), scene.gt.height(), 1, 0.0f);
    std::size_t with_gt = 0, fill_count = 0;
    for (std::size_t i = 0; i < n; ++i) {
      bool any = false;
      for (const auto& input : scene.inputs)
        any = any || validAt(input.second, i);
      valid.data()[i] = any ? 1.0f : 0.0f;
      fill.data()[i] = any ? 0.0f : 1.0f;
      if (validAt(scene.gt, i)) {
        ++with_gt;
        if (!any) ++fill_count;
      }
    }
    fill_shares_.push_back(with_gt > 0 ? static_cast<double>(fill_count) /
                                             static_cast<double>(with_gt)
                                       : 0.0);
    const auto split = [&](const nf::NormalMap& estimate) {
      return SplitScore{scoreOn(estimate, scene.gt, valid),
                        scoreOn(estimate, scene.gt, fill)};
    };
    scene_ids_.push_back(scene.scene_id);
    // Kept for the settings added past a grid's edge later.
    stored_.push_back(
        {scene.image, scene.gt, scene.filter_inputs, valid, fill});
    // Inputs, each on its own pixels within the valid set.
    if (input_scores_.empty()) input_scores_.resize(scene.inputs.size());
    for (std::size_t k = 0; k < scene.inputs.size(); ++k) {
      input_names_.resize(scene.inputs.size());
      input_names_[k] = scene.inputs[k].first;
      input_scores_[k].push_back(
          {scoreOn(scene.inputs[k].second, scene.gt, valid), Score()});
    }
    // Every setting of every filter.
    for (std::size_t c = 0; c < candidates_.size(); ++c) {
      candidate_scores_[c].push_back(
          scoreCandidate(candidates_[c], stored_.back()));
    }
    // The regularizer runs.
    std::vector<nf::NormalMap> regularized;
    if (run_scores_.empty()) run_scores_.resize(scene.runs.size());
    run_names_.clear();
    for (std::size_t r = 0; r < scene.runs.size(); ++r) {
      run_names_.push_back(scene.runs[r].first);
      regularized.push_back(regularize(scene.image, scene.K,
                                       scene.runs[r].second, options_.settings,
                                       &timers_->solver));
      run_scores_[r].push_back(split(regularized.back()));
    }
    return regularized;
  }

  /// Extends the grids past their edges where a filter's best setting lies
  /// on one, then ranks every filter's settings.
  CaseResult finish(const std::string& id, const std::string& title) {
    extendGrids();
    CaseResult result;
    result.id = id;
    result.title = title;
    result.variant_names = variant_names_;
    result.scene_ids = scene_ids_;
    result.candidates = candidates_;
    for (const auto& scores : candidate_scores_) {
      result.candidate_means.push_back(meanOf(scores));
    }
    double fill_share = 0.0;
    for (double s : fill_shares_) fill_share += s / fill_shares_.size();
    result.fill_share = fill_share;
    result.has_fill = fill_share > 0.0;
    for (std::size_t k = 0; k < input_scores_.size(); ++k) {
      result.rows.push_back(
          {input_names_[k], "", input_scores_[k], meanOf(input_scores_[k])});
    }
    result.num_inputs = static_cast<int>(input_scores_.size());
    // Each filter at its setting with the best mean PSNR on the valid pixels.
    result.first_filter_row = static_cast<int>(result.rows.size());
    for (int family = 0; family < numFamilies(); ++family) {
      const int best = bestCandidate(family);
      result.best.push_back(candidates_[best]);
      result.rows.push_back({familyName(family) + " best",
                             candidateLabel(candidates_[best], variant_names_),
                             candidate_scores_[best],
                             result.candidate_means[best]});
    }
    for (std::size_t r = 0; r < run_scores_.size(); ++r) {
      result.rows.push_back(
          {run_names_[r], "", run_scores_[r], meanOf(run_scores_[r])});
    }
    result.regularizer_row = static_cast<int>(result.rows.size()) - 1;
    return result;
  }

 private:
  /// What scoring a filter setting on a scene needs.
  struct StoredScene {
    nf::ColorImage image;
    nf::NormalMap gt;
    std::vector<nf::NormalMap> filter_inputs;
    nf::ScalarMap valid, fill;
  };

  SplitScore scoreCandidate(const Candidate& candidate,
                            const StoredScene& scene) {
    const nf::NormalMap filtered =
        timed(&timers_->filters[candidate.family], [&] {
          return applyCandidate(candidate,
                                scene.filter_inputs[candidate.variant],
                                scene.image, options_.settings.num_threads);
        });
    return {scoreOn(filtered, scene.gt, scene.valid),
            scoreOn(filtered, scene.gt, scene.fill)};
  }

  /// Index of the family's best setting so far.
  int bestCandidate(int family) const {
    int best = -1;
    Score best_score;
    for (std::size_t c = 0; c < candidates_.size(); ++c) {
      if (candidates_[c].family != family) continue;
      const Score score = meanOf(candidate_scores_[c]).valid;
      if (best < 0 || ranksAbove(score, best_score)) {
        best = static_cast<int>(c);
        best_score = score;
      }
    }
    return best;
  }

  /// Where a peer's best setting lies on the edge of the values tried for
  /// one of its two parameters (on the same filter input), one geometric
  /// step further is tried, up to kMaxGridExtensions times: the peers are
  /// shown at their best, not at the best of a grid fixed beforehand.
  void extendGrids() {
    for (int family = 1; family < numFamilies(); ++family) {
      for (int round = 0; round < kMaxGridExtensions; ++round) {
        const Candidate best = candidates_[bestCandidate(family)];
        std::vector<double> as, bs;
        for (const Candidate& c : candidates_) {
          if (c.family != family || c.variant != best.variant) continue;
          as.push_back(c.peer.a);
          bs.push_back(c.peer.b);
        }
        const auto beyond = [](std::vector<double> values, double at) {
          std::sort(values.begin(), values.end());
          values.erase(std::unique(values.begin(), values.end()), values.end());
          if (values.size() < 2) return at;
          // One geometric step past the smallest or largest value.
          if (at == values.front()) return at * at / values[1];
          if (at == values.back()) {
            return at * at / values[values.size() - 2];
          }
          return at;
        };
        double a_next = beyond(as, best.peer.a);
        const double b_next = beyond(bs, best.peer.b);
        if (best.peer.filter == peers::PeerFilter::kGuided) {
          a_next = std::round(a_next);  // a radius in whole pixels
        }
        std::vector<Candidate> added;
        for (const auto& ab : {std::make_pair(a_next, best.peer.b),
                               std::make_pair(best.peer.a, b_next),
                               std::make_pair(a_next, b_next)}) {
          if (ab.first == best.peer.a && ab.second == best.peer.b) continue;
          if (!(ab.first > 0.0) || !(ab.second > 0.0)) continue;
          bool known = false;
          for (const Candidate& c : candidates_) {
            known = known || (c.family == family && c.variant == best.variant &&
                              c.peer.a == ab.first && c.peer.b == ab.second);
          }
          for (const Candidate& c : added) {
            known = known || (c.peer.a == ab.first && c.peer.b == ab.second);
          }
          if (known) continue;
          Candidate c = best;
          c.peer.a = ab.first;
          c.peer.b = ab.second;
          c.beyond_grid = true;
          added.push_back(c);
        }
        if (added.empty()) break;
        for (const Candidate& c : added) {
          candidates_.push_back(c);
          candidate_scores_.emplace_back();
          for (const StoredScene& scene : stored_) {
            candidate_scores_.back().push_back(scoreCandidate(c, scene));
          }
        }
      }
    }
  }

  std::vector<std::string> variant_names_;
  const Options& options_;
  Timers* timers_;
  std::vector<Candidate> candidates_;
  std::vector<std::vector<SplitScore>> candidate_scores_;
  std::vector<std::string> input_names_;
  std::vector<std::vector<SplitScore>> input_scores_;
  std::vector<std::string> run_names_;
  std::vector<std::vector<SplitScore>> run_scores_;
  std::vector<double> fill_shares_;
  std::vector<StoredScene> stored_;
  std::vector<int> scene_ids_;
};

/// The scene of the example pictures, kept with the case result.
struct Example {
  bool taken = false;
  std::string tag;  ///< part of the file names: "scene0_sigma0.50"
  std::string input_name, input_setting;
  nf::ColorImage image;
  nf::NormalMap gt, input, regularizer;
  double sigma = 0.0;  ///< paper case: the noise level it belongs to
};

std::vector<CaseResult> runPaperCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Example* example, Timers* timers) {
  // The example is the sigma nearest to 0.5 on the first scene.
  double example_sigma = options.sigmas.front();
  for (double sigma : options.sigmas) {
    if (std::fabs(sigma - kExampleSigma) <
        std::fabs(example_sigma - kExampleSigma)) {
      example_sigma = sigma;
    }
  }
  std::vector<CaseResult> results;
  for (double sigma : options.sigmas) {
    CaseRunner runner({"noisy input"}, options, timers);
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const nf::synthetic::Frame& frame = frames[s];
      SceneData scene;
      scene.scene_id = options.scenes[s];
      scene.image = frame.image;
      scene.K = frame.K;
      scene.gt = frame.normals_gt;
      // Noisy input: the paper's noise model.
      const nf::NormalMap noisy = nf::synthetic::addPaperNoise(
          frame.normals_gt, sigma,
          noiseSeed(options, scene.scene_id, 0, sigma));
      scene.inputs = {{"noisy input", noisy}};
      scene.filter_inputs = {noisy};
      scene.runs = {{"regularizer", {inputOf(noisy)}}};
      const std::vector<nf::NormalMap> regularized = runner.addScene(scene);
      if (s == 0 && sigma == example_sigma) {
        example->taken = true;
        example->tag = "scene" + std::to_string(scene.scene_id) + "_sigma" +
                       fixed(sigma, 2);
        example->input_name = "noisy input";
        example->input_setting = "sigma " + fixed(sigma, 2);
        example->sigma = sigma;
        example->image = frame.image;
        example->gt = frame.normals_gt;
        example->input = noisy;
        example->regularizer = regularized.front();
      }
    }
    CaseResult result = runner.finish("paper sigma " + fixed(sigma, 2),
                                      "Paper noise, sigma " + fixed(sigma, 2));
    result.sigma = sigma;
    const Row& reg = result.rows[result.regularizer_row];
    std::cerr << "evaluate: paper sigma " << fixed(sigma, 2) << ": noisy "
              << fixed(result.rows[0].mean.valid.psnr_db, 2)
              << " dB, regularizer " << fixed(reg.mean.valid.psnr_db, 2)
              << " dB\n";
    results.push_back(std::move(result));
  }
  return results;
}

/// Normals of a noisy depth map of each scene (the depth case's input and
/// the fusion's depth-derived dense input).
nf::NormalMap depthInput(const Options& options,
                         const nf::synthetic::Frame& frame, int scene) {
  const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
      frame.depth, options.depth_sigma_at_1m, options.depth_step_m,
      options.depth_dropout, noiseSeed(options, scene, 2, 0.0));
  return nf::synthetic::normalsFromDepth(noisy_depth, frame.K);
}

std::string depthNoiseText(const Options& options) {
  return fixed(options.depth_sigma_at_1m * 1000.0, 2) +
         " mm at 1 m growing with z^2, " +
         fixed(options.depth_step_m * 1000.0, 2) + " mm steps, " +
         fixed(options.depth_dropout * 100.0, 1) + " % dropout";
}

CaseResult runDepthCase(const Options& options,
                        const std::vector<nf::synthetic::Frame>& frames,
                        Timers* timers) {
  CaseRunner runner({"depth normals"}, options, timers);
  for (std::size_t s = 0; s < frames.size(); ++s) {
    SceneData scene;
    scene.scene_id = options.scenes[s];
    scene.image = frames[s].image;
    scene.K = frames[s].K;
    scene.gt = frames[s].normals_gt;
    const nf::NormalMap dense = depthInput(options, frames[s], scene.scene_id);
    scene.inputs = {{"normals of noisy depth", dense}};
    scene.filter_inputs = {dense};
    scene.runs = {{"regularizer", {inputOf(dense)}}};
    runner.addScene(scene);
    std::cerr << "evaluate: depth case, scene " << scene.scene_id << " done\n";
  }
  return runner.finish("depth", "Normals of a noisy depth map (" +
                                    depthNoiseText(options) + ")");
}

std::vector<CaseResult> runFusionCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Timers* timers) {
  std::vector<CaseResult> results;
  for (int d = 0; d < 2; ++d) {
    const std::string dense_name =
        d == 0 ? "paper noise sigma " + fixed(options.dense_sigma, 2)
               : "normals of noisy depth";
    // The filters take one map: the dense one, the sparse one, or both
    // merged (the sparse normal where there is one).
    CaseRunner runner({"dense", "sparse", "merged"}, options, timers);
    for (std::size_t s = 0; s < frames.size(); ++s) {
      const nf::synthetic::Frame& frame = frames[s];
      const nf::NormalMap& gt = frame.normals_gt;
      SceneData scene;
      scene.scene_id = options.scenes[s];
      scene.image = frame.image;
      scene.K = frame.K;
      scene.gt = gt;
      const nf::NormalMap dense =
          d == 0
              ? nf::synthetic::addPaperNoise(
                    gt, options.dense_sigma,
                    noiseSeed(options, scene.scene_id, 1, options.dense_sigma))
              : depthInput(options, frame, scene.scene_id);
      // Sparse input: few pixels, little noise (the same for both inputs).
      const nf::NormalMap sparse = nf::synthetic::sparseAccurate(
          gt, options.sparse_density, options.sparse_sigma,
          noiseSeed(options, scene.scene_id, 3, options.sparse_sigma));
      nf::NormalMap merged = dense;
      for (std::size_t i = 0; i < sparse.pixelCount(); ++i) {
        if (!validAt(sparse, i)) continue;
        for (int c = 0; c < 3; ++c) {
          merged.plane(c)[i] = sparse.plane(c)[i];
        }
      }
      scene.inputs = {{"dense input (" + dense_name + ")", dense},
                      {"sparse input", sparse}};
      scene.filter_inputs = {dense, sparse, merged};
      // Fused: the sparse, accurate input first (it initializes where given).
      scene.runs = {{"regularizer, dense alone", {inputOf(dense)}},
                    {"regularizer, sparse alone", {inputOf(sparse)}},
                    {"regularizer, fused (sparse + dense)",
                     {inputOf(sparse, options.sparse_weight), inputOf(dense)}}};
      runner.addScene(scene);
      std::cerr << "evaluate: fusion with " << dense_name << ", scene "
                << scene.scene_id << " done\n";
    }
    results.push_back(runner.finish(
        "fusion, " + dense_name,
        "Fusion: dense " + dense_name + " + sparse accurate (density " +
            fixed(options.sparse_density, 2) + ", sigma " +
            fixed(options.sparse_sigma, 2) + ", weight " +
            fixed(options.sparse_weight, 2) + ")"));
  }
  return results;
}

/// The castle case, or a note why it was skipped.
struct CastleOutcome {
  bool ran = false;
  std::string note;
  CaseResult result;
  std::vector<int> frames;
  double agreement = 0.0;     ///< mean share of depth pixels with ground truth
  int width = 0, height = 0;  ///< mean crop size
  Example example;            ///< the first frame
};

CastleOutcome runCastleCase(const Options& options, Timers* timers) {
  CastleOutcome outcome;
  if (!nf::castle::available(options.castle_dir)) {
    outcome.note = "skipped: the ViSP Castle-simu sequence is not at '" +
                   options.castle_dir +
                   "' (Debian package visp-images-data; scripts/setup.sh "
                   "installs it)";
    return outcome;
  }
  const std::vector<int> numbers = nf::castle::frameNumbers(options.castle_dir);
  // Evenly spaced frames over the sequence.
  const int count = std::min<int>(options.castle_frames, numbers.size());
  for (int k = 0; k < count; ++k) {
    const std::size_t at =
        count == 1
            ? 0
            : static_cast<std::size_t>(std::lround(
                  static_cast<double>(k) * (numbers.size() - 1) / (count - 1)));
    outcome.frames.push_back(numbers[at]);
  }
  const std::vector<nf::castle::Face> model =
      nf::castle::loadModel(options.castle_dir);
  nf::castle::LoadSettings load;
  load.agreement_tolerance_m = options.castle_tolerance_m;
  CaseRunner runner({"depth normals"}, options, timers);
  for (int number : outcome.frames) {
    const nf::castle::Frame frame =
        nf::castle::loadFrame(options.castle_dir, number, model, load);
    outcome.agreement += frame.agreement / count;
    outcome.width += frame.image.width();
    outcome.height += frame.image.height();
    SceneData scene;
    scene.scene_id = number;
    scene.image = frame.image;
    scene.K = frame.K;
    scene.gt = frame.normals_gt;
    // Input: normals of the depth map with depth-camera noise.
    const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
        frame.depth, options.depth_sigma_at_1m, options.depth_step_m,
        options.depth_dropout, noiseSeed(options, 100 + number, 4, 0.0));
    const nf::NormalMap dense =
        nf::synthetic::normalsFromDepth(noisy_depth, frame.K);
    scene.inputs = {{"normals of noisy depth", dense}};
    scene.filter_inputs = {dense};
    scene.runs = {{"regularizer", {inputOf(dense)}}};
    const std::vector<nf::NormalMap> regularized = runner.addScene(scene);
    if (!outcome.example.taken) {
      Example& example = outcome.example;
      example.taken = true;
      example.tag = "castle_frame" + std::to_string(number);
      example.input_name = "normals of noisy depth";
      example.input_setting = "depth noise";
      example.image = frame.image;
      example.gt = frame.normals_gt;
      example.input = dense;
      example.regularizer = regularized.front();
    }
    std::cerr << "evaluate: castle frame " << number << " done\n";
  }
  outcome.width /= std::max(count, 1);
  outcome.height /= std::max(count, 1);
  outcome.ran = true;
  outcome.result =
      runner.finish("castle",
                    "ViSP Castle (synthetic RGB-D), normals of its depth maps "
                    "with depth-camera noise (" +
                        depthNoiseText(options) + ")");
  return outcome;
}

// --- Streams
// -------------------------------------------------------------------

/// One frame of a stream: what the solver gets, the ground truth, and the
/// camera's rotation since the previous frame.
struct StreamFrame {
  nf::FusionProblem problem;
  nf::NormalMap gt;
  std::array<double, 9> R_cur_prev{{1, 0, 0, 0, 1, 0, 0, 0, 1}};
};

/// The ways a stream is solved, in table order.
const std::array<const char*, 4> kStreamMethods{{
    "each frame alone",
    "each frame alone, inputs averaged over time",
    "stream (warm start)",
    "stream (warm start), inputs averaged over time",
}};

/// Scores of one stream sequence: [method][frame].
struct StreamResult {
  std::string title;
  std::string tag;  ///< file name part: "synthetic", "castle"
  std::vector<std::vector<Score>> scores;
  double seconds_per_solve = 0.0;  ///< one solve, mean over every method
};

/// Solves a sequence four ways (kStreamMethods) and scores every frame on the
/// pixels with ground truth. The warm-started streams warp their state by
/// the camera's rotation (warpStateByRotation, as the node does with tf);
/// the averages are carried by the same rotation (TemporalAverage).
StreamResult runStream(const std::string& title, const std::string& tag,
                       const std::vector<StreamFrame>& frames,
                       const Options& options) {
  StreamResult result;
  result.title = title;
  result.tag = tag;
  result.scores.resize(kStreamMethods.size());
  nf::Solver solver(options.settings);
  nf::TemporalAverage average;
  nf::SolverState plain_state, averaged_state;
  Timer timer;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const StreamFrame& frame = frames[k];
    nf::FusionProblem averaged = frame.problem;
    average.apply(averaged.inputs, averaged.K,
                  k > 0 ? &frame.R_cur_prev : nullptr, options.temporal,
                  options.settings.num_threads);
    nf::ScalarMap all(frame.gt.width(), frame.gt.height(), 1, 1.0f);
    const nf::FusionProblem* problems[2] = {&frame.problem, &averaged};
    for (int m = 0; m < 4; ++m) {
      const nf::FusionProblem& problem = *problems[m % 2];
      nf::NormalMap solved;
      if (m < 2) {
        solved = timed(&timer, [&] { return solver.solve(problem); });
      } else {
        nf::SolverState& state = m == 2 ? plain_state : averaged_state;
        if (k > 0) {
          nf::warpStateByRotation(state, problem.K, frame.R_cur_prev);
        }
        timed(&timer, [&] { return solver.solve(problem, state, k > 0); });
        solved = state.normals;
      }
      result.scores[m].push_back(scoreOn(solved, frame.gt, all));
    }
    std::cerr << "evaluate: " << title << ", frame " << k << " done\n";
  }
  result.seconds_per_solve = timer.mean();
  return result;
}

/// The synthetic stream: scene options.scenes[0], the camera turning 0.3
/// degrees per frame at 30 fps (with the translation of the sequence), two
/// inputs with new noise in each frame: the paper's noise and normals of a
/// noisy depth map.
std::vector<StreamFrame> syntheticStream(const Options& options) {
  const int scene = options.scenes.front();
  const std::vector<nf::synthetic::Frame> sequence =
      nf::synthetic::renderSequence(scene, options.width, options.height,
                                    options.stream_frames);
  std::vector<StreamFrame> frames(sequence.size());
  for (std::size_t k = 0; k < sequence.size(); ++k) {
    const int id = 10000 + 100 * scene + static_cast<int>(k);
    StreamFrame& f = frames[k];
    f.problem.image = sequence[k].image;
    f.problem.K = sequence[k].K;
    f.problem.inputs = {inputOf(nf::synthetic::addPaperNoise(
                            sequence[k].normals_gt, options.stream_sigma,
                            noiseSeed(options, id, 1, options.stream_sigma))),
                        inputOf(depthInput(options, sequence[k], id))};
    f.gt = sequence[k].normals_gt;
    if (k > 0) {
      f.R_cur_prev = nf::synthetic::relativeRotation(sequence[k].pose,
                                                     sequence[k - 1].pose);
    }
  }
  return frames;
}

/// Castle's first frames in a row, uncropped (a stream keeps its size), the
/// normals of each depth map with new depth-camera noise; empty when the
/// sequence is not installed.
std::vector<StreamFrame> castleStream(const Options& options) {
  std::vector<StreamFrame> frames;
  if (!nf::castle::available(options.castle_dir)) return frames;
  const std::vector<int> numbers = nf::castle::frameNumbers(options.castle_dir);
  const std::vector<nf::castle::Face> model =
      nf::castle::loadModel(options.castle_dir);
  nf::castle::LoadSettings load;
  load.agreement_tolerance_m = options.castle_tolerance_m;
  load.crop_margin = -1;
  const int count =
      std::min<int>(options.stream_frames, static_cast<int>(numbers.size()));
  nf::synthetic::Pose previous;
  for (int k = 0; k < count; ++k) {
    const nf::castle::Frame frame =
        nf::castle::loadFrame(options.castle_dir, numbers[k], model, load);
    StreamFrame f;
    f.problem.image = frame.image;
    f.problem.K = frame.K;
    const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
        frame.depth, options.depth_sigma_at_1m, options.depth_step_m,
        options.depth_dropout, noiseSeed(options, 20000 + numbers[k], 4, 0.0));
    f.problem.inputs = {
        inputOf(nf::synthetic::normalsFromDepth(noisy_depth, frame.K))};
    f.gt = frame.normals_gt;
    if (k > 0) {
      f.R_cur_prev =
          nf::synthetic::relativeRotation(frame.T_depth_obj, previous);
    }
    previous = frame.T_depth_obj;
    frames.push_back(std::move(f));
  }
  return frames;
}

/// The table of a stream: per method the mean PSNR and angles over the
/// frames, and the PSNR against each frame solved alone (mean, worst frame)
/// over the frames after the first (the first is the same for all).
std::string streamTable(const StreamResult& r) {
  std::ostringstream t;
  t << "| method | PSNR (dB) | mean angle (deg) | median angle (deg) | PSNR "
       "against each frame alone, frames 1 on: mean / worst frame (dB) |\n"
       "|---|---:|---:|---:|---:|\n";
  const std::vector<Score>& alone = r.scores[0];
  for (std::size_t m = 0; m < kStreamMethods.size(); ++m) {
    const Score mean = meanOf(r.scores[m]);
    double sum = 0.0, worst = std::numeric_limits<double>::infinity();
    for (std::size_t k = 1; k < alone.size(); ++k) {
      const double d = r.scores[m][k].psnr_db - alone[k].psnr_db;
      sum += d;
      worst = std::min(worst, d);
    }
    t << "| " << kStreamMethods[m] << " | " << fixed(mean.psnr_db, 2) << " | "
      << fixed(mean.angles.mean_deg, 2) << " | "
      << fixed(mean.angles.median_deg, 2) << " | ";
    if (m == 0) {
      t << "- |\n";
    } else {
      t << signedFixed(sum / (alone.size() - 1), 2) << " / "
        << signedFixed(worst, 2) << " |\n";
    }
  }
  t << "\nPer frame, PSNR (dB):\n\n| frame |";
  for (std::size_t m = 0; m < kStreamMethods.size(); ++m) {
    t << " " << kStreamMethods[m] << " |";
  }
  t << "\n|---:|";
  for (std::size_t m = 0; m < kStreamMethods.size(); ++m) t << "---:|";
  t << "\n";
  for (std::size_t k = 0; k < alone.size(); ++k) {
    t << "| " << k << " |";
    for (std::size_t m = 0; m < kStreamMethods.size(); ++m) {
      t << " " << fixed(r.scores[m][k].psnr_db, 2) << " |";
    }
    t << "\n";
  }
  return t.str();
}

// --- Output
// --------------------------------------------------------------------

const Row& bilateralRow(const CaseResult& r) {
  return r.rows[r.first_filter_row];
}

/// Mean PSNR of the bilateral setting `config` in the paper case.
double bilateralPsnr(const CaseResult& r, int config) {
  for (std::size_t c = 0; c < r.candidates.size(); ++c) {
    if (r.candidates[c].family == kBilateralFamily &&
        r.candidates[c].bilateral_config == config) {
      return r.candidate_means[c].valid.psnr_db;
    }
  }
  return std::numeric_limits<double>::quiet_NaN();
}

/// Better sigma_S for each w (by PSNR).
std::array<int, 3> bestConfigPerW(const CaseResult& r) {
  std::array<int, 3> best{};
  for (int wi = 0; wi < 3; ++wi) {
    best[wi] = wi * kNumSpatialChoices;
    for (int j = 1; j < kNumSpatialChoices; ++j) {
      const int k = wi * kNumSpatialChoices + j;
      if (bilateralPsnr(r, k) > bilateralPsnr(r, best[wi])) best[wi] = k;
    }
  }
  return best;
}

/// The best peer's row (by PSNR) of a case.
int bestPeerRow(const CaseResult& r) {
  int best = r.first_filter_row + 1;
  for (int f = 2; f < numFamilies(); ++f) {
    const int row = r.first_filter_row + f;
    if (rankOf(r.rows[row].mean.valid) > rankOf(r.rows[best].mean.valid)) {
      best = row;
    }
  }
  return best;
}

std::string peerHeader() {
  std::string header;
  for (peers::PeerFilter filter : peers::allPeers()) {
    header += " | " + peers::name(filter);
  }
  return header;
}

std::string psnrTable(const std::vector<CaseResult>& results) {
  std::ostringstream out;
  out << "| sigma | noisy input | bilateral w=3 | bilateral w=5 | bilateral "
         "w=7 | regularizer | regularizer - best bilateral (dB)"
      << peerHeader() << " | regularizer - best peer (dB) |\n|---:";
  for (int k = 0; k < 7 + numFamilies() - 1; ++k) out << "|---:";
  out << "|\n";
  for (const CaseResult& r : results) {
    const std::array<int, 3> per_w = bestConfigPerW(r);
    const Row& reg = r.rows[r.regularizer_row];
    const Row& bil = bilateralRow(r);
    out << "| " << fixed(r.sigma, 2) << " | "
        << fixed(r.rows[0].mean.valid.psnr_db, 2);
    for (int k : per_w) {
      out << " | " << fixed(bilateralPsnr(r, k), 2) << " (" << sigmaSLabel(k)
          << ")"
          << (k == r.best[kBilateralFamily].bilateral_config ? " *" : "");
    }
    out << " | " << fixed(reg.mean.valid.psnr_db, 2) << " | "
        << signedFixed(reg.mean.valid.psnr_db - bil.mean.valid.psnr_db, 2);
    for (int f = 1; f < numFamilies(); ++f) {
      out << " | "
          << fixed(r.rows[r.first_filter_row + f].mean.valid.psnr_db, 2);
    }
    out << " | "
        << signedFixed(reg.mean.valid.psnr_db -
                           r.rows[bestPeerRow(r)].mean.valid.psnr_db,
                       2)
        << " |\n";
  }
  return out.str();
}

std::string angleTable(const std::vector<CaseResult>& results) {
  std::ostringstream out;
  out << "| sigma | noisy input | bilateral w=3 | bilateral w=5 | bilateral "
         "w=7"
      << peerHeader()
      << " | regularizer | regularizer median | regularizer <= 11.25 deg "
         "|\n|---:";
  for (int k = 0; k < 7 + numFamilies() - 1; ++k) out << "|---:";
  out << "|\n";
  for (const CaseResult& r : results) {
    // The bilateral columns at the setting each w has in the PSNR table.
    std::array<double, 3> bilateral_deg{};
    const std::array<int, 3> per_w = bestConfigPerW(r);
    for (int wi = 0; wi < 3; ++wi) {
      for (std::size_t c = 0; c < r.candidates.size(); ++c) {
        if (r.candidates[c].family == kBilateralFamily &&
            r.candidates[c].bilateral_config == per_w[wi]) {
          bilateral_deg[wi] = r.candidate_means[c].valid.angles.mean_deg;
        }
      }
    }
    const Row& reg = r.rows[r.regularizer_row];
    out << "| " << fixed(r.sigma, 2) << " | "
        << fixed(r.rows[0].mean.valid.angles.mean_deg, 2);
    for (double deg : bilateral_deg) out << " | " << fixed(deg, 2);
    for (int f = 1; f < numFamilies(); ++f) {
      out << " | "
          << fixed(r.rows[r.first_filter_row + f].mean.valid.angles.mean_deg,
                   2);
    }
    out << " | " << fixed(reg.mean.valid.angles.mean_deg, 2) << " | "
        << fixed(reg.mean.valid.angles.median_deg, 2) << " | "
        << percent(reg.mean.valid.angles.within_11_25) << " |\n";
  }
  return out.str();
}

/// Table of one split: rows = methods.
std::string splitTable(const CaseResult& r, bool fill) {
  std::ostringstream out;
  out << "| method | setting | " << (fill ? "filled" : "pixels scored")
      << " | PSNR (dB) | mean (deg) | median (deg) | <= 11.25 deg | <= 22.5 "
         "deg | <= 30 deg |\n"
         "|---|---|---:|---:|---:|---:|---:|---:|---:|\n";
  for (std::size_t k = 0; k < r.rows.size(); ++k) {
    const Row& row = r.rows[k];
    const bool is_input = static_cast<int>(k) < r.num_inputs;
    if (fill && is_input) continue;  // inputs hold nothing there
    const Score& m = fill ? row.mean.fill : row.mean.valid;
    const bool bold = static_cast<int>(k) == r.regularizer_row;
    const std::string b = bold ? "**" : "";
    out << "| " << b << row.method << b << " | "
        << (row.setting.empty() ? "-" : row.setting) << " | "
        << percent(m.produced) << " | " << b << fixed(m.psnr_db, 2) << b
        << " | " << fixed(m.angles.mean_deg, 2) << " | "
        << fixed(m.angles.median_deg, 2) << " | "
        << percent(m.angles.within_11_25) << " | "
        << percent(m.angles.within_22_5) << " | " << percent(m.angles.within_30)
        << " |\n";
  }
  return out.str();
}

std::string caseTables(const CaseResult& r, const std::string& heading) {
  std::ostringstream out;
  out << heading << r.title << "\n\n"
      << "Pixels where an input holds a normal and the ground truth is "
         "valid; each filter at its best setting for this case (by PSNR, "
         "mean over the scenes); 'pixels scored' is the share of them the "
         "map holds.\n\n"
      << splitTable(r, false);
  if (r.has_fill) {
    out << "\nFill-in: pixels with ground truth where no input holds a "
           "normal ("
        << percent(r.fill_share)
        << " of them); 'filled' is the share each method produces (the "
           "filters fill by normalized convolution and leave NaN where they "
           "do not reach).\n\n"
        << splitTable(r, true);
  }
  return out.str();
}

/// One line of the summary: the regularizer against every peer.
struct PeerVerdict {
  bool ahead_psnr = true;
  bool ahead_angle = true;
  double margin_db = 0.0;  ///< over the best peer by PSNR
  std::string best_peer;
};

PeerVerdict verdictOf(const CaseResult& r) {
  PeerVerdict v;
  const Score& reg = r.rows[r.regularizer_row].mean.valid;
  for (int f = 1; f < numFamilies(); ++f) {
    const Score& peer = r.rows[r.first_filter_row + f].mean.valid;
    if (peer.empty) continue;
    v.ahead_psnr = v.ahead_psnr && !reg.empty && reg.psnr_db > peer.psnr_db;
    v.ahead_angle = v.ahead_angle && !reg.empty &&
                    reg.angles.mean_deg < peer.angles.mean_deg;
  }
  const Row& best = r.rows[bestPeerRow(r)];
  v.margin_db = reg.psnr_db - best.mean.valid.psnr_db;
  v.best_peer = best.method + " (" + best.setting + ")";
  return v;
}

std::string summaryLine(const CaseResult& r) {
  const PeerVerdict v = verdictOf(r);
  std::ostringstream out;
  out << "| " << r.id << " | " << r.rows[r.regularizer_row].method << " | "
      << (v.ahead_psnr ? "yes" : "**no**") << " | "
      << (v.ahead_angle ? "yes" : "**no**") << " | "
      << signedFixed(v.margin_db, 2) << " | " << v.best_peer << " |";
  if (r.has_fill) {
    const Score& reg = r.rows[r.regularizer_row].mean.fill;
    double best_fill = -std::numeric_limits<double>::infinity();
    for (int f = 1; f < numFamilies(); ++f) {
      best_fill =
          std::max(best_fill, rankOf(r.rows[r.first_filter_row + f].mean.fill));
    }
    out << " " << signedFixed(reg.psnr_db - best_fill, 2) << " |";
  } else {
    out << " - |";
  }
  return out.str();
}

void writeCsv(const std::string& path, const std::vector<CaseResult>& cases) {
  std::ofstream out(path);
  if (!out) throw nf::InputError("cannot write '" + path + "'");
  out << "case,scene,method,setting,pixels,psnr_db,mean_deg,median_deg,"
         "within_11_25,within_22_5,within_30,produced\n";
  for (const CaseResult& r : cases) {
    for (const Row& row : r.rows) {
      for (std::size_t s = 0; s < row.scenes.size(); ++s) {
        for (int split = 0; split < (r.has_fill ? 2 : 1); ++split) {
          const Score& m =
              split == 0 ? row.scenes[s].valid : row.scenes[s].fill;
          out << "\"" << r.id << "\"," << r.scene_ids[s] << ",\"" << row.method
              << "\",\"" << row.setting << "\","
              << (split == 0 ? "valid" : "fill") << "," << std::setprecision(8)
              << m.psnr_db << "," << m.angles.mean_deg << ","
              << m.angles.median_deg << "," << m.angles.within_11_25 << ","
              << m.angles.within_22_5 << "," << m.angles.within_30 << ","
              << m.produced << "\n";
        }
      }
    }
  }
  if (!out) throw nf::InputError("failed writing '" + path + "'");
}

/// Every filter setting's mean scores: the grids the best settings come from.
void writeGridCsv(const std::string& path,
                  const std::vector<CaseResult>& cases) {
  std::ofstream out(path);
  if (!out) throw nf::InputError("cannot write '" + path + "'");
  out << "case,filter,setting,psnr_db,mean_deg,produced,fill_psnr_db,"
         "fill_mean_deg,fill_produced\n";
  for (const CaseResult& r : cases) {
    for (std::size_t c = 0; c < r.candidates.size(); ++c) {
      const SplitScore& m = r.candidate_means[c];
      out << "\"" << r.id << "\",\"" << familyName(r.candidates[c].family)
          << "\",\"" << candidateLabel(r.candidates[c], r.variant_names)
          << "\"," << std::setprecision(8) << m.valid.psnr_db << ","
          << m.valid.angles.mean_deg << "," << m.valid.produced << ","
          << m.fill.psnr_db << "," << m.fill.angles.mean_deg << ","
          << m.fill.produced << "\n";
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

void writeLinePlot(const std::string& path, const std::string& title,
                   const std::string& x_label, const std::vector<double>& xs,
                   int x_digits, const std::vector<Series>& series);

/// PSNR against sigma for each method of the paper case.
void writePlot(const std::string& path, const std::vector<CaseResult>& results,
               const Options& options) {
  std::vector<Series> series = {
      {"noisy input", cv::Scalar(140, 140, 140), 2, {}},
      {"bilateral (paper), best", cv::Scalar(60, 160, 40), 2, {}}};
  const std::vector<cv::Scalar> peer_colours = {
      cv::Scalar(200, 120, 30), cv::Scalar(30, 140, 230),
      cv::Scalar(180, 60, 160), cv::Scalar(40, 190, 200)};
  for (int f = 1; f < numFamilies(); ++f) {
    series.push_back({familyName(f) + ", best",
                      peer_colours[(f - 1) % peer_colours.size()],
                      2,
                      {}});
  }
  series.push_back({"regularizer", cv::Scalar(30, 30, 210), 3, {}});
  std::vector<double> sigmas;
  for (const CaseResult& r : results) {
    sigmas.push_back(r.sigma);
    series[0].psnr_db.push_back(r.rows[0].mean.valid.psnr_db);
    for (int f = 0; f < numFamilies(); ++f) {
      series[1 + f].psnr_db.push_back(
          r.rows[r.first_filter_row + f].mean.valid.psnr_db);
    }
    series.back().psnr_db.push_back(
        r.rows[r.regularizer_row].mean.valid.psnr_db);
  }
  writeLinePlot(path,
                "PSNR of the normals vs noise level (" +
                    std::to_string(options.scenes.size()) + " scene(s), " +
                    std::to_string(options.width) + "x" +
                    std::to_string(options.height) + "; filters at their best)",
                "noise sigma", sigmas, 1, series);
}

/// A line plot of PSNR (dB) against x, one curve per series, markers at the
/// xs (ticks labelled with x_digits decimals), the legend right of the axes.
void writeLinePlot(const std::string& path, const std::string& title,
                   const std::string& x_label, const std::vector<double>& xs,
                   int x_digits, const std::vector<Series>& series) {
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
  // x padded by half the smallest spacing of the xs.
  double pad = 0.5;
  for (std::size_t i = 1; i < xs.size(); ++i) {
    pad = std::min(pad, 0.5 * std::abs(xs[i] - xs[i - 1]));
  }
  const double x_min = *std::min_element(xs.begin(), xs.end()) - pad;
  const double x_max = *std::max_element(xs.begin(), xs.end()) + pad;

  // The legend sits right of the axes, clear of the curves, as wide as its
  // longest label.
  int legend_w = 250;
  for (const Series& s : series) {
    int baseline = 0;
    const cv::Size text =
        cv::getTextSize(s.label, cv::FONT_HERSHEY_SIMPLEX, 0.5, 1, &baseline);
    legend_w = std::max(legend_w, text.width + 70);
  }
  const int row_h = 24;
  const int width = 900 + legend_w, height = 600;
  const int left = 80, right = 30 + legend_w, top = 50, bottom = 70;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const cv::Scalar black(0, 0, 0), grid(225, 225, 225);
  const auto px = [&](double x) {
    return left + static_cast<int>(std::lround((x - x_min) / (x_max - x_min) *
                                               (width - left - right)));
  };
  const auto py = [&](double psnr_db) {
    return height - bottom -
           static_cast<int>(std::lround((psnr_db - y_min) / (y_max - y_min) *
                                        (height - top - bottom)));
  };
  // Grid and ticks: x at every xs, y every `step` dB.
  for (double value : xs) {
    const int x = px(value);
    cv::line(canvas, {x, top}, {x, height - bottom}, grid, 1);
    cv::line(canvas, {x, height - bottom}, {x, height - bottom + 6}, black, 1);
    drawText(&canvas, fixed(value, x_digits), {x - 12, height - bottom + 24},
             0.5, black);
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
  drawText(&canvas, x_label, {(width + left) / 2 - 50, height - 20}, 0.6,
           black);
  // The y label, drawn horizontally then turned by 90 degrees.
  cv::Mat label(30, 120, CV_8UC3, cv::Scalar(255, 255, 255));
  drawText(&label, "PSNR (dB)", {5, 22}, 0.6, black);
  cv::rotate(label, label, cv::ROTATE_90_COUNTERCLOCKWISE);
  label.copyTo(
      canvas(cv::Rect(8, (height - label.rows) / 2, label.cols, label.rows)));
  drawText(&canvas, title, {left, 32}, 0.6, black, 1);
  // Curves with markers.
  for (const Series& s : series) {
    for (std::size_t i = 0; i < xs.size(); ++i) {
      if (!std::isfinite(s.psnr_db[i])) continue;
      const cv::Point p(px(xs[i]), py(s.psnr_db[i]));
      cv::circle(canvas, p, 4, s.colour, cv::FILLED, cv::LINE_AA);
      if (i + 1 < xs.size() && std::isfinite(s.psnr_db[i + 1])) {
        cv::line(canvas, p, {px(xs[i + 1]), py(s.psnr_db[i + 1])}, s.colour,
                 s.thickness, cv::LINE_AA);
      }
    }
  }
  // Legend, right of the axes.
  const cv::Point corner(width - legend_w - 20, top + 10);
  const cv::Rect legend_box(corner.x, corner.y, legend_w,
                            row_h * static_cast<int>(series.size()) + 10);
  cv::rectangle(canvas, legend_box, cv::Scalar(255, 255, 255), cv::FILLED);
  cv::rectangle(canvas, legend_box, black, 1);
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

/// PSNR per frame of a stream, the four ways of kStreamMethods.
void writeStreamPlot(const std::string& path, const StreamResult& r,
                     const Options& options) {
  const std::array<cv::Scalar, 4> colours = {
      cv::Scalar(140, 140, 140), cv::Scalar(40, 170, 230),
      cv::Scalar(200, 120, 30), cv::Scalar(30, 30, 210)};
  std::vector<Series> series;
  for (std::size_t m = 0; m < kStreamMethods.size(); ++m) {
    Series s{kStreamMethods[m], colours[m], m == 3 ? 3 : 2, {}};
    for (const Score& score : r.scores[m]) s.psnr_db.push_back(score.psnr_db);
    series.push_back(std::move(s));
  }
  std::vector<double> frames;
  for (std::size_t k = 0; k < r.scores[0].size(); ++k) {
    frames.push_back(static_cast<double>(k));
  }
  writeLinePlot(path,
                "PSNR per frame, " + r.title + " (temporal_frames " +
                    std::to_string(options.temporal.frames) + ", gate " +
                    fixed(options.temporal.gate_degrees, 0) + " deg)",
                "frame", frames, 0, series);
}

/// File-name form of a method name: lower case, '_' for anything else.
std::string slug(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (std::isalnum(static_cast<unsigned char>(c))) {
      out.push_back(
          static_cast<char>(std::tolower(static_cast<unsigned char>(c))));
    } else if (!out.empty() && out.back() != '_') {
      out.push_back('_');
    }
  }
  while (!out.empty() && out.back() == '_') out.pop_back();
  return out;
}

/// A picture with a caption bar above it.
cv::Mat captioned(const cv::Mat& picture, const std::string& line1,
                  const std::string& line2) {
  const int bar = 44;
  cv::Mat out(picture.rows + bar, picture.cols, CV_8UC3,
              cv::Scalar(255, 255, 255));
  picture.copyTo(out(cv::Rect(0, bar, picture.cols, picture.rows)));
  // Each line as large as fits the width, 0.5 at most.
  const auto fitted = [&](const std::string& text) {
    int baseline = 0;
    const cv::Size size =
        cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, 1.0, 1, &baseline);
    return std::min(0.5, (picture.cols - 8.0) / std::max(size.width, 1));
  };
  drawText(&out, line1, {4, 18}, fitted(line1), cv::Scalar(0, 0, 0));
  drawText(&out, line2, {4, 38}, fitted(line2), cv::Scalar(60, 60, 60));
  return out;
}

cv::Mat readBack(const std::string& path) {
  cv::Mat picture = cv::imread(path, cv::IMREAD_COLOR);
  if (picture.empty()) throw nf::InputError("cannot read back '" + path + "'");
  return picture;
}

/// The example scene's pictures: normal maps and angular-error maps of every
/// method (same colour scale), and one panel of all error maps.
std::vector<std::string> writeExamples(const std::string& dir,
                                       const Example& example,
                                       const CaseResult& result,
                                       const Options& options) {
  std::vector<std::string> files;
  if (!example.taken) return files;
  const std::string& tag = example.tag;
  const std::string stem =
      (std::filesystem::path(dir) / ("example_" + tag + "_")).string();
  const auto add = [&](const std::string& name) {
    files.push_back(stem + name);
    return stem + name;
  };
  nf::io::writeImage(add("image.png"), example.image);
  nf::io::writeNormalPicture(add("gt.png"), example.gt);
  // The methods: input, each filter at its best setting for this sigma, the
  // regularizer.
  std::vector<std::pair<std::string, nf::NormalMap>> methods;
  std::vector<std::string> settings;
  methods.push_back({example.input_name, example.input});
  settings.push_back(example.input_setting);
  for (int f = 0; f < numFamilies(); ++f) {
    const Candidate& best = result.best[f];
    methods.push_back({familyName(f) + " best",
                       applyCandidate(best, example.input, example.image,
                                      options.settings.num_threads)});
    settings.push_back(candidateLabel(best, result.variant_names));
  }
  methods.push_back({"regularizer", example.regularizer});
  settings.push_back("default settings");
  std::vector<cv::Mat> panels;
  panels.push_back(captioned(readBack(files[0]), "image", "guide"));
  panels.push_back(
      captioned(readBack(files[1]), "ground truth", "normals (colour-coded)"));
  for (std::size_t m = 0; m < methods.size(); ++m) {
    const std::string name = slug(methods[m].first);
    nf::io::writeNormalPicture(add(name + ".png"), methods[m].second);
    const std::string error_path = add("error_" + name + ".png");
    nf::io::writeHeatmap(error_path,
                         nf::angularErrorMap(methods[m].second, example.gt),
                         0.0, kHeatmapMaxDeg);
    const nf::AngularErrorStats stats =
        nf::angularError(methods[m].second, example.gt);
    panels.push_back(captioned(
        readBack(error_path),
        methods[m].first + ": mean " + fixed(stats.mean_deg, 1) + " deg",
        settings[m]));
  }
  // Grid of 3 columns and a colour bar of the error scale.
  const int columns = 3;
  const int cell_w = panels[0].cols, cell_h = panels[0].rows, gap = 6;
  const int rows = (static_cast<int>(panels.size()) + columns - 1) / columns;
  const int bar_h = 64;
  cv::Mat canvas(rows * (cell_h + gap) + bar_h + gap,
                 columns * (cell_w + gap) + gap, CV_8UC3,
                 cv::Scalar(255, 255, 255));
  for (std::size_t p = 0; p < panels.size(); ++p) {
    const int r = static_cast<int>(p) / columns,
              c = static_cast<int>(p) % columns;
    cv::Mat cell;
    cv::resize(panels[p], cell, cv::Size(cell_w, cell_h));
    cell.copyTo(canvas(cv::Rect(gap + c * (cell_w + gap),
                                gap + r * (cell_h + gap), cell_w, cell_h)));
  }
  // Colour bar: 0 .. kHeatmapMaxDeg degrees.
  const int bar_x = gap + 10, bar_y = rows * (cell_h + gap) + gap;
  const int bar_w = canvas.cols - 2 * bar_x;
  cv::Mat ramp(1, bar_w, CV_8UC1);
  for (int x = 0; x < bar_w; ++x) {
    ramp.at<unsigned char>(0, x) =
        static_cast<unsigned char>(std::lround(255.0 * x / (bar_w - 1)));
  }
  cv::Mat ramp_colour;
  cv::applyColorMap(ramp, ramp_colour, cv::COLORMAP_INFERNO);
  cv::resize(ramp_colour, ramp_colour, cv::Size(bar_w, 16), 0, 0,
             cv::INTER_NEAREST);
  ramp_colour.copyTo(canvas(cv::Rect(bar_x, bar_y, bar_w, 16)));
  for (int deg = 0; deg <= static_cast<int>(kHeatmapMaxDeg); deg += 15) {
    const int x = bar_x + static_cast<int>(
                              std::lround(deg / kHeatmapMaxDeg * (bar_w - 1)));
    drawText(&canvas, std::to_string(deg), {std::max(0, x - 8), bar_y + 34},
             0.45, cv::Scalar(0, 0, 0));
  }
  drawText(&canvas, "angular error, degrees (black: no normal)",
           {bar_x + bar_w / 2 - 150, bar_y + 56}, 0.45, cv::Scalar(0, 0, 0));
  const std::string panel_path =
      (std::filesystem::path(dir) / ("errors_" + tag + ".png")).string();
  if (!cv::imwrite(panel_path, canvas)) {
    throw nf::InputError("cannot write '" + panel_path + "'");
  }
  files.insert(files.begin(), panel_path);
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
      << nf::toString(s.penalty) << ", data Huber threshold " << s.data_eps
      << " + " << s.data_eps_local << " x local spread, density power "
      << s.density_power << ", local radius " << s.local_radius
      << ", hole link weight " << s.hole_link_weight << ", visibility "
      << nf::toString(s.visibility) << ", edges "
      << (s.edges.enabled ? "on" : "off") << " (alpha " << s.edges.alpha
      << ", beta " << s.edges.beta << ", w_min " << s.edges.w_min << ", sigma "
      << s.edges.smoothing_sigma << ", " << nf::toString(s.edges.color_mode)
      << ", " << nf::toString(s.edges.gradient) << ", "
      << nf::toString(s.edges.function) << "), " << s.inner_iterations
      << " inner x <= " << s.max_outer_iterations
      << " outer, <= " << s.max_total_inner_iterations
      << " inner in all, tolerance " << s.relative_tolerance
      << ", pyramid levels " << s.pyramid_levels << ", preconditioning "
      << (s.preconditioning ? "on" : "off");
  if (s.tau > 0.0 || s.sigma > 0.0) {
    out << ", tau " << s.tau << ", sigma " << s.sigma;
  }
  if (s.time_budget_ms > 0.0) out << ", budget " << s.time_budget_ms << " ms";
  out << ", backend " << nf::toString(s.backend);
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
  if (options.settings.num_threads > 0) {
    cv::setNumThreads(options.settings.num_threads);
  }

  // Ground truth of every scene.
  std::vector<nf::synthetic::Frame> frames;
  if (options.run_paper || options.run_depth || options.run_fusion) {
    for (int scene : options.scenes) {
      frames.push_back(
          nf::synthetic::renderScene(scene, options.width, options.height));
    }
  }
  Timers timers;
  timers.filters.resize(numFamilies());
  Example example;
  std::vector<CaseResult> paper, fusion;
  CaseResult depth;
  CastleOutcome castle;
  if (options.run_paper) {
    paper = runPaperCase(options, frames, &example, &timers);
  }
  if (options.run_depth) depth = runDepthCase(options, frames, &timers);
  if (options.run_fusion) fusion = runFusionCase(options, frames, &timers);
  if (options.run_castle) {
    castle = runCastleCase(options, &timers);
    if (!castle.ran)
      std::cerr << "evaluate: castle case " << castle.note << "\n";
  }
  std::vector<StreamResult> streams;
  if (options.run_stream) {
    streams.push_back(
        runStream("synthetic scene " + std::to_string(options.scenes.front()),
                  "synthetic", syntheticStream(options), options));
    const std::vector<StreamFrame> castle_frames = castleStream(options);
    if (castle_frames.size() < 2) {
      std::cerr << "evaluate: castle stream skipped (fewer than two frames of "
                   "the sequence at '"
                << options.castle_dir << "')\n";
    } else {
      streams.push_back(
          runStream("ViSP Castle", "castle", castle_frames, options));
    }
  }
  std::vector<CaseResult> all = paper;
  if (options.run_depth) all.push_back(depth);
  all.insert(all.end(), fusion.begin(), fusion.end());
  if (castle.ran) all.push_back(castle.result);

  // The paper's claim: ahead of the best bilateral filter at every sigma.
  std::vector<std::string> failures;
  for (const CaseResult& r : paper) {
    const double best = bilateralRow(r).mean.valid.psnr_db;
    const double reg = r.rows[r.regularizer_row].mean.valid.psnr_db;
    if (!(reg > best)) {
      failures.push_back("sigma " + fixed(r.sigma, 2) + ": regularizer " +
                         fixed(reg, 2) + " dB, best bilateral (" +
                         bilateralRow(r).setting + ") " + fixed(best, 2) +
                         " dB");
    }
  }

  // Output files.
  const std::filesystem::path dir(options.output_dir);
  const std::string plot_path = (dir / "psnr_vs_sigma.png").string();
  const std::string csv_path = (dir / "results.csv").string();
  const std::string grid_path = (dir / "filter_grid.csv").string();
  const std::string md_path = (dir / "results.md").string();
  if (!paper.empty()) writePlot(plot_path, paper, options);
  writeCsv(csv_path, all);
  writeGridCsv(grid_path, all);
  std::vector<std::string> example_files;
  for (const CaseResult& r : paper) {
    if (example.taken && r.sigma == example.sigma) {
      example_files = writeExamples(options.output_dir, example, r, options);
    }
  }
  if (castle.ran) {
    for (const std::string& f : writeExamples(
             options.output_dir, castle.example, castle.result, options)) {
      example_files.push_back(f);
    }
  }
  std::vector<std::string> stream_plots;
  for (const StreamResult& r : streams) {
    stream_plots.push_back((dir / ("stream_" + r.tag + ".png")).string());
    writeStreamPlot(stream_plots.back(), r, options);
  }
  const double total_seconds =
      std::chrono::duration<double>(Clock::now() - start).count();

  const bool defaults =
      settingsText(options.settings) == settingsText(nf::SolverSettings());
  std::ostringstream md;
  md << "# normal_fusion evaluation\n\n"
     << "- synthetic scenes: ";
  for (std::size_t s = 0; s < options.scenes.size(); ++s) {
    md << (s ? "," : "") << options.scenes[s];
  }
  md << " at " << options.width << "x" << options.height << ", noise seed "
     << options.seed << "\n"
     << "- regularizer: " << settingsText(options.settings) << " ("
     << (defaults ? "the default set, as in config/normal_fusion.yaml; "
                  : "set on the command line; ")
     << "one parameter set for every case)\n"
     << "- bilateral (paper): cross-bilateral filter guided by the image "
        "luminance, sigma_I = "
     << kSigmaIntensity
     << ", w = 3, 5, 7, sigma_S = 5w/3 or 3w/5 (6 settings)\n"
     << "- peers (OpenCV ximgproc, on the three channels, renormalized, "
        "holes by normalized convolution):";
  for (peers::PeerFilter filter : peers::allPeers()) {
    md << " " << peers::name(filter) << " ("
       << peers::settingsGrid(filter).size() << " settings);";
  }
  md << " each filter is shown at its best setting for each case (best mean "
        "PSNR over the scenes on the pixels with input, among the settings "
        "that produce a normal at "
     << percent(kMinProducedShare)
     << " of them or more; where the best lies on the edge of the grid, up "
        "to "
     << kMaxGridExtensions
     << " geometric steps past it are tried and marked 'beyond the grid'; "
        "every setting's score is in filter_grid.csv)\n"
     << "- machine: " << cpuModel() << ", "
     << std::thread::hardware_concurrency() << " hardware thread(s), "
     << (options.settings.num_threads > 0
             ? std::to_string(options.settings.num_threads)
             : std::string("all"))
     << " used\n"
     << "- time: " << fixed(total_seconds, 1) << " s in all; regularizer "
     << fixed(timers.solver.mean(), 3) << " s per solve ("
     << timers.solver.calls << " solves)";
  for (int f = 0; f < numFamilies(); ++f) {
    md << "; " << familyName(f) << " " << fixed(timers.filters[f].mean(), 3)
       << " s per call (" << timers.filters[f].calls << ")";
  }
  md << "\n\n";
  if (!paper.empty()) {
    md << "## 1. Paper noise (Fig. 6): PSNR (dB) against the noise level, "
          "mean over the scenes\n\n"
       << "Bilateral (paper): w = 3, 5, 7 each at the better of sigma_S = "
          "5w/3, 3w/5 (in brackets); * marks the best of all six. Peers: "
          "each at its best setting for that sigma.\n\n"
       << psnrTable(paper) << "\n"
       << "Mean angular error (deg), same settings:\n\n"
       << angleTable(paper) << "\n";
    if (failures.empty()) {
      md << "The regularizer is ahead of the best bilateral filter at every "
            "sigma.\n";
    } else {
      md << "The regularizer is NOT ahead of the best bilateral filter at:\n\n";
      for (const std::string& f : failures) md << "- " << f << "\n";
    }
    md << "\nPer noise level, every metric:\n";
    for (const CaseResult& r : paper) md << "\n" << caseTables(r, "### ");
  }
  if (options.run_depth) md << "\n" << caseTables(depth, "## 2. ");
  for (std::size_t k = 0; k < fusion.size(); ++k) {
    md << "\n"
       << caseTables(fusion[k], "## 3" + std::string(1, 'a' + k) + ". ")
       << "\nThe filters take one map: the dense input, the sparse input, "
          "or both merged (the sparse normal where there is one); which one "
          "is part of their setting.\n";
  }
  if (options.run_castle) {
    if (castle.ran) {
      md << "\n" << caseTables(castle.result, "## 4. ") << "\nFrames ";
      for (std::size_t k = 0; k < castle.frames.size(); ++k) {
        md << (k ? ", " : "") << castle.frames[k];
      }
      md << " of " << options.castle_dir
         << ", in the depth camera's pixels, cropped to the object (mean "
         << castle.width << "x" << castle.height
         << "). Ground truth: the model's faces (chateau.wrl and cube.cao) "
            "ray cast with the recorded pose, kept where the model's depth "
            "is within "
         << fixed(options.castle_tolerance_m * 1000.0, 1)
         << " mm of the sequence's depth map (" << percent(castle.agreement)
         << " of the pixels with depth; the rest are silhouettes and parts "
            "the model lacks). Guide: the colour camera's image resampled "
            "at each depth pixel (5 cm baseline, no occlusion test).\n";
    } else {
      md << "\n## 4. ViSP Castle\n\nThe castle case was " << castle.note
         << ".\n";
    }
  }
  if (options.run_stream) {
    md << "\n## 5. Streams: each frame alone, the warm-started stream, and "
          "the inputs averaged over time\n\n"
       << "Consecutive frames of a moving camera with new noise in every "
          "frame, solved with the regularizer's settings above: each frame "
          "alone (a cold start), or as a stream (warm-started from the "
          "previous frame's result warped by the camera's rotation, as the "
          "node does with tf; no time budget), each on the frame's own inputs "
          "or on its inputs averaged over time (TemporalAverage: "
       << options.temporal.frames << " frames, gate "
       << fixed(options.temporal.gate_degrees, 0)
       << " degrees, carried by the same rotation; the node's "
          "temporal_frames). Scores on every pixel with ground truth; frame "
          "0 is the same for all four.\n";
    for (std::size_t k = 0; k < streams.size(); ++k) {
      const StreamResult& r = streams[k];
      md << "\n### 5" << static_cast<char>('a' + k) << ". " << r.title << " ("
         << r.scores[0].size() << " frames, " << fixed(r.seconds_per_solve, 3)
         << " s per solve)\n\n"
         << streamTable(r);
    }
    md << "\nSynthetic: scene " << options.scenes.front() << " at "
       << options.width << "x" << options.height
       << ", the camera turning 0.3 degrees per frame (and moving), inputs: "
          "paper noise sigma "
       << fixed(options.stream_sigma, 2)
       << " and normals of a noisy depth map (" << depthNoiseText(options)
       << "). Castle: its first frames in a row, uncropped, normals of each "
          "depth map with new depth-camera noise, ground truth as in case 4.\n";
  }
  if (!all.empty()) {
    md << "\n## Summary: the regularizer against every ximgproc peer\n\n"
       << "Each peer at its best setting for the case; the regularizer with "
          "one parameter set. PSNR and mean angle on the pixels with input; "
          "the last column is the fill-in PSNR margin over the best peer "
          "there.\n\n"
       << "| case | regularizer row | ahead in PSNR | ahead in mean angle | "
          "PSNR margin over the best peer (dB) | best peer (setting) | "
          "fill-in margin (dB) |\n"
          "|---|---|---|---|---:|---|---:|\n";
    for (const CaseResult& r : all) md << summaryLine(r) << "\n";
  }
  // Files by name: results.md sits beside them.
  auto file_name = [](const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    return slash == std::string::npos ? path : path.substr(slash + 1);
  };
  md << "\n## Files\n\nIn the output folder, beside this file:\n\n";
  if (!paper.empty()) md << "- " << file_name(plot_path) << "\n";
  md << "- " << file_name(csv_path) << "\n- " << file_name(grid_path) << "\n";
  for (const std::string& f : stream_plots) md << "- " << file_name(f) << "\n";
  for (const std::string& f : example_files) {
    md << "- " << file_name(f) << "\n";
  }

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
