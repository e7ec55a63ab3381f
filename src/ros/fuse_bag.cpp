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
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <map>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/ros/parameters.h"
#include "normal_fusion/ros/pipeline.h"
#include "normal_fusion/ros/synchronizer.h"

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
    "Exit status: 0 on success, 1 when a bag cannot be read or written or\n"
    "no set could be fused, 2 on a bad command line.\n";

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
}

double percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const std::size_t i = static_cast<std::size_t>(q * (values.size() - 1) + 0.5);
  return values[i];
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parseOptions(argc, argv);
  nn::NodeSettings settings;
  try {
    settings = loadSettings(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fuse_bag: %s\n", e.what());
    return 1;
  }
  ros::Time::init();

  // Topics and their roles, as the node has them.
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
    }
  }
  std::map<std::string, int> topic_index;
  std::vector<std::string> topics;
  for (std::size_t j = 0; j < roles.size(); ++j) {
    topic_index[roles[j].name] = static_cast<int>(j);
    topics.push_back(roles[j].name);
  }

  rosbag::Bag in, out;
  try {
    in.open(o.input, rosbag::bagmode::Read);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fuse_bag: cannot read %s: %s\n", o.input.c_str(),
                 e.what());
    return 1;
  }

  // The bag's transforms, all loaded first, for the rotation lookup.
  std::unique_ptr<tf2::BufferCore> tf_buffer;
  nn::RotationLookup rotation;
  if (!settings.fixed_frame.empty()) {
    rosbag::View all(in);
    const double span = (all.getEndTime() - all.getBeginTime()).toSec() + 10.0;
    tf_buffer = std::make_unique<tf2::BufferCore>(ros::Duration(span));
    rosbag::View tf_view(
        in, rosbag::TopicQuery(std::vector<std::string>{"/tf", "/tf_static"}));
    std::size_t transforms = 0;
    for (const rosbag::MessageInstance& m : tf_view) {
      const auto tf = m.instantiate<tf2_msgs::TFMessage>();
      if (!tf) continue;
      for (const auto& t : tf->transforms) {
        tf_buffer->setTransform(t, "bag", m.getTopic() == "/tf_static");
        ++transforms;
      }
    }
    rotation = nn::rotationLookupFromBuffer(*tf_buffer, settings.fixed_frame);
    if (!o.quiet) {
      std::fprintf(stderr, "fuse_bag: %zu transforms from /tf, /tf_static\n",
                   transforms);
    }
  }

  rosbag::View view(in, rosbag::TopicQuery(topics));
  const std::size_t total = view.size();
  std::vector<bool> seen(roles.size(), false);
  for (const rosbag::ConnectionInfo* c : view.getConnections()) {
    auto it = topic_index.find(c->topic);
    if (it != topic_index.end()) seen[it->second] = true;
  }
  std::string missing;
  for (std::size_t j = 0; j < roles.size(); ++j) {
    if (!seen[j]) missing += " " + roles[j].name;
  }
  if (!missing.empty()) {
    std::fprintf(stderr, "fuse_bag: %s has no messages on:%s\n",
                 o.input.c_str(), missing.c_str());
    return 1;
  }
  try {
    out.open(o.output, rosbag::bagmode::Write);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "fuse_bag: cannot write %s: %s\n", o.output.c_str(),
                 e.what());
    return 1;
  }

  using Synchronizer = nn::StampSynchronizer<nn::QueuedMessage>;
  Synchronizer::Options sync_options;
  sync_options.approximate = settings.approximate_sync;
  sync_options.queue_size = settings.queue_size;
  sync_options.max_interval_ns =
      static_cast<std::int64_t>(settings.max_interval * 1e9 + 0.5);
  Synchronizer sync(nn::requiredTopics(roles, settings), sync_options);
  nn::FusionPipeline pipeline(settings,
                              nn::topicNamesOf(roles, settings.num_inputs));

  std::uint64_t skipped = 0, bad_messages = 0;
  std::vector<double> solve_times, iterations;
  std::size_t warm = 0, done = 0;
  const bool show_progress = !o.quiet && isatty(fileno(stderr));
  const auto started = std::chrono::steady_clock::now();
  auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() -
                                         started)
        .count();
  };
  std::map<std::string, int> reported;  // errors printed per kind
  auto report = [&](const std::string& text) {
    const std::string key = text.substr(0, text.find(':'));
    if (reported[key]++ < 3) {
      if (show_progress) std::fputc('\n', stderr);
      std::fprintf(stderr, "fuse_bag: %s\n", text.c_str());
    }
  };
  nn::PipelineOutput output;
  auto processSets = [&](std::vector<Synchronizer::Set> sets) {
    for (const auto& discard : sync.takeDiscards()) {
      if (discard.missing_topic >= 0 &&
          roles[discard.missing_topic].kind == nn::TopicRole::kCameraInfo) {
        ++skipped;
        report(roles[discard.missing_topic].name +
               ": no camera_info for an image; frame skipped");
      }
    }
    for (const auto& set : sets) {
      const nn::InputSet input = nn::inputSetFrom(
          roles, set.messages, set.present, settings.num_inputs);
      try {
        pipeline.process(input, rotation, o.vis, &output);
      } catch (const std::exception& e) {
        ++skipped;
        report(std::string(e.what()) + "; frame skipped");
        continue;
      }
      if (!output.warning.empty()) report(output.warning);
      output.stats->frames_skipped = skipped;
      output.stats->frames_dropped = 0;
      const ros::Time stamp = output.fused->header.stamp;
      out.write(o.fused, stamp, *output.fused);
      if (output.fused_vis) out.write(o.fused_vis, stamp, *output.fused_vis);
      out.write(o.stats, stamp, *output.stats);
      solve_times.push_back(output.stats->solve_time);
      iterations.push_back(output.stats->inner_iterations +
                           output.stats->coarse_inner_iterations);
      warm += output.stats->warm_started ? 1 : 0;
    }
  };

  std::size_t read = 0;
  for (const rosbag::MessageInstance& m : view) {
    ++read;
    const int topic = topic_index.at(m.getTopic());
    nn::QueuedMessage message;
    const std_msgs::Header* header = nullptr;
    if (roles[topic].kind == nn::TopicRole::kCameraInfo) {
      message.info = m.instantiate<sensor_msgs::CameraInfo>();
      if (message.info) header = &message.info->header;
    } else {
      message.image = m.instantiate<sensor_msgs::Image>();
      if (message.image) header = &message.image->header;
    }
    if (header == nullptr) {
      ++bad_messages;
      report(m.getTopic() + ": unexpected message type " + m.getDataType());
      continue;
    }
    try {
      nn::precheckMessage(roles[topic].name, *header, message.image.get());
    } catch (const nf::Error& e) {
      ++bad_messages;
      report(std::string(e.what()) + "; message skipped");
      continue;
    }
    const auto result = sync.add(topic, header->stamp.toNSec(), message);
    if (result == Synchronizer::AddResult::kOutOfOrder) {
      ++bad_messages;
      report(roles[topic].name + ": stamp out of order; message skipped");
      continue;
    }
    if (result == Synchronizer::AddResult::kTimeReset) {
      report(roles[topic].name + ": time jumped back; synchronizer reset");
    }
    processSets(sync.poll());
    if (show_progress && (read % 8 == 0 || read == total)) {
      progress(read, total, solve_times.size(), elapsed());
    }
  }
  processSets(sync.flush());
  done = solve_times.size();
  out.close();
  in.close();
  if (show_progress) {
    progress(total, total, done, elapsed());
    std::fputc('\n', stderr);
  }

  const double wall = elapsed();
  const double mean_solve =
      done > 0
          ? std::accumulate(solve_times.begin(), solve_times.end(), 0.0) / done
          : 0.0;
  const double mean_iterations =
      done > 0
          ? std::accumulate(iterations.begin(), iterations.end(), 0.0) / done
          : 0.0;
  std::printf("fuse_bag: %s -> %s\n", o.input.c_str(), o.output.c_str());
  std::printf("  inputs:             %zu messages on %zu topics, %d input(s)\n",
              total, roles.size(), settings.num_inputs);
  std::printf("  frames fused:       %zu (%zu warm-started)\n", done, warm);
  std::printf("  images without set: %llu\n",
              static_cast<unsigned long long>(sync.unmatchedPivots()));
  std::printf("  frames skipped:     %llu (bad input), %llu bad messages\n",
              static_cast<unsigned long long>(skipped),
              static_cast<unsigned long long>(bad_messages));
  std::printf("  frames dropped:     0 (offline: every set is solved)\n");
  std::printf(
      "  solve time / frame: mean %.1f ms, median %.1f ms, max %.1f ms\n",
      1e3 * mean_solve, 1e3 * percentile(solve_times, 0.5),
      1e3 * percentile(solve_times, 1.0));
  std::printf("  inner iterations:   mean %.0f per frame\n", mean_iterations);
  std::printf("  wall time:          %.2f s (%.1f frames/s)\n", wall,
              wall > 0 ? done / wall : 0.0);
  return done > 0 ? 0 : 1;
}
