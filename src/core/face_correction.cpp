// The face correction of a warm start: the faces of the map, the quadratic
// model of E in one tangent direction per face, and damped Newton steps on
// it (docs/algorithm.md, "The face correction").
#include "normal_fusion/detail/face_correction.h"

#include <algorithm>
#include <cmath>

#include <omp.h>

#include "normal_fusion/detail/multiversion.h"

namespace normal_fusion {
namespace internal {

namespace {

/// The root of `i`'s tree, halving the path on the way.
int findRoot(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

/// Joins the trees of `a` and `b` (the smaller root becomes the parent).
void unite(std::vector<int>& parent, int a, int b) {
  a = findRoot(parent, a);
  b = findRoot(parent, b);
  if (a != b) parent[std::max(a, b)] = std::min(a, b);
}

/// The gradient of w huber_eps(|d|) with respect to d: w d / max(|d|, eps).
inline float huberGain(float w, float d2, float eps) {
  const float len = std::max(std::sqrt(d2), eps);
  return len > 0.0f ? w / len : 0.0f;
}

}  // namespace

void tangentEnergyGradient(const PreparedLevel& level, double huber_eps,
                           DataPenalty penalty, const PlanarImage& normals,
                           PlanarImage& gradient, int threads) {
  const int W = level.width, H = level.height;
  gradient.resizeKeepingCapacity(W, H, 3);
  const float eps = static_cast<float>(huber_eps);
  const float* n[3] = {normals.plane(0), normals.plane(1), normals.plane(2)};
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      const float m[3] = {n[0][i], n[1][i], n[2][i]};
      float acc[3] = {0.0f, 0.0f, 0.0f};
      // Data: c_l (n - f_l) / max(|n - f_l|, delta_l); squared: c_l (n - f_l).
      for (int l = 0; l < level.num_inputs; ++l) {
        const float c = level.data_weight[l].plane(0)[i];
        if (c <= 0.0f) continue;
        float r[3], r2 = 0.0f;
        for (int ch = 0; ch < 3; ++ch) {
          r[ch] = m[ch] - level.data[l].plane(ch)[i];
          r2 += r[ch] * r[ch];
        }
        float k = c;
        if (penalty != DataPenalty::kSquaredL2) {
          const float delta =
              level.data_huber ? level.data_eps[l].plane(0)[i] : 0.0f;
          k = huberGain(c, r2, delta);
        }
        for (int ch = 0; ch < 3; ++ch) acc[ch] += k * r[ch];
      }
      // Smoothness: w huber(|n_j - n_i|) on each of the pixel's links adds
      // -w (n_j - n_i) / max(|n_j - n_i|, eps).
      auto link = [&](float w, std::size_t j) {
        float d[3], d2 = 0.0f;
        for (int ch = 0; ch < 3; ++ch) {
          d[ch] = n[ch][j] - m[ch];
          d2 += d[ch] * d[ch];
        }
        const float k = huberGain(w, d2, eps);
        for (int ch = 0; ch < 3; ++ch) acc[ch] -= k * d[ch];
      };
      if (x + 1 < W) link(w_h[i], i + 1);
      if (x > 0) link(w_h[i - 1], i - 1);
      if (y + 1 < H) link(w_v[i], i + W);
      if (y > 0) link(w_v[i - W], i - W);
      // Onto the tangent plane: g - (n . g) n.
      const float dot = acc[0] * m[0] + acc[1] * m[1] + acc[2] * m[2];
      for (int ch = 0; ch < 3; ++ch) {
        gradient.plane(ch)[i] = acc[ch] - dot * m[ch];
      }
    }
  }
}

void FaceLabelScratch::reserve(std::size_t pixels, int height) {
  // Sized, so that their memory is touched here rather than in a live
  // frame's first correction.
  run_start.resize(std::max(run_start.size(), pixels));
  run_parent.resize(std::max(run_parent.size(), pixels));
  row_runs.resize(std::max(row_runs.size(), static_cast<std::size_t>(height)));
  right.resize(std::max(right.size(), pixels));
  down.resize(std::max(down.size(), pixels));
}

void FaceLabelScratch::fit(std::size_t pixels, int height) {
  releaseIfOversized(run_start, pixels);
  releaseIfOversized(run_parent, pixels);
  releaseIfOversized(row_runs, static_cast<std::size_t>(height));
  releaseIfOversized(right, pixels);
  releaseIfOversized(down, pixels);
}

std::size_t FaceLabelScratch::bytesHeld() const {
  return internal::bytesHeld(run_start) + internal::bytesHeld(run_parent) +
         internal::bytesHeld(row_runs) + internal::bytesHeld(right) +
         internal::bytesHeld(down);
}

namespace {

/// Whether each pixel of a row is close to its right neighbour and to the
/// one below (cos of the angle >= cos_limit; the last column and, without
/// a row below, every pixel: not). Branch-free (vectorized).
NF_MULTIVERSION void closeNeighboursRow(const float* __restrict n0,
                                        const float* __restrict n1,
                                        const float* __restrict n2, int W,
                                        bool has_below, float cos_limit,
                                        unsigned char* __restrict right,
                                        unsigned char* __restrict down) {
  for (int x = 0; x + 1 < W; ++x) {
    right[x] =
        n0[x] * n0[x + 1] + n1[x] * n1[x + 1] + n2[x] * n2[x + 1] >= cos_limit
            ? 1
            : 0;
  }
  right[W - 1] = 0;
  if (!has_below) {
    std::fill(down, down + W, static_cast<unsigned char>(0));
    return;
  }
  for (int x = 0; x < W; ++x) {
    down[x] =
        n0[x] * n0[x + W] + n1[x] * n1[x + W] + n2[x] * n2[x + W] >= cos_limit
            ? 1
            : 0;
  }
}

}  // namespace

int labelFaces(const PlanarImage& normals, double degrees,
               std::vector<int>& label, FaceLabelScratch& scratch,
               int threads) {
  const int W = normals.width(), H = normals.height();
  const std::size_t N = normals.pixelCount();
  label.resize(N);
  scratch.run_start.resize(N);
  scratch.run_parent.resize(N);
  scratch.row_runs.resize(static_cast<std::size_t>(H));
  scratch.right.resize(N);
  scratch.down.resize(N);
  if (N == 0) return 0;
  const float cos_limit =
      static_cast<float>(std::cos(degrees * 3.14159265358979 / 180.0));
  int* run_start = scratch.run_start.data();
  int* parent = scratch.run_parent.data();
  int* row_runs = scratch.row_runs.data();
  const unsigned char* down = scratch.down.data();
  // The end of run k of row y (the next run's start, or the row's end).
  auto runEnd = [&](int y, int k) {
    return k + 1 < row_runs[y] ? run_start[y * W + k + 1] : W;
  };
  // Rows in parallel: the neighbour tests, then the row's runs (a new run
  // where a pixel is not close to its left neighbour), each its own tree.
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    unsigned char* right = scratch.right.data() + row;
    closeNeighboursRow(normals.plane(0) + row, normals.plane(1) + row,
                       normals.plane(2) + row, W, y + 1 < H, cos_limit, right,
                       scratch.down.data() + row);
    int runs = 0;
    run_start[row] = 0;
    parent[row] = static_cast<int>(row);
    for (int x = 1; x < W; ++x) {
      if (right[x - 1] != 0) continue;
      ++runs;
      run_start[row + runs] = x;
      parent[row + runs] = static_cast<int>(row) + runs;
    }
    row_runs[y] = runs + 1;
  }
  // The runs of each pair of rows joined where they overlap and some pixel
  // of the overlap is close to the one below (serial: one sweep per pair).
  for (int y = 0; y + 1 < H; ++y) {
    const int a_base = y * W, b_base = a_base + W;
    const int a_count = row_runs[y], b_count = row_runs[y + 1];
    int i = 0, j = 0;
    while (i < a_count && j < b_count) {
      const int a_end = runEnd(y, i), b_end = runEnd(y + 1, j);
      const int lo = std::max(run_start[a_base + i], run_start[b_base + j]);
      const int hi = std::min(a_end, b_end);
      if (lo < hi) {
        const unsigned char* d = down + a_base;
        if (std::find(d + lo, d + hi, static_cast<unsigned char>(1)) !=
            d + hi) {
          unite(scratch.run_parent, a_base + i, b_base + j);
        }
      }
      if (a_end <= b_end) ++i;
      if (b_end <= a_end) ++j;
    }
  }
  // Every parent precedes its child (a run's own slot, or the smaller root
  // of a union), so in raster order the parent's root is already final.
  // Sizes at the roots (label as a counter per run slot), then each root's
  // face (or -1), then each run's.
  for (int y = 0; y < H; ++y) {
    const int base = y * W;
    for (int k = 0; k < row_runs[y]; ++k) {
      const int r = base + k;
      parent[r] = parent[parent[r]];
      label[static_cast<std::size_t>(r)] = 0;
      label[static_cast<std::size_t>(parent[r])] += runEnd(y, k) - run_start[r];
    }
  }
  int faces = 0;
  for (int y = 0; y < H; ++y) {
    const int base = y * W;
    for (int k = 0; k < row_runs[y]; ++k) {
      const int r = base + k;
      if (parent[r] != r) continue;
      // A root's slot becomes its face's label (or -1).
      label[static_cast<std::size_t>(r)] =
          label[static_cast<std::size_t>(r)] >= kMinFacePixels ? faces++ : -1;
    }
  }
  for (int y = 0; y < H; ++y) {
    const int base = y * W;
    for (int k = 0; k < row_runs[y]; ++k) {
      parent[base + k] = label[static_cast<std::size_t>(parent[base + k])];
    }
  }
  // The pixels' labels, run by run (a row writes only its own pixels, and
  // reads only its own runs).
#pragma omp parallel for num_threads(std::max(1, threads)) schedule(static)
  for (int y = 0; y < H; ++y) {
    const int base = y * W;
    for (int k = 0; k < row_runs[y]; ++k) {
      std::fill(label.begin() + base + run_start[base + k],
                label.begin() + base + runEnd(y, k), parent[base + k]);
    }
  }
  return faces;
}

void FaceCorrection::reserve(int width, int height, int threads) {
  const std::size_t N = static_cast<std::size_t>(width) * height;
  label_.resize(std::max(label_.size(), N));
  label_scratch_.reserve(N, height);
  const std::size_t all_faces = N / kMinFacePixels + 1;
  face_size_.reserve(all_faces);
  face_order_.reserve(all_faces);
  const std::size_t S = 3 * kMaxFaces;
  gradient_.reserve(S);
  direction_.reserve(S);
  directions_float_.reserve(S);
  hessian_.reserve(S * S);
  factor_.reserve(S * S);
  thread_sums_.reserve(modelDoubles(kMaxFaces) *
                       static_cast<std::size_t>(std::max(1, threads)));
  row_scratch_.reserve(6 * static_cast<std::size_t>(width) *
                       static_cast<std::size_t>(std::max(1, threads)));
  trial_.resize(width, height, 3);
}

void FaceCorrection::fit(int width, int height) {
  const std::size_t N = static_cast<std::size_t>(width) * height;
  releaseIfOversized(label_, N);
  label_scratch_.fit(N, height);
  releaseIfOversized(face_size_, N / kMinFacePixels + 1);
  releaseIfOversized(face_order_, N / kMinFacePixels + 1);
  releaseIfOversized(row_scratch_, 6 * static_cast<std::size_t>(width) * 64);
  releaseIfOversized(trial_, 3 * N);
}

std::size_t FaceCorrection::modelDoubles(int faces) {
  const std::size_t S = 3 * static_cast<std::size_t>(faces);
  return S + 6 * static_cast<std::size_t>(faces) + S * S;
}

std::size_t FaceCorrection::bytesHeld() const {
  return internal::bytesHeld(label_) + label_scratch_.bytesHeld() +
         internal::bytesHeld(face_size_) + internal::bytesHeld(face_order_) +
         internal::bytesHeld(gradient_) + internal::bytesHeld(direction_) +
         internal::bytesHeld(directions_float_) +
         internal::bytesHeld(hessian_) + internal::bytesHeld(factor_) +
         internal::bytesHeld(thread_sums_) + internal::bytesHeld(row_scratch_) +
         trial_.bytesHeld();
}

int FaceCorrection::begin(const PlanarImage& n0, double degrees,
                          const EnergyFunction& energy_of, int threads) {
  faces_ = labelFaces(n0, degrees, label_, label_scratch_, threads);
  if (faces_ > kMaxFaces) keepLargestFaces();
  damping_ = kInitialDamping;
  energy_ = faces_ > 0 ? energy_of(n0) : 0.0;
  return faces_;
}

void FaceCorrection::keepLargestFaces() {
  face_size_.assign(static_cast<std::size_t>(faces_), 0);
  for (int f : label_) {
    if (f >= 0) face_size_[static_cast<std::size_t>(f)] += 1;
  }
  face_order_.resize(static_cast<std::size_t>(faces_));
  for (int f = 0; f < faces_; ++f) face_order_[static_cast<std::size_t>(f)] = f;
  // The kMaxFaces largest (ties by label, so the choice is deterministic).
  std::nth_element(face_order_.begin(), face_order_.begin() + (kMaxFaces - 1),
                   face_order_.end(), [&](int a, int b) {
                     const int sa = face_size_[static_cast<std::size_t>(a)];
                     const int sb = face_size_[static_cast<std::size_t>(b)];
                     return sa != sb ? sa > sb : a < b;
                   });
  // face_size_ becomes the new label of each old one (-1: dropped), in the
  // old labels' order.
  std::sort(face_order_.begin(), face_order_.begin() + kMaxFaces);
  std::fill(face_size_.begin(), face_size_.end(), -1);
  for (int k = 0; k < kMaxFaces; ++k) {
    face_size_[static_cast<std::size_t>(
        face_order_[static_cast<std::size_t>(k)])] = k;
  }
  for (int& f : label_) {
    if (f >= 0) f = face_size_[static_cast<std::size_t>(f)];
  }
  faces_ = kMaxFaces;
}

namespace {

/// out (3x3, row stride `stride`) += s h A B with A = I - a a^T and
/// B = I - b b^T: a link's curvature h I seen from the tangent planes at a
/// and b.
inline void addProjectedLink(double* out, std::size_t stride, double s,
                             const float a[3], const float b[3], double h) {
  const double ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      // (A B)_rc = delta_rc - a_r a_c - b_r b_c + a_r (a . b) b_c.
      const double AB =
          (r == c ? 1.0 : 0.0) - a[r] * a[c] - b[r] * b[c] + a[r] * ab * b[c];
      out[r * stride + c] += s * h * AB;
    }
  }
}

/// One input's data terms over a row of `count` pixels: g += k r and
/// m_grad += k (m . r) with r = m - f and k = c / max(|r|, delta) (c for
/// the squared penalty), a += the majorizer's curvature c / max(|r|, delta,
/// min_residual) (c squared). `delta` is 0 without the data Huber.
NF_MULTIVERSION void dataModelRow(
    const float* __restrict m0, const float* __restrict m1,
    const float* __restrict m2, const float* __restrict f0,
    const float* __restrict f1, const float* __restrict f2,
    const float* __restrict c, const float* __restrict delta, int count,
    bool squared, float min_residual, float* __restrict g0,
    float* __restrict g1, float* __restrict g2, float* __restrict m_grad,
    float* __restrict a) {
  const float squared_one = squared ? 1.0f : 0.0f, linear = 1.0f - squared_one;
  for (int x = 0; x < count; ++x) {
    const float r0 = m0[x] - f0[x], r1 = m1[x] - f1[x], r2 = m2[x] - f2[x];
    const float len = std::sqrt(r0 * r0 + r1 * r1 + r2 * r2);
    const float den = std::max(len, delta[x]);
    const float cx = std::max(c[x], 0.0f);
    // At r = 0 with delta = 0, k r = 0 (k finite: den floored at 1e-30);
    // the squared penalty: k = curvature = c.
    const float k = cx / std::max(den * linear + squared_one, 1e-30f);
    const float curvature =
        cx / (std::max(den, min_residual) * linear + squared_one);
    g0[x] += k * r0;
    g1[x] += k * r1;
    g2[x] += k * r2;
    m_grad[x] += k * (m0[x] * r0 + m1[x] * r1 + m2[x] * r2);
    a[x] += curvature;
  }
}

/// One neighbour per pixel over a row of `count` pixels (j: the neighbours,
/// w: the links' weights): g -= k d with d = n_j - m and k = w / max(|d|,
/// eps); m_grad -= k (m . d) where the neighbour's label differs.
NF_MULTIVERSION void linkModelRow(
    const float* __restrict m0, const float* __restrict m1,
    const float* __restrict m2, const float* __restrict j0,
    const float* __restrict j1, const float* __restrict j2,
    const float* __restrict w, const int* __restrict label_i,
    const int* __restrict label_j, int count, float eps, float* __restrict g0,
    float* __restrict g1, float* __restrict g2, float* __restrict m_grad) {
  for (int x = 0; x < count; ++x) {
    const float d0 = j0[x] - m0[x], d1 = j1[x] - m1[x], d2 = j2[x] - m2[x];
    const float den = std::max(std::sqrt(d0 * d0 + d1 * d1 + d2 * d2), eps);
    // At d = 0 with eps = 0 (plain TV) the subgradient 0: k d = 0 with k
    // finite (den floored at 1e-30).
    const float k = w[x] / std::max(den, 1e-30f);
    g0[x] -= k * d0;
    g1[x] -= k * d1;
    g2[x] -= k * d2;
    const float md = k * (m0[x] * d0 + m1[x] * d1 + m2[x] * d2);
    m_grad[x] -= label_i[x] != label_j[x] ? md : 0.0f;
  }
}

/// One run of `count` pixels of one face: sum[0..2] = the sum of the
/// tangent gradients (I - u u^T) grad, sum[3..8] = the sum of the packed
/// blocks s (I - u u^T) with s = a - m . grad. In float, vectorized (the
/// order of the additions within the run is the compiler's).
NF_MULTIVERSION void faceRunSums(
    const float* __restrict u0, const float* __restrict u1,
    const float* __restrict u2, const float* __restrict g0,
    const float* __restrict g1, const float* __restrict g2,
    const float* __restrict m_grad, const float* __restrict a, int count,
    float sum[9]) {
  float s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, s5 = 0, s6 = 0, s7 = 0, s8 = 0;
#pragma omp simd reduction(+ : s0, s1, s2, s3, s4, s5, s6, s7, s8)
  for (int x = 0; x < count; ++x) {
    const float ug = u0[x] * g0[x] + u1[x] * g1[x] + u2[x] * g2[x];
    const float sc = a[x] - m_grad[x];
    s0 += g0[x] - ug * u0[x];
    s1 += g1[x] - ug * u1[x];
    s2 += g2[x] - ug * u2[x];
    s3 += sc * (1.0f - u0[x] * u0[x]);
    s4 -= sc * u0[x] * u1[x];
    s5 -= sc * u0[x] * u2[x];
    s6 += sc * (1.0f - u1[x] * u1[x]);
    s7 -= sc * u1[x] * u2[x];
    s8 += sc * (1.0f - u2[x] * u2[x]);
  }
  sum[0] = s0;
  sum[1] = s1;
  sum[2] = s2;
  sum[3] = s3;
  sum[4] = s4;
  sum[5] = s5;
  sum[6] = s6;
  sum[7] = s7;
  sum[8] = s8;
}

}  // namespace

void FaceCorrection::buildModel(const PreparedLevel& level, double huber_eps,
                                DataPenalty penalty, const PlanarImage& n0,
                                int threads) {
  const int W = level.width, H = level.height, K = faces_;
  const std::size_t S = 3 * static_cast<std::size_t>(K);
  const std::size_t per_thread = modelDoubles(K);
  const int slices = std::max(1, threads);
  thread_sums_.assign(per_thread * static_cast<std::size_t>(slices), 0.0);
  row_scratch_.resize(6 * static_cast<std::size_t>(W) * slices);
  const float eps = static_cast<float>(huber_eps);
  const float min_residual = static_cast<float>(kMinResidual);
  const bool squared = penalty == DataPenalty::kSquaredL2;
  const float* n[3] = {n0.plane(0), n0.plane(1), n0.plane(2)};
  const float* w_h = level.edge_weight.plane(0);
  const float* w_v = level.edge_weight.plane(1);
  const int* label = label_.data();
#pragma omp parallel num_threads(slices)
  {
    const int t = omp_get_thread_num();
    double* G = &thread_sums_[per_thread * static_cast<std::size_t>(t)];
    double* B = G + S;      // per face: the pixels' packed 3x3 blocks
    double* M = B + 6 * K;  // S x S: the links between different labels
    // Per row: the gradient (3 planes), m . grad, a and a row of zeros.
    float* g_row = &row_scratch_[6 * static_cast<std::size_t>(W) * t];
    // A link between different labels: its curvature w / max(|d|, eps) I
    // (the majorizer's in the Huber's linear zone, the Huber's own in the
    // quadratic one) seen from both ends' tangent planes.
    auto crossLink = [&](std::size_t i, std::size_t j, float w) {
      const int f = label[i], g = label[j];
      const float a[3] = {n[0][i], n[1][i], n[2][i]};
      const float b[3] = {n[0][j], n[1][j], n[2][j]};
      const double d[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
      const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      const double h =
          w / std::max({len, static_cast<double>(eps), kMinResidual});
      if (f >= 0) addProjectedLink(M + 3 * f * S + 3 * f, S, 1.0, a, a, h);
      if (g >= 0) addProjectedLink(M + 3 * g * S + 3 * g, S, 1.0, b, b, h);
      if (f >= 0 && g >= 0) {
        addProjectedLink(M + 3 * f * S + 3 * g, S, -1.0, a, b, h);
        addProjectedLink(M + 3 * g * S + 3 * f, S, -1.0, b, a, h);
      }
    };
#pragma omp for schedule(static)
    for (int y = 0; y < H; ++y) {
      const std::size_t row = static_cast<std::size_t>(y) * W;
      // The row's gradient (g), m . dE/dn of the modelled terms (data,
      // links to other labels: their curvature on the sphere) and the data
      // majorizers' curvature (a).
      std::fill(g_row, g_row + 6 * static_cast<std::size_t>(W), 0.0f);
      float* g[3] = {g_row, g_row + W, g_row + 2 * W};
      float* m_grad = g_row + 3 * W;
      float* a = g_row + 4 * W;
      const float* zeros = g_row + 5 * W;
      const float* m[3] = {n[0] + row, n[1] + row, n[2] + row};
      for (int l = 0; l < level.num_inputs; ++l) {
        const float* f[3] = {level.data[l].plane(0) + row,
                             level.data[l].plane(1) + row,
                             level.data[l].plane(2) + row};
        const float* c = level.data_weight[l].plane(0) + row;
        // Without the data Huber, delta is the row of zeros after a.
        const float* delta =
            level.data_huber ? level.data_eps[l].plane(0) + row : zeros;
        dataModelRow(m[0], m[1], m[2], f[0], f[1], f[2], c, delta, W, squared,
                     min_residual, g[0], g[1], g[2], m_grad, a);
      }
      // Right and left neighbours, then the rows below and above.
      const int* lab = label + row;
      linkModelRow(m[0], m[1], m[2], m[0] + 1, m[1] + 1, m[2] + 1, w_h + row,
                   lab, lab + 1, W - 1, eps, g[0], g[1], g[2], m_grad);
      linkModelRow(m[0] + 1, m[1] + 1, m[2] + 1, m[0], m[1], m[2], w_h + row,
                   lab + 1, lab, W - 1, eps, g[0] + 1, g[1] + 1, g[2] + 1,
                   m_grad + 1);
      if (y + 1 < H) {
        linkModelRow(m[0], m[1], m[2], m[0] + W, m[1] + W, m[2] + W, w_v + row,
                     lab, lab + W, W, eps, g[0], g[1], g[2], m_grad);
      }
      if (y > 0) {
        linkModelRow(m[0], m[1], m[2], m[0] - W, m[1] - W, m[2] - W,
                     w_v + row - W, lab, lab - W, W, eps, g[0], g[1], g[2],
                     m_grad);
      }
      // The row's sums per face, run by run of one label (in float within a
      // run, in double across runs): G_f += g, block_f += s (I - m m^T).
      for (int x = 0; x < W;) {
        const int f = lab[x];
        int end = x + 1;
        while (end < W && lab[end] == f) ++end;
        if (f >= 0) {
          float sum[9];
          faceRunSums(m[0] + x, m[1] + x, m[2] + x, g[0] + x, g[1] + x,
                      g[2] + x, m_grad + x, a + x, end - x, sum);
          for (int k = 0; k < 3; ++k) G[3 * f + k] += sum[k];
          for (int k = 0; k < 6; ++k) B[6 * f + k] += sum[3 + k];
        }
        x = end;
      }
      // The links (owned by their left or upper pixel) between labels.
      for (int x = 0; x < W; ++x) {
        const std::size_t i = row + x;
        if (x + 1 < W && label[i] != label[i + 1]) crossLink(i, i + 1, w_h[i]);
        if (y + 1 < H && label[i] != label[i + W]) crossLink(i, i + W, w_v[i]);
      }
    }
  }
  // The threads' sums, then the pixels' blocks into the matrix's diagonal.
  gradient_.assign(S, 0.0);
  hessian_.assign(S * S, 0.0);
  for (int t = 0; t < slices; ++t) {
    const double* G = &thread_sums_[per_thread * static_cast<std::size_t>(t)];
    const double* B = G + S;
    const double* M = B + 6 * K;
    for (std::size_t k = 0; k < S; ++k) gradient_[k] += G[k];
    for (std::size_t k = 0; k < S * S; ++k) hessian_[k] += M[k];
    for (int f = 0; f < K; ++f) {
      const double* b = B + 6 * f;
      const int idx[3][3] = {{0, 1, 2}, {1, 3, 4}, {2, 4, 5}};
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          hessian_[(3 * f + r) * S + 3 * f + c] += b[idx[r][c]];
        }
      }
    }
  }
}

bool FaceCorrection::solveDamped(double damping) {
  const std::size_t S = 3 * static_cast<std::size_t>(faces_);
  factor_ = hessian_;
  // (M + damping diag) D = -G, the damping scaled by each face's mean
  // curvature (the direction along a face's normal has almost none).
  for (int f = 0; f < faces_; ++f) {
    double trace = 0.0;
    for (int k = 0; k < 3; ++k) trace += hessian_[(3 * f + k) * S + 3 * f + k];
    const double lift = damping * (std::abs(trace) / 3.0 + 1e-9);
    for (int k = 0; k < 3; ++k) factor_[(3 * f + k) * S + 3 * f + k] += lift;
  }
  // Cholesky, lower triangle in place.
  for (std::size_t j = 0; j < S; ++j) {
    double diag = factor_[j * S + j];
    for (std::size_t k = 0; k < j; ++k)
      diag -= factor_[j * S + k] * factor_[j * S + k];
    if (!(diag > 0.0)) return false;
    diag = std::sqrt(diag);
    factor_[j * S + j] = diag;
    for (std::size_t i = j + 1; i < S; ++i) {
      double v = factor_[i * S + j];
      for (std::size_t k = 0; k < j; ++k)
        v -= factor_[i * S + k] * factor_[j * S + k];
      factor_[i * S + j] = v / diag;
    }
  }
  direction_.resize(S);
  for (std::size_t i = 0; i < S; ++i) {
    double v = -gradient_[i];
    for (std::size_t k = 0; k < i; ++k) v -= factor_[i * S + k] * direction_[k];
    direction_[i] = v / factor_[i * S + i];
  }
  for (std::size_t i = S; i-- > 0;) {
    double v = direction_[i];
    for (std::size_t k = i + 1; k < S; ++k)
      v -= factor_[k * S + i] * direction_[k];
    direction_[i] = v / factor_[i * S + i];
  }
  return true;
}

namespace {

/// One row of W pixels: on a face f (label >= 0) v = n0 + alpha (d_f -
/// (d_f . n0) n0), normalized, then (soft mode) projected onto the visible
/// half-space of the pixel's ray as projectVisible() does; elsewhere n0.
/// `dirs` holds d_f's entries per face (x, y, z); written without branches
/// so that it vectorizes (the directions gathered by label).
NF_MULTIVERSION void rotateRow(const float* __restrict m0,
                               const float* __restrict m1,
                               const float* __restrict m2,
                               const int* __restrict label, int W, int y,
                               const float* __restrict dirs, float alpha,
                               bool soft_visibility, const double* K_inv,
                               float* __restrict o0, float* __restrict o1,
                               float* __restrict o2) {
  // The ray's entries are affine in x: r_c = K_inv[3c] x + base_c.
  const float base[3] = {static_cast<float>(K_inv[1] * y + K_inv[2]),
                         static_cast<float>(K_inv[4] * y + K_inv[5]),
                         static_cast<float>(K_inv[7] * y + K_inv[8])};
  const float k0 = static_cast<float>(K_inv[0]),
              k1 = static_cast<float>(K_inv[3]),
              k2 = static_cast<float>(K_inv[6]);
  // One loop per mode (no branch inside: it vectorizes).
  auto pixel = [&](int x, bool soft) {
    const int f = label[x];
    const int at = 3 * std::max(f, 0);
    const float d0 = dirs[at], d1 = dirs[at + 1], d2 = dirs[at + 2];
    const float u0 = m0[x], u1 = m1[x], u2 = m2[x];
    const float dot = d0 * u0 + d1 * u1 + d2 * u2;
    float v0 = u0 + alpha * (d0 - dot * u0);
    float v1 = u1 + alpha * (d1 - dot * u1);
    float v2 = u2 + alpha * (d2 - dot * u2);
    const float inv =
        1.0f / std::sqrt(std::max(v0 * v0 + v1 * v1 + v2 * v2, 1e-30f));
    v0 *= inv;
    v1 *= inv;
    v2 *= inv;
    if (soft) {
      const float xf = static_cast<float>(x);
      const float r0 = k0 * xf + base[0];
      const float r1 = k1 * xf + base[1];
      const float r2 = k2 * xf + base[2];
      projectVisibleSelect(r0, r1, r2, v0, v1, v2);
    }
    const bool on_face = f >= 0;
    o0[x] = on_face ? v0 : u0;
    o1[x] = on_face ? v1 : u1;
    o2[x] = on_face ? v2 : u2;
  };
  if (soft_visibility) {
    for (int x = 0; x < W; ++x) pixel(x, true);
  } else {
    for (int x = 0; x < W; ++x) pixel(x, false);
  }
}

}  // namespace

void FaceCorrection::candidateAt(const PreparedLevel& level,
                                 bool soft_visibility, const PlanarImage& n0,
                                 const std::vector<double>& direction,
                                 double alpha, PlanarImage& candidate,
                                 int threads) {
  const int W = level.width, H = level.height;
  candidate.resizeKeepingCapacity(W, H, 3);
  // The faces' directions in float (0 for any face `direction` lacks).
  const std::size_t S = 3 * static_cast<std::size_t>(faces_);
  directions_float_.assign(std::max<std::size_t>(S, 3), 0.0f);
  for (std::size_t k = 0; k < std::min(S, direction.size()); ++k) {
    directions_float_[k] = static_cast<float>(direction[k]);
  }
  const float a = static_cast<float>(alpha);
  const double* K_inv = level.K_inv.data();
  const float* dirs = directions_float_.data();
#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t row = static_cast<std::size_t>(y) * W;
    rotateRow(n0.plane(0) + row, n0.plane(1) + row, n0.plane(2) + row,
              label_.data() + row, W, y, dirs, a, soft_visibility, K_inv,
              candidate.plane(0) + row, candidate.plane(1) + row,
              candidate.plane(2) + row);
  }
}

bool FaceCorrection::step(const PreparedLevel& level, double huber_eps,
                          DataPenalty penalty, bool soft_visibility,
                          const EnergyFunction& energy_of, PlanarImage& n0,
                          int threads) {
  if (faces_ == 0) return false;
  // The quadratic model of E in the faces' directions: G and M.
  buildModel(level, huber_eps, penalty, n0, threads);
  // The damped Newton direction; more damping until M + damping is
  // positive definite (M is not where E is concave along a face).
  while (!solveDamped(damping_)) {
    damping_ *= 10.0;
    if (damping_ > kMaxDamping) return false;
  }
  double slope = 0.0;
  for (std::size_t k = 0; k < gradient_.size(); ++k) {
    slope += gradient_[k] * direction_[k];
  }
  if (!(slope < 0.0)) return false;
  // The full step, or when it does not lower E the minimum of the parabola
  // through E(0), E'(0) = G . D and E(1).
  candidateAt(level, soft_visibility, n0, direction_, 1.0, trial_, threads);
  double e = energy_of(trial_);
  const double curvature = e - energy_ - slope;
  // Levenberg-Marquardt: trust the model more where it held.
  const bool model_held = e <= energy_ + 0.25 * slope;
  damping_ = model_held ? std::max(kMinDamping, damping_ / 3.0)
                        : std::min(kMaxDamping, damping_ * 4.0);
  if (!(e < energy_) && curvature > 0.0) {
    const double alpha = std::max(0.1, -slope / (2.0 * curvature));
    if (alpha < 1.0) {
      candidateAt(level, soft_visibility, n0, direction_, alpha, trial_,
                  threads);
      e = energy_of(trial_);
    }
  }
  if (!(e < energy_)) return false;
  std::swap(n0, trial_);
  energy_ = e;
  return true;
}

}  // namespace internal
}  // namespace normal_fusion
