// evaluate's scores (PSNR and angles on a set of pixels, means over scenes)
// and the filters it compares: the paper's bilateral and the ximgproc peers.
#include <cmath>
#include <iomanip>
#include <sstream>

#include "evaluate/evaluate.h"

namespace evaluate {

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

/// True when setting a ranks above setting b.
bool ranksAbove(const Score& a, const Score& b) {
  const bool a_dense = a.produced >= kMinProducedShare;
  const bool b_dense = b.produced >= kMinProducedShare;
  if (a_dense != b_dense) return a_dense;
  return rankOf(a) > rankOf(b);
}

// --- Filters: the paper's bilateral and the ximgproc peers ----------------

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

nf::NormalInput inputOf(const nf::NormalMap& normals, double weight) {
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

}  // namespace evaluate
