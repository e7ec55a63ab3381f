// The parts of `evaluate` (main.cpp describes the tool): options, scores,
// the filters compared, the cases and the report.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <limits>
#include <ostream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "eval/aloe.h"
#include "eval/castle.h"
#include "eval/depth_camera.h"
#include "eval/peers.h"
#include "eval/stereo.h"
#include "eval/synthetic.h"
#include "normal_fusion/bilateral.h"
#include "normal_fusion/depth.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/settings.h"
#include "normal_fusion/solver.h"
#include "normal_fusion/solver_options.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/types.h"

namespace evaluate {

namespace nf = normal_fusion;
namespace peers = normal_fusion::peers;
using Clock = std::chrono::steady_clock;

constexpr int kExitClaimFailed = 1;
constexpr int kExitUsageError = 2;
constexpr int kExitFailure = 3;

/// Half windows of the baseline and its two candidate spatial sigmas
/// (the paper's garbled fraction of w: 5w/3 or 3w/5).
constexpr std::array<int, 3> kHalfWindows{{3, 5, 7}};
constexpr int kNumSpatialChoices = 2;
constexpr int kNumBilateral = 3 * kNumSpatialChoices;
constexpr double kSigmaIntensity = 0.1;
/// The noise level of the example pictures.
constexpr double kExampleSigma = 0.5;
/// Range of the angular-error heat maps, degrees.
constexpr double kHeatmapMaxDeg = 45.0;
/// Family index of the paper's bilateral filter; peers follow from 1.
constexpr int kBilateralFamily = 0;

/// A malformed command line: unknown option, missing or bad value.
using UsageError = nf::cli::UsageError;

struct Options {
  std::string output_dir;
  int width = 320;
  int height = 240;
  bool quick = false;
  std::vector<int> scenes{0, 1, 2};
  std::vector<double> sigmas;  ///< empty: by --quick
  std::uint64_t seed = 2014;
  nf::SolverSettings settings;
  // Cases.
  bool run_paper = true;
  bool run_depth = true;
  bool run_fusion = true;
  bool run_castle = true;
  bool run_stream = true;
  bool run_estimators = true;  ///< depth-to-normals estimators (with rgbd)
  bool run_textured = true;    ///< textured scenes, depth-camera normals
  bool run_curved = true;      ///< curved objects
  bool run_depthcam = true;    ///< structured-light and time-of-flight
  bool run_stereo = true;      ///< a rendered stereo pair through SGBM
  bool run_aloe = true;        ///< Middlebury Aloe through SGBM
  // Depth-camera noise (depth and castle cases, depth input of the fusion).
  double depth_sigma_at_1m = 0.0015;
  double depth_dropout = 0.02;
  double depth_step_m = nf::synthetic::kDepthQuantizationM;
  // Fusion.
  double dense_sigma = 0.4;
  double sparse_density = 0.05;
  double sparse_sigma = 0.05;
  double sparse_weight = 1.0;
  // Castle.
  std::string castle_dir = nf::castle::kDefaultDirectory;
  int castle_frames = 5;  ///< 0: by --quick
  double castle_tolerance_m = nf::castle::LoadSettings().agreement_tolerance_m;
  // Streams.
  int stream_frames = 12;  ///< per sequence; 0: by --quick
  double stream_sigma = 0.4;
  nf::TemporalSettings temporal{20, 45.0};
  // Robot-like inputs.
  double curved_sigma = 0.3;       ///< paper noise of the curved case
  double stereo_baseline_m = 0.1;  ///< the rendered pair's baseline
  /// s0 of the depth normals' confidence in the robot cases.
  double confidence_sigma_scale =
      nf::depth::DepthNormalSettings().normal_sigma_scale;
  std::string aloe_dir = nf::aloe::kDefaultDirectory;
  bool help = false;
};

// --- options.cpp

void printUsage(std::ostream& out);
/// Throws UsageError for a malformed command line.
Options parseArguments(int argc, char** argv);

// --- scores.cpp

std::string fixed(double value, int digits);
std::string signedFixed(double value, int digits);
std::string percent(double share);

/// Accuracy of one map against the ground truth on one set of pixels.
struct Score {
  bool empty = true;  ///< no pixel evaluated (the metrics are then NaN)
  double psnr_db = std::numeric_limits<double>::quiet_NaN();
  nf::AngularErrorStats angles;
  /// Share of the set's pixels (with ground truth) that the map holds.
  double produced = 0.0;
};

/// Scores on the two pixel sets of a case: where an input holds a normal
/// ("valid") and where none does ("fill-in").
struct SplitScore {
  Score valid;
  Score fill;
};

bool validAt(const nf::NormalMap& normals, std::size_t i);
/// Scores `estimate` on the pixels of `mask` (> 0.5) with ground truth.
Score scoreOn(const nf::NormalMap& estimate, const nf::NormalMap& gt,
              const nf::ScalarMap& mask);
/// Mean over scenes: metrics over the scenes where the map has pixels,
/// the produced share over all scenes.
Score meanOf(const std::vector<Score>& scores);
SplitScore meanOf(const std::vector<SplitScore>& scores);
/// PSNR used to rank methods; an empty score ranks last.
double rankOf(const Score& score);

/// Filter settings that leave more than this share of the pixels without a
/// normal (normalized convolution that does not reach) rank after all that
/// do not: they would be scored on the easy pixels only.
constexpr double kMinProducedShare = 0.9;

/// How many times a filter's grid is extended past the edge its best
/// setting lies on (see CaseRunner::extendGrids).
constexpr int kMaxGridExtensions = 2;

/// True when setting a ranks above setting b.
bool ranksAbove(const Score& a, const Score& b);

/// Wall-clock seconds spent in one kind of work, and how often.
struct Timer {
  double seconds = 0.0;
  int calls = 0;
  double mean() const { return calls > 0 ? seconds / calls : 0.0; }
};

template <typename Work>
auto timed(Timer* timer, Work work) -> decltype(work()) {
  const auto start = Clock::now();
  auto result = work();
  timer->seconds += std::chrono::duration<double>(Clock::now() - start).count();
  ++timer->calls;
  return result;
}

/// Timers of the solver and of each filter family.
struct Timers {
  Timer solver;
  std::vector<Timer> filters;  ///< by family
};

nf::BilateralSettings bilateralSettings(int config, int num_threads);
std::string sigmaSLabel(int config);
std::string bilateralLabel(int config);
int numFamilies();
std::string familyName(int family);

/// One setting of one filter on one of the case's filter inputs.
struct Candidate {
  int family = kBilateralFamily;
  int variant = 0;  ///< index into the case's filter inputs
  int bilateral_config = 0;
  peers::PeerSetting peer;
  bool beyond_grid = false;  ///< added past the edge of the filter's grid
};

std::string candidateLabel(const Candidate& c,
                           const std::vector<std::string>& variant_names);
/// Every setting of every filter on every filter input.
std::vector<Candidate> allCandidates(int num_variants);
nf::NormalMap applyCandidate(const Candidate& c, const nf::NormalMap& input,
                             const nf::ColorImage& image, int num_threads);

/// Runs the regularizer (a fresh cold start) on the given inputs.
nf::NormalMap regularize(const nf::ColorImage& image,
                         const nf::CameraIntrinsics& K,
                         std::vector<nf::NormalInput> inputs,
                         const nf::SolverSettings& settings, Timer* timer);
nf::NormalInput inputOf(const nf::NormalMap& normals, double weight = 1.0);
std::uint64_t noiseSeed(const Options& options, int scene, int stream,
                        double sigma);

// --- case_runner.cpp

/// One scene (or frame) of a case: ground truth, guide and inputs.
struct SceneData {
  int scene_id = 0;
  nf::ColorImage image;
  nf::CameraIntrinsics K;
  nf::NormalMap gt;
  /// The inputs as given, each scored as a row of its own.
  std::vector<std::pair<std::string, nf::NormalMap>> inputs;
  /// What the filters may take, one per variant of the case.
  std::vector<nf::NormalMap> filter_inputs;
  /// Regularizer runs: a row name and the data terms.
  std::vector<std::pair<std::string, std::vector<nf::NormalInput>>> runs;
};

/// One row of a case's table.
struct Row {
  std::string method;
  std::string setting;  ///< empty for inputs and the regularizer
  std::vector<SplitScore> scenes;
  SplitScore mean;
};

struct CaseResult {
  std::string id;           ///< short name: "paper sigma 0.50", "depth", ...
  std::string title;        ///< heading of its tables
  double sigma = 0.0;       ///< paper case only
  bool has_fill = false;    ///< some pixels with ground truth lack every input
  double fill_share = 0.0;  ///< their share of the pixels with ground truth
  std::vector<std::string> variant_names;
  std::vector<int> scene_ids;  ///< scene ids (castle: frame numbers)
  std::vector<Row> rows;  ///< inputs, best of each filter, regularizer runs
  int num_inputs = 0;
  int first_filter_row = 0;  ///< bilateral, then the peers
  int regularizer_row = 0;   ///< the run the summary compares
  /// The regularizer with the producer's confidence as its data weight (the
  /// depth-derived robot cases), also in the summary; -1: none.
  int confidence_row = -1;
  std::vector<Candidate> best;  ///< per family
  std::vector<Candidate> candidates;
  std::vector<SplitScore> candidate_means;
};

/// Accumulates the scores of one case over its scenes.
class CaseRunner {
 public:
  CaseRunner(std::vector<std::string> variant_names, const Options& options,
             Timers* timers);

  /// Scores the inputs, every filter setting and the regularizer runs on one
  /// scene; the regularized maps are returned (for pictures).
  std::vector<nf::NormalMap> addScene(const SceneData& scene);

  /// Extends the grids past their edges where a filter's best setting lies
  /// on one, then ranks every filter's settings.
  CaseResult finish(const std::string& id, const std::string& title);

 private:
  /// What scoring a filter setting on a scene needs.
  struct StoredScene {
    nf::ColorImage image;
    nf::NormalMap gt;
    std::vector<nf::NormalMap> filter_inputs;
    nf::ScalarMap valid, fill;
  };

  SplitScore scoreCandidate(const Candidate& candidate,
                            const StoredScene& scene);
  /// Index of the family's best setting so far.
  int bestCandidate(int family) const;
  /// Where a peer's best setting lies on the edge of the values tried for
  /// one of its two parameters (on the same filter input), one geometric
  /// step further is tried, up to kMaxGridExtensions times: the peers are
  /// shown at their best, not at the best of a grid fixed beforehand.
  void extendGrids();

  std::vector<std::string> variant_names_;
  const Options& options_;
  Timers* timers_;
  std::vector<Candidate> candidates_;
  std::vector<std::vector<SplitScore>> candidate_scores_;
  std::vector<std::string> input_names_;
  std::vector<std::vector<SplitScore>> input_scores_;
  std::vector<std::string> run_names_;
  std::vector<std::vector<SplitScore>> run_scores_;
  std::vector<double> fill_shares_;
  std::vector<StoredScene> stored_;
  std::vector<int> scene_ids_;
};

/// The scene of the example pictures, kept with the case result.
struct Example {
  bool taken = false;
  std::string tag;  ///< part of the file names: "scene0_sigma0.50"
  std::string input_name, input_setting;
  nf::ColorImage image;
  nf::NormalMap gt, input, regularizer;
  double sigma = 0.0;  ///< paper case: the noise level it belongs to
  /// Also a panel of the normal maps (input, each method's result) beside
  /// the panel of their errors.
  bool normals_panel = false;
};

// --- cases_synthetic.cpp

std::vector<CaseResult> runPaperCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Example* example, Timers* timers);
/// Normals of a noisy depth map of each scene (the depth case's input and
/// the fusion's depth-derived dense input).
nf::NormalMap depthInput(const Options& options,
                         const nf::synthetic::Frame& frame, int scene);
std::string depthNoiseText(const Options& options);
CaseResult runDepthCase(const Options& options,
                        const std::vector<nf::synthetic::Frame>& frames,
                        Timers* timers);
std::vector<CaseResult> runFusionCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Timers* timers);

// --- cases_robot.cpp: textured scenes, curved objects, depth cameras

/// Normals of a simulated depth camera's depth, computed as a driver user
/// does: depth::depthToNormals at its defaults, `method`, with the camera's
/// noise coefficient; their confidence too (with s0 =
/// options.confidence_sigma_scale) when `confidence` is given.
nf::NormalMap cameraNormals(const Options& options,
                            const nf::synthetic::Frame& frame,
                            const nf::synthetic::DepthCameraModel& camera,
                            nf::depth::NormalMethod method, std::uint64_t seed,
                            nf::ScalarMap* confidence = nullptr);
std::string cameraText(const nf::synthetic::DepthCameraModel& camera);

/// The row name of the regularizer run with the producer's confidence.
extern const char* const kConfidenceRun;
/// The two regularizer runs of a depth-derived input: plain (every pixel
/// weight 1) and with `confidence` as the data weight.
std::vector<std::pair<std::string, std::vector<nf::NormalInput>>>
runsWithConfidence(const nf::NormalMap& normals,
                   const nf::ScalarMap& confidence);
/// CaseRunner::finish for a case whose scenes ran runsWithConfidence: the
/// plain run stays the one the summary compares, the other is its
/// confidence_row.
CaseResult finishWithConfidence(CaseRunner& runner, const std::string& id,
                                const std::string& title);

/// The textured scenes: one case per depth-normal method; the example is
/// the first scene with plane_fit.
std::vector<CaseResult> runTexturedCase(const Options& options,
                                        Example* example, Timers* timers);
/// Curved objects: paper noise and depth-camera normals.
std::vector<CaseResult> runCurvedCase(const Options& options, Timers* timers);
/// Structured light and time of flight, each with both methods, on the
/// rooms of --scenes.
std::vector<CaseResult> runDepthCameraCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames,
    Timers* timers);

// --- case_stereo.cpp: rendered stereo and Middlebury Aloe

/// Scene ids of the stereo case.
extern const std::array<int, 3> kStereoScenes;

/// The rendered stereo case and how correlated its depth error is.
struct StereoOutcome {
  bool ran = false;
  CaseResult result;
  /// Correlation of the depth error over z^2 between pixels 1, 4 and 16
  /// apart along a row, mean over the scenes: stereo's and, on the same
  /// scenes, the structured-light camera's.
  std::array<double, 3> correlation_stereo{}, correlation_camera{};
  double depth_share = 0.0;  ///< pixels with a stereo depth, mean
  Example example;           ///< the first scene
};

StereoOutcome runStereoCase(const Options& options, Timers* timers);

/// The Aloe case, or a note why it was skipped.
struct AloeOutcome {
  bool ran = false;
  std::string note;
  CaseResult result;
  int width = 0, height = 0;
  double gt_share = 0.0;     ///< pixels with ground-truth normals
  double depth_share = 0.0;  ///< of them, with an SGBM depth
  /// Mean angle (deg) between the ground truth's plane fits of two window
  /// sizes: what the whole-pixel steps leave in it.
  double gt_window_change_deg = 0.0;
  /// Mean angle (deg) that the same steps and fit leave on a rendered scene
  /// against its exact normals.
  double gt_floor_deg = 0.0;
  double depth_min_m = 0.0, depth_max_m = 0.0;  ///< of the ground truth
  Example example;
};

AloeOutcome runAloeCase(const Options& options, Timers* timers);

// --- case_castle.cpp

/// The castle case, or a note why it was skipped.
struct CastleOutcome {
  bool ran = false;
  std::string note;
  CaseResult result;
  std::vector<int> frames;
  double agreement = 0.0;     ///< mean share of depth pixels with ground truth
  int width = 0, height = 0;  ///< mean crop size
  Example example;            ///< the first frame
};

CastleOutcome runCastleCase(const Options& options, Timers* timers);
/// The Castle frames the castle cases use: options.castle_frames of them,
/// evenly spaced over the sequence.
std::vector<int> castleFrames(const Options& options);

// --- case_stream.cpp

/// One frame of a stream: what the solver gets, the ground truth, and the
/// camera's rotation since the previous frame.
struct StreamFrame {
  nf::FusionProblem problem;
  nf::NormalMap gt;
  std::array<double, 9> R_cur_prev{{1, 0, 0, 0, 1, 0, 0, 0, 1}};
};

/// The ways a stream is solved, in table order.
extern const std::array<const char*, 4> kStreamMethods;

/// Scores of one stream sequence: [method][frame].
struct StreamResult {
  std::string title;
  std::string tag;  ///< file name part: "synthetic", "castle"
  std::vector<std::vector<Score>> scores;
  double seconds_per_solve = 0.0;  ///< one solve, mean over every method
};

StreamResult runStream(const std::string& title, const std::string& tag,
                       const std::vector<StreamFrame>& frames,
                       const Options& options);
std::vector<StreamFrame> syntheticStream(const Options& options);
std::vector<StreamFrame> castleStream(const Options& options);
std::string streamTable(const StreamResult& r);
void writeStreamPlot(const std::string& path, const StreamResult& r,
                     const Options& options);

// --- case_depth_estimators.cpp

/// One row of a depth-estimators table: an estimator and one way of making
/// normals of its own.
struct EstimatorRow {
  std::string estimator;  ///< "plane_fit", "OpenCV FALS", ...
  std::string use;        ///< "own normals", "regularizer", ...
  std::string setting;    ///< the fast global smoother's best setting
  Score mean;             ///< mean over the data set's scenes
};

/// One data set's table.
struct EstimatorTable {
  std::string title;
  std::vector<EstimatorRow> rows;
};

/// The depth-estimators case: a table per data set, and why one is missing.
struct EstimatorsOutcome {
  std::vector<EstimatorTable> tables;
  std::string note;
  Timer solver;  ///< apart from Results::timers, which the set-up reports
};

EstimatorsOutcome runEstimatorsCase(
    const Options& options, const std::vector<nf::synthetic::Frame>& frames);
std::string estimatorsTable(const EstimatorTable& table);

// --- report.cpp: tables and CSV files

const Row& bilateralRow(const CaseResult& r);
std::string psnrTable(const std::vector<CaseResult>& results);
std::string angleTable(const std::vector<CaseResult>& results);
std::string caseTables(const CaseResult& r, const std::string& heading);
/// The case's summary line; a second one for its confidence_row.
std::string summaryLine(const CaseResult& r);
void writeCsv(const std::string& path, const std::vector<CaseResult>& cases);
/// Every filter setting's mean scores: the grids the best settings come from.
void writeGridCsv(const std::string& path,
                  const std::vector<CaseResult>& cases);

// --- pictures.cpp

/// PSNR against sigma for each method of the paper case.
void writePlot(const std::string& path, const std::vector<CaseResult>& results,
               const Options& options);
/// The example scene's pictures: normal maps and angular-error maps of every
/// method (same colour scale), and one panel of all error maps. Returns the
/// files written, the panel first.
std::vector<std::string> writeExamples(const std::string& dir,
                                       const Example& example,
                                       const CaseResult& result,
                                       const Options& options);

// --- main.cpp and markdown.cpp: the whole run

/// What every case produced.
struct Results {
  Timers timers;
  Example example;  ///< of the paper case
  std::vector<CaseResult> paper, fusion;
  CaseResult depth;
  CastleOutcome castle;
  std::vector<StreamResult> streams;
  EstimatorsOutcome estimators;
  std::vector<CaseResult> textured, curved, depthcam;
  Example textured_example;
  StereoOutcome stereo;
  AloeOutcome aloe;
  std::vector<CaseResult> all;  ///< every case with tables, in report order
  /// The paper's claim: the sigmas where the regularizer is not ahead of the
  /// best bilateral filter.
  std::vector<std::string> failures;
};

/// The files written beside results.md.
struct OutputFiles {
  std::string plot, csv, grid, markdown;
  std::vector<std::string> stream_plots, examples;
};

/// results.md: the set-up, the tables of every case, the summary and the
/// list of files.
std::string markdown(const Options& options, const Results& results,
                     const OutputFiles& files, double total_seconds);
/// Sections 7 - 11 of results.md: the cases of what robots feed the fusion.
std::string robotCasesText(const Options& options, const Results& results);

}  // namespace evaluate
