// Every setting of the solver in one plain struct with documented defaults.
#pragma once

#include <climits>
#include <string>

namespace normal_fusion {

/// Penalty phi of each data term.
enum class DataPenalty {
  kL2,         ///< |n - f|_2, robust (the paper's default)
  kSquaredL2,  ///< |n - f|_2^2 / 2, equals 1 - cos(angle) for unit vectors
};

/// How the camera intrinsics constrain the normals (all must face the camera).
enum class VisibilityMode {
  kOff,   ///< no constraint
  kHard,  ///< observations facing away from the camera get weight 0
  kSoft,  ///< every iterate is kept in n . r <= 0 (observations still pull)
};

/// Which image gradient drives the edge weights.
enum class EdgeColorMode {
  kLuminance,  ///< gradient of the Rec. 601 luminance
  kColorMax,   ///< per direction, the largest gradient magnitude of R, G and B
};

/// How the image gradient g of the edge weights is measured.
enum class EdgeGradient {
  kSobel,              ///< 3x3 Sobel / 8 (centred; the paper's choice)
  kForwardDifference,  ///< |I(x+1) - I(x)|: exactly between the coupled pixels
};

/// Shape of the edge-weight function of the gradient magnitude g.
enum class EdgeWeightFunction {
  kExponential,  ///< exp(-alpha g^beta)
  kRational,     ///< 1 / (1 + alpha g^beta)
};

/// Which implementation runs the inner iterations.
enum class SolverBackend {
  kFast,       ///< fused, multithreaded kernels
  kReference,  ///< plain, readable kernels: the oracle the fast path is tested
               ///< against
};

/// The defaults of the settings table (detail/settings_table.def), by
/// parameter name: the fields below start from these.
namespace settings_default {
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  constexpr double name = def;
#define NF_DOUBLE_ABOVE(name, field, def, lo, hi, when, meaning, old) \
  constexpr double name = def;
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  constexpr int name = def;
#define NF_BOOL(name, field, def, when, meaning, old) constexpr bool name = def;
#define NF_ENUM(name, field, def, Type, values, when, meaning, old) \
  constexpr Type name = Type::def;
#include "normal_fusion/detail/settings_table.def"
}  // namespace settings_default

struct EdgeWeightSettings {
  bool enabled = settings_default::edge_enabled;  ///< false: w_h = w_v = 1
                                                  ///< (plain, unguided TV)
  /// Gaussian pre-smoothing of the guide in pixels (0: none). Raise it to
  /// 0.5 - 1 for guides with visible sensor noise.
  double smoothing_sigma = settings_default::edge_smoothing_sigma;
  double alpha = settings_default::edge_alpha;
  double beta = settings_default::edge_beta;
  double w_min =
      settings_default::edge_w_min;  ///< floor of the weights, in [0, 1]
  EdgeColorMode color_mode = settings_default::edge_color_mode;
  EdgeWeightFunction function = settings_default::edge_function;
  EdgeGradient gradient = settings_default::edge_gradient;
};

struct SolverSettings {
  // Model.
  // Defaults: the best set found by `evaluate` on the synthetic scenes (the
  // paper's own settings: docs/accuracy.md).
  double lambda =
      settings_default::lambda;  ///< global data weight (the paper's lambda)
  double huber_eps = settings_default::huber_eps;  ///< Huber threshold; 0 =
                                                   ///< plain total variation
  /// Second-order smoothness (total generalized variation of order 2):
  /// the smoothness term becomes min_v sum w_d |grad_d n - v_d| + alpha0
  /// |E v|, so that normals varying linearly (curved surfaces) cost nothing;
  /// 0 = off. Runs on the reference backend whatever `backend` says
  /// (docs/method.md).
  double tgv_alpha0 = settings_default::tgv_alpha0;
  DataPenalty penalty = settings_default::penalty;
  VisibilityMode visibility = settings_default::visibility;
  EdgeWeightSettings edges;
  /// Huber threshold delta(x) of the unsquared data terms (penalty l2), per
  /// pixel and input: c huber_delta(|n - f|), quadratic below delta (Gaussian
  /// noise is averaged), linear above (outliers pull with a bounded force);
  /// delta = 0 is the plain unsquared L2 of the paper.
  ///   delta(x) = data_eps + data_eps_local * s(x),
  ///   s(x) = sqrt(2 (1 - |mean of f over the window|)): the RMS spread of
  ///          the input around its local mean in the (2 local_radius + 1)^2
  ///          window (0 where fewer than 2 of its pixels are valid).
  /// Noisy regions of an input get a softer, smoothing data term, clean ones
  /// and sparse inputs keep the robust one. Computed from the inputs before
  /// the solve, so the energy stays convex and the outer loop monotone.
  /// Ignored with the squared penalty.
  double data_eps = settings_default::data_eps;
  double data_eps_local = settings_default::data_eps_local;
  /// Density correction of the data weights: c(x) *= (window / valid)^p, the
  /// count of the input's valid pixels in the window around x. A sample of a
  /// sparse input stands for the pixels around it that the input misses, so
  /// a sparse, accurate input is not outvoted by a dense, noisy one; dense
  /// inputs keep their weight (window = valid). 0 = off.
  double density_power = settings_default::density_power;
  /// Half-size of the window of s(x) and of the density, in pixels (>= 1).
  int local_radius = settings_default::local_radius;
  /// Noise estimate across scales (docs/algorithm.md): the median spread
  /// of each input at radii local_radius, 2 local_radius, ... up to
  /// noise_radius, read as white noise would be; its gain g = the largest
  /// ratio of a wider radius's to the local one's (1 for white noise, more
  /// where neighbouring pixels share their error). With noise_radius >
  /// local_radius, delta(x) = data_eps + g data_eps_local s(x) and c(x) *=
  /// g^-noise_weight_power. Fixed before the solve. 0 = off.
  int noise_radius = settings_default::noise_radius;
  double noise_weight_power = settings_default::noise_weight_power;
  /// The noise estimate's spreads read around each window's least-squares
  /// plane of the normals (f as an affine function of the pixel offset)
  /// rather than around their mean: a curved surface's steady turn is not
  /// counted as noise, so its gain stays near 1. false = around the mean.
  bool noise_plane_residual = settings_default::noise_plane_residual;
  /// An input's confidence (NormalInput::confidence) divided by its mean
  /// over the pixels it observes: it then only ranks that input's
  /// observations, and the level of its data term stays lambda times its
  /// weight (and its noise estimate's), as without a confidence. false = the
  /// confidence multiplies the data weight as it is, so a producer's
  /// confidence that is low everywhere lowers the whole input.
  bool confidence_relative = settings_default::confidence_relative;
  /// Edge weights of the links between two pixels that no input observes are
  /// multiplied by this, in (0, 1] (1 = off): a pixel next to an
  /// observed surface and inside a hole (a dropout, a silhouette's rim)
  /// follows that surface rather than the empty region around it. Fixed
  /// before the solve. Lower values act like a larger lambda for sparse
  /// inputs, whose pixels are nearly all holes (docs/accuracy.md).
  double hole_link_weight = settings_default::hole_link_weight;
  /// Dynamic guidance (docs/method.md): the weight of each link becomes
  ///   w = w_img + dynamic_guidance (1 - w_img) exp(-(|n_p - n_q| / s)^2),
  /// s the chord of dynamic_guidance_deg, from the outer iterate n0 and
  /// updated at every accepted outer step, so that a texture edge where the
  /// normals agree smooths again while a crease still cuts. In [0, 1], 0 =
  /// off (the image weights alone).
  double dynamic_guidance = settings_default::dynamic_guidance;
  double dynamic_guidance_deg = settings_default::dynamic_guidance_deg;

  /// Local refinement of a warm start. The pixels that the warm start does
  /// not predict (NaN or zero normals: uncovered by a warp, or at an edge of
  /// the previous map) are filled from their known neighbours and the
  /// inputs; they, the pixels whose warm normal every observing input
  /// contradicts, the edges of the warm map (which a camera's translation
  /// moves) and the pixels within warm_refine_radius of these are solved
  /// first, every other pixel held fixed, for warm_refine_iterations inner
  /// iterations (outer steps of 5; not counted in max_total_inner_iterations,
  /// but stopped by the time budget; relative_tolerance stops it only after
  /// half of them); the whole image follows without a time budget (with one,
  /// the warm frame ends with the refinement). Costs in proportion to those
  /// pixels, not the image. 0 = off.
  int warm_refine_iterations = settings_default::warm_refine_iterations;
  int warm_refine_radius = settings_default::warm_refine_radius;
  /// Face correction of a warm start, after the local refinement: the
  /// faces of the map (4-connected pixels whose neighbours' normals lie
  /// within warm_face_degrees, of at least 64 pixels; the 64 largest) each
  /// turn by one tangent direction, found by warm_face_steps damped Newton
  /// steps on a quadratic model of E, each kept only when E falls (under a
  /// time budget, as many as fit in the time the refinement leaves). It
  /// corrects the error over whole faces that a moving camera's stream
  /// gathers and the local refinement does not reach. 0 = off.
  int warm_face_steps = settings_default::warm_face_steps;
  double warm_face_degrees = settings_default::warm_face_degrees;
  /// Under a time budget the correction gets only the time the refinement
  /// leaves, which on a slow core may be none for many frames while the
  /// error it corrects gathers: a warm frame that follows warm_face_period
  /// frames without a face step ends its refinement early enough for the
  /// correction's set-up and one step. 0 = never.
  int warm_face_period = settings_default::warm_face_period;

  // Iterations and stopping.
  int inner_iterations =
      settings_default::inner_iterations;  ///< Chambolle-Pock iterations per
                                           ///< outer step
  int max_outer_iterations =
      settings_default::max_outer_iterations;  ///< majorize-minimize steps
                                               ///< (cap)
  int max_total_inner_iterations =
      settings_default::max_total_inner_iterations;  ///< cap over all outer
                                                     ///< steps and levels
  double relative_tolerance =
      settings_default::relative_tolerance;  ///< stop when (E_prev - E) /
                                             ///< E_prev falls below
  double time_budget_ms =
      settings_default::time_budget_ms;  ///< wall-clock budget; 0 = none
                                         ///< (anytime)
  /// The budget of a stream's cold start: a solve asked to warm-start whose
  /// state cannot be used (empty, or of another size), while time_budget_ms
  /// is set. 0 = none (the iteration caps and the tolerance end it), > 0 =
  /// this many ms. Warm frames carry a cold start's map on and refine only
  /// where the view changed, so a stream's quality is set by how well its
  /// first frame was solved: cut to a live frame's budget it leaves a much
  /// worse map for many frames (docs/experiments/2026-11.md).
  /// Solves not asked to warm-start keep time_budget_ms.
  double cold_start_budget_ms = settings_default::cold_start_budget_ms;

  /// Coarse-to-fine levels on a cold start: 1 = off, 0 = automatic (used when
  /// some pixels have no valid input), n > 1 = exactly n levels (fewer if the
  /// image gets too small).
  int pyramid_levels = settings_default::pyramid_levels;
  /// Coarse-to-fine also carries the duals (the smoothness duals copied,
  /// the data duals halved, as the coarser level's data weights are doubled)
  /// to the finer level, which then starts near its equilibrium; false: the
  /// duals restart from 0 at every level.
  bool prolong_duals = settings_default::prolong_duals;
  /// A cold start's normals (the coarsest level's with the pyramid): 0 =
  /// the first input with data per pixel; r > 0 = the inputs' data-weighted
  /// mean smoothed by the domain transform's recursive filter over about r
  /// pixels, its links cut by the edge weights, so that the iterations start
  /// near a smooth solution rather than at the noise.
  int cold_filter_radius = settings_default::cold_filter_radius;

  // Execution.
  int num_threads =
      settings_default::num_threads;  ///< 0 = all hardware threads
  /// The local refinement of a warm start measures its steps and runs on one
  /// thread while that is faster than num_threads (a machine whose other
  /// work holds a thread back at its frequent barriers). The results are the
  /// same bits either way; false: always num_threads.
  bool adaptive_refine_threads = settings_default::adaptive_refine_threads;
  SolverBackend backend = settings_default::backend;
  /// Automatic steps: diagonal preconditioning (tau = 1 / (4 + L), sigma =
  /// 1/2 for the differences and 1 for the data terms) when true, else the
  /// scalar steps tau = sigma = 0.99 / sqrt(8 + L).
  bool preconditioning = settings_default::preconditioning;
  /// Explicit step sizes (override the automatic ones); 0 = automatic. When
  /// set, tau * sigma * (8 + L) must be below 1.
  double tau = settings_default::tau;
  double sigma = settings_default::sigma;
  /// Balance of the automatic steps between the normals and the duals:
  /// tau *= step_balance and every sigma /= step_balance; tau * sigma, and
  /// with it the convergence guarantee, are unchanged. Below 1 the duals
  /// take the larger steps. 1 = the steps above; in [1e-3, 1e3]; not applied
  /// to explicit tau and sigma, nor to the warm start's local refinement and
  /// the pyramid's coarser levels, which keep 1 (their normals start far
  /// from their solution: filled in, or cold). 0.25 because it reaches the
  /// converged energy sooner than 1 (docs/performance.md, time to solution).
  double step_balance = settings_default::step_balance;
  /// Relaxed Chambolle-Pock (Condat 2013; Chambolle & Pock 2016) on the
  /// whole-image levels: each inner iteration moves the normals and the
  /// duals rho times its plain step, x <- x + rho (x_hat - x); rho in
  /// [1, 1.95] (convergent for rho < 2 under the same step condition). 1 =
  /// the plain iteration; the warm start's local refinement keeps 1.
  double over_relaxation = settings_default::over_relaxation;

  /// Throws ParameterError naming the first setting that is out of the
  /// table's range (settings_table.def) or a bad step pair.
  void validate() const;
};

/// The threads a `num_threads` setting stands for: itself when > 0, else
/// (0 = all) the processors OpenMP sees, at least 1.
int resolveThreadCount(int num_threads);

/// Parses "l2" / "squared_l2", "off" / "hard" / "soft", "luminance" /
/// "color_max", "exponential" / "rational", "sobel" / "forward_difference",
/// "fast" / "reference". Throws ParameterError.
DataPenalty parseDataPenalty(const std::string& name);
VisibilityMode parseVisibilityMode(const std::string& name);
EdgeColorMode parseEdgeColorMode(const std::string& name);
EdgeWeightFunction parseEdgeWeightFunction(const std::string& name);
EdgeGradient parseEdgeGradient(const std::string& name);
SolverBackend parseSolverBackend(const std::string& name);
std::string toString(DataPenalty value);
std::string toString(VisibilityMode value);
std::string toString(EdgeColorMode value);
std::string toString(EdgeWeightFunction value);
std::string toString(EdgeGradient value);
std::string toString(SolverBackend value);

}  // namespace normal_fusion
