// CaseRunner: one case's scores over its scenes, every filter setting, and
// the grids extended past their edges where a best setting lies on one.
#include <algorithm>
#include <cmath>
#include <utility>

#include "evaluate/evaluate.h"

namespace evaluate {

CaseRunner::CaseRunner(std::vector<std::string> variant_names,
                       const Options& options, Timers* timers)
    : variant_names_(std::move(variant_names)),
      options_(options),
      timers_(timers),
      candidates_(allCandidates(static_cast<int>(variant_names_.size()))),
      candidate_scores_(candidates_.size()) {}

std::vector<nf::NormalMap> CaseRunner::addScene(const SceneData& scene) {
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
  stored_.push_back({scene.image, scene.gt, scene.filter_inputs, valid, fill});
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
    regularized.push_back(regularize(scene.image, scene.K, scene.runs[r].second,
                                     options_.settings, &timers_->solver));
    run_scores_[r].push_back(split(regularized.back()));
  }
  return regularized;
}

CaseResult CaseRunner::finish(const std::string& id, const std::string& title) {
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

SplitScore CaseRunner::scoreCandidate(const Candidate& candidate,
                                      const StoredScene& scene) {
  const nf::NormalMap filtered =
      timed(&timers_->filters[candidate.family], [&] {
        return applyCandidate(candidate, scene.filter_inputs[candidate.variant],
                              scene.image, options_.settings.num_threads);
      });
  return {scoreOn(filtered, scene.gt, scene.valid),
          scoreOn(filtered, scene.gt, scene.fill)};
}

int CaseRunner::bestCandidate(int family) const {
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

void CaseRunner::extendGrids() {
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

}  // namespace evaluate
