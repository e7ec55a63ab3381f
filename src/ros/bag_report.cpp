// bag_report: pictures and a summary of a fused bag, for the demo.
//
//   bag_report --input IN.bag --fused OUT.bag --dir DIR [--offline OFF.bag]
//              [--ground-truth GT.bag] [--title TEXT] [--image TOPIC]
//              [--normals-0 TOPIC] [--normals-1 TOPIC] [--played DRIVER.bag]
//              [--played-topic TOPIC] [--normals-source TEXT] [--run TEXT]
//
// For every fused frame it writes DIR/frames/frame_NNN.png: the image, the
// two input normal maps of IN.bag (colour-coded, lower resolutions shown
// with nearest-neighbour pixels) and the fused map, side by side.
// DIR/summary.md gets where the normals came from (--normals-source), the
// frames played (--played: the driver's bag, counted on --played-topic) and
// those dropped on the way, the per-frame statistics of /fusion_stats, their
// totals, a roughness measure of every map (mean angle between neighbouring
// normals), the agreement with an offline run (fuse_bag) and, when ground
// truth is given, the PSNR and mean angular error of inputs and output.
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Image.h>
#include <sys/stat.h>

#include <normal_fusion/FusionStats.h>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <numeric>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"
#include "normal_fusion/metrics.h"
#include "normal_fusion/ros/conversions.h"

namespace nf = normal_fusion;
namespace nn = normal_fusion::node;

namespace {

const char* const kUsage =
    "usage: bag_report --input IN.bag --fused OUT.bag --dir DIR\n"
    "                  [--offline OFF.bag] [--ground-truth GT.bag] "
    "[--title TEXT]\n"
    "                  [--image TOPIC] [--normals-0 TOPIC] [--normals-1 "
    "TOPIC]\n"
    "                  [--played DRIVER.bag] [--played-topic TOPIC]\n"
    "                  [--normals-source TEXT] [--run TEXT]\n";

using Stamped = std::map<ros::Time, sensor_msgs::ImageConstPtr>;

Stamped readImages(const std::string& path, const std::string& topic) {
  Stamped out;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag, rosbag::TopicQuery(topic));
  for (const rosbag::MessageInstance& m : view) {
    if (auto msg = m.instantiate<sensor_msgs::Image>()) {
      out[msg->header.stamp] = msg;
    }
  }
  return out;
}

std::map<ros::Time, normal_fusion::FusionStatsConstPtr> readStats(
    const std::string& path) {
  std::map<ros::Time, normal_fusion::FusionStatsConstPtr> out;
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag, rosbag::TopicQuery("/fusion_stats"));
  for (const rosbag::MessageInstance& m : view) {
    if (auto msg = m.instantiate<normal_fusion::FusionStats>()) {
      out[msg->header.stamp] = msg;
    }
  }
  return out;
}

nf::NormalMap normalsOf(const sensor_msgs::Image& msg) {
  nf::NormalMap normals;
  nn::normalsFromMessage(msg, "map", 0.5, normals);
  return normals;
}

/// Colour coding as a BGR picture (for OpenCV), black where missing.
cv::Mat picture(const nf::NormalMap& normals, int width, int height) {
  cv::Mat rgb(normals.height(), normals.width(), CV_8UC3);
  for (int y = 0; y < normals.height(); ++y) {
    for (int x = 0; x < normals.width(); ++x) {
      const float n[3] = {normals.at(0, y, x), normals.at(1, y, x),
                          normals.at(2, y, x)};
      cv::Vec3b& p = rgb.at<cv::Vec3b>(y, x);
      const bool ok = nf::isValidNormal(n[0], n[1], n[2]);
      for (int c = 0; c < 3; ++c) {
        // The library's colour code, x -> R, y -> G, z -> B (stored as BGR).
        p[2 - c] = ok ? nf::io::colorCodeByte(n[c]) : 0;
      }
    }
  }
  cv::Mat resized;
  cv::resize(rgb, resized, cv::Size(width, height), 0, 0, cv::INTER_NEAREST);
  return resized;
}

cv::Mat imagePicture(const sensor_msgs::Image& msg) {
  nf::ColorImage image;
  nn::imageFromMessage(msg, "image", image);
  cv::Mat out(image.height(), image.width(), CV_8UC3);
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      for (int c = 0; c < 3; ++c) {
        const int plane = image.channels() == 1 ? 0 : c;
        out.at<cv::Vec3b>(y, x)[2 - c] = static_cast<std::uint8_t>(
            std::lround(255.0f * image.at(plane, y, x)));
      }
    }
  }
  return out;
}

cv::Mat labelled(const cv::Mat& image, const std::string& label) {
  cv::Mat out = image.clone();
  const double scale = std::max(0.4, image.cols / 640.0 * 0.7);
  cv::putText(out, label, cv::Point(6, static_cast<int>(22 * scale) + 4),
              cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(255, 255, 255), 2);
  return out;
}

/// Mean angle in degrees between each valid normal and its valid right and
/// lower neighbours: how rough a map is.
double roughnessDeg(const nf::NormalMap& n) {
  double sum = 0.0;
  long count = 0;
  for (int y = 0; y + 1 < n.height(); ++y) {
    for (int x = 0; x + 1 < n.width(); ++x) {
      const float a[3] = {n.at(0, y, x), n.at(1, y, x), n.at(2, y, x)};
      if (!nf::isValidNormal(a[0], a[1], a[2])) continue;
      for (int k = 0; k < 2; ++k) {
        const int xx = x + (k == 0), yy = y + (k == 1);
        const float b[3] = {n.at(0, yy, xx), n.at(1, yy, xx), n.at(2, yy, xx)};
        if (!nf::isValidNormal(b[0], b[1], b[2])) continue;
        const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        const double la = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        const double lb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
        sum += std::acos(std::min(1.0, std::max(-1.0, dot / (la * lb))));
        ++count;
      }
    }
  }
  return count > 0 ? sum / count * 180.0 / M_PI : 0.0;
}

double validShare(const nf::NormalMap& n) {
  long valid = 0;
  for (std::size_t i = 0; i < n.pixelCount(); ++i) {
    valid += nf::isValidNormal(n.plane(0)[i], n.plane(1)[i], n.plane(2)[i]);
  }
  return static_cast<double>(valid) / n.pixelCount();
}

double mean(const std::vector<double>& v) {
  return v.empty() ? 0.0 : std::accumulate(v.begin(), v.end(), 0.0) / v.size();
}

struct Options {
  std::string input, fused_path, dir, offline, ground_truth,
      title = "normal_fusion demo";
  std::string image_topic = "/image", normals0_topic = "/normals_0",
              normals1_topic = "/normals_1";
  /// The driver's bag that was played, and the topic whose messages count
  /// the frames played.
  std::string played, played_topic = "/camera/depth/image_rect_raw";
  /// Where the input normal maps came from, and what fused them.
  std::string normals_source, run = "bag.launch";
};

/// Messages of `topic` in a bag.
std::size_t countMessages(const std::string& path, const std::string& topic) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  return rosbag::View(bag, rosbag::TopicQuery(topic)).size();
}

/// Reads the command line into `options`; false (after a message) on a
/// missing value or an unknown option.
bool parseOptions(int argc, char** argv, Options& options) {
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (i + 1 >= argc) {
      std::fprintf(stderr, "bag_report: %s needs a value\n%s", key.c_str(),
                   kUsage);
      return false;
    }
    const std::string value = argv[++i];
    if (key == "--input") {
      options.input = value;
    } else if (key == "--fused") {
      options.fused_path = value;
    } else if (key == "--dir") {
      options.dir = value;
    } else if (key == "--offline") {
      options.offline = value;
    } else if (key == "--ground-truth") {
      options.ground_truth = value;
    } else if (key == "--title") {
      options.title = value;
    } else if (key == "--image") {
      options.image_topic = value;
    } else if (key == "--normals-0") {
      options.normals0_topic = value;
    } else if (key == "--normals-1") {
      options.normals1_topic = value;
    } else if (key == "--played") {
      options.played = value;
    } else if (key == "--played-topic") {
      options.played_topic = value;
    } else if (key == "--normals-source") {
      options.normals_source = value;
    } else if (key == "--run") {
      options.run = value;
    } else {
      std::fprintf(stderr, "bag_report: unknown option %s\n%s", key.c_str(),
                   kUsage);
      return false;
    }
  }
  return true;
}

/// Every topic the report reads, by stamp.
struct Bags {
  Stamped images, normals0, normals1, fused;
  std::map<ros::Time, normal_fusion::FusionStatsConstPtr> stats;
  Stamped fused_offline, gt;
  std::size_t played = 0;  ///< frames of the driver's bag, 0: not given
};

Bags readBags(const Options& options) {
  Bags bags;
  bags.images = readImages(options.input, options.image_topic);
  bags.normals0 = readImages(options.input, options.normals0_topic);
  bags.normals1 = readImages(options.input, options.normals1_topic);
  if (!options.played.empty()) {
    bags.played = countMessages(options.played, options.played_topic);
  }
  bags.fused = readImages(options.fused_path, "/fused_normals");
  bags.stats = readStats(options.fused_path);
  if (!options.offline.empty()) {
    bags.fused_offline = readImages(options.offline, "/fused_normals");
  }
  if (!options.ground_truth.empty()) {
    bags.gt = readImages(options.ground_truth, "/normals_gt");
  }
  return bags;
}

/// What the frames add up to, and the per-frame table of the summary.
struct Tally {
  std::ostringstream table;
  std::vector<double> rough_in0, rough_in1, rough_out, solve, latency, inner,
      offline_diff, psnr_in0, psnr_in1, psnr_out, angle_in0, angle_in1,
      angle_out;
  double valid0 = 0, valid1 = 0;
  int warm = 0;
  std::uint64_t dropped = 0, skipped = 0;
};

/// Writes DIR/frames/frame_NNN.png (and DIR/first_frame.png for the first)
/// and returns the inputs of that stamp (empty where missing).
std::pair<nf::NormalMap, nf::NormalMap> writeFramePicture(
    const Bags& bags, const ros::Time& stamp, const nf::NormalMap& out,
    int index, const std::string& dir, Tally& tally) {
  const int W = out.width(), H = out.height();
  std::vector<cv::Mat> tiles;
  if (bags.images.count(stamp)) {
    tiles.push_back(labelled(imagePicture(*bags.images.at(stamp)), "image"));
  }
  nf::NormalMap in0, in1;
  if (bags.normals0.count(stamp)) {
    in0 = normalsOf(*bags.normals0.at(stamp));
    tiles.push_back(labelled(picture(in0, W, H), "normals_0"));
    tally.rough_in0.push_back(roughnessDeg(in0));
    tally.valid0 += validShare(in0);
  }
  if (bags.normals1.count(stamp)) {
    in1 = normalsOf(*bags.normals1.at(stamp));
    tiles.push_back(labelled(picture(in1, W, H), "normals_1"));
    tally.rough_in1.push_back(roughnessDeg(in1));
    tally.valid1 += validShare(in1);
  }
  tiles.push_back(labelled(picture(out, W, H), "fused"));
  tally.rough_out.push_back(roughnessDeg(out));
  cv::Mat row;
  cv::hconcat(tiles, row);
  char name[64];
  std::snprintf(name, sizeof(name), "/frames/frame_%03d.png", index);
  cv::imwrite(dir + name, row);
  if (index == 0) cv::imwrite(dir + "/first_frame.png", row);
  return {in0, in1};
}

/// Adds the largest difference to the offline run and the errors against the
/// ground truth, where the bags have that stamp.
void compareFrame(const Bags& bags, const ros::Time& stamp,
                  const nf::NormalMap& out, const nf::NormalMap& in0,
                  const nf::NormalMap& in1, Tally& tally) {
  if (bags.fused_offline.count(stamp)) {
    const nf::NormalMap other = normalsOf(*bags.fused_offline.at(stamp));
    double worst = 0.0;
    for (int c = 0; c < 3; ++c) {
      for (std::size_t i = 0; i < out.pixelCount(); ++i) {
        worst = std::max(
            worst,
            static_cast<double>(std::abs(out.plane(c)[i] - other.plane(c)[i])));
      }
    }
    tally.offline_diff.push_back(worst);
  }
  if (bags.gt.count(stamp)) {
    const nf::NormalMap truth = normalsOf(*bags.gt.at(stamp));
    tally.psnr_out.push_back(nf::psnr(out, truth));
    tally.angle_out.push_back(nf::angularError(out, truth).mean_deg);
    if (!in0.empty() && in0.sameSize(truth)) {
      tally.psnr_in0.push_back(nf::psnr(in0, truth));
      tally.angle_in0.push_back(nf::angularError(in0, truth).mean_deg);
    }
    if (!in1.empty() && in1.sameSize(truth)) {
      tally.psnr_in1.push_back(nf::psnr(in1, truth));
      tally.angle_in1.push_back(nf::angularError(in1, truth).mean_deg);
    }
  }
}

/// One row of the per-frame table from /fusion_stats (null: none).
void addStatsRow(const normal_fusion::FusionStatsConstPtr& st, int index,
                 const ros::Time& stamp, Tally& tally) {
  std::ostringstream& table = tally.table;
  table << "| " << index << " | " << stamp.toSec() << " | ";
  if (!st) {
    table << "(no stats) | | | | | | | | |\n";
    return;
  }
  std::string present;
  for (std::size_t i = 0; i < st->inputs_present.size(); ++i) {
    present += st->inputs_present[i] ? std::to_string(i) : "-";
  }
  table << present << " | " << st->outer_iterations << " | "
        << st->inner_iterations + st->coarse_inner_iterations << " | "
        << (st->warm_started ? "yes" : "no") << " | " << 1e3 * st->solve_time
        << " | " << 1e3 * st->latency << " | " << st->initial_energy << " | "
        << st->final_energy << " | " << st->frames_dropped << " |\n";
  tally.solve.push_back(st->solve_time);
  tally.latency.push_back(st->latency);
  tally.inner.push_back(st->inner_iterations + st->coarse_inner_iterations);
  tally.warm += st->warm_started;
  tally.dropped = std::max<std::uint64_t>(tally.dropped, st->frames_dropped);
  tally.skipped = std::max<std::uint64_t>(tally.skipped, st->frames_skipped);
}

/// The summary's lines on where the maps came from and how many frames made
/// it through each stage.
void writeFrameCounts(std::ostream& md, const Options& options,
                      const Bags& bags, const Tally& tally, int frames) {
  if (!options.normals_source.empty()) {
    md << "- where the normals came from: " << options.normals_source << "\n";
  }
  if (!options.played.empty()) {
    const auto lost = [&](std::size_t got) {
      return got < bags.played ? bags.played - got : 0;
    };
    md << "- played: `" << options.played << "`, " << bags.played
       << " frames on " << options.played_topic << "; dropped before the "
       << "fusion: " << lost(bags.normals0.size()) << " on normals_0, "
       << lost(bags.normals1.size())
       << " on normals_1; not fused: " << lost(static_cast<std::size_t>(frames))
       << "\n";
  }
  md << "- inputs read from `" << options.input << "` (" << bags.images.size()
     << " images on " << options.image_topic << ", " << bags.normals0.size()
     << " maps on " << options.normals0_topic << " (normals_0), "
     << bags.normals1.size() << " on " << options.normals1_topic
     << " (normals_1))\n";
  md << "- fused by the nodelet (" << options.run << "): `"
     << options.fused_path << "`: " << frames << " fused frames, " << tally.warm
     << " warm-started, " << tally.dropped << " dropped (worker busy), "
     << tally.skipped << " skipped (bad input)\n";
}

void writeSummary(const Options& options, const Bags& bags, const Tally& tally,
                  int frames) {
  std::ofstream md(options.dir + "/summary.md");
  md << "# " << options.title << "\n\n";
  writeFrameCounts(md, options, bags, tally, frames);
  md << "- solve time per frame: mean " << 1e3 * mean(tally.solve)
     << " ms; latency (set complete -> outputs ready): mean "
     << 1e3 * mean(tally.latency) << " ms; inner iterations per frame: mean "
     << mean(tally.inner) << "\n";
  if (!options.offline.empty()) {
    const std::vector<double>& diff = tally.offline_diff;
    md << "- the same bag through `fuse_bag` (`" << options.offline
       << "`): " << bags.fused_offline.size() << " frames; " << diff.size()
       << " frames in both; largest difference of a normal component: "
       << (diff.empty() ? 0.0 : *std::max_element(diff.begin(), diff.end()))
       << "\n";
  }
  md << "\n## Maps\n\n"
     << "Roughness = mean angle between neighbouring normals (degrees; "
        "lower is smoother); valid = share of pixels with a normal.\n\n"
     << "| map | roughness (deg) | valid |\n|---|---|---|\n";
  if (!tally.rough_in0.empty()) {
    md << "| normals_0 | " << mean(tally.rough_in0) << " | "
       << tally.valid0 / tally.rough_in0.size() << " |\n";
  }
  if (!tally.rough_in1.empty()) {
    md << "| normals_1 (at its own resolution) | " << mean(tally.rough_in1)
       << " | " << tally.valid1 / tally.rough_in1.size() << " |\n";
  }
  md << "| fused | " << mean(tally.rough_out) << " | 1 |\n";
  if (!tally.psnr_out.empty()) {
    md << "\n## Accuracy against the ground truth\n\n"
       << "| map | PSNR (dB) | mean angular error (deg) |\n|---|---|---|\n";
    if (!tally.psnr_in0.empty()) {
      md << "| normals_0 | " << mean(tally.psnr_in0) << " | "
         << mean(tally.angle_in0) << " |\n";
    }
    if (!tally.psnr_in1.empty()) {
      md << "| normals_1 | " << mean(tally.psnr_in1) << " | "
         << mean(tally.angle_in1) << " |\n";
    }
    md << "| fused | " << mean(tally.psnr_out) << " | " << mean(tally.angle_out)
       << " |\n";
  }
  md << "\n## Pictures\n\n"
     << "`frames/frame_NNN.png`: image, normals_0, normals_1 (a smaller "
        "map upsampled for display), fused; colour c = (n + 1) / 2 * 255 with "
        "x -> R, "
        "y -> G, z -> B, black = missing.\n\n"
     << "![first frame](first_frame.png)\n";
  md << "\n## Per frame\n\n" << tally.table.str();
}

}  // namespace

int main(int argc, char** argv) {
  Options options;
  if (!parseOptions(argc, argv, options)) return 2;
  if (options.input.empty() || options.fused_path.empty() ||
      options.dir.empty()) {
    std::fputs(kUsage, stderr);
    return 2;
  }
  ros::Time::init();
  try {
    const Bags bags = readBags(options);
    mkdir(options.dir.c_str(), 0755);
    mkdir((options.dir + "/frames").c_str(), 0755);

    Tally tally;
    tally.table << "| frame | stamp (s) | inputs | outer | inner | warm | "
                   "solve (ms) | latency (ms) | E start | E end | dropped so "
                   "far |\n"
                << "|---|---|---|---|---|---|---|---|---|---|---|\n";
    int index = 0;
    for (const auto& [stamp, fused_msg] : bags.fused) {
      const nf::NormalMap out = normalsOf(*fused_msg);
      const auto inputs =
          writeFramePicture(bags, stamp, out, index, options.dir, tally);
      compareFrame(bags, stamp, out, inputs.first, inputs.second, tally);
      addStatsRow(bags.stats.count(stamp) ? bags.stats.at(stamp) : nullptr,
                  index, stamp, tally);
      ++index;
    }
    const int frames = index;
    writeSummary(options, bags, tally, frames);
    std::printf("bag_report: %d frames -> %s/summary.md, %s/frames/\n", frames,
                options.dir.c_str(), options.dir.c_str());
    return frames > 0 ? 0 : 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bag_report: %s\n", e.what());
    return 1;
  }
}
