// bench_soak: a camera-rate stream into a running normal_fusion node for a
// long time, and a table of what the node did: output rate, drops, latency
// and frame time against the budget, memory slope.
//
//   bench_soak [--duration S] [--rate HZ] [--width W] [--height H]
//              [--process NODE] [--budget-ms MS] [--warmup S]
//
// Publishes /image, /camera_info, /normals_0 (the paper's noise) and
// /normals_1 (normals of a noisy depth map) of a slowly turning synthetic
// room at the given rate, the same stamp on all four, and collects
// /fusion_stats. The node's process (NODE, found through the master: the
// nodelet manager, or the standalone node) is sampled for its resident memory
// every second; the slope is fitted after the warm-up.
#include <normal_fusion/FusionStats.h>
#include <ros/master.h>
#include <ros/network.h>
#include <ros/ros.h>
#include <xmlrpcpp/XmlRpc.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <string>
#include <vector>

#include "../../test/ros/ros_test_util.h"
#include "eval/synthetic.h"

namespace nf = normal_fusion;

namespace {

struct Options {
  double duration = 600.0, rate = 30.0, budget_ms = 33.0, warmup = 30.0;
  int width = 640, height = 480;
  std::string process = "/normal_fusion_manager";
};

Options parseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "bench_soak: %s needs a value\n", key.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (key == "--duration") {
      o.duration = std::atof(value().c_str());
    } else if (key == "--rate") {
      o.rate = std::atof(value().c_str());
    } else if (key == "--width") {
      o.width = std::atoi(value().c_str());
    } else if (key == "--height") {
      o.height = std::atoi(value().c_str());
    } else if (key == "--budget-ms") {
      o.budget_ms = std::atof(value().c_str());
    } else if (key == "--warmup") {
      o.warmup = std::atof(value().c_str());
    } else if (key == "--process") {
      o.process = value();
    } else {
      std::fprintf(stderr,
                   "usage: bench_soak [--duration S] [--rate HZ] [--width W] "
                   "[--height H] [--budget-ms MS] [--warmup S] "
                   "[--process NODE]\n");
      std::exit(2);
    }
  }
  return o;
}

/// The pid of a node's process, from its XML-RPC API; -1 if unknown.
int pidOf(const std::string& node) {
  XmlRpc::XmlRpcValue args, result, payload;
  args[0] = ros::this_node::getName();
  args[1] = node;
  if (!ros::master::execute("lookupNode", args, result, payload, true)) {
    return -1;
  }
  std::string host;
  std::uint32_t port = 0;
  if (!ros::network::splitURI(static_cast<std::string>(payload), host, port)) {
    return -1;
  }
  XmlRpc::XmlRpcClient client(host.c_str(), static_cast<int>(port), "/");
  XmlRpc::XmlRpcValue pid_args, pid_result;
  pid_args[0] = ros::this_node::getName();
  if (!client.execute("getPid", pid_args, pid_result)) return -1;
  return static_cast<int>(pid_result[2]);
}

/// Resident memory of a process in MiB (VmRSS), or -1.
double residentMiB(int pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::atof(line.c_str() + 6) / 1024;
  }
  return -1.0;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(q * (v.size() - 1) + 0.5)];
}

double shareAbove(const std::vector<double>& v, double bound) {
  if (v.empty()) return 0.0;
  return static_cast<double>(std::count_if(
             v.begin(), v.end(), [&](double x) { return x > bound; })) /
         v.size();
}

/// Least-squares slope of y over x.
double slope(const std::vector<double>& x, const std::vector<double>& y) {
  const std::size_t n = x.size();
  if (n < 2) return 0.0;
  double mx = 0, my = 0;
  for (std::size_t i = 0; i < n; ++i) {
    mx += x[i];
    my += y[i];
  }
  mx /= n;
  my /= n;
  double sxy = 0, sxx = 0;
  for (std::size_t i = 0; i < n; ++i) {
    sxy += (x[i] - mx) * (y[i] - my);
    sxx += (x[i] - mx) * (x[i] - mx);
  }
  return sxx > 0 ? sxy / sxx : 0.0;
}

/// What /fusion_stats reported, filled by the subscriber's thread.
struct Received {
  std::mutex mutex;
  std::vector<double> latency, frame_time, queue_time, solve_time, receive_s,
      reserve;
  std::uint64_t dropped = 0, skipped = 0, warm = 0;
};

struct Frame {
  sensor_msgs::ImagePtr image, n0, n1;
  sensor_msgs::CameraInfoPtr info;
};

/// A second of frames of the synthetic room, as messages.
std::vector<Frame> renderMessages(const Options& o) {
  const int frames = std::max(2, static_cast<int>(o.rate));
  std::fprintf(stderr, "bench_soak: rendering %d frames at %dx%d\n", frames,
               o.width, o.height);
  const auto sequence =
      nf::synthetic::renderSequence(0, o.width, o.height, frames, 0.2, o.rate);
  std::vector<Frame> messages;
  for (int k = 0; k < frames; ++k) {
    const nf::test::NoisyFrame f = nf::test::noisyFrame(sequence[k], 500 + k);
    const std_msgs::Header header = nf::test::makeHeader(1.0);
    messages.push_back(
        {nf::test::imageMessage(f.frame.image, header),
         nf::test::normalsMessage(f.noisy, header),
         nf::test::normalsMessage(f.from_depth, header),
         nf::test::cameraInfoMessage(f.frame.K, o.width, o.height, header)});
  }
  return messages;
}

struct Publishers {
  ros::Publisher image, info, n0, n1;
};

/// Resident memory of the node's process, sampled every second.
struct MemoryTrace {
  std::vector<double> t, mib;
};

/// Publishes the frames in a loop (forward and back, so the motion has no
/// jump; the stamps run on) until the duration is over; returns the number
/// of sets published.
std::uint64_t streamFrames(const Options& o, const std::vector<Frame>& messages,
                           const Publishers& pubs, int pid,
                           const ros::WallTime& stream_start,
                           MemoryTrace& memory) {
  const int frames = static_cast<int>(messages.size());
  std::uint64_t published = 0;
  ros::WallTime next_sample = stream_start;
  const double period = 1.0 / o.rate;
  ros::Time stamp = ros::Time::now();
  while (ros::ok()) {
    const double t = (ros::WallTime::now() - stream_start).toSec();
    if (t >= o.duration) break;
    const ros::WallTime due =
        stream_start + ros::WallDuration(published * period);
    if (ros::WallTime::now() < due) (due - ros::WallTime::now()).sleep();
    const int cycle = 2 * frames - 2;
    const int phase = static_cast<int>(published % cycle);
    const Frame& f = messages[phase < frames ? phase : cycle - phase];
    stamp += ros::Duration(period);
    auto with_stamp = [&](const sensor_msgs::ImagePtr& m) {
      auto copy = boost::make_shared<sensor_msgs::Image>(*m);
      copy->header.stamp = stamp;
      return copy;
    };
    auto info = boost::make_shared<sensor_msgs::CameraInfo>(*f.info);
    info->header.stamp = stamp;
    pubs.info.publish(info);
    pubs.n0.publish(with_stamp(f.n0));
    pubs.n1.publish(with_stamp(f.n1));
    pubs.image.publish(with_stamp(f.image));
    ++published;
    if (ros::WallTime::now() >= next_sample) {
      memory.t.push_back(t);
      memory.mib.push_back(residentMiB(pid));
      next_sample += ros::WallDuration(1.0);
    }
  }
  return published;
}

void printCounts(const Options& o, const Received& r, std::uint64_t published,
                 double seconds) {
  std::printf("| bench_soak | %dx%d, 2 inputs, %.0f Hz, %.0f s |\n", o.width,
              o.height, o.rate, o.duration);
  std::printf("|---|---|\n");
  std::printf("| sets published | %llu |\n",
              static_cast<unsigned long long>(published));
  std::printf("| outputs | %zu (%.1f Hz), %llu warm-started |\n",
              r.latency.size(), r.latency.size() / seconds,
              static_cast<unsigned long long>(r.warm));
  std::printf("| dropped (worker busy) | %llu (%.1f %%) |\n",
              static_cast<unsigned long long>(r.dropped),
              published > 0 ? 100.0 * r.dropped / published : 0.0);
  std::printf("| skipped (bad input) | %llu |\n",
              static_cast<unsigned long long>(r.skipped));
  std::printf(
      "| lost (neither output nor counted) | %lld |\n",
      static_cast<long long>(published) -
          static_cast<long long>(r.latency.size() + r.dropped + r.skipped));
}

void printTimes(const Options& o, const Received& r) {
  const double budget = o.budget_ms / 1e3;
  auto ms = [](double s) { return 1e3 * s; };
  std::printf(
      "| frame time (budget %.0f ms) p50 / p95 / p99 / max | %.1f / %.1f / "
      "%.1f / %.1f ms, %.1f %% over the budget |\n",
      o.budget_ms, ms(percentile(r.frame_time, 0.5)),
      ms(percentile(r.frame_time, 0.95)), ms(percentile(r.frame_time, 0.99)),
      ms(percentile(r.frame_time, 1.0)),
      100.0 * shareAbove(r.frame_time, budget));
  std::printf(
      "| latency (set complete -> outputs) p50 / p95 / p99 / max | %.1f / "
      "%.1f / %.1f / %.1f ms, %.1f %% over the budget |\n",
      ms(percentile(r.latency, 0.5)), ms(percentile(r.latency, 0.95)),
      ms(percentile(r.latency, 0.99)), ms(percentile(r.latency, 1.0)),
      100.0 * shareAbove(r.latency, budget));
  std::printf("| queue time p50 / p95 / max | %.1f / %.1f / %.1f ms |\n",
              ms(percentile(r.queue_time, 0.5)),
              ms(percentile(r.queue_time, 0.95)),
              ms(percentile(r.queue_time, 1.0)));
  std::printf("| solve time p50 / p95 | %.1f / %.1f ms |\n",
              ms(percentile(r.solve_time, 0.5)),
              ms(percentile(r.solve_time, 0.95)));
  std::printf("| overrun reserve p50 / max | %.1f / %.1f ms |\n",
              ms(percentile(r.reserve, 0.5)), ms(percentile(r.reserve, 1.0)));
}

void printMemory(const Options& o, const MemoryTrace& memory, double seconds) {
  std::vector<double> t_after, m_after;
  for (std::size_t i = 0; i < memory.t.size(); ++i) {
    if (memory.t[i] >= o.warmup) {
      t_after.push_back(memory.t[i] / 60.0);
      m_after.push_back(memory.mib[i]);
    }
  }
  std::printf(
      "| resident memory: start / end, slope after %.0f s | %.1f / %.1f MiB, "
      "%.2f MiB/min |\n",
      o.warmup, memory.mib.empty() ? 0.0 : memory.mib.front(),
      memory.mib.empty() ? 0.0 : memory.mib.back(), slope(t_after, m_after));
  // The shape of the curve: a slope that falls towards 0 is the allocator
  // settling, one that stays is a leak.
  std::vector<double> t_late, m_late;
  for (std::size_t i = 0; i < t_after.size(); ++i) {
    if (t_after[i] * 60.0 >= 0.5 * seconds) {
      t_late.push_back(t_after[i]);
      m_late.push_back(m_after[i]);
    }
  }
  std::printf("| resident memory slope, second half | %.2f MiB/min |\n",
              slope(t_late, m_late));
  std::printf("| resident memory each minute | ");
  for (std::size_t i = 0; i < memory.t.size(); ++i) {
    if (i == 0 || static_cast<int>(memory.t[i] / 60.0) !=
                      static_cast<int>(memory.t[i - 1] / 60.0)) {
      std::printf("%.0f ", memory.mib[i]);
    }
  }
  std::printf("MiB |\n");
}

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "bench_soak", ros::init_options::AnonymousName);
  const Options o = parseOptions(argc, argv);
  ros::NodeHandle nh;
  Publishers pubs;
  pubs.image = nh.advertise<sensor_msgs::Image>("/image", 2);
  pubs.info = nh.advertise<sensor_msgs::CameraInfo>("/camera_info", 2);
  pubs.n0 = nh.advertise<sensor_msgs::Image>("/normals_0", 2);
  pubs.n1 = nh.advertise<sensor_msgs::Image>("/normals_1", 2);

  Received received;
  const ros::WallTime start = ros::WallTime::now();
  ros::Subscriber stats_sub = nh.subscribe<nf::FusionStats>(
      "/fusion_stats", 100, [&](const nf::FusionStatsConstPtr& m) {
        std::lock_guard<std::mutex> lock(received.mutex);
        received.receive_s.push_back((ros::WallTime::now() - start).toSec());
        received.latency.push_back(m->latency);
        received.frame_time.push_back(m->frame_time);
        received.queue_time.push_back(m->queue_time);
        received.solve_time.push_back(m->solve_time);
        received.reserve.push_back(m->budget_reserve);
        received.dropped = m->frames_dropped;
        received.skipped = m->frames_skipped;
        received.warm += m->warm_started ? 1 : 0;
      });
  ros::AsyncSpinner spinner(1);
  spinner.start();

  const std::vector<Frame> messages = renderMessages(o);
  const int pid = pidOf(o.process);
  if (pid < 0) {
    std::fprintf(stderr, "bench_soak: no process for %s\n", o.process.c_str());
    return 1;
  }
  for (int k = 0; k < 100 && pubs.image.getNumSubscribers() == 0; ++k) {
    ros::WallDuration(0.1).sleep();
  }
  if (pubs.image.getNumSubscribers() == 0) {
    std::fprintf(stderr,
                 "bench_soak: nobody subscribes to /image (is the "
                 "node up and lazy? bench_soak subscribes to "
                 "/fusion_stats)\n");
    return 1;
  }
  std::fprintf(stderr, "bench_soak: %.0f s at %.0f Hz into %s (pid %d)\n",
               o.duration, o.rate, o.process.c_str(), pid);

  MemoryTrace memory;
  const ros::WallTime stream_start = ros::WallTime::now();
  const std::uint64_t published =
      streamFrames(o, messages, pubs, pid, stream_start, memory);
  ros::WallDuration(1.0).sleep();  // the last outputs
  spinner.stop();

  std::lock_guard<std::mutex> lock(received.mutex);
  const double seconds = (ros::WallTime::now() - stream_start).toSec();
  printCounts(o, received, published, seconds);
  printTimes(o, received);
  printMemory(o, memory, seconds);
  return 0;
}
