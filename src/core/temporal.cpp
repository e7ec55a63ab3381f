#include "normal_fusion/temporal.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "normal_fusion/detail/previous_pixel.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {

namespace {

void checkThreePlanes(const std::vector<NormalInput>& inputs) {
  for (std::size_t l = 0; l < inputs.size(); ++l) {
    if (inputs[l].normals.channels() != 3) {
      throw InputError(
          "TemporalAverage: input " + std::to_string(l) + " holds " +
          std::to_string(inputs[l].normals.channels()) + " planes; expected 3");
    }
  }
}

/// Sizes an input's averages to W x H (restarting them when the size
/// changes); the carry's scratch follows (a much larger one gives its memory
/// back now, not only when the next carry sizes it).
void sizeAverages(int W, int H, NormalMap& average, ScalarMap& count,
                  NormalMap& scratch_average, ScalarMap& scratch_count) {
  if (average.width() == W && average.height() == H) return;
  average.resize(W, H, 3);
  count.resize(W, H, 1);
  count.fill(0.0f);
  if (!scratch_average.empty()) {
    scratch_average.resize(W, H, 3);
    scratch_count.resize(W, H, 1);
  }
}

/// The rotation in the input's frame: the solver reads n_optical = M
/// n_input, so an input-frame vector turns by M^T R M.
void rotationInInputFrame(const std::array<float, 9>& M,
                          const std::array<double, 9>& R, float R_in[9]) {
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double sum = 0.0;
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          sum += M[3 * a + i] * R[3 * a + b] * M[3 * b + j];
        }
      }
      R_in[3 * i + j] = static_cast<float>(sum);
    }
  }
}

/// How an input's averages move into this frame and take its samples.
struct CarryRule {
  const internal::PreviousPixel& previous;
  bool carry;         ///< false: the averages stay where they are
  const float* R_in;  ///< 3x3, the rotation in the input's frame
  float cos_gate;     ///< cos(settings.gate_degrees)
  float max_count;    ///< settings.frames
};

/// One pass: each pixel's average carried from the previous frame, then its
/// sample blended in; written to next_average / next_count, which may be
/// average / count themselves when not carried (each pixel reads only
/// itself).
void carryAndBlend(const CarryRule& rule, const NormalMap& average,
                   const ScalarMap& counts, NormalMap& samples,
                   NormalMap& next_average, ScalarMap& next_count,
                   int threads) {
  const internal::PreviousPixel& previous = rule.previous;
  const bool carry = rule.carry;
  const float* R_in = rule.R_in;
  const float cos_gate = rule.cos_gate, max_count = rule.max_count;
  const int W = samples.width(), H = samples.height();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const long i = static_cast<long>(y) * W + x;
      // Carry: the average of the nearest previous pixel, rotated.
      long j = i;
      bool inside = true;
      if (carry) {
        double u = 0.0, v = 0.0;
        inside = previous.at(x, y, W, H, &u, &v);
        // u, v >= 0 inside: + 0.5 and truncation round to nearest.
        j = inside ? static_cast<long>(v + 0.5) * W + static_cast<long>(u + 0.5)
                   : 0;
      }
      float count = inside ? counts.plane(0)[j] : 0.0f;
      const float s[3] = {average.plane(0)[j], average.plane(1)[j],
                          average.plane(2)[j]};
      float a[3] = {0.0f, 0.0f, 0.0f};
      if (count > 0.0f) {
        for (int r = 0; r < 3; ++r) {
          a[r] = R_in[3 * r] * s[0] + R_in[3 * r + 1] * s[1] +
                 R_in[3 * r + 2] * s[2];
        }
      }
      // Blend: the pixel's sample, if valid, into the carried average,
      // which the input then holds.
      float f[3] = {samples.plane(0)[i], samples.plane(1)[i],
                    samples.plane(2)[i]};
      if (isValidNormal(f[0], f[1], f[2])) {
        const float inv_f =
            1.0f / std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        for (float& c : f) c *= inv_f;
        bool restart = true;
        if (count > 0.0f &&
            a[0] * f[0] + a[1] * f[1] + a[2] * f[2] >= cos_gate) {
          // Within the gate: the running mean, exponential past `frames`.
          const float k = std::min(count + 1.0f, max_count);
          const float w = 1.0f / k;
          float m[3], norm2 = 0.0f;
          for (int c = 0; c < 3; ++c) {
            m[c] = (1.0f - w) * a[c] + w * f[c];
            norm2 += m[c] * m[c];
          }
          // |m| >= cos(gate / 2) > 0 for a gate of at most 180 degrees,
          // except for exactly opposite vectors, which restart it.
          if (norm2 > 1e-12f) {
            const float inv = 1.0f / std::sqrt(norm2);
            for (int c = 0; c < 3; ++c) a[c] = m[c] * inv;
            count = k;
            restart = false;
          }
        }
        if (restart) {
          // No average here yet, or the sample left the gate: a new one.
          for (int c = 0; c < 3; ++c) a[c] = f[c];
          count = 1.0f;
        }
        for (int c = 0; c < 3; ++c) samples.plane(c)[i] = a[c];
      }
      for (int c = 0; c < 3; ++c) next_average.plane(c)[i] = a[c];
      next_count.plane(0)[i] = count;
    }
  }
}

}  // namespace

void TemporalSettings::validate() const {
  if (frames < 0) {
    throw ParameterError("setting temporal_frames = " + std::to_string(frames) +
                         ": expected >= 0 (0 or 1 = off)");
  }
  if (!(gate_degrees > 0.0 && gate_degrees <= 180.0)) {
    throw ParameterError(
        "setting temporal_gate_deg = " + std::to_string(gate_degrees) +
        ": expected in (0, 180]");
  }
}

void TemporalAverage::reset() {
  for (History& history : histories_) history.count.fill(0.0f);
}

std::size_t TemporalAverage::bytesHeld() const {
  std::size_t bytes = 0;
  for (const History& h : histories_) {
    bytes += h.average.bytesHeld() + h.count.bytesHeld() +
             h.scratch_average.bytesHeld() + h.scratch_count.bytesHeld();
  }
  return bytes;
}

int TemporalAverage::count(int l, int i) const {
  if (l < 0 || l >= static_cast<int>(histories_.size())) return 0;
  const ScalarMap& count = histories_[l].count;
  if (i < 0 || static_cast<std::size_t>(i) >= count.pixelCount()) return 0;
  return static_cast<int>(count.plane(0)[i]);
}

void TemporalAverage::apply(std::vector<NormalInput>& inputs,
                            const CameraIntrinsics& K,
                            const std::array<double, 9>* R_cur_prev,
                            const TemporalSettings& settings, int num_threads) {
  settings.validate();
  if (!settings.enabled()) return;
  if (R_cur_prev != nullptr) {
    internal::checkRotation(*R_cur_prev, "TemporalAverage");
  }
  const internal::PreviousPixel previous(
      K, R_cur_prev != nullptr
             ? *R_cur_prev
             : std::array<double, 9>{1, 0, 0, 0, 1, 0, 0, 0, 1});
  const int threads = resolveThreadCount(num_threads);
  const int L = static_cast<int>(inputs.size());
  checkThreePlanes(inputs);
  if (static_cast<int>(histories_.size()) != L) {
    histories_.resize(L);
    reset();
  }
  const float max_count = static_cast<float>(settings.frames);
  const float cos_gate =
      static_cast<float>(std::cos(settings.gate_degrees * M_PI / 180.0));
  for (int l = 0; l < L; ++l) {
    NormalMap& samples = inputs[l].normals;
    History& h = histories_[l];
    const int W = samples.width(), H = samples.height();
    sizeAverages(W, H, h.average, h.count, h.scratch_average, h.scratch_count);
    const bool carry = R_cur_prev != nullptr;
    float R_in[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    if (carry) {
      rotationInInputFrame(inputs[l].orientation.M, *R_cur_prev, R_in);
      h.scratch_average.resize(W, H, 3);
      h.scratch_count.resize(W, H, 1);
    }
    // Written to the scratch buffers when carried (then swapped in), in place
    // otherwise.
    const CarryRule rule{previous, carry, R_in, cos_gate, max_count};
    carryAndBlend(rule, h.average, h.count, samples,
                  carry ? h.scratch_average : h.average,
                  carry ? h.scratch_count : h.count, threads);
    if (carry) {
      std::swap(h.average, h.scratch_average);
      std::swap(h.count, h.scratch_count);
    }
  }
}

}  // namespace normal_fusion
