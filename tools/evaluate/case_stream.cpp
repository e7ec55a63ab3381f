// evaluate's stream case: consecutive frames of a moving camera solved each
// alone and as a warm-started stream, on their own inputs and on the inputs
// averaged over time.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <iostream>
#include <limits>
#include <memory>
#include <sstream>

#include "eval/plot.h"
#include "evaluate/evaluate.h"
#include "normal_fusion/stream_fuser.h"

namespace evaluate {

using nf::plot::Series;
using nf::plot::writeLinePlot;

/// The ways a stream is solved, in table order.
const std::array<const char*, 4> kStreamMethods{{
    "each frame alone",
    "each frame alone, inputs averaged over time",
    "stream (warm start)",
    "stream (warm start), inputs averaged over time",
}};

/// Solves a sequence four ways (kStreamMethods) and scores every frame on the
/// pixels with ground truth. The three ways after the first run through
/// StreamFuser, the policy the node runs: the warm start warped by the
/// camera's rotation (as the node does with tf), the averages carried by the
/// same rotation, the stream's reset rules; frames are stamped at 30 fps.
StreamResult runStream(const std::string& title, const std::string& tag,
                       const std::vector<StreamFrame>& frames,
                       const Options& options) {
  StreamResult result;
  result.title = title;
  result.tag = tag;
  result.scores.resize(kStreamMethods.size());
  nf::Solver solver(options.settings);
  std::vector<std::unique_ptr<nf::StreamFuser>> fusers;
  for (int m = 1; m < 4; ++m) {
    nf::StreamSettings stream;
    stream.solver = options.settings;
    stream.warm_start = m >= 2;
    if (m % 2 == 1) stream.temporal = options.temporal;
    fusers.push_back(std::make_unique<nf::StreamFuser>(stream, title));
  }
  Timer timer;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const StreamFrame& frame = frames[k];
    const nf::ScalarMap all(frame.gt.width(), frame.gt.height(), 1, 1.0f);
    const nf::NormalMap alone =
        timed(&timer, [&] { return solver.solve(frame.problem); });
    result.scores[0].push_back(scoreOn(alone, frame.gt, all));
    const nf::FrameRotation rotation =
        k == 0 ? nf::FrameRotation::still()
               : nf::FrameRotation::known(frame.R_cur_prev);
    const std::int64_t stamp_ns =
        static_cast<std::int64_t>(k) * 1000000000 / 30;
    for (int m = 1; m < 4; ++m) {
      nf::StreamFuser& fuser = *fusers[m - 1];
      nf::FusionProblem problem = frame.problem;  // averaged in place
      nf::StreamResult fused;
      timed(&timer, [&] {
        fuser.fuse(stamp_ns, problem, rotation,
                   std::chrono::steady_clock::now(), &fused);
        return fuser.endFrame(0.0);
      });
      result.scores[m].push_back(scoreOn(fuser.fusedNormals(), frame.gt, all));
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

}  // namespace evaluate
