// evaluate's command line: the options of the experiment and the solver's.
#include <algorithm>
#include <cstdint>
#include <functional>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include "evaluate/evaluate.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/solver_options.h"

namespace evaluate {
namespace {

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

/// The value of the option being read (taken from the command line when
/// called: an unknown option takes none).
using ValueFn = std::function<std::string()>;

/// Which size options the command line gave (--quick fills the others).
struct GivenOptions {
  bool width = false, height = false, castle_frames = false;
  bool stream_frames = false;
};

/// --cases LIST.
void parseCases(const std::string& option, const std::string& list,
                Options* options) {
  options->run_paper = options->run_depth = options->run_fusion =
      options->run_castle = options->run_stream = options->run_estimators =
          false;
  options->run_textured = options->run_curved = options->run_depthcam =
      options->run_stereo = options->run_aloe = false;
  for (const std::string& item : splitCommas(option, list)) {
    if (item == "paper") {
      options->run_paper = true;
    } else if (item == "depth") {
      options->run_depth = true;
    } else if (item == "fusion") {
      options->run_fusion = true;
    } else if (item == "castle") {
      options->run_castle = true;
    } else if (item == "stream") {
      options->run_stream = true;
    } else if (item == "estimators") {
      options->run_estimators = true;
    } else if (item == "textured") {
      options->run_textured = true;
    } else if (item == "curved") {
      options->run_curved = true;
    } else if (item == "depthcam") {
      options->run_depthcam = true;
    } else if (item == "stereo") {
      options->run_stereo = true;
    } else if (item == "aloe") {
      options->run_aloe = true;
    } else {
      throw UsageError(option +
                       ": expected paper, depth, fusion, castle, stream, "
                       "estimators, textured, curved, depthcam, stereo or "
                       "aloe, got '" +
                       item + "'");
    }
  }
}

/// --scenes LIST: distinct ids, in the order given.
void parseScenes(const std::string& option, const std::string& list,
                 Options* options) {
  options->scenes.clear();
  for (const std::string& item : splitCommas(option, list)) {
    const int id = parseInt(option, item);
    if (id < 0 || id >= nf::synthetic::kNumScenes) {
      throw UsageError(option + ": expected scene ids in 0.." +
                       std::to_string(nf::synthetic::kNumScenes - 1) +
                       ", got " + item);
    }
    if (std::find(options->scenes.begin(), options->scenes.end(), id) ==
        options->scenes.end()) {
      options->scenes.push_back(id);
    }
  }
}

/// The options of the experiment's size and cases; false for another.
bool applyExperimentOption(const std::string& option, const ValueFn& value,
                           Options* options, GivenOptions* given) {
  if (option == "--output-dir") {
    options->output_dir = value();
  } else if (option == "--cases") {
    parseCases(option, value(), options);
  } else if (option == "--width") {
    options->width = parseInt(option, value());
    given->width = true;
  } else if (option == "--height") {
    options->height = parseInt(option, value());
    given->height = true;
  } else if (option == "--scenes") {
    parseScenes(option, value(), options);
  } else if (option == "--sigmas") {
    options->sigmas.clear();
    for (const std::string& item : splitCommas(option, value())) {
      const double sigma = parseDouble(option, item);
      requireInRange(option, sigma, 1e-6, 10.0);
      options->sigmas.push_back(sigma);
    }
  } else if (option == "--seed") {
    const int seed = parseInt(option, value());
    if (seed < 0) throw UsageError(option + ": expected a seed >= 0");
    options->seed = static_cast<std::uint64_t>(seed);
  } else {
    return false;
  }
  return true;
}

/// Reads a number option into `target`, checked against [lo, hi].
void setDouble(const std::string& option, const std::string& value, double lo,
               double hi, double* target) {
  *target = parseDouble(option, value);
  requireInRange(option, *target, lo, hi);
}

void setInt(const std::string& option, const std::string& value, int lo, int hi,
            int* target) {
  *target = parseInt(option, value);
  requireInRange(option, *target, lo, hi);
}

/// The options of the noise, the castle and the streams; false for another.
bool applyCaseOption(const std::string& option, const ValueFn& value,
                     Options* o, GivenOptions* given) {
  if (option == "--dense-sigma") {
    setDouble(option, value(), 0.0, 10.0, &o->dense_sigma);
  } else if (option == "--depth-sigma") {
    setDouble(option, value(), 0.0, 1.0, &o->depth_sigma_at_1m);
  } else if (option == "--depth-dropout") {
    setDouble(option, value(), 0.0, 1.0, &o->depth_dropout);
  } else if (option == "--depth-step") {
    setDouble(option, value(), 0.0, 1.0, &o->depth_step_m);
  } else if (option == "--sparse-density") {
    setDouble(option, value(), 0.0, 1.0, &o->sparse_density);
  } else if (option == "--sparse-sigma") {
    setDouble(option, value(), 0.0, 10.0, &o->sparse_sigma);
  } else if (option == "--sparse-weight") {
    setDouble(option, value(), 0.0, 1e6, &o->sparse_weight);
  } else if (option == "--castle-dir") {
    o->castle_dir = value();
  } else if (option == "--castle-frames") {
    setInt(option, value(), 1, 1000, &o->castle_frames);
    given->castle_frames = true;
  } else if (option == "--castle-tolerance") {
    setDouble(option, value(), 0.0, 1.0, &o->castle_tolerance_m);
  } else if (option == "--stream-frames") {
    setInt(option, value(), 2, 1000, &o->stream_frames);
    given->stream_frames = true;
  } else if (option == "--stream-sigma") {
    setDouble(option, value(), 0.0, 10.0, &o->stream_sigma);
  } else if (option == "--temporal-frames") {
    setInt(option, value(), 0, 100000, &o->temporal.frames);
  } else if (option == "--temporal-gate-deg") {
    setDouble(option, value(), 0.1, 180.0, &o->temporal.gate_degrees);
  } else if (option == "--curved-sigma") {
    setDouble(option, value(), 0.0, 10.0, &o->curved_sigma);
  } else if (option == "--stereo-baseline") {
    setDouble(option, value(), 0.01, 0.5, &o->stereo_baseline_m);
  } else if (option == "--confidence-sigma-scale") {
    setDouble(option, value(), 1e-6, 100.0, &o->confidence_sigma_scale);
  } else if (option == "--aloe-dir") {
    o->aloe_dir = value();
  } else {
    return false;
  }
  return true;
}

/// --quick's sizes where none was given, the default sigmas, and the checks
/// of the whole command line.
void completeAndCheck(const GivenOptions& given, Options* options) {
  if (options->output_dir.empty()) throw UsageError("missing --output-dir");
  if (options->quick) {
    if (!given.width) options->width = 160;
    if (!given.height) options->height = 120;
    if (options->sigmas.empty()) options->sigmas = {0.1, 0.5, 0.9};
    if (!given.castle_frames) options->castle_frames = 2;
    if (!given.stream_frames) options->stream_frames = 5;
  }
  if (options->sigmas.empty()) {
    for (int k = 1; k <= 9; ++k) options->sigmas.push_back(0.1 * k);
  }
  if (options->width < 16 || options->height < 16 || options->width > 8192 ||
      options->height > 8192) {
    throw UsageError("image size: expected 16..8192 x 16..8192, got " +
                     std::to_string(options->width) + " x " +
                     std::to_string(options->height));
  }
  try {
    options->settings.validate();
  } catch (const nf::ParameterError& e) {
    throw UsageError(std::string("solver settings: ") + e.what());
  }
}

}  // namespace

void printUsage(std::ostream& out) {
  const Options o;
  out << "Usage: evaluate --output-dir DIR [--cases "
         "paper,depth,fusion,castle,...]\n"
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
         "  --cases LIST          any of paper, depth, fusion, castle, "
         "stream,\n"
         "                        estimators, textured, curved, depthcam,\n"
         "                        stereo, aloe [all]\n"
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
         "  --no-estimators       same as leaving estimators (the depth-to-\n"
         "                        normals estimators) out of --cases\n"
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
      << "  --curved-sigma X      paper noise of the curved case ["
      << o.curved_sigma << "]\n"
      << "  --stereo-baseline X   the rendered stereo pair's baseline, metres ["
      << o.stereo_baseline_m << "]\n"
      << "  --confidence-sigma-scale X  s0 of the depth normals' confidence "
         "in the\n                        robot cases (normal_sigma_scale) ["
      << o.confidence_sigma_scale << "]\n"
      << "  --aloe-dir DIR        Middlebury Aloe (aloeL.jpg, aloeR.jpg, "
         "aloeGT.png)\n"
      << "                        [" << o.aloe_dir << "]\n"
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

Options parseArguments(int argc, char** argv) {
  Options options;
  nf::SolverSettings& s = options.settings;
  GivenOptions given;
  nf::cli::ArgumentCursor arguments(argc, argv);
  while (arguments.next()) {
    const std::string& option = arguments.option();
    // Flags without a value.
    if (option == "--help" || option == "--no-edges" || option == "--quick" ||
        option == "--no-fusion" || option == "--no-estimators") {
      arguments.expectNoValue();
      if (option == "--help") options.help = true;
      if (option == "--no-edges") s.edges.enabled = false;
      if (option == "--quick") options.quick = true;
      if (option == "--no-fusion") options.run_fusion = false;
      if (option == "--no-estimators") options.run_estimators = false;
      continue;
    }
    const ValueFn value = [&]() -> std::string { return arguments.value(); };
    if (nf::cli::isSolverOption(option)) {
      try {
        nf::cli::applySolverOption(option, value(), s);
      } catch (const nf::ParameterError& e) {
        throw UsageError(e.what());
      }
      continue;
    }
    if (!applyExperimentOption(option, value, &options, &given) &&
        !applyCaseOption(option, value, &options, &given)) {
      throw UsageError("unknown option '" + option + "' (see --help)");
    }
  }
  if (options.help) return options;
  completeAndCheck(given, &options);
  return options;
}

}  // namespace evaluate
