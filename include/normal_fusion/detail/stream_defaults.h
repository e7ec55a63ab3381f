// The defaults of the stream policy's settings, by parameter name, from the
// one table that declares them (detail/stream_settings_table.def).
#pragma once

namespace normal_fusion {
namespace stream_default {
#define NF_GROUP(name)
#define NF_DOUBLE(name, field, def, lo, hi, when, meaning, old) \
  constexpr double name = def;
#define NF_INT(name, field, def, lo, hi, when, meaning, old) \
  constexpr int name = def;
#define NF_BOOL(name, field, def, when, meaning, old) constexpr bool name = def;
#include "normal_fusion/detail/stream_settings_table.def"
#undef NF_GROUP
#undef NF_DOUBLE
#undef NF_INT
#undef NF_BOOL
}  // namespace stream_default
}  // namespace normal_fusion
