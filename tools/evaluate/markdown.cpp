// evaluate's results.md: the set-up, the tables of every case, the summary
// and the list of files.
#include <fstream>
#include <sstream>
#include <thread>

#include "evaluate/evaluate.h"
#include "normal_fusion/solver_options.h"

namespace evaluate {
namespace {

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
  if (s.noise_radius > s.local_radius) {
    out << ", noise radius " << s.noise_radius << ", noise weight power "
        << s.noise_weight_power
        << (s.noise_plane_residual ? ", about a plane" : "");
  }
  if (s.dynamic_guidance > 0.0) {
    out << ", dynamic guidance " << s.dynamic_guidance << " at "
        << s.dynamic_guidance_deg << " deg";
  }
  if (s.tgv_alpha0 > 0.0) out << ", tgv alpha0 " << s.tgv_alpha0;
  out << ", backend " << nf::toString(s.backend);
  return out.str();
}

/// The set-up: scenes, settings, filters, machine and times.
std::string setupText(const Options& options, const Results& r,
                      double total_seconds) {
  std::ostringstream md;
  const bool defaults =
      settingsText(options.settings) == settingsText(nf::SolverSettings());
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
     << fixed(r.timers.solver.mean(), 3) << " s per solve ("
     << r.timers.solver.calls << " solves)";
  for (int f = 0; f < numFamilies(); ++f) {
    md << "; " << familyName(f) << " " << fixed(r.timers.filters[f].mean(), 3)
       << " s per call (" << r.timers.filters[f].calls << ")";
  }
  md << "\n\n";
  return md.str();
}

/// Section 1: the paper's noise.
std::string paperText(const Results& r) {
  std::ostringstream md;
  if (!r.paper.empty()) {
    md << "## 1. Paper noise (Fig. 6): PSNR (dB) against the noise level, "
          "mean over the scenes\n\n"
       << "Bilateral (paper): w = 3, 5, 7 each at the better of sigma_S = "
          "5w/3, 3w/5 (in brackets); * marks the best of all six. Peers: "
          "each at its best setting for that sigma.\n\n"
       << psnrTable(r.paper) << "\n"
       << "Mean angular error (deg), same settings:\n\n"
       << angleTable(r.paper) << "\n";
    if (r.failures.empty()) {
      md << "The regularizer is ahead of the best bilateral filter at every "
            "sigma.\n";
    } else {
      md << "The regularizer is NOT ahead of the best bilateral filter at:\n\n";
      for (const std::string& f : r.failures) md << "- " << f << "\n";
    }
    md << "\nPer noise level, every metric:\n";
    for (const CaseResult& c : r.paper) md << "\n" << caseTables(c, "### ");
  }
  return md.str();
}

/// Sections 2 to 4: the depth, fusion and castle cases.
std::string casesText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (options.run_depth) md << "\n" << caseTables(r.depth, "## 2. ");
  for (std::size_t k = 0; k < r.fusion.size(); ++k) {
    md << "\n"
       << caseTables(r.fusion[k], "## 3" + std::string(1, 'a' + k) + ". ")
       << "\nThe filters take one map: the dense input, the sparse input, "
          "or both merged (the sparse normal where there is one); which one "
          "is part of their setting.\n";
  }
  if (options.run_castle) {
    if (r.castle.ran) {
      md << "\n" << caseTables(r.castle.result, "## 4. ") << "\nFrames ";
      for (std::size_t k = 0; k < r.castle.frames.size(); ++k) {
        md << (k ? ", " : "") << r.castle.frames[k];
      }
      md << " of " << options.castle_dir
         << ", in the depth camera's pixels, cropped to the object (mean "
         << r.castle.width << "x" << r.castle.height
         << "). Ground truth: the model's faces (chateau.wrl and cube.cao) "
            "ray cast with the recorded pose, kept where the model's depth "
            "is within "
         << fixed(options.castle_tolerance_m * 1000.0, 1)
         << " mm of the sequence's depth map (" << percent(r.castle.agreement)
         << " of the pixels with depth; the rest are silhouettes and parts "
            "the model lacks). Guide: the colour camera's image resampled "
            "at each depth pixel (5 cm baseline, no occlusion test).\n";
    } else {
      md << "\n## 4. ViSP Castle\n\nThe castle case was " << r.castle.note
         << ".\n";
    }
  }
  return md.str();
}

/// Section 5: the streams.
std::string streamsText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (options.run_stream) {
    md << "\n## 5. Streams: each frame alone, the warm-started stream, and "
          "the inputs averaged over time\n\n"
       << "Consecutive frames of a moving camera with new noise in every "
          "frame, solved with the regularizer's settings above: each frame "
          "alone (a cold start), or as a stream through StreamFuser, the "
          "node's stream policy (warm-started from the previous frame's "
          "result warped by the camera's rotation, as the node does with tf; "
          "no time budget), each on the frame's own inputs "
          "or on its inputs averaged over time (TemporalAverage: "
       << options.temporal.frames << " frames, gate "
       << fixed(options.temporal.gate_degrees, 0)
       << " degrees, carried by the same rotation; the node's "
          "temporal_frames). Scores on every pixel with ground truth; frame "
          "0 is the same for all four.\n";
    for (std::size_t k = 0; k < r.streams.size(); ++k) {
      const StreamResult& s = r.streams[k];
      md << "\n### 5" << static_cast<char>('a' + k) << ". " << s.title << " ("
         << s.scores[0].size() << " frames, " << fixed(s.seconds_per_solve, 3)
         << " s per solve)\n\n"
         << streamTable(s);
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
  return md.str();
}

/// Section 6: the depth-to-normals estimators.
std::string estimatorsText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (!options.run_estimators) return md.str();
  md << "\n## 6. Depth-to-normals estimators: the library's and OpenCV's "
        "RgbdNormals\n\n"
     << "The same noisy depth maps as cases 2 and 4 ("
     << depthNoiseText(options)
     << ") to normals by each estimator at its defaults (central_difference "
        "and plane_fit of normal_fusion/depth.h; OpenCV rgbd's FALS, LINEMOD "
        "and SRI, window 5, turned to face the camera), scored on every "
        "pixel with ground truth: the estimator's own normals, the "
        "regularizer (the settings above, the image as guide) on them "
        "without and, for the library's methods, with their confidence, and "
        "the fast global smoother on them at its best setting of its grid "
        "(by mean PSNR among the settings that give "
     << percent(kMinProducedShare)
     << " of the pixels a normal or more). 'with a normal': the share of "
        "those pixels given one. Mean over the scenes; "
     << fixed(r.estimators.solver.mean(), 3) << " s per solve ("
     << r.estimators.solver.calls << " solves).\n";
  for (std::size_t k = 0; k < r.estimators.tables.size(); ++k) {
    const EstimatorTable& t = r.estimators.tables[k];
    md << "\n### 6" << static_cast<char>('a' + k) << ". " << t.title << "\n\n"
       << estimatorsTable(t);
  }
  if (!r.estimators.note.empty()) {
    md << "\nNot shown: " << r.estimators.note << ".\n";
  }
  return md.str();
}

/// The summary against the peers and the list of files.
std::string summaryText(const Results& r, const OutputFiles& files) {
  std::ostringstream md;
  if (!r.all.empty()) {
    md << "\n## Summary: the regularizer against every ximgproc peer\n\n"
       << "Each peer at its best setting for the case; the regularizer with "
          "one parameter set. PSNR and mean angle on the pixels with input; "
          "the last column is the fill-in PSNR margin over the best peer "
          "there.\n\n"
       << "| case | regularizer row | ahead in PSNR | ahead in mean angle | "
          "PSNR margin over the best peer (dB) | best peer (setting) | "
          "fill-in margin (dB) |\n"
          "|---|---|---|---|---:|---|---:|\n";
    for (const CaseResult& c : r.all) md << summaryLine(c) << "\n";
  }
  // Files by name: results.md sits beside them.
  auto file_name = [](const std::string& path) {
    const std::size_t slash = path.find_last_of('/');
    return slash == std::string::npos ? path : path.substr(slash + 1);
  };
  md << "\n## Files\n\nIn the output folder, beside this file:\n\n";
  if (!r.paper.empty()) md << "- " << file_name(files.plot) << "\n";
  md << "- " << file_name(files.csv) << "\n- " << file_name(files.grid) << "\n";
  for (const std::string& f : files.stream_plots)
    md << "- " << file_name(f) << "\n";
  for (const std::string& f : files.examples) {
    md << "- " << file_name(f) << "\n";
  }

  return md.str();
}

}  // namespace

std::string markdown(const Options& options, const Results& results,
                     const OutputFiles& files, double total_seconds) {
  return setupText(options, results, total_seconds) + paperText(results) +
         casesText(options, results) + streamsText(options, results) +
         estimatorsText(options, results) + robotCasesText(options, results) +
         summaryText(results, files);
}

}  // namespace evaluate
