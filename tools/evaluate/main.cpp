// evaluate: accuracy of the regularizer against the paper's cross-bilateral
// baseline and against the edge-aware filters people use today (OpenCV
// ximgproc: joint bilateral, guided, fast global smoother, domain transform),
// each filter at its best setting of a small grid for each case.
//
//   evaluate --output-dir DIR
//            [--cases paper,depth,fusion,castle,stream,estimators,
//                     textured,curved,depthcam,stereo,aloe]
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
// averaged over time; a synthetic sequence and Castle's frames), and
// "estimators" (depth-to-normals: the library's methods and OpenCV's
// RgbdNormals on the depth case's and the castle case's noisy depth, alone,
// regularized and smoothed by the fast global smoother). What robots feed
// the fusion: "textured" (strong textures on planes, weak creases; normals
// of structured-light depth), "curved" (cylinders, spheres, tori; paper
// noise and depth normals), "depthcam" (structured-light and time-of-flight
// depth with flying pixels and dropouts, normals by central_difference and
// plane_fit), "stereo" (a rendered textured pair through OpenCV's SGBM) and
// "aloe" (Middlebury's Aloe pair through SGBM against its ground truth).
//
// Writes DIR/results.md (the tables, also printed to stdout),
// DIR/results.csv (per scene), DIR/filter_grid.csv (every filter setting),
// DIR/psnr_vs_sigma.png (the plot), the error pictures of every method on
// one scene at sigma 0.5 and their panel. Exit codes: 0 the regularizer is
// ahead of the best bilateral filter at every sigma of the paper case, 1 it
// is not (the sigmas are printed), 2 usage error, 3 failure (unwritable
// output, library error). The comparison with the ximgproc filters is
// reported, not part of the exit code.
//
// The parts: options.cpp (the command line), scores.cpp (scores and the
// filters compared), case_runner.cpp (one case over its scenes and the grid
// search), cases_synthetic.cpp, case_castle.cpp, case_stream.cpp and
// case_depth_estimators.cpp, cases_robot.cpp and case_stereo.cpp (the
// cases), report.cpp, markdown.cpp and markdown_robot.cpp (tables, CSV,
// results.md), pictures.cpp (plot and example pictures).
#include <chrono>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "evaluate/evaluate.h"
#include "normal_fusion/errors.h"

namespace evaluate {
namespace {

/// The stream case: the synthetic sequence, and Castle's when installed.
std::vector<StreamResult> runStreams(const Options& options) {
  std::vector<StreamResult> streams;
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
  return streams;
}

/// The cases of what robots feed the fusion.
void runRobotCases(const Options& options,
                   const std::vector<nf::synthetic::Frame>& frames,
                   Results* r) {
  if (options.run_textured) {
    r->textured = runTexturedCase(options, &r->textured_example, &r->timers);
  }
  if (options.run_curved) r->curved = runCurvedCase(options, &r->timers);
  if (options.run_depthcam) {
    r->depthcam = runDepthCameraCase(options, frames, &r->timers);
  }
  if (options.run_stereo) r->stereo = runStereoCase(options, &r->timers);
  if (options.run_aloe) {
    r->aloe = runAloeCase(options, &r->timers);
    if (!r->aloe.ran)
      std::cerr << "evaluate: aloe case " << r->aloe.note << "\n";
  }
}

/// Runs the cases the options ask for.
Results runCases(const Options& options) {
  // Ground truth of every scene.
  std::vector<nf::synthetic::Frame> frames;
  if (options.run_paper || options.run_depth || options.run_fusion ||
      options.run_estimators || options.run_depthcam) {
    for (int scene : options.scenes) {
      frames.push_back(
          nf::synthetic::renderScene(scene, options.width, options.height));
    }
  }
  Results r;
  r.timers.filters.resize(numFamilies());
  if (options.run_paper) {
    r.paper = runPaperCase(options, frames, &r.example, &r.timers);
  }
  if (options.run_depth) r.depth = runDepthCase(options, frames, &r.timers);
  if (options.run_fusion) r.fusion = runFusionCase(options, frames, &r.timers);
  if (options.run_castle) {
    r.castle = runCastleCase(options, &r.timers);
    if (!r.castle.ran)
      std::cerr << "evaluate: castle case " << r.castle.note << "\n";
  }
  if (options.run_stream) r.streams = runStreams(options);
  if (options.run_estimators) {
    r.estimators = runEstimatorsCase(options, frames);
  }
  runRobotCases(options, frames, &r);
  r.all = r.paper;
  if (options.run_depth) r.all.push_back(r.depth);
  r.all.insert(r.all.end(), r.fusion.begin(), r.fusion.end());
  if (r.castle.ran) r.all.push_back(r.castle.result);
  for (const auto* cases : {&r.textured, &r.curved, &r.depthcam}) {
    r.all.insert(r.all.end(), cases->begin(), cases->end());
  }
  if (r.stereo.ran) r.all.push_back(r.stereo.result);
  if (r.aloe.ran) r.all.push_back(r.aloe.result);

  // The paper's claim: ahead of the best bilateral filter at every sigma.
  for (const CaseResult& c : r.paper) {
    const double best = bilateralRow(c).mean.valid.psnr_db;
    const double reg = c.rows[c.regularizer_row].mean.valid.psnr_db;
    if (!(reg > best)) {
      r.failures.push_back("sigma " + fixed(c.sigma, 2) + ": regularizer " +
                           fixed(reg, 2) + " dB, best bilateral (" +
                           bilateralRow(c).setting + ") " + fixed(best, 2) +
                           " dB");
    }
  }
  return r;
}

/// The plot, the CSV files, the example pictures and the stream plots.
OutputFiles writeFiles(const Options& options, const Results& r) {
  const std::filesystem::path dir(options.output_dir);
  OutputFiles files;
  files.plot = (dir / "psnr_vs_sigma.png").string();
  files.csv = (dir / "results.csv").string();
  files.grid = (dir / "filter_grid.csv").string();
  files.markdown = (dir / "results.md").string();
  if (!r.paper.empty()) writePlot(files.plot, r.paper, options);
  writeCsv(files.csv, r.all);
  writeGridCsv(files.grid, r.all);
  for (const CaseResult& c : r.paper) {
    if (r.example.taken && c.sigma == r.example.sigma) {
      files.examples = writeExamples(options.output_dir, r.example, c, options);
    }
  }
  if (r.castle.ran) {
    for (const std::string& f : writeExamples(
             options.output_dir, r.castle.example, r.castle.result, options)) {
      files.examples.push_back(f);
    }
  }
  const std::vector<std::pair<const Example*, const CaseResult*>> robot = {
      {&r.textured_example, r.textured.empty() ? nullptr : &r.textured.front()},
      {&r.stereo.example, r.stereo.ran ? &r.stereo.result : nullptr},
      {&r.aloe.example, r.aloe.ran ? &r.aloe.result : nullptr}};
  for (const auto& example : robot) {
    if (example.second == nullptr) continue;
    for (const std::string& f : writeExamples(
             options.output_dir, *example.first, *example.second, options)) {
      files.examples.push_back(f);
    }
  }
  for (const StreamResult& s : r.streams) {
    files.stream_plots.push_back((dir / ("stream_" + s.tag + ".png")).string());
    writeStreamPlot(files.stream_plots.back(), s, options);
  }
  return files;
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
  const Results results = runCases(options);
  const OutputFiles files = writeFiles(options, results);
  const double total_seconds =
      std::chrono::duration<double>(Clock::now() - start).count();
  const std::string md = markdown(options, results, files, total_seconds);
  std::cout << md;
  std::ofstream md_file(files.markdown);
  md_file << md;
  if (!md_file) throw nf::InputError("cannot write '" + files.markdown + "'");
  std::cout << "\nevaluate: wrote " << files.markdown << "\n";
  if (!results.failures.empty()) {
    for (const std::string& f : results.failures) {
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
}  // namespace evaluate

int main(int argc, char** argv) {
  try {
    return evaluate::run(argc, argv);
  } catch (const evaluate::UsageError& e) {
    evaluate::printError(e.what());
    return evaluate::kExitUsageError;
  } catch (const std::exception& e) {
    evaluate::printError(e.what());
    return evaluate::kExitFailure;
  } catch (...) {
    evaluate::printError("unexpected failure");
    return evaluate::kExitFailure;
  }
}
