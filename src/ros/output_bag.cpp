#include "normal_fusion/ros/output_bag.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace normal_fusion {
namespace node {

std::string withErrno(const std::string& what, int error) {
  if (error == 0) return what;
  return what + " (" + std::strerror(error) + ")";
}

OutputBag::OutputBag(const std::string& path) : path_(path), final_(path) {
  struct stat st {};
  const bool exists = ::stat(path.c_str(), &st) == 0;
  if (exists && S_ISDIR(st.st_mode)) fail("", EISDIR);
  if (exists && !S_ISREG(st.st_mode)) {
    open(path);
    return;
  }
  if (exists) {
    // A file the user may not write stays as it is (as with writing it in
    // place), though the rename would replace it.
    if (::access(path.c_str(), W_OK) != 0) {
      const int error = errno;
      fail("", error);
    }
    // Through a symbolic link: the bag replaces the file it points to.
    if (char* real = ::realpath(path.c_str(), nullptr)) {
      final_ = real;
      std::free(real);
    }
  }
  std::string temporary = final_ + ".partial-XXXXXX";
  const int fd = ::mkstemp(&temporary[0]);
  if (fd < 0) {
    const int error = errno;
    fail("", error);
  }
  temporary_ = temporary;
  // The mode of the file replaced, else the one of a new file (mkstemp
  // makes it 0600).
  mode_t mode = st.st_mode & 07777;
  if (!exists) {
    const mode_t mask = ::umask(0);
    ::umask(mask);
    mode = 0666 & ~mask;
  }
  ::fchmod(fd, mode);
  ::close(fd);
  open(temporary_);
}

void OutputBag::commit() {
  errno = 0;
  try {
    bag_->close();
  } catch (const std::exception& e) {
    const int error = errno;
    fail(e.what(), error);
  }
  closed_ = true;
  if (temporary_.empty()) return;
  if (::rename(temporary_.c_str(), final_.c_str()) != 0) {
    const int error = errno;
    fail("cannot rename " + temporary_ + " to " + final_, error);
  }
  temporary_.clear();
}

void OutputBag::open(const std::string& file) {
  bag_ = new rosbag::Bag;
  errno = 0;
  try {
    bag_->open(file, rosbag::bagmode::Write);
  } catch (const std::exception& e) {
    const int error = errno;
    discard();  // the destructor does not run after a throwing constructor
    fail(e.what(), error);
  }
}

void OutputBag::discard() {
  if (!temporary_.empty()) ::unlink(temporary_.c_str());
  temporary_.clear();
  if (closed_) delete bag_;
  bag_ = nullptr;
}

void OutputBag::fail(const std::string& what, int error) const {
  std::string text = "cannot write " + path_;
  if (!what.empty()) {
    text += ": " + withErrno(what, error);
  } else if (error != 0) {
    text += std::string(": ") + std::strerror(error);
  }
  throw FatalError(text);
}

}  // namespace node
}  // namespace normal_fusion
