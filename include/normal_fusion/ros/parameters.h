// Parameters of the ROS interface: every solver setting of the library plus the
// node's own (inputs, synchronization, warm start), read from one flat map of
// named values in one function that corrects invalid values with a warning.
//
// The map comes from the parameter server at start, from dynamic_reconfigure
// at run time, and from a YAML file in fuse_bag; the names are the same
// everywhere (config/normal_fusion.yaml lists them all with their defaults).
#pragma once

#include <map>
#include <string>
#include <variant>
#include <vector>

#include "normal_fusion/settings.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace node {

/// Most normal-map inputs a node takes (topics normals_0 .. normals_7).
constexpr int kMaxInputs = 8;
/// Default bound on an input image's pixels: 12 megapixels, above 4K UHD
/// (3840x2160) and 4000x3000 sensors.
constexpr int kDefaultMaxPixels = 12000000;

/// One parameter value as the parameter server types it.
using ParameterValue = std::variant<bool, int, double, std::string>;
/// Parameters by name (flat, relative to the node's private namespace).
using ParameterMap = std::map<std::string, ParameterValue>;

/// How a normal map of another resolution than the image is resampled to it.
enum class Resampling {
  kNearest,   ///< the nearest source pixel
  kBilinear,  ///< bilinear over the valid neighbours, renormalized
};

/// The settings of one normal-map input (topic normals_i).
struct InputSettings {
  double weight = 1.0;                       ///< weight of its data term, >= 0
  std::string orientation_name = "optical";  ///< preset or 9 numbers
  Orientation orientation;                   ///< parsed from orientation_name
  bool use_confidence = false;  ///< subscribe to confidence_i (32FC1)
  bool optional = false;        ///< sets form without it; it joins when present
};

/// Everything the node and fuse_bag are configured with.
struct NodeSettings {
  SolverSettings solver;

  int num_inputs = 1;  ///< normal-map inputs, 1 .. kMaxInputs
  std::vector<InputSettings> inputs =
      std::vector<InputSettings>(kMaxInputs);  ///< kMaxInputs entries

  // Synchronization.
  bool approximate_sync = true;  ///< false: stamps must be equal
  int queue_size = 5;            ///< messages kept per input topic
  double max_interval = 0.05;    ///< largest stamp spread of a set, seconds
  double missing_input_timeout = 5.0;  ///< warn when no set formed for so long

  /// Larger images are refused on arrival, before any buffer is sized.
  int max_pixels = kDefaultMaxPixels;

  // Diagnostics: the fused_normals rate expected (Hz); outside it the
  // frequency status warns.
  double expected_rate_min = 0.5;
  double expected_rate_max = 100.0;

  // Inputs.
  Resampling resampling = Resampling::kBilinear;
  /// Valid float normals must have |n| within 1 +- unit_tolerance (they are
  /// then normalized); a map with other vectors is rejected.
  double unit_tolerance = 0.1;

  // Warm start.
  bool warm_start = true;
  /// Largest stamp gap to warm-start over, on top of the time the previous
  /// set took to process (sets arriving meanwhile are dropped).
  double warm_start_max_gap = 0.5;
  std::string fixed_frame;   ///< non-empty: rotation-compensated via tf2
  double tf_timeout = 0.05;  ///< seconds to wait for the transform

  /// Each input averaged over the stream's frames before the solve (carried
  /// by the same rotation as the warm start); frames <= 1 = off.
  TemporalSettings temporal;
};

/// True for parameters that dynamic_reconfigure may change at run time; the
/// others (num_inputs, approximate_sync, queue_size, use_confidence_i,
/// optional_i, max_pixels, expected_rate_min / max) shape the subscriptions,
/// the arrival checks or the diagnostics and are read at start only.
bool isDynamicParameter(const std::string& name);

/// The range a numeric parameter accepts (inclusive; an open lower bound of 0
/// is the smallest positive double).
struct ParameterRange {
  std::string name;
  double min, max;
};

/// Every numeric parameter's range, as settingsFromParameters checks it (the
/// node also publishes them to dynamic_reconfigure clients).
std::vector<ParameterRange> numericParameterRanges();

/// Every parameter with the value `settings` gives it.
ParameterMap parametersFromSettings(const NodeSettings& settings);

/// The one place where parameters become settings. Starts from `base` (the
/// library's defaults at start, the settings in use when reconfiguring):
/// missing entries are added with its values; values of the wrong type,
/// non-finite, out of range or unparsable are refused and keep `base`'s
/// value, in `params` too, and each refusal appends a warning that names the
/// parameter, the value given and the value used (a non-integer for an
/// integer is rounded instead). A combination the library rejects refuses
/// the one parameter whose base value makes it valid. Unknown names are
/// reported likewise and left alone. Never throws.
NodeSettings settingsFromParameters(ParameterMap& params,
                                    std::vector<std::string>* warnings,
                                    const NodeSettings& base = NodeSettings());

/// Reads a flat YAML map of parameters (as `rosparam load` takes it) with the
/// types YAML gives the scalars. Throws InputError for an unreadable file or a
/// file that is not a map; nested values are skipped with a warning.
ParameterMap parametersFromYamlFile(const std::string& path,
                                    std::vector<std::string>* warnings);

/// A scalar typed as YAML (and rosparam) types it: true / false (also yes,
/// no, on, off), integers, floating-point numbers (also .inf, .nan), else a
/// string; `quoted` text is always a string.
ParameterValue parameterFromText(const std::string& text, bool quoted = false);

std::string toString(Resampling value);
/// "nearest" or "bilinear"; throws ParameterError otherwise.
Resampling parseResampling(const std::string& name);
/// The value as text (for warnings and tables).
std::string toString(const ParameterValue& value);

}  // namespace node
}  // namespace normal_fusion
