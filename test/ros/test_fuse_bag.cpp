// fuse_bag, run as a program on a synthetic bag (no master).
#include <gtest/gtest.h>
#include <normal_fusion/FusionStats.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "bag_test_util.h"

namespace nf = normal_fusion;
namespace fs = std::filesystem;

namespace {

struct ToolRun {
  int status = -1;     ///< exit code; -1 when killed by a signal
  int signal = 0;      ///< the signal that ended it, 0 when it exited
  std::string output;  ///< stdout and stderr together
};

/// Runs fuse_bag with `args` through /bin/sh, after the shell commands
/// `prefix` (e.g. "ulimit -f 100;"); the shell execs the binary, so the
/// status is the tool's own.
ToolRun run(const std::string& args, const std::string& prefix = "") {
  ToolRun r;
  const std::string command =
      prefix + " exec " + std::string(FUSE_BAG_BIN) + " " + args + " 2>&1";
  FILE* pipe = popen(command.c_str(), "r");
  char buffer[512];
  while (pipe && std::fgets(buffer, sizeof(buffer), pipe)) r.output += buffer;
  const int status = pipe ? pclose(pipe) : -1;
  if (status != -1 && WIFEXITED(status)) r.status = WEXITSTATUS(status);
  if (status != -1 && WIFSIGNALED(status)) r.signal = WTERMSIG(status);
  return r;
}

std::string tempDir() {
  char dir[] = "/tmp/nf_fuse_bag_XXXXXX";
  return mkdtemp(dir);
}

std::string readBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream bytes;
  bytes << in.rdbuf();
  return bytes.str();
}

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

/// The names in a directory.
std::set<std::string> listDir(const std::string& dir) {
  std::set<std::string> names;
  for (const auto& entry : fs::directory_iterator(dir)) {
    names.insert(entry.path().filename().string());
  }
  return names;
}

/// The number of lines of a text (its newlines).
long lines(const std::string& text) {
  return std::count(text.begin(), text.end(), '\n');
}

/// The failure contract: a clean exit with status 1 (no signal, no abort),
/// the last line an error of the tool that contains `needle`.
void expectFailure(const ToolRun& r, const std::string& needle) {
  EXPECT_EQ(r.signal, 0) << "killed by signal " << r.signal << ":\n"
                         << r.output;
  EXPECT_EQ(r.status, 1) << r.output;
  ASSERT_FALSE(r.output.empty());
  EXPECT_EQ(r.output.back(), '\n') << r.output;
  const std::size_t start = r.output.rfind('\n', r.output.size() - 2);
  const std::string last =
      r.output.substr(start == std::string::npos ? 0 : start + 1);
  EXPECT_EQ(last.rfind("fuse_bag: ", 0), 0u) << r.output;
  EXPECT_NE(last.find(needle), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("terminate called"), std::string::npos) << r.output;
}

/// Byte offsets of the message data records of a bag (format 2.0), in the
/// order they were written. A record is: header length (uint32), the header
/// fields "conn=" (uint32), "op=" 0x02, "time=" (uint64), each prefixed by
/// its length, then the data length (uint32) and the serialized message.
std::vector<std::size_t> messageRecords(const std::string& bag) {
  const char op_field[] = {4, 0, 0, 0, 'o', 'p', '=', 2};
  const char conn_field[] = {9, 0, 0, 0, 'c', 'o', 'n', 'n', '='};
  const std::string op(op_field, sizeof(op_field));
  const std::string conn(conn_field, sizeof(conn_field));
  std::vector<std::size_t> records;
  for (std::size_t at = bag.find(op); at != std::string::npos;
       at = bag.find(op, at + 1)) {
    if (at >= 17 && bag.compare(at - 13, conn.size(), conn) == 0) {
      records.push_back(at - 17);
    }
  }
  return records;
}

std::uint32_t readU32(const std::string& bytes, std::size_t at) {
  std::uint32_t v = 0;
  std::memcpy(&v, bytes.data() + at, 4);
  return v;
}

void writeU32(std::string& bytes, std::size_t at, std::uint32_t v) {
  std::memcpy(&bytes[at], &v, 4);
}

TEST(FuseBag, WritesOneOutputPerSetWithTheImageStamps) {
  ros::Time::init();
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 5);
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --num-inputs 2 --set num_threads=2 --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("frames fused:       5 (4 warm-started)"),
            std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("solve time / frame"), std::string::npos);
  const auto images =
      nf::test::readTopic<sensor_msgs::Image>(dir + "/in.bag", "/image");
  const auto fused = nf::test::readTopic<sensor_msgs::Image>(dir + "/out.bag",
                                                             "/fused_normals");
  const auto vis = nf::test::readTopic<sensor_msgs::Image>(
      dir + "/out.bag", "/fused_normals_vis");
  const auto stats =
      nf::test::readTopic<nf::FusionStats>(dir + "/out.bag", "/fusion_stats");
  ASSERT_EQ(fused.size(), images.size());
  EXPECT_EQ(vis.size(), images.size());
  EXPECT_EQ(stats.size(), images.size());
  for (const auto& [stamp, image] : images) {
    ASSERT_EQ(fused.count(stamp), 1u);
    EXPECT_EQ(fused.at(stamp)->header.frame_id, image->header.frame_id);
    EXPECT_EQ(fused.at(stamp)->width, image->width);
    EXPECT_EQ(stats.at(stamp)->inputs_present,
              (std::vector<std::uint8_t>{1, 1}));
  }
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, ParametersFromTheFileAndTheCommandLine) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 2);
  {
    FILE* f = std::fopen((dir + "/p.yaml").c_str(), "w");
    std::fputs("num_inputs: 2\ninner_iterations: 7\nlambda: -1\n", f);
    std::fclose(f);
  }
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --params " + dir +
                        "/p.yaml --set max_outer_iterations=1 --set "
                        "pyramid_levels=1 --no-vis --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("'lambda' = -1"), std::string::npos) << r.output;
  const auto stats =
      nf::test::readTopic<nf::FusionStats>(dir + "/out.bag", "/fusion_stats");
  ASSERT_EQ(stats.size(), 2u);
  for (const auto& entry : stats) {
    EXPECT_EQ(entry.second->inner_iterations, 7u);
    EXPECT_EQ(entry.second->outer_iterations, 1u);
  }
  EXPECT_TRUE(nf::test::readTopic<sensor_msgs::Image>(dir + "/out.bag",
                                                      "/fused_normals_vis")
                  .empty());
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, RotationCompensatedWarmStartFromTheBagsTf) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 3, true);
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --num-inputs 2 --set fixed_frame=world "
                        "--set num_threads=2 --no-vis");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("3 transforms from /tf"), std::string::npos)
      << r.output;
  const auto stats =
      nf::test::readTopic<nf::FusionStats>(dir + "/out.bag", "/fusion_stats");
  ASSERT_EQ(stats.size(), 3u);
  int compensated = 0;
  for (const auto& entry : stats) {
    compensated += entry.second->rotation_compensated;
    EXPECT_EQ(entry.second->rotation_compensated, entry.second->warm_started);
  }
  EXPECT_EQ(compensated, 2);
  // Without the transforms: a warning, and cold starts.
  nf::test::writeSyntheticBag(dir + "/no_tf.bag", 2);
  const ToolRun cold = run("--input " + dir + "/no_tf.bag --output " + dir +
                           "/out2.bag --num-inputs 2 --set fixed_frame=world");
  ASSERT_EQ(cold.status, 0) << cold.output;
  EXPECT_NE(cold.output.find("cold start"), std::string::npos) << cold.output;
  EXPECT_NE(cold.output.find("frames fused:       2 (0 warm-started)"),
            std::string::npos)
      << cold.output;
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, FailsClearly) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 1);
  ToolRun r = run("--output " + dir + "/out.bag");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.output.find("--input and --output are required"),
            std::string::npos);
  r = run("--input " + dir + "/missing.bag --output " + dir + "/out.bag");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.output.find("cannot read"), std::string::npos);
  // Three inputs asked for, the bag has two.
  r = run("--input " + dir + "/in.bag --output " + dir +
          "/out.bag --num-inputs 3 --quiet");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.output.find("no messages on: /normals_2"), std::string::npos)
      << r.output;
  r = run("--input " + dir + "/in.bag --output " + dir + "/out.bag --bogus");
  EXPECT_EQ(r.status, 2);
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, RefusesToWriteOverItsInput) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 2);
  const std::string before = readBytes(dir + "/in.bag");
  ASSERT_FALSE(before.empty());
  fs::create_symlink(dir + "/in.bag", dir + "/link.bag");
  fs::create_hard_link(dir + "/in.bag", dir + "/hard.bag");
  // The same file under other names: spelled differently, through a
  // symbolic link, through a hard link.
  for (const std::string& output :
       {dir + "/in.bag", dir + "/./in.bag", dir + "//in.bag", dir + "/link.bag",
        dir + "/hard.bag"}) {
    SCOPED_TRACE(output);
    const ToolRun r = run("--input " + dir + "/in.bag --output " + output +
                          " --num-inputs 2 --quiet");
    expectFailure(r, "is the input bag");
    EXPECT_EQ(lines(r.output), 1) << r.output;
    EXPECT_EQ(readBytes(dir + "/in.bag"), before);
    EXPECT_EQ(listDir(dir),
              (std::set<std::string>{"in.bag", "link.bag", "hard.bag"}));
  }
  // The input named through the link, the output by its own name.
  const ToolRun r = run("--input " + dir + "/link.bag --output " + dir +
                        "/in.bag --num-inputs 2 --quiet");
  expectFailure(r, "is the input bag");
  EXPECT_EQ(readBytes(dir + "/in.bag"), before);
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, CorruptMessageRecordsAreSkippedCountedAndFail) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/good.bag", 4);
  const std::string good = readBytes(dir + "/good.bag");
  const std::vector<std::size_t> records = messageRecords(good);
  // Four frames of /camera_info, /normals_0, /normals_1, /image.
  ASSERT_EQ(records.size(), 16u);
  // Frame 1's /image.
  const std::size_t record = records[7];
  const std::uint32_t header_length = readU32(good, record);
  const std::size_t data_length_at = record + 4 + header_length;
  const std::uint32_t data_length = readU32(good, data_length_at);
  ASSERT_GT(data_length, 1000u);

  struct Case {
    std::string name, bytes, needle;
  };
  std::vector<Case> cases;
  {
    // An op code that is not "message data" (0x02).
    std::string bytes = good;
    bytes[record + 4 + 13 + 7] = '\x09';
    cases.push_back({"bad op code", bytes, "Expected MSG_DATA op not found"});
  }
  {
    // A header length that ends the header after its first field.
    std::string bytes = good;
    writeU32(bytes, record, 13);
    cases.push_back(
        {"bad header length", bytes, "Required 'op' field missing"});
  }
  {
    // A data length shorter than the serialized message.
    std::string bytes = good;
    writeU32(bytes, data_length_at, data_length - 16);
    cases.push_back({"truncated payload", bytes, "Buffer Overrun"});
  }
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    writeBytes(dir + "/in.bag", c.bytes);
    fs::remove(dir + "/out.bag");
    const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                          "/out.bag --num-inputs 2 --no-vis --quiet");
    expectFailure(r, "1 of 16 messages could not be read");
    EXPECT_NE(r.output.find("/image: unreadable message at 50.1"),
              std::string::npos)
        << r.output;
    EXPECT_NE(r.output.find(c.needle), std::string::npos) << r.output;
    EXPECT_NE(r.output.find("unreadable:         1 of 16 messages"),
              std::string::npos)
        << r.output;
    // The other frames are fused and written.
    EXPECT_NE(r.output.find("frames fused:       3"), std::string::npos)
        << r.output;
    const auto fused = nf::test::readTopic<sensor_msgs::Image>(
        dir + "/out.bag", "/fused_normals");
    EXPECT_EQ(fused.size(), 3u);
    EXPECT_EQ(fused.count(ros::Time(50.1)), 0u);
    EXPECT_EQ(listDir(dir),
              (std::set<std::string>{"good.bag", "in.bag", "out.bag"}));
  }
  // The file cut in the middle of that message's payload (its index, at the
  // end, is gone with the rest).
  writeBytes(dir + "/in.bag",
             good.substr(0, data_length_at + 4 + data_length / 2));
  fs::remove(dir + "/out.bag");
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                        "/out.bag --num-inputs 2 --quiet");
  expectFailure(r, "cannot read");
  EXPECT_EQ(lines(r.output), 1) << r.output;
  EXPECT_EQ(listDir(dir), (std::set<std::string>{"good.bag", "in.bag"}));
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, OutputThatCannotBeWrittenFails) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 3);
  // A device that is always full.
  ASSERT_TRUE(fs::is_character_file("/dev/full"));
  ToolRun r = run("--input " + dir +
                  "/in.bag --output /dev/full --num-inputs 2 --quiet");
  expectFailure(r, "cannot write /dev/full");
  EXPECT_NE(r.output.find("No space left on device"), std::string::npos)
      << r.output;
  EXPECT_TRUE(fs::is_character_file("/dev/full"));
  // A directory that does not exist.
  r = run("--input " + dir + "/in.bag --output " + dir +
          "/missing/out.bag --num-inputs 2 --quiet");
  expectFailure(r, "cannot write " + dir + "/missing/out.bag");
  EXPECT_EQ(lines(r.output), 1) << r.output;
  // A directory.
  r = run("--input " + dir + "/in.bag --output " + dir +
          " --num-inputs 2 --quiet");
  expectFailure(r, "cannot write " + dir);
  EXPECT_EQ(lines(r.output), 1) << r.output;
  EXPECT_EQ(listDir(dir), (std::set<std::string>{"in.bag"}));
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, FileSizeLimitReachedMidRunLeavesNoOutput) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 5);
  // 200 blocks (512 or 1024 bytes): less than the 5 fused frames and their
  // colour coding (about 100 kB a frame), more than the bag's first record.
  const ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                            "/out.bag --num-inputs 2 --quiet",
                        "ulimit -f 200;");
  expectFailure(r, "cannot write " + dir + "/out.bag");
  EXPECT_NE(r.output.find("File too large"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir + "/out.bag"));
  EXPECT_EQ(listDir(dir), (std::set<std::string>{"in.bag"}));
  std::system(("rm -rf " + dir).c_str());
}

TEST(FuseBag, SuccessLeavesOnlyTheOutput) {
  const std::string dir = tempDir();
  nf::test::writeSyntheticBag(dir + "/in.bag", 2);
  // An older output is replaced.
  writeBytes(dir + "/out.bag", "an older output");
  ToolRun r = run("--input " + dir + "/in.bag --output " + dir +
                  "/out.bag --num-inputs 2 --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(listDir(dir), (std::set<std::string>{"in.bag", "out.bag"}));
  EXPECT_EQ(nf::test::readTopic<sensor_msgs::Image>(dir + "/out.bag",
                                                    "/fused_normals")
                .size(),
            2u);
  // An output named through a symbolic link: the link stays, the bag is
  // written where it points.
  writeBytes(dir + "/target.bag", "");
  fs::create_symlink(dir + "/target.bag", dir + "/link.bag");
  r = run("--input " + dir + "/in.bag --output " + dir +
          "/link.bag --num-inputs 2 --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_TRUE(fs::is_symlink(dir + "/link.bag"));
  EXPECT_EQ(listDir(dir), (std::set<std::string>{"in.bag", "out.bag",
                                                 "target.bag", "link.bag"}));
  EXPECT_EQ(nf::test::readTopic<sensor_msgs::Image>(dir + "/target.bag",
                                                    "/fused_normals")
                .size(),
            2u);
  std::system(("rm -rf " + dir).c_str());
}

}  // namespace
