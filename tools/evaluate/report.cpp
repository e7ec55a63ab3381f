// evaluate's report: the Markdown tables of the cases and the CSV files.
#include <algorithm>
#include <fstream>
#include <iomanip>
#include <limits>
#include <sstream>

#include "evaluate/evaluate.h"
#include "normal_fusion/errors.h"

namespace evaluate {
namespace {

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

/// One line of the summary: the regularizer against every peer.
struct PeerVerdict {
  bool ahead_psnr = true;
  bool ahead_angle = true;
  double margin_db = 0.0;  ///< over the best peer by PSNR
  std::string best_peer;
};

PeerVerdict verdictOf(const CaseResult& r, int regularizer_row) {
  PeerVerdict v;
  const Score& reg = r.rows[regularizer_row].mean.valid;
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

}  // namespace

const Row& bilateralRow(const CaseResult& r) {
  return r.rows[r.first_filter_row];
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

namespace {

std::string summaryLineOf(const CaseResult& r, int regularizer_row) {
  const PeerVerdict v = verdictOf(r, regularizer_row);
  std::ostringstream out;
  out << "| " << r.id << " | " << r.rows[regularizer_row].method << " | "
      << (v.ahead_psnr ? "yes" : "**no**") << " | "
      << (v.ahead_angle ? "yes" : "**no**") << " | "
      << signedFixed(v.margin_db, 2) << " | " << v.best_peer << " |";
  if (r.has_fill) {
    const Score& reg = r.rows[regularizer_row].mean.fill;
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

}  // namespace

std::string summaryLine(const CaseResult& r) {
  std::string lines = summaryLineOf(r, r.regularizer_row);
  if (r.confidence_row >= 0) {
    lines += "\n" + summaryLineOf(r, r.confidence_row);
  }
  return lines;
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

}  // namespace evaluate
