// Text helpers shared by the Castle loader (castle.cpp) and its model files
// (castle_model.cpp).
#pragma once

#include <string>
#include <vector>

namespace normal_fusion {
namespace castle {
namespace internal {

/// The whole file; throws InputError when it cannot be opened.
std::string readText(const std::string& path);

/// Numbers of a text, separators being anything that cannot start a number.
std::vector<double> numbersIn(const std::string& text);

/// The text between `open` (searched from `from`) and the next `close`;
/// `after` (may be null) gets the position past `close`.
bool between(const std::string& text, const std::string& open,
             const std::string& close, std::size_t from, std::string* inner,
             std::size_t* after);

}  // namespace internal
}  // namespace castle
}  // namespace normal_fusion
