// evaluate's depth-estimators case: the library's depth-to-normals methods
// (central_difference, plane_fit) against OpenCV's RgbdNormals (FALS,
// LINEMOD, SRI) on the same noisy depth maps: each estimator's own normals,
// the regularizer's fusion of them, and the fast global smoother on them.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <sstream>

#include "evaluate/evaluate.h"
#include "normal_fusion/depth.h"
#ifdef NF_HAVE_RGBD
#include "eval/depth_peers.h"
#endif

namespace evaluate {
namespace {

namespace depth = normal_fusion::depth;

/// One estimator: a library method or an OpenCV one.
struct Estimator {
  std::string name;
  bool library = true;
  depth::NormalMethod method = depth::NormalMethod::kPlaneFit;
#ifdef NF_HAVE_RGBD
  nf::depth_peers::OpenCvNormalMethod opencv =
      nf::depth_peers::OpenCvNormalMethod::kFals;
#endif
};

std::vector<Estimator> allEstimators() {
  std::vector<Estimator> estimators;
  for (depth::NormalMethod method : {depth::NormalMethod::kCentralDifference,
                                     depth::NormalMethod::kPlaneFit}) {
    Estimator e;
    e.name = depth::toString(method);
    e.method = method;
    estimators.push_back(e);
  }
#ifdef NF_HAVE_RGBD
  for (auto method : nf::depth_peers::allOpenCvMethods()) {
    Estimator e;
    e.name = "OpenCV " + nf::depth_peers::name(method);
    e.library = false;
    e.opencv = method;
    estimators.push_back(e);
  }
#endif
  return estimators;
}

/// The normals (and, for the library's methods, the confidence) of a depth
/// map by one estimator at its default settings.
nf::NormalMap estimate(const Estimator& e, const nf::ScalarMap& depth_m,
                       const nf::CameraIntrinsics& K,
                       nf::ScalarMap* confidence) {
  nf::NormalMap normals;
  if (e.library) {
    depth::DepthNormalSettings settings;
    settings.method = e.method;
    depth::depthToNormals(depth_m, K, settings, normals, confidence);
    return normals;
  }
#ifdef NF_HAVE_RGBD
  return nf::depth_peers::opencvDepthNormals(depth_m, K, e.opencv);
#else
  return normals;
#endif
}

/// The ways normals are made of an estimator's, in table order.
enum Use { kOwn, kRegularizer, kRegularizerConfidence, kSmoother, kNumUses };

const char* useName(int use) {
  switch (use) {
    case kOwn:
      return "own normals";
    case kRegularizer:
      return "regularizer";
    case kRegularizerConfidence:
      return "regularizer, with its confidence";
    default:
      return "fast global smoother";
  }
}

/// Scores of one data set, by estimator: per use (and per FGS setting) the
/// scores over its scenes.
class EstimatorScores {
 public:
  EstimatorScores(const Options& options, Timer* solver_timer)
      : options_(options),
        solver_timer_(solver_timer),
        estimators_(allEstimators()),
        grid_(peers::settingsGrid(peers::PeerFilter::kFastGlobalSmoother)),
        uses_(estimators_.size(), std::vector<std::vector<Score>>(kNumUses)),
        grid_scores_(estimators_.size(),
                     std::vector<std::vector<Score>>(grid_.size())) {}

  void addScene(const nf::ColorImage& image, const nf::CameraIntrinsics& K,
                const nf::NormalMap& gt, const nf::ScalarMap& noisy_depth);
  EstimatorTable finish(const std::string& title) const;

 private:
  const Options& options_;
  Timer* solver_timer_;
  std::vector<Estimator> estimators_;
  std::vector<peers::PeerSetting> grid_;
  std::vector<std::vector<std::vector<Score>>> uses_;         ///< [e][use]
  std::vector<std::vector<std::vector<Score>>> grid_scores_;  ///< [e][s]
};

void EstimatorScores::addScene(const nf::ColorImage& image,
                               const nf::CameraIntrinsics& K,
                               const nf::NormalMap& gt,
                               const nf::ScalarMap& noisy_depth) {
  const nf::ScalarMap every_pixel(gt.width(), gt.height(), 1, 1.0f);
  for (std::size_t e = 0; e < estimators_.size(); ++e) {
    nf::ScalarMap confidence;
    const nf::NormalMap normals =
        estimate(estimators_[e], noisy_depth, K, &confidence);
    uses_[e][kOwn].push_back(scoreOn(normals, gt, every_pixel));
    const nf::NormalMap fused = regularize(image, K, {inputOf(normals)},
                                           options_.settings, solver_timer_);
    uses_[e][kRegularizer].push_back(scoreOn(fused, gt, every_pixel));
    if (estimators_[e].library) {
      nf::NormalInput input = inputOf(normals);
      input.confidence = confidence;
      const nf::NormalMap fused_confidence =
          regularize(image, K, {input}, options_.settings, solver_timer_);
      uses_[e][kRegularizerConfidence].push_back(
          scoreOn(fused_confidence, gt, every_pixel));
    }
    for (std::size_t s = 0; s < grid_.size(); ++s) {
      grid_scores_[e][s].push_back(
          scoreOn(peers::applyPeer(normals, image, grid_[s]), gt, every_pixel));
    }
  }
}

EstimatorTable EstimatorScores::finish(const std::string& title) const {
  EstimatorTable table;
  table.title = title;
  for (std::size_t e = 0; e < estimators_.size(); ++e) {
    for (int use = 0; use < kNumUses; ++use) {
      EstimatorRow row;
      row.estimator = estimators_[e].name;
      row.use = useName(use);
      if (use == kRegularizerConfidence && !estimators_[e].library) continue;
      if (use == kSmoother) {
        std::size_t best = 0;
        for (std::size_t s = 1; s < grid_.size(); ++s) {
          if (ranksAbove(meanOf(grid_scores_[e][s]),
                         meanOf(grid_scores_[e][best]))) {
            best = s;
          }
        }
        row.setting = grid_[best].label();
        row.mean = meanOf(grid_scores_[e][best]);
      } else {
        row.mean = meanOf(uses_[e][use]);
      }
      table.rows.push_back(row);
    }
  }
  return table;
}

EstimatorTable castleTable(const Options& options, Timer* solver_timer) {
  const std::vector<nf::castle::Face> model =
      nf::castle::loadModel(options.castle_dir);
  nf::castle::LoadSettings load;
  load.agreement_tolerance_m = options.castle_tolerance_m;
  EstimatorScores scores(options, solver_timer);
  const std::vector<int> frames = castleFrames(options);
  for (int number : frames) {
    const nf::castle::Frame frame =
        nf::castle::loadFrame(options.castle_dir, number, model, load);
    // The castle case's depth noise, with its seed.
    const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
        frame.depth, options.depth_sigma_at_1m, options.depth_step_m,
        options.depth_dropout, noiseSeed(options, 100 + number, 4, 0.0));
    scores.addScene(frame.image, frame.K, frame.normals_gt, noisy_depth);
    std::cerr << "evaluate: estimators, castle frame " << number << " done\n";
  }
  std::ostringstream title;
  title << "ViSP Castle, frames";
  for (std::size_t k = 0; k < frames.size(); ++k) {
    title << (k ? ", " : " ") << frames[k];
  }
  return scores.finish(title.str());
}

}  // namespace

EstimatorsOutcome runEstimatorsCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames) {
  EstimatorsOutcome outcome;
  EstimatorScores synthetic(options, &outcome.solver);
  for (std::size_t s = 0; s < frames.size(); ++s) {
    const int scene = options.scenes[s];
    // The depth case's depth noise, with its seed.
    const nf::ScalarMap noisy_depth = nf::synthetic::addDepthNoise(
        frames[s].depth, options.depth_sigma_at_1m, options.depth_step_m,
        options.depth_dropout, noiseSeed(options, scene, 2, 0.0));
    synthetic.addScene(frames[s].image, frames[s].K, frames[s].normals_gt,
                       noisy_depth);
    std::cerr << "evaluate: estimators, scene " << scene << " done\n";
  }
  std::ostringstream title;
  title << "Synthetic scenes";
  for (std::size_t s = 0; s < options.scenes.size(); ++s) {
    title << (s ? ", " : " ") << options.scenes[s];
  }
  title << " at " << options.width << "x" << options.height;
  outcome.tables.push_back(synthetic.finish(title.str()));
  if (nf::castle::available(options.castle_dir)) {
    outcome.tables.push_back(castleTable(options, &outcome.solver));
  } else {
    outcome.note =
        "the ViSP Castle-simu sequence is not at '" + options.castle_dir + "'";
  }
#ifndef NF_HAVE_RGBD
  outcome.note += std::string(outcome.note.empty() ? "" : "; ") +
                  "OpenCV's rgbd module was not found at build time";
#endif
  return outcome;
}

std::string estimatorsTable(const EstimatorTable& table) {
  std::ostringstream md;
  md << "| estimator | normals | FGS setting | PSNR (dB) | mean (deg) | "
        "median (deg) | < 11.25 | < 22.5 | < 30 | with a normal |\n"
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const EstimatorRow& row : table.rows) {
    const Score& s = row.mean;
    md << "| " << row.estimator << " | " << row.use << " | "
       << (row.setting.empty() ? "" : row.setting) << " | "
       << fixed(s.psnr_db, 2) << " | " << fixed(s.angles.mean_deg, 2) << " | "
       << fixed(s.angles.median_deg, 2) << " | "
       << percent(s.angles.within_11_25) << " | "
       << percent(s.angles.within_22_5) << " | " << percent(s.angles.within_30)
       << " | " << percent(s.produced) << " |\n";
  }
  return md.str();
}

}  // namespace evaluate
