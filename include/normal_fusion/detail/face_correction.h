// The face correction of a warm start (docs/algorithm.md, "The face
// correction"): one turn per face of the warm map, found by damped Newton
// steps on a quadratic model of E with a line search, each step kept only
// when E falls. It moves whole faces at once, the low-frequency error that the
// local refinement carries about one pixel per iteration.
#pragma once

#include <cstddef>
#include <functional>
#include <vector>

#include "normal_fusion/detail/solver_internal.h"

namespace normal_fusion {
namespace internal {

/// Faces smaller than this many pixels are not corrected (the noise and the
/// map's edges, which the local refinement solves).
constexpr int kMinFacePixels = 64;

/// dE/dn at every pixel (the data terms and the Huber smoothness of
/// reference::energy(), edge weights as the level holds them), projected onto
/// the pixel's tangent plane at `normals`: g <- (I - n n^T) dE/dn. The
/// readable oracle of FaceCorrection::buildModel()'s gradient.
void tangentEnergyGradient(const PreparedLevel& level, double huber_eps,
                           DataPenalty penalty, const PlanarImage& normals,
                           PlanarImage& gradient, int threads);

/// labelFaces()' buffers: the runs of each row (a run: pixels joined to
/// their left neighbour), their trees, and the neighbour tests.
struct FaceLabelScratch {
  /// Run k of row y is entry y W + k: its first pixel, its tree's parent
  /// (then its face).
  std::vector<int> run_start, run_parent;
  std::vector<int> row_runs;  ///< runs per row
  /// Per pixel: close to the pixel on the right / below.
  std::vector<unsigned char> right, down;

  void reserve(std::size_t pixels, int height);
  void fit(std::size_t pixels, int height);
  std::size_t bytesHeld() const;
};

/// The faces of a map: 4-connected components of pixels whose neighbours'
/// normals lie within `degrees` of each other; a face of fewer than
/// kMinFacePixels pixels gets -1. Returns the number of faces (labels 0 ..
/// count - 1, in the raster order of each face's first pixel). The
/// components are joined run by run (serial work in proportion to the runs,
/// not the pixels); rows are scanned and written on `threads` threads.
int labelFaces(const PlanarImage& normals, double degrees,
               std::vector<int>& label, FaceLabelScratch& scratch,
               int threads = 1);

/// At most this many faces (the largest) are corrected: their Newton
/// system is dense, 3 kMaxFaces unknowns.
constexpr int kMaxFaces = 64;

/// The state of one frame's correction and its buffers (allocated once per
/// size by reserve()).
class FaceCorrection {
 public:
  /// E of a candidate map (the backend's energy on the level).
  using EnergyFunction = std::function<double(const PlanarImage&)>;

  /// Sizes every buffer for W x H maps and steps on `threads` threads.
  void reserve(int width, int height, int threads);
  /// Gives back the buffers sized for much larger maps than W x H.
  void fit(int width, int height);
  /// Labels the faces of `n0` (within `degrees`; the kMaxFaces largest),
  /// measures E(n0); returns the number of faces.
  int begin(const PlanarImage& n0, double degrees,
            const EnergyFunction& energy_of, int threads = 1);
  /// One damped Newton step on one tangent direction per face: the
  /// quadratic model (buildModel), (M + damping) D = -G, then the line
  /// search (the full step, or when it does not lower E the minimum of the
  /// parabola through E(0), E'(0) and E(1)). `n0` takes the candidate when
  /// it is below E(n0); returns whether it did.
  bool step(const PreparedLevel& level, double huber_eps, DataPenalty penalty,
            bool soft_visibility, const EnergyFunction& energy_of,
            PlanarImage& n0, int threads);
  /// The model of E(n(D)) - E(n0) ~ G . D + D^T M D / 2 at `n0`: G_f the
  /// face's sum of tangent gradients, M the pixels' Hessians on the sphere
  /// plus the links between different faces (links inside a face, which a
  /// common turn leaves almost unchanged, are left out).
  void buildModel(const PreparedLevel& level, double huber_eps,
                  DataPenalty penalty, const PlanarImage& n0, int threads);
  /// candidate = n0 + alpha u, u = (I - n0 n0^T) D_f on face f (the
  /// labels of begin(); `direction` holds D_f's x, y, z per face),
  /// normalized and in soft mode projected onto the visible set as
  /// projectVisible() does; n0 off the faces.
  void candidateAt(const PreparedLevel& level, bool soft_visibility,
                   const PlanarImage& n0, const std::vector<double>& direction,
                   double alpha, PlanarImage& candidate, int threads);
  const std::vector<double>& modelGradient() const { return gradient_; }
  const std::vector<double>& modelHessian() const { return hessian_; }
  const std::vector<int>& labels() const { return label_; }
  double energy() const { return energy_; }
  int faces() const { return faces_; }
  std::size_t bytesHeld() const;

 private:
  static constexpr double kInitialDamping = 1e-2;
  static constexpr double kMinDamping = 1e-4;
  static constexpr double kMaxDamping = 1e4;
  /// The majorizers' curvatures c / |r| and w / |d| are capped where |r|,
  /// |d| are below this.
  static constexpr double kMinResidual = 1e-2;

  /// Doubles of one thread's model sums for `faces` faces.
  static std::size_t modelDoubles(int faces);
  void keepLargestFaces();
  /// direction_ = -(M + damping diag)^-1 G (Cholesky); false when not
  /// positive definite.
  bool solveDamped(double damping);

  std::vector<int> label_, face_size_, face_order_;
  FaceLabelScratch label_scratch_;
  std::vector<double> gradient_, direction_, hessian_, factor_;
  std::vector<float> directions_float_;  ///< direction_ in float
  std::vector<double> thread_sums_;      ///< per-thread sums of buildModel()
  std::vector<float> row_scratch_;       ///< per-thread rows of buildModel()
  PlanarImage trial_;
  int faces_ = 0;
  double energy_ = 0.0, damping_ = kInitialDamping;
};

}  // namespace internal
}  // namespace normal_fusion
