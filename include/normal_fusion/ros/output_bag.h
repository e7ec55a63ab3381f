// The output bag of the bag tools: written under a temporary name and renamed
// to its path only once complete, so that a failed run leaves no bag there.
#pragma once

#include <rosbag/bag.h>

#include <cerrno>
#include <stdexcept>
#include <string>

namespace normal_fusion {
namespace node {

/// An error that ends a bag tool's run: printed as one line "<tool>: <what>",
/// exit status 1.
class FatalError : public std::runtime_error {
 public:
  explicit FatalError(const std::string& what) : std::runtime_error(what) {}
};

/// `what`, with the text of `error` (an errno value) when there is one.
std::string withErrno(const std::string& what, int error);

/// The output bag. A regular file is written under a temporary name in its
/// directory and renamed to the output path by commit() only; until then (a
/// failed write, an error elsewhere) the destructor removes the temporary
/// file. A device or a pipe is written in place.
class OutputBag {
 public:
  /// Throws FatalError naming the path when it cannot be opened.
  explicit OutputBag(const std::string& path);
  ~OutputBag() { discard(); }

  OutputBag(const OutputBag&) = delete;
  OutputBag& operator=(const OutputBag&) = delete;

  template <typename M>
  void write(const std::string& topic, const ros::Time& stamp,
             const M& message) {
    errno = 0;
    try {
      bag_->write(topic, stamp, message);
    } catch (const std::exception& e) {
      const int error = errno;
      fail(e.what(), error);
    }
  }

  /// Closes the bag and gives it its name.
  void commit();

 private:
  void open(const std::string& file);
  /// Removes the temporary file. A bag not closed is left open, not
  /// deleted: rosbag::Bag's destructor would close it, write its index and,
  /// after a failed write, throw again (std::terminate).
  void discard();
  [[noreturn]] void fail(const std::string& what, int error) const;

  std::string path_;            ///< as given
  std::string final_;           ///< the file that becomes the bag
  std::string temporary_;       ///< written until commit(); empty when none
  rosbag::Bag* bag_ = nullptr;  ///< deleted once closed only (see discard())
  bool closed_ = false;
};

}  // namespace node
}  // namespace normal_fusion
