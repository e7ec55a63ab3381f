// bench_streaming --translation forward|sideways: a translating camera (the
// synthetic scene from the default orientation, moving by a step per frame
// along its optical axis or to its right) fused by two StreamFusers under the
// same live settings, one warm-started by the rotation alone and one by the
// full motion through the previous frame's depth (the noisy depth that the
// depth input's normals come from). Per frame and as medians: the warm
// start's PSNR before refinement (its unknown pixels skipped, their share
// shown), the live PSNR and the warp's time.
#pragma once

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

#include "bench_util.h"
#include "eval/synthetic.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/stream_fuser.h"
#include "normal_fusion/warp.h"
#include "normal_fusion/warp_motion.h"

namespace normal_fusion {
namespace bench {

struct TranslationRun {
  int scene = 0, width = 640, height = 480, frames = 15;
  bool forward = true;     ///< false: sideways (to the camera's right)
  double step_m = 0.047;   ///< per frame: 1.4 m/s at 30 Hz
  SolverSettings live;     ///< the frames after the first
  SolverSettings startup;  ///< the first frame (converged)
  /// The frame's inputs; the depth input's normals come from `depth_m`.
  std::function<FusionProblem(const synthetic::Frame&, int index)> problem;
  std::function<ScalarMap(const synthetic::Frame&, int index)> depth_m;
};

/// The share of pixels without a prediction (NaN).
inline double unknownShare(const NormalMap& normals) {
  std::size_t unknown = 0;
  for (std::size_t i = 0; i < normals.pixelCount(); ++i) {
    unknown += !(normals.plane(0)[i] == normals.plane(0)[i]);
  }
  return static_cast<double>(unknown) / normals.pixelCount();
}

/// One stream of the comparison: its fuser and its per-frame figures.
struct TranslationStream {
  explicit TranslationStream(const StreamSettings& settings, bool by_motion)
      : fuser(settings, by_motion ? "motion" : "rotation"), motion(by_motion) {}
  StreamFuser fuser;
  bool motion;
  std::vector<double> start_db, live_db, warp_ms, unknown;
};

// Over 80 lines: the per-frame loop and its table row share the streams.
inline int runTranslation(const TranslationRun& run) {
  const Vec3 step =
      run.forward ? Vec3{{0.0, 0.0, run.step_m}} : Vec3{{run.step_m, 0.0, 0.0}};
  const std::vector<synthetic::Frame> sequence = synthetic::renderTranslation(
      run.scene, run.width, run.height, run.frames + 1, step);
  StreamSettings settings;
  settings.solver = run.startup;
  std::vector<TranslationStream> streams;
  streams.emplace_back(settings, false);
  streams.emplace_back(settings, true);
  std::printf(
      "# %s\n# translation: scene %d, %dx%d, %s %.1f mm per frame at 30 Hz, "
      "budget %.1f ms per frame, %d threads; warm start by the rotation "
      "alone (rotation) or by the full motion through the previous frame's "
      "noisy depth (motion)\n",
      bench::machineLine().c_str(), run.scene, run.width, run.height,
      run.forward ? "forward" : "sideways", 1e3 * run.step_m,
      run.live.time_budget_ms, run.live.num_threads);
  std::printf(
      "| frame | warm start PSNR rotation (dB) | motion (dB) | unknown "
      "rotation (%%) | motion (%%) | live PSNR rotation (dB) | motion (dB) | "
      "warp rotation (ms) | motion (ms) |\n"
      "|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
  ScalarMap depth_prev;
  for (int k = 0; k <= run.frames; ++k) {
    const synthetic::Frame& truth = sequence[k];
    const ScalarMap depth_m = run.depth_m(truth, k);
    const Pose T_cur_prev =
        k == 0 ? Pose()
               : synthetic::relativePose(truth.pose, sequence[k - 1].pose);
    for (TranslationStream& s : streams) {
      FusionProblem problem = run.problem(truth, k);
      if (k > 0) {
        // What the stream's warp predicts, measured outside it.
        SolverState predicted;
        predicted.normals = s.fuser.fusedNormals();
        if (s.motion) {
          warpStateByMotion(predicted, depth_prev, truth.K, T_cur_prev);
        } else {
          warpStateByRotation(predicted, truth.K, T_cur_prev.R);
        }
        s.start_db.push_back(psnr(predicted.normals, truth.normals_gt));
        s.unknown.push_back(100.0 * unknownShare(predicted.normals));
      }
      const FrameRotation rotation =
          k == 0 ? FrameRotation::still()
                 : (s.motion ? FrameRotation::knownMotion(T_cur_prev)
                             : FrameRotation::known(T_cur_prev.R));
      StreamResult result;
      s.fuser.fuse(std::llround(k * 1e9 / 30.0), problem, rotation,
                   std::chrono::steady_clock::now(), &result,
                   s.motion ? &depth_m : nullptr);
      s.fuser.endFrame(0.0);
      if (k == 0) {
        StreamSettings live = settings;
        live.solver = run.live;
        s.fuser.setSettings(live);
        continue;
      }
      if (result.motion_warped != s.motion) {
        std::fprintf(stderr, "bench_streaming: frame %d not warped as asked\n",
                     k);
        return 1;
      }
      s.live_db.push_back(psnr(s.fuser.fusedNormals(), truth.normals_gt));
      s.warp_ms.push_back(1e3 * result.warp_seconds);
    }
    depth_prev = depth_m;
    if (k == 0) continue;
    const TranslationStream &r = streams[0], &m = streams[1];
    std::printf(
        "| %d | %.2f | %.2f | %.1f | %.1f | %.2f | %.2f | %.2f | %.2f |\n", k,
        r.start_db.back(), m.start_db.back(), r.unknown.back(),
        m.unknown.back(), r.live_db.back(), m.live_db.back(), r.warp_ms.back(),
        m.warp_ms.back());
    std::fflush(stdout);
  }
  const TranslationStream &r = streams[0], &m = streams[1];
  std::printf(
      "| median | %.2f | %.2f | %.1f | %.1f | %.2f | %.2f | %.2f | %.2f |\n",
      median(r.start_db), median(m.start_db), median(r.unknown),
      median(m.unknown), median(r.live_db), median(m.live_db),
      median(r.warp_ms), median(m.warp_ms));
  return 0;
}

}  // namespace bench
}  // namespace normal_fusion
