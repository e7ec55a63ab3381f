// Internal types shared by the solver's outer loop and its two kernel
// backends. Not part of the stable API; exposed for the unit tests.
#pragma once

#include <array>
#include <atomic>
#include <cmath>
#include <vector>

#include "normal_fusion/detail/tgv_state.h"
#include "normal_fusion/settings.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace internal {

/// Bytes of memory a vector holds (its capacity, not its size).
template <typename T, typename A>
std::size_t bytesHeld(const std::vector<T, A>& v) {
  return v.capacity() * sizeof(T);
}

/// Gives back the memory of a vector sized for a much larger image: room
/// for more than 4 times the `values` it needs now (PlanarImage::resize()'s
/// rule). Its contents are then gone.
template <typename T, typename A>
void releaseIfOversized(std::vector<T, A>& v, std::size_t values) {
  if (values < v.capacity() / 4) std::vector<T, A>().swap(v);
}

/// The same for an image (`values`: floats, all planes).
inline void releaseIfOversized(PlanarImage& image, std::size_t values) {
  if (values < image.bytesHeld() / sizeof(float) / 4) image = PlanarImage();
}

/// A problem after input preparation, at one pyramid level: everything the
/// inner iterations read and never write.
struct PreparedLevel {
  int width = 0;
  int height = 0;
  int num_inputs = 0;
  std::vector<PlanarImage> data;  ///< f_l: 3 planes, unit or 0 where missing
  /// c_l = lambda * weight_l * conf * valid: 1 plane each.
  std::vector<PlanarImage> data_weight;
  /// delta_l: Huber threshold of each data term, 1 plane each; read only when
  /// `data_huber` (else every delta is 0: the plain unsquared penalty).
  std::vector<PlanarImage> data_eps;
  bool data_huber = false;
  /// Per input, at the finest level when the local refinement of warm
  /// starts is on: the normalized mean of f over the local window (planes
  /// 0 - 2) and its spread s (plane 3; -1 below 2 samples).
  std::vector<PlanarImage> data_mean;
  PlanarImage edge_weight;  ///< w_h (plane 0), w_v (plane 1)
  std::array<double, 9> K_inv{{1, 0, 0, 0, 1, 0, 0, 0, 1}};
  CameraIntrinsics K;
  /// The problem's own image at the finest level (not copied; valid during
  /// the solve); null at coarser levels, which own their image in `image`.
  /// (No level points into another level, so the level vector may move.)
  const ColorImage* problem_image = nullptr;
  ColorImage image;
  /// Guide image at this level (read to build the next coarser level).
  const ColorImage& guide() const {
    return problem_image != nullptr ? *problem_image : image;
  }
  int valid_pixels = 0;

  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;

  /// Ray r(x, y) = K^-1 (x, y, 1)^T of a pixel (not normalized).
  void ray(int x, int y, float r[3]) const {
    r[0] = static_cast<float>(K_inv[0] * x + K_inv[1] * y + K_inv[2]);
    r[1] = static_cast<float>(K_inv[3] * x + K_inv[4] * y + K_inv[5]);
    r[2] = static_cast<float>(K_inv[6] * x + K_inv[7] * y + K_inv[8]);
  }
};

/// Step sizes and model constants of one run of inner iterations.
struct InnerParams {
  float tau = 0.0f;         ///< primal step
  float sigma = 0.0f;       ///< dual step of the smoothness terms (p_h, p_v)
  float sigma_data = 0.0f;  ///< dual step of the data terms (q_l)
  /// Relaxation rho of the relaxed iteration (Condat 2013): x <- x +
  /// rho (x_hat - x) for the normals and the duals; 1 = the plain step.
  float relaxation = 1.0f;
  float huber_eps = 0.0f;
  DataPenalty penalty = DataPenalty::kL2;
  bool soft_visibility = false;
  int num_threads = 1;
  int block_depth = 6;  ///< iterations per thread per sweep (fast backend)
  TgvParams tgv;        ///< the second-order term (alpha0 = 0: off)
  /// Stop request (Solver::requestCancel()), or null: none. The kernels
  /// read it between rows (fast backend) or iterations and return early
  /// once it is set.
  const std::atomic<bool>* cancel = nullptr;
};

/// True when a stop request is set (`cancel` may be null: none).
inline bool stopRequested(const std::atomic<bool>* cancel) {
  return cancel != nullptr && cancel->load(std::memory_order_relaxed);
}

/// Variables of the primal-dual iteration (allocated once per size).
struct IterationState {
  PlanarImage n0;    ///< linearization point (unit), 3 planes
  PlanarImage n;     ///< primal iterate on the tangent plane, 3 planes
  PlanarImage nbar;  ///< over-relaxed primal, 3 planes
  PlanarImage p_h;   ///< dual of the horizontal differences, 3 planes
  PlanarImage p_v;   ///< dual of the vertical differences, 3 planes
  std::vector<PlanarImage> q;  ///< duals of the data terms, 3 planes each
  TgvState tgv;  ///< v and r of the second-order term (empty while off)
  // Scratch of the reference backend: gradients, divergence, data-dual sum
  // (sized by runInnerReference(), so the fast backend holds none).
  PlanarImage grad_h, grad_v, div, q_sum;
  // Scratch of the fast backend: three rows per thread, and each thread's
  // progress through the rows (the temporal-blocking pipeline).
  std::vector<float> row_scratch;
  std::vector<std::atomic<long>> progress;

  /// Sizes every buffer for one level of a solve, keeping the capacity (the
  /// pyramid's levels reuse the finest level's buffers). A set `cancel`,
  /// read between the buffers, stops it (returns false; the buffers are then
  /// not all sized): on a first solve at 1920x1440 the buffers' fresh memory
  /// takes about half a second.
  bool resize(int width, int height, int num_inputs,
              const std::atomic<bool>* cancel = nullptr);
  /// Before the levels of a solve whose finest level is W x H with
  /// `threads` threads: releases the buffers sized for a much larger image
  /// (releaseIfOversized()); the levels then size what they use.
  void fit(int width, int height, int threads);
  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;
};

/// The pixels of a local refinement and the links that touch them. Buffers
/// are reserved for the whole image when its size changes, so a stream of
/// frames of one size allocates nothing here.
struct ActiveSet {
  int width = 0;
  int height = 0;
  std::vector<unsigned char> mask;  ///< W * H, 1 = active
  std::vector<int> pixels;          ///< active pixels (y * W + x), ascending
  std::vector<int> links_h;  ///< left pixel of each horizontal link with an
                             ///< active end
  std::vector<int> links_v;  ///< upper pixel of each vertical link with an
                             ///< active end
  std::vector<unsigned char> scratch;
  std::vector<int> links_up, links_down;  ///< scratch of build()

  /// Marks active every pixel within `radius` (Chebyshev distance) of a seed
  /// (seed[i] != 0, W * H entries) and lists the pixels and links.
  void build(const std::vector<unsigned char>& seed, int width, int height,
             int radius);
  /// Sizes the buffers for a W x H image (written once).
  void preallocate(int width, int height);
  bool empty() const { return pixels.empty(); }
  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;
};

/// Runs `iterations` Chambolle-Pock iterations of the subproblem on the
/// active pixels, every other pixel held at n (= nbar = n0 there): the duals
/// of the links that touch an active pixel, the data duals and the primal
/// step at active pixels, each the reference backend's per-pixel step.
/// Returns false when params.cancel stopped it before the last iteration
/// (read before each one; n and nbar are then those of an unfinished
/// iteration, and only n0 and the duals are to be used).
bool runInnerActive(const PreparedLevel& level, const InnerParams& params,
                    IterationState& state, const ActiveSet& active,
                    int iterations);

/// A warm start's normals made usable (what the solver does first with
/// them): n / |n|, projected onto the visible set in soft mode
/// (projectVisible()); pixels without a usable one (NaN, infinite, zero,
/// tiny) take the cold start and unknown = 1, the others unknown = 0.
void sanitizeWarmStart(const PreparedLevel& level, VisibilityMode mode,
                       PlanarImage& normals,
                       std::vector<unsigned char>& unknown, int threads);

/// Fills the unknown pixels of a warm start (known[i] == 0; all of them in
/// `active`) inwards from the known ones (known[i] == 1), pass by pass: a pixel
/// next to a known one takes, among the normals of its known 4-neighbours and
/// its own observations, the one of the lowest energy terms with those
/// neighbours; it is then known. Pixels still unknown after `max_passes` keep
/// their normal.
/// `filled` and `pending` are scratch (grown to the unknown pixels' count;
/// reserve them once for a stream without allocations); `threads` share
/// each pass. A set `cancel` (read before each pass) ends it early.
void fillUnknownPixels(const PreparedLevel& level, double huber_eps,
                       DataPenalty penalty, bool soft, PlanarImage& normals,
                       std::vector<unsigned char>& known,
                       const ActiveSet& active, int max_passes,
                       std::vector<unsigned char>& filled,
                       std::vector<int>& pending, int threads,
                       const std::atomic<bool>* cancel = nullptr);

/// The variables of a local refinement gathered into contiguous arrays, one
/// array per component (the fast path of runInnerActive()). Nodes are the
/// active pixels [0, P), then the inactive pixels next to them (ghosts, held
/// at n0). Link `num_links` is a dummy with w = 0 and p = 0 that stands for
/// a missing link. Vectors only grow, so a steady stream allocates nothing.
struct ActiveBuffers {
  int num_inputs = 0;
  int num_active = 0;  ///< P
  /// Links: [0, P) the link to the right of each active pixel, [P, 2 P)
  /// the one below it (dummies where the image ends), then the
  /// num_ghost_links_h horizontal and then the vertical links whose first
  /// (left, upper) node is a ghost.
  int num_links = 0;
  int num_ghost_links_h = 0;
  bool isHorizontal(int m) const {
    return m < num_active ||
           (m >= 2 * num_active && m < 2 * num_active + num_ghost_links_h);
  }
  std::vector<int> node_pixel;  ///< pixel of each node (active, then ghosts)
  std::vector<int> node_of;     ///< W * H: node of each pixel, -1 if none
  std::array<std::vector<float>, 3> nbar;        ///< per node (ghosts: n0)
  std::array<std::vector<float>, 3> n, n0, ray;  ///< per active pixel
  std::vector<float> q, f;  ///< component ch of input l at [(3 l + ch) P + k]
  std::vector<float> c, delta;  ///< input l at [l P + k]
  /// The link to the left of and the link above each active pixel (the
  /// dummy where there is none); its links to the right and below are k and
  /// P + k.
  std::vector<int> left_link, above_link;
  std::vector<int> link_a, link_b;  ///< nodes of each link (p of a -> b)
  std::vector<int> link_pixel;  ///< pixel of node a of each link, -1: a dummy
  std::vector<float> link_w;    ///< w of each link
  std::array<std::vector<float>, 3> p;  ///< per link
  std::array<std::vector<float>, 3> d;  ///< scratch: div p - sum q
  /// Terms per float partial sum of energy() (the blocks are summed in
  /// double).
  static constexpr int kEnergyBlock = 256;
  /// scratch of energy(): one partial sum per block of terms
  mutable std::vector<double> block_sums;
  /// Unit normals of the nodes that E is evaluated at: the candidate n / |n|
  /// (or n0) at the active pixels, n0 at the ghosts.
  std::array<std::vector<float>, 3> node_n;

  /// Sizes every buffer for `active` active pixels of a W x H image with L
  /// inputs (written once, so that the first warm start does not pay for
  /// fresh memory).
  void preallocate(int width, int height, int num_inputs, int active);
  /// Gathers the state at the active pixels (and their links and ghosts);
  /// n = nbar = n0 there. The nodes are numbered in one thread, the values
  /// copied with `threads`.
  void gather(const PreparedLevel& level, const IterationState& state,
              const ActiveSet& active, int threads = 1);
  /// gather()'s first part: numbers the nodes and the links, sizes the
  /// buffers (one thread).
  void gatherTopology(const PreparedLevel& level, const ActiveSet& active);
  /// Sizes the buffers of the nodes and the active pixels once they are
  /// numbered.
  void sizeNodeBuffers();
  /// gather()'s second part: copies the values, with `threads`.
  void gatherValues(const PreparedLevel& level, const IterationState& state,
                    int threads);
  /// node_n <- n / |n| at the active pixels (the candidate of an outer step).
  void normalizeCandidate();
  /// The terms of E that involve an active pixel, at node_n (as
  /// energyActive()): blocks of terms summed with `threads`, the blocks'
  /// sums then added in order (the same result for any thread count).
  double energy(double huber_eps, DataPenalty penalty, int threads = 1) const;
  /// n0 <- node_n at the active pixels; n = nbar = n0 (a new outer step).
  void acceptCandidate();
  /// Writes n0 (into state.n0) and the duals of the links and data terms
  /// back, with `threads`.
  void scatter(IterationState& state, int threads = 1) const;
  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;
};

/// Picks the thread count of the local refinement's steps from their
/// measured cost. The refinement synchronises its threads twice per
/// iteration on small sets, so a thread that the operating system (or the
/// hypervisor) holds back stalls the other at every barrier: on a loaded
/// machine one thread can be faster than all of them. Its results do not
/// depend on the count (each pixel and link is computed the same way and the
/// energy is summed in fixed blocks), so only the time changes.
///
/// Keeps the last cost per pixel-iteration measured with one thread and with
/// all `max_threads`, runs the cheaper, and re-measures the other every
/// kProbeInterval steps (a count never measured is tried first). Lives in
/// the solver, across frames.
class RefineThreadChooser {
 public:
  static constexpr int kProbeInterval = 8;

  /// Forgets what was measured (e.g. when the thread count changes).
  void reset(int max_threads);
  /// The thread count for the next step.
  int choose();
  /// The cost of a step that ran on `threads` threads: its seconds per pixel
  /// and iteration.
  void record(int threads, double seconds_per_pixel_iteration);
  /// Lowers the cost of `threads` threads by kShrink: called when that cost
  /// kept a step from running (a frame's first step, or a probe). A cost
  /// measured in a stall (the process descheduled in a step) would
  /// otherwise refuse those steps for good, and with no step nothing
  /// measures it again.
  void shrink(int threads);
  static constexpr double kShrink = 0.5;
  int maxThreads() const { return max_threads_; }
  /// The count that choose() runs between probes (all threads until both
  /// are measured).
  int cheaper() const;
  /// The last cost per pixel-iteration measured with `threads` threads (1 or
  /// all), 0 when none was.
  double cost(int threads) const {
    return threads == 1 ? cost_one_ : cost_all_;
  }

 private:
  int max_threads_ = 1;
  double cost_one_ = 0.0;  ///< 0: not measured yet
  double cost_all_ = 0.0;
  int steps_since_probe_ = 0;
};

/// runInnerActive() on gathered buffers: the same steps on contiguous
/// arrays, vectorised, on up to params.num_threads threads. Returns false
/// when params.cancel stopped it (as runInnerActive()).
bool runInnerActiveFast(const PreparedLevel& level, const InnerParams& params,
                        ActiveBuffers& buffers, int iterations);

/// Angle between a warm start's normal and an input's window mean, beyond
/// the window's spread, from which the input contradicts the warm start.
constexpr double kInconsistentDegrees = 15.0;

/// Marks unknown (unknown[i] = 1) the pixels whose warm-start normal every
/// input observing them contradicts: |n - m_l| > chord(kInconsistentDegrees)
/// + 2 s_l / (2 local_radius + 1) (two standard errors of the window's mean),
/// m_l and s_l the input's window mean and spread (data_mean). Such pixels
/// show content that changed or moved in a way the warp could not know of.
/// Returns how many it marked (0 without data_mean).
int markInconsistentPixels(const PreparedLevel& level,
                           const PlanarImage& normals, int local_radius,
                           std::vector<unsigned char>& unknown, int threads);

/// Marks (unknown[i] = 2) the pixels not yet marked whose warm-start normal is
/// more than kInconsistentDegrees from a known 4-neighbour's: the edges of
/// the previous map, which the camera's translation moves by a parallax that
/// a rotation-only warp does not follow. `edge` is scratch (resized).
/// Returns how many it marked.
int markMapEdges(const PlanarImage& normals,
                 std::vector<unsigned char>& unknown,
                 std::vector<unsigned char>& edge, int threads);

/// The terms of E(n) that involve an active pixel: its data terms and the
/// smoothness terms of the links that touch it (double accumulation). With
/// the other pixels fixed, E changes exactly as this does.
double energyActive(const PreparedLevel& level, double huber_eps,
                    DataPenalty penalty, const PlanarImage& normals,
                    const ActiveSet& active, int num_threads);

/// Runs `iterations` Chambolle-Pock iterations on the tangent plane at n0.
/// Reference backend: one plain function per step of the maths.
/// Both return false when params.cancel stopped them before the last
/// iteration ended: read before each iteration (reference) or each row
/// (fast; its threads then leave their sweeps where they are). n and nbar
/// are then those of an unfinished iteration, to be dropped; the duals are
/// each the result of a whole step (finite, feasible), n0 is untouched.
bool runInnerReference(const PreparedLevel& level, const InnerParams& params,
                       IterationState& state, int iterations);
/// Fast backend: fused per-pixel passes, multithreaded.
bool runInnerFast(const PreparedLevel& level, const InnerParams& params,
                  IterationState& state, int iterations);

/// huber_eps(z) = z^2 / (2 eps) below eps, z - eps / 2 above (eps = 0: z).
inline double huberPenalty(double z, double eps) {
  return z < eps ? z * z / (2.0 * eps) : z - 0.5 * eps;
}

/// The data terms of E at pixel i for the normal n: sum_l c_l phi(n - f_l),
/// phi = huber_delta_l(|.|) for the unsquared penalty (delta_l = 0: |.|),
/// |.|^2 / 2 for the squared one.
inline double dataEnergyAt(const PreparedLevel& level, DataPenalty penalty,
                           std::size_t i, const double n[3]) {
  double total = 0.0;
  for (int l = 0; l < level.num_inputs; ++l) {
    const double c = level.data_weight[l].plane(0)[i];
    if (c <= 0.0) continue;
    double d2 = 0.0;
    for (int ch = 0; ch < 3; ++ch) {
      const double d = n[ch] - level.data[l].plane(ch)[i];
      d2 += d * d;
    }
    if (penalty == DataPenalty::kSquaredL2) {
      total += c * 0.5 * d2;
      continue;
    }
    const double delta = level.data_huber ? level.data_eps[l].plane(0)[i] : 0.0;
    total += c * huberPenalty(std::sqrt(d2), delta);
  }
  return total;
}

/// Projection onto C = {n : n0 . n = 1} (and n . r <= 0 when `soft`).
/// Closed form: project on the plane; if the half-space is violated, project
/// within the plane onto the line where n . r = 0.
inline void projectTangentFeasible(const float n0[3], const float r[3],
                                   bool soft, float v[3]) {
  // Plane n0 . n = 1: v <- v - (n0 . v - 1) n0.
  const float off = n0[0] * v[0] + n0[1] * v[1] + n0[2] * v[2] - 1.0f;
  v[0] -= off * n0[0];
  v[1] -= off * n0[1];
  v[2] -= off * n0[2];
  if (!soft) return;
  const float rv = r[0] * v[0] + r[1] * v[1] + r[2] * v[2];
  if (rv <= 0.0f) return;
  // Within the plane: r_t = r - (n0 . r) n0; v <- v - (r . v / |r_t|^2) r_t.
  const float rn0 = r[0] * n0[0] + r[1] * n0[1] + r[2] * n0[2];
  const float rt[3] = {r[0] - rn0 * n0[0], r[1] - rn0 * n0[1],
                       r[2] - rn0 * n0[2]};
  const float rt2 = rt[0] * rt[0] + rt[1] * rt[1] + rt[2] * rt[2];
  if (rt2 <= 1e-20f) return;  // n0 is parallel to r: the half-space is inactive
  const float s = rv / rt2;
  v[0] -= s * rt[0];
  v[1] -= s * rt[1];
  v[2] -= s * rt[2];
}

/// Projects a unit normal onto the visible set n . r <= 0 (in place):
/// n <- (r x n) x r = n |r|^2 - r (r . n), normalized; -r/|r| if degenerate.
inline void projectVisible(const float r[3], float n[3]) {
  const float rn = r[0] * n[0] + r[1] * n[1] + r[2] * n[2];
  if (rn <= 0.0f) return;
  const float r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
  float m[3] = {n[0] * r2 - r[0] * rn, n[1] * r2 - r[1] * rn,
                n[2] * r2 - r[2] * rn};
  float len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
  if (len <= 1e-6f * r2) {
    const float rl = std::sqrt(r2);
    n[0] = -r[0] / rl;
    n[1] = -r[1] / rl;
    n[2] = -r[2] / rl;
    return;
  }
  n[0] = m[0] / len;
  n[1] = m[1] / len;
  n[2] = m[2] / len;
}

/// projectVisible() without branches, for vectorized row kernels: the
/// unit normal v and the pixel's ray r in registers, v replaced when it
/// faces away (r . v > 0).
inline void projectVisibleSelect(float r0, float r1, float r2, float& v0,
                                 float& v1, float& v2) {
  const float rn = r0 * v0 + r1 * v1 + r2 * v2;
  const float rr = r0 * r0 + r1 * r1 + r2 * r2;
  const float m0 = v0 * rr - r0 * rn, m1 = v1 * rr - r1 * rn,
              m2 = v2 * rr - r2 * rn;
  const float m_len = std::sqrt(m0 * m0 + m1 * m1 + m2 * m2);
  const bool away = rn > 0.0f;
  // Onto the plane normal to r, or -r / |r| when v is (nearly) r itself.
  const bool degenerate = m_len <= 1e-6f * rr;
  const float inv_m = 1.0f / (degenerate ? 1.0f : m_len);
  const float inv_r = 1.0f / std::sqrt(rr);
  const float p0 = degenerate ? -r0 * inv_r : m0 * inv_m;
  const float p1 = degenerate ? -r1 * inv_r : m1 * inv_m;
  const float p2 = degenerate ? -r2 * inv_r : m2 * inv_m;
  v0 = away ? p0 : v0;
  v1 = away ? p1 : v1;
  v2 = away ? p2 : v2;
}

namespace reference {
/// The single steps of the reference iteration (exposed for the unit tests).
void gradient(const PlanarImage& n, PlanarImage& grad_h, PlanarImage& grad_v);
void divergence(const PlanarImage& p_h, const PlanarImage& p_v,
                PlanarImage& div);
void clampVector(float v[3], float radius);
/// The dual proxes at one pixel, applied to v = p + sigma grad (smoothness,
/// weight w) or v = q + sigma (nbar - f) (data, weight c, threshold delta).
void huberDualProx(float v[3], float w, float sigma, float eps);
void dataDualProx(float v[3], float c_weight, float delta, float sigma,
                  DataPenalty penalty);
/// The dual steps over an image, relaxed by rho (1 = the plain prox).
void proxHuberDual(PlanarImage& p, const PlanarImage& grad, const float* weight,
                   float sigma, float eps, float rho = 1.0f);
/// `delta` may be null (0 everywhere).
void proxDataDual(PlanarImage& q, const PlanarImage& nbar, const PlanarImage& f,
                  const float* c_weight, const float* delta, float sigma,
                  DataPenalty penalty, float rho = 1.0f);
void primalStep(const PreparedLevel& level, const InnerParams& params,
                const PlanarImage& div, const PlanarImage& q_sum,
                const PlanarImage& n0, PlanarImage& n, PlanarImage& nbar);
}  // namespace reference

/// Buffers of the edge-weight computation, reused from frame to frame.
struct EdgeWeightScratch {
  std::vector<float> mag_h, mag_v, plane, blurred, blur, kernel;
  /// Bytes of memory its buffers hold.
  std::size_t bytesHeld() const;
};

/// computeEdgeWeights() into reused buffers, with `threads` threads. The
/// forward differences of the unsmoothed image (the default) take one pass
/// per row; the other settings computeEdgeWeightsPassByPass().
void computeEdgeWeightsInto(const ColorImage& image,
                            const EdgeWeightSettings& settings,
                            PlanarImage& weights, EdgeWeightScratch& scratch,
                            int threads);
/// The same in passes over whole planes (luminance, smoothing, gradients,
/// weights) for any settings: the oracle of the one-pass case.
void computeEdgeWeightsPassByPass(const ColorImage& image,
                                  const EdgeWeightSettings& settings,
                                  PlanarImage& weights,
                                  EdgeWeightScratch& scratch, int threads);

/// Validates the problem and builds the finest level (its guide points to the
/// problem's image, which must outlive it): f_l in the optical
/// frame (unit, 0 where missing), c_l = lambda * weight_l * confidence * valid
/// (0 where facing away in hard mode) times the density correction, the data
/// terms' Huber thresholds and the edge weights (weakened inside holes).
PreparedLevel prepareFinest(const FusionProblem& problem,
                            const SolverSettings& settings);
/// Each input's noise gain (estimateNoise()) kept across a stream's live
/// (warm, budgeted) frames: the gain describes the producer of an input (how
/// far its errors are shared between pixels), which does not change from one
/// frame to the next, while its estimate costs about 1 ms per input at 640x480.
struct NoiseGainMemory {
  /// Frames a kept gain is used for before it is estimated again.
  static constexpr int kFrames = 8;
  std::vector<float> gains;  ///< per input (empty: none kept)
  int uses = 0;              ///< frames the kept gains were used for

  /// Forgets the gains (the next frame estimates them).
  void clear() {
    gains.clear();
    uses = 0;
  }
};

/// The same into reused buffers, with `threads` threads. Returns false when
/// a set `cancel` (read between its steps) stopped it: the level is then
/// incomplete (not to be solved on). With `noise_gains`, a warm frame
/// (`reuse_noise_gains`) uses the kept gains for up to
/// NoiseGainMemory::kFrames frames, and an estimated gain is kept.
bool prepareFinestInto(const FusionProblem& problem,
                       const SolverSettings& settings, PreparedLevel& level,
                       EdgeWeightScratch& scratch, int threads,
                       const std::atomic<bool>* cancel = nullptr,
                       NoiseGainMemory* noise_gains = nullptr,
                       bool reuse_noise_gains = false);

/// Multiplies the edge weights of the links between two pixels that no input
/// observes by `factor` (SolverSettings::hole_link_weight).
void weakenHoleLinks(PreparedLevel& level, float factor, int threads);

/// The local statistics of one prepared input (SolverSettings: data_eps,
/// data_eps_local, density_power, local_radius): reads f (3 planes, 0 where
/// missing), writes the Huber thresholds delta (1 plane; only when the
/// unsquared penalty has a threshold) and scales the weights c (1 plane) by
/// the density correction.
/// With `mean_spread` (4 planes), also writes each window's normalized mean
/// of f (0 where the input has no sample in it) and its spread s (-1 below 2
/// samples): what a warm start is checked against.
void applyLocalStatistics(const SolverSettings& settings,
                          const PlanarImage& data, PlanarImage& data_eps,
                          PlanarImage& data_weight, PlanarImage* mean_spread,
                          int threads);

/// E(n) of the fast backend: float terms summed per row, rows in double.
double energyFast(const PreparedLevel& level, double huber_eps,
                  DataPenalty penalty, const PlanarImage& normals,
                  int num_threads);

/// E(n) of docs/algorithm.md on a prepared level (double accumulation).
double energy(const PreparedLevel& level, double huber_eps, DataPenalty penalty,
              const PlanarImage& normals, int num_threads);

}  // namespace internal
}  // namespace normal_fusion
