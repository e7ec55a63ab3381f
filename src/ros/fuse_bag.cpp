// fuse_bag: the node's processing offline, bag in, bag out, no master.
//
//   fuse_bag --input IN.bag --output OUT.bag [--params FILE.yaml]
//            [--set NAME=VALUE]... [--num-inputs N] [topic options]
//
// Reads the inputs with the rosbag C++ API in the bag's order, synchronizes
// them as the node does (same synchronizer, same checks), solves every set as
// fast as the solver runs (nothing is dropped: sets are processed one after
// the other) and writes the fused map, its colour coding and the statistics
// into OUT.bag with the images' stamps (header and bag time). With the
// parameter fixed_frame set, /tf and /tf_static of the bag feed the
// rotation-compensated warm start.
//
// The input is only read. OUT is written under a temporary name beside it
// and renamed to OUT at the end, after a complete write only: a failed run
// (a full disk, a file size limit, an error) leaves no bag at OUT and removes
// the temporary file. An OUT that is the input under any name is refused.
// Message records that cannot be read are skipped and counted; the run then
// ends with status 1.
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sys/stat.h>
#include <tf2_msgs/TFMessage.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <map>
#include <memory>
#include <new>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/ros/output_bag.h"
#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/ros/pipeline.h"
#include "normal_fusion/synchronizer.h"

namespace nf = normal_fusion;
namespace nn = normal_fusion::node;

namespace {

const char* const kUsage =
    "usage: fuse_bag --input IN.bag --output OUT.bag [options]\n"
    "\n"
    "Fuses the normal maps of a bag as the normal_fusion nodelet does and\n"
    "writes the outputs into a new bag, with the images' stamps.\n"
    "\n"
    "options:\n"
    "  --params FILE.yaml     parameters (config/normal_fusion.yaml format)\n"
    "  --set NAME=VALUE       one parameter (after --params; repeatable)\n"
    "  --num-inputs N         normal-map inputs (the parameter num_inputs)\n"
    "  --image TOPIC          input image            (default /image)\n"
    "  --camera-info TOPIC    its camera_info        (default /camera_info)\n"
    "  --normals-I TOPIC      normal map I = 0..7    (default /normals_I)\n"
    "  --confidence-I TOPIC   confidence of input I  (default /confidence_I;\n"
    "                         read when use_confidence_I is true)\n"
    "  --fused TOPIC          output fused map       (default /fused_normals)\n"
    "  --fused-vis TOPIC      output colour coding   "
    "(default /fused_normals_vis)\n"
    "  --stats TOPIC          output statistics      (default /fusion_stats)\n"
    "  --no-vis               do not write the colour coding\n"
    "  --quiet                no progress bar\n"
    "  --help                 this text\n"
    "\n"
    "OUT is written under a temporary name beside it (OUT.partial-XXXXXX)\n"
    "and renamed to OUT once complete; a failed run leaves no OUT. OUT must\n"
    "not be IN.\n"
    "\n"
    "Exit status: 0 on success, 1 when a bag cannot be read or written, some\n"
    "of its messages are unreadable (the others are fused) or no set could\n"
    "be fused, 2 on a bad command line.\n";

struct Options {
  std::string input, output, params;
  std::vector<std::pair<std::string, std::string>> sets;
  int num_inputs = -1;
  std::string image = "/image", camera_info = "/camera_info";
  std::map<int, std::string> normals, confidence;
  std::string fused = "/fused_normals", fused_vis = "/fused_normals_vis",
              stats = "/fusion_stats";
  bool vis = true, quiet = false;
};

[[noreturn]] void usageError(const std::string& text) {
  std::fprintf(stderr, "fuse_bag: %s\n\n%s", text.c_str(), kUsage);
  std::exit(2);
}

Options parseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) usageError(key + " needs a value");
      return argv[++i];
    };
    if (key == "--help" || key == "-h") {
      std::fputs(kUsage, stdout);
      std::exit(0);
    } else if (key == "--input") {
      o.input = value();
    } else if (key == "--output") {
      o.output = value();
    } else if (key == "--params") {
      o.params = value();
    } else if (key == "--set") {
      const std::string text = value();
      const std::size_t eq = text.find('=');
      if (eq == std::string::npos || eq == 0) {
        usageError("--set expects NAME=VALUE, got '" + text + "'");
      }
      o.sets.emplace_back(text.substr(0, eq), text.substr(eq + 1));
    } else if (key == "--num-inputs") {
      const std::string text = value();
      char* end = nullptr;
      o.num_inputs = static_cast<int>(std::strtol(text.c_str(), &end, 10));
      if (*end != '\0') usageError("--num-inputs expects an integer");
    } else if (key == "--image") {
      o.image = value();
    } else if (key == "--camera-info") {
      o.camera_info = value();
    } else if (key.rfind("--normals-", 0) == 0 && key.size() == 11 &&
               key[10] >= '0' && key[10] < '0' + nn::kMaxInputs) {
      o.normals[key[10] - '0'] = value();
    } else if (key.rfind("--confidence-", 0) == 0 && key.size() == 14 &&
               key[13] >= '0' && key[13] < '0' + nn::kMaxInputs) {
      o.confidence[key[13] - '0'] = value();
    } else if (key == "--fused") {
      o.fused = value();
    } else if (key == "--fused-vis") {
      o.fused_vis = value();
    } else if (key == "--stats") {
      o.stats = value();
    } else if (key == "--no-vis") {
      o.vis = false;
    } else if (key == "--quiet") {
      o.quiet = true;
    } else {
      usageError("unknown option '" + key + "'");
    }
  }
  if (o.input.empty() || o.output.empty()) {
    usageError("--input and --output are required");
  }
  return o;
}

/// The parameters: the file, then --set and --num-inputs on top.
nn::NodeSettings loadSettings(const Options& o) {
  std::vector<std::string> warnings;
  nn::ParameterMap params;
  if (!o.params.empty())
    params = nn::parametersFromYamlFile(o.params, &warnings);
  for (const auto& kv : o.sets) {
    params[kv.first] = nn::parameterFromText(kv.second);
  }
  if (o.num_inputs >= 0) params["num_inputs"] = o.num_inputs;
  nn::NodeSettings settings = nn::settingsFromParameters(params, &warnings);
  for (const std::string& w : warnings) {
    std::fprintf(stderr, "fuse_bag: warning: %s\n", w.c_str());
  }
  return settings;
}

/// A message on one line.
std::string oneLine(std::string text) {
  for (char& c : text) {
    if (c == '\n' || c == '\r') c = ' ';
  }
  return text;
}

/// Refuses an output that is the input under another name (another
/// spelling, a symbolic or a hard link): the same device and inode.
void refuseOutputIsInput(const Options& o) {
  struct stat in_stat {};
  struct stat out_stat {};
  if (::stat(o.input.c_str(), &in_stat) != 0) return;    // reported on reading
  if (::stat(o.output.c_str(), &out_stat) != 0) return;  // a new file
  if (in_stat.st_dev == out_stat.st_dev && in_stat.st_ino == out_stat.st_ino) {
    throw nn::FatalError(
        "--output " + o.output + " is the input bag " + o.input +
        "; refusing to overwrite it (choose another output path)");
  }
}

bool progress_line_open = false;  ///< the progress bar ends no line yet

void progress(std::size_t done, std::size_t total, std::size_t frames,
              double seconds) {
  const int width = 30;
  const double share = total > 0 ? static_cast<double>(done) / total : 1.0;
  const int filled = static_cast<int>(share * width + 0.5);
  std::fprintf(stderr, "\r[%s%s] %3.0f%%  %zu frames  %.1f s",
               std::string(filled, '#').c_str(),
               std::string(width - filled, ' ').c_str(), 100.0 * share, frames,
               seconds);
  std::fflush(stderr);
  progress_line_open = true;
}

/// Ends the progress bar's line, if one is open.
void endProgressLine() {
  if (!progress_line_open) return;
  std::fputc('\n', stderr);
  progress_line_open = false;
}

double percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const std::size_t i = static_cast<std::size_t>(q * (values.size() - 1) + 0.5);
  return values[i];
}

/// The topics' roles, as the node has them, with the command line's names.
std::vector<nn::TopicRole> rolesFor(const Options& o,
                                    const nn::NodeSettings& settings) {
  std::vector<nn::TopicRole> roles = nn::topicRoles(settings);
  for (nn::TopicRole& role : roles) {
    switch (role.kind) {
      case nn::TopicRole::kImage:
        role.name = o.image;
        break;
      case nn::TopicRole::kCameraInfo:
        role.name = o.camera_info;
        break;
      case nn::TopicRole::kNormals:
        role.name = o.normals.count(role.input) ? o.normals.at(role.input)
                                                : "/" + role.name;
        break;
      case nn::TopicRole::kConfidence:
        role.name = o.confidence.count(role.input) ? o.confidence.at(role.input)
                                                   : "/" + role.name;
        break;
      case nn::TopicRole::kDepth:
        role.name = "/" + role.name;
        break;
    }
  }
  return roles;
}

/// One run: the input bag read in its order, synchronized, fused set after
/// set into the output bag.
class BagFusion {
 public:
  using Synchronizer = nf::StampSynchronizer<nn::QueuedMessage>;

  explicit BagFusion(const Options& o)
      : o_(o), settings_(loadSettings(o)), roles_(rolesFor(o, settings_)) {
    for (std::size_t j = 0; j < roles_.size(); ++j) {
      topic_index_[roles_[j].name] = static_cast<int>(j);
      topics_.push_back(roles_[j].name);
    }
    show_progress_ = !o.quiet && isatty(fileno(stderr));
  }

  /// Throws FatalError (and whatever else goes wrong) to end the run.
  int run();

 private:
  void reportAs(const std::string& kind, const std::string& text) {
    if (reported_[kind]++ < 3) {
      endProgressLine();
      std::fprintf(stderr, "fuse_bag: %s\n", oneLine(text).c_str());
    }
  }
  void report(const std::string& text) {
    reportAs(text.substr(0, text.find(':')), text);
  }
  void reportUnreadable(const rosbag::MessageInstance& m,
                        const std::exception& e) {
    char stamp[32];
    std::snprintf(stamp, sizeof(stamp), "%.3f", m.getTime().toSec());
    reportAs("unreadable", m.getTopic() + ": unreadable message at " + stamp +
                               " s (" + e.what() + "); message skipped");
  }
  double elapsed() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() -
                                         started_)
        .count();
  }

  /// The bag's transforms, all loaded first, for the rotation lookup.
  void loadTransforms(rosbag::Bag& in);
  /// Refuses a bag without messages on some input topic.
  void checkTopics(rosbag::View& view) const;
  void processSets(std::vector<Synchronizer::Set> sets);
  /// One message of the bag into the synchronizer (and the sets it forms
  /// through the pipeline).
  void addMessage(const rosbag::MessageInstance& m);
  int printSummary(std::size_t total) const;

  const Options& o_;
  nn::NodeSettings settings_;
  std::vector<nn::TopicRole> roles_;
  std::map<std::string, int> topic_index_;
  std::vector<std::string> topics_;
  bool show_progress_ = false;
  std::map<std::string, int> reported_;  ///< errors printed per kind
  /// Messages whose records cannot be read (corrupt bag): skipped, counted.
  std::size_t unreadable_ = 0, tf_unreadable_ = 0;
  std::unique_ptr<tf2::BufferCore> tf_buffer_;
  nn::MotionLookup motion_;
  std::unique_ptr<nn::OutputBag> out_;
  std::unique_ptr<Synchronizer> sync_;
  nn::MessageLimits limits_;
  std::unique_ptr<nn::FusionPipeline> pipeline_;
  nn::PipelineOutput output_;
  std::uint64_t skipped_ = 0, bad_messages_ = 0;
  std::vector<double> solve_times_, iterations_;
  std::size_t warm_ = 0;
  std::chrono::steady_clock::time_point started_;
};

void BagFusion::loadTransforms(rosbag::Bag& in) {
  rosbag::View all(in);
  // The whole bag's transforms are kept (a Duration holds at most 2^31 s).
  const double span = std::min(
      nn::secondsBetween(all.getEndTime(), all.getBeginTime()) + 10.0, 2e9);
  tf_buffer_ = std::make_unique<tf2::BufferCore>(ros::Duration(span));
  rosbag::View tf_view(
      in, rosbag::TopicQuery(std::vector<std::string>{"/tf", "/tf_static"}));
  std::size_t transforms = 0;
  for (const rosbag::MessageInstance& m : tf_view) {
    tf2_msgs::TFMessage::ConstPtr tf;
    try {
      tf = m.instantiate<tf2_msgs::TFMessage>();
    } catch (const std::exception& e) {
      ++tf_unreadable_;
      reportUnreadable(m, e);
      continue;
    }
    if (!tf) continue;
    for (const auto& t : tf->transforms) {
      tf_buffer_->setTransform(t, "bag", m.getTopic() == "/tf_static");
      ++transforms;
    }
  }
  motion_ = nn::motionLookupFromBuffer(*tf_buffer_, settings_.fixed_frame);
  if (!o_.quiet) {
    std::fprintf(stderr, "fuse_bag: %zu transforms from /tf, /tf_static\n",
                 transforms);
  }
}

void BagFusion::checkTopics(rosbag::View& view) const {
  std::vector<bool> seen(roles_.size(), false);
  for (const rosbag::ConnectionInfo* c : view.getConnections()) {
    auto it = topic_index_.find(c->topic);
    if (it != topic_index_.end()) seen[it->second] = true;
  }
  std::string missing;
  for (std::size_t j = 0; j < roles_.size(); ++j) {
    if (!seen[j]) missing += " " + roles_[j].name;
  }
  if (!missing.empty()) {
    throw nn::FatalError(o_.input + " has no messages on:" + missing);
  }
}

void BagFusion::processSets(std::vector<Synchronizer::Set> sets) {
  for (const auto& discard : sync_->takeDiscards()) {
    if (discard.missing_topic >= 0 &&
        roles_[discard.missing_topic].kind == nn::TopicRole::kCameraInfo) {
      ++skipped_;
      report(roles_[discard.missing_topic].name +
             ": no camera_info for an image; frame skipped");
    }
  }
  for (const auto& set : sets) {
    // Unusable input skips the frame, as in the node; running out of
    // memory ends the run.
    try {
      const nn::InputSet input = nn::inputSetFrom(
          roles_, set.messages, set.present, settings_.num_inputs);
      pipeline_->process(input, motion_, o_.vis, &output_);
    } catch (const std::bad_alloc&) {
      throw nn::FatalError("out of memory while fusing a set");
    } catch (const std::exception& e) {
      ++skipped_;
      report(std::string(e.what()) + "; frame skipped");
      continue;
    }
    if (!output_.warning.empty()) report(output_.warning);
    if (!output_.error.empty()) report(output_.error);
    output_.stats->frames_skipped = skipped_;
    output_.stats->frames_dropped = 0;
    const ros::Time stamp = output_.fused->header.stamp;
    out_->write(o_.fused, stamp, *output_.fused);
    if (output_.fused_vis) out_->write(o_.fused_vis, stamp, *output_.fused_vis);
    out_->write(o_.stats, stamp, *output_.stats);
    solve_times_.push_back(output_.stats->solve_time);
    iterations_.push_back(output_.stats->inner_iterations +
                          output_.stats->coarse_inner_iterations);
    warm_ += output_.stats->warm_started ? 1 : 0;
  }
}

void BagFusion::addMessage(const rosbag::MessageInstance& m) {
  const int topic = topic_index_.at(m.getTopic());
  nn::QueuedMessage message;
  const std_msgs::Header* header = nullptr;
  try {
    if (roles_[topic].kind == nn::TopicRole::kCameraInfo) {
      message.info = m.instantiate<sensor_msgs::CameraInfo>();
      if (message.info) header = &message.info->header;
    } else {
      message.image = m.instantiate<sensor_msgs::Image>();
      if (message.image) header = &message.image->header;
    }
  } catch (const std::bad_alloc&) {
    throw;
  } catch (const std::exception& e) {
    // A corrupt record (rosbag::BagException, a serialization overrun): the
    // bag's index still leads to the next message.
    ++unreadable_;
    reportUnreadable(m, e);
    return;
  }
  if (header == nullptr) {
    ++bad_messages_;
    report(m.getTopic() + ": unexpected message type " + m.getDataType());
    return;
  }
  try {
    nn::precheckMessage(roles_[topic].name, *header, message.image.get(),
                        limits_);
  } catch (const nf::Error& e) {
    ++bad_messages_;
    report(std::string(e.what()) + "; message skipped");
    return;
  }
  const auto result = sync_->add(topic, header->stamp.toNSec(), message);
  if (result == Synchronizer::AddResult::kOutOfOrder) {
    ++bad_messages_;
    report(roles_[topic].name + ": stamp out of order; message skipped");
    return;
  }
  if (result == Synchronizer::AddResult::kTimeReset) {
    report(roles_[topic].name + ": time jumped back; synchronizer reset");
  }
  processSets(sync_->poll());
}

int BagFusion::run() {
  ros::Time::init();
  rosbag::Bag in;
  try {
    in.open(o_.input, rosbag::bagmode::Read);
  } catch (const std::exception& e) {
    throw nn::FatalError("cannot read " + o_.input + ": " + e.what());
  }
  if (!settings_.fixed_frame.empty()) loadTransforms(in);
  rosbag::View view(in, rosbag::TopicQuery(topics_));
  const std::size_t total = view.size();
  checkTopics(view);
  out_ = std::make_unique<nn::OutputBag>(o_.output);

  Synchronizer::Options sync_options;
  sync_options.approximate = settings_.approximate_sync;
  sync_options.queue_size = settings_.queue_size;
  sync_options.max_interval_ns =
      static_cast<std::int64_t>(settings_.max_interval * 1e9 + 0.5);
  sync_ = std::make_unique<Synchronizer>(nn::requiredTopics(roles_, settings_),
                                         sync_options);
  limits_.max_pixels = static_cast<std::uint64_t>(settings_.max_pixels);
  pipeline_ = std::make_unique<nn::FusionPipeline>(
      settings_, nn::topicNamesOf(roles_, settings_.num_inputs));
  started_ = std::chrono::steady_clock::now();
  std::size_t read = 0;
  try {
    for (const rosbag::MessageInstance& m : view) {
      ++read;
      addMessage(m);
      if (show_progress_ && (read % 8 == 0 || read == total)) {
        progress(read, total, solve_times_.size(), elapsed());
      }
    }
  } catch (const rosbag::BagException& e) {
    // Writing errors come as FatalError: this one is of the input.
    throw nn::FatalError("cannot read " + o_.input + ": " + e.what());
  }
  processSets(sync_->flush());
  out_->commit();
  in.close();
  if (show_progress_) {
    progress(total, total, solve_times_.size(), elapsed());
    endProgressLine();
  }
  return printSummary(total);
}

int BagFusion::printSummary(std::size_t total) const {
  const std::size_t done = solve_times_.size();
  const double wall = elapsed();
  const double mean_solve =
      done > 0
          ? std::accumulate(solve_times_.begin(), solve_times_.end(), 0.0) /
                done
          : 0.0;
  const double mean_iterations =
      done > 0
          ? std::accumulate(iterations_.begin(), iterations_.end(), 0.0) / done
          : 0.0;
  std::printf("fuse_bag: %s -> %s\n", o_.input.c_str(), o_.output.c_str());
  std::printf("  inputs:             %zu messages on %zu topics, %d input(s)\n",
              total, roles_.size(), settings_.num_inputs);
  std::printf(
      "  unreadable:         %zu of %zu messages (corrupt records, "
      "skipped)\n",
      unreadable_, total);
  std::printf("  frames fused:       %zu (%zu warm-started)\n", done, warm_);
  std::printf("  images without set: %llu\n",
              static_cast<unsigned long long>(sync_->unmatchedPivots()));
  std::printf("  frames skipped:     %llu (bad input), %llu bad messages\n",
              static_cast<unsigned long long>(skipped_),
              static_cast<unsigned long long>(bad_messages_));
  std::printf("  frames dropped:     0 (offline: every set is solved)\n");
  std::printf(
      "  solve time / frame: mean %.1f ms, median %.1f ms, max %.1f ms\n",
      1e3 * mean_solve, 1e3 * percentile(solve_times_, 0.5),
      1e3 * percentile(solve_times_, 1.0));
  std::printf("  inner iterations:   mean %.0f per frame\n", mean_iterations);
  std::printf("  wall time:          %.2f s (%.1f frames/s)\n", wall,
              wall > 0 ? done / wall : 0.0);
  std::fflush(stdout);
  if (unreadable_ > 0 || tf_unreadable_ > 0) {
    std::string text = o_.input + ": " + std::to_string(unreadable_) + " of " +
                       std::to_string(total) + " messages";
    if (tf_unreadable_ > 0) {
      text += " and " + std::to_string(tf_unreadable_) + " of /tf, /tf_static";
    }
    std::fprintf(stderr,
                 "fuse_bag: %s could not be read (corrupt records); %s has "
                 "the sets of the others\n",
                 text.c_str(), o_.output.c_str());
    return 1;
  }
  if (done == 0) {
    std::fprintf(stderr, "fuse_bag: no set could be fused (%s is empty)\n",
                 o_.output.c_str());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // Past a file size limit (ulimit -f), a write fails with EFBIG and is
  // reported, instead of the signal ending the process.
  std::signal(SIGXFSZ, SIG_IGN);
  const Options o = parseOptions(argc, argv);
  const char* text = nullptr;
  std::string message;
  try {
    // Before the parameters are read (and warned about).
    refuseOutputIsInput(o);
    return BagFusion(o).run();
  } catch (const std::bad_alloc&) {
    text = "out of memory";
  } catch (const std::exception& e) {
    message = oneLine(e.what());
    text = message.c_str();
  } catch (...) {
    text = "unknown error";
  }
  std::fflush(stdout);
  endProgressLine();
  std::fprintf(stderr, "fuse_bag: %s\n", text);
  return 1;
}
