// Parameters of the ROS interface: every solver setting of the library plus the
// node's own (inputs, synchronization, warm start), read from one flat map of
// named values in one function that corrects invalid values with a warning.
//
// The map comes from the parameter server at start, from dynamic_reconfigure
// at run time, and from a YAML file in fuse_bag; the names are the same
// everywhere. Names, defaults and ranges come from the settings tables
// (normal_fusion/detail/settings_table.def for the solver,
// normal_fusion/ros/detail/node_settings_table.def for the node);
// docs/parameters.md lists them.
#pragma once

#include <climits>
#include <map>
#include <string>
#include <variant>
#include <vector>

#include "normal_fusion/settings.h"
#include "normal_fusion/settings_table.h"
#include "normal_fusion/temporal.h"
#include "normal_fusion/types.h"

namespace normal_fusion {
namespace node {

/// Most normal-map inputs a node takes (topics normals_0 .. normals_7).
constexpr int kMaxInputs = 8;

/// One parameter value as the parameter server types it.
using ParameterValue = SettingValue;
/// Parameters by name (flat, relative to the node's private namespace).
using ParameterMap = std::map<std::string, ParameterValue>;

/// How a normal map of another resolution than the image is resampled to it.
enum class Resampling {
  kNearest,   ///< the nearest source pixel
  kBilinear,  ///< bilinear over the valid neighbours, renormalized
};

/// The defaults of the node's settings table, by parameter name (per input:
/// by stem).
namespace node_default {
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  constexpr double name = def;
#define NF_INPUT_DOUBLE NF_DOUBLE
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  constexpr int name = def;
#define NF_BOOL(name, field, def, when, meaning, old) constexpr bool name = def;
#define NF_INPUT_BOOL NF_BOOL
#define NF_ENUM(name, field, def, Type, values, when, meaning, old) \
  constexpr Type name = Type::def;
#define NF_STRING(name, field, def, when, meaning, old) \
  constexpr const char* name = def;
#define NF_INPUT_ORIENTATION NF_STRING
#include "normal_fusion/ros/detail/node_settings_table.def"
}  // namespace node_default

/// Default bound on an input image's pixels: 12 megapixels, above 4K UHD
/// (3840x2160) and 4000x3000 sensors.
constexpr int kDefaultMaxPixels = node_default::max_pixels;

/// The settings of one normal-map input (topic normals_i).
struct InputSettings {
  double weight = node_default::weight;  ///< weight of its data term, >= 0
  /// A preset or 9 numbers.
  std::string orientation_name = node_default::orientation;
  /// Parsed from orientation_name (the default's, optical, is the identity).
  Orientation orientation;
  /// Subscribe to confidence_i (32FC1).
  bool use_confidence = node_default::use_confidence;
  /// Sets form without it; it joins when present.
  bool optional = node_default::optional;
};

/// Everything the node and fuse_bag are configured with.
struct NodeSettings {
  SolverSettings solver;

  int num_inputs = node_default::num_inputs;  ///< 1 .. kMaxInputs
  std::vector<InputSettings> inputs =
      std::vector<InputSettings>(kMaxInputs);  ///< kMaxInputs entries

  // Synchronization.
  bool approximate_sync = node_default::approximate_sync;  ///< false: equal
  int queue_size = node_default::queue_size;  ///< messages kept per topic
  /// Largest stamp spread of a set, seconds.
  double max_interval = node_default::max_interval;
  /// Warn when no set formed for so long, seconds.
  double missing_input_timeout = node_default::missing_input_timeout;

  /// Larger images are refused on arrival, before any buffer is sized.
  int max_pixels = kDefaultMaxPixels;

  // Diagnostics: the fused_normals rate expected (Hz); outside it the
  // frequency status warns.
  double expected_rate_min = node_default::expected_rate_min;
  double expected_rate_max = node_default::expected_rate_max;

  // Inputs.
  Resampling resampling = node_default::resampling;
  /// Valid float normals must have |n| within 1 +- unit_tolerance (they are
  /// then normalized); a map with other vectors is rejected.
  double unit_tolerance = node_default::unit_tolerance;

  // Warm start.
  bool warm_start = node_default::warm_start;
  /// Largest stamp gap to warm-start over, on top of the time the previous
  /// set took to process (sets arriving meanwhile are dropped).
  double warm_start_max_gap = node_default::warm_start_max_gap;
  /// Non-empty: rotation-compensated via tf2.
  std::string fixed_frame = node_default::fixed_frame;
  /// Seconds to wait for the transform.
  double tf_timeout = node_default::tf_timeout;
  /// Subscribe to `depth` (aligned with the image): with fixed_frame the
  /// warm start follows the full motion (tf2's translation too) through it.
  bool use_depth = node_default::use_depth;

  /// Each input averaged over the stream's frames before the solve (carried
  /// by the same rotation as the warm start); frames <= 1 = off.
  TemporalSettings temporal = {node_default::temporal_frames,
                               node_default::temporal_gate_deg};
};

/// The node's own settings (not the solver's) in the order of their table;
/// per-input ones (per_input) stand for name_0 .. name_{kMaxInputs-1}.
const std::vector<SettingDescriptor>& nodeSettingDescriptors();

/// True for parameters that dynamic_reconfigure may change at run time (the
/// tables' DYNAMIC); the others shape the subscriptions, the arrival checks
/// or the diagnostics and are read at start only.
bool isDynamicParameter(const std::string& name);

/// The range a numeric parameter accepts (inclusive; an open lower bound is
/// the next double above it: the smallest positive double for 0).
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
