// evaluate's pictures: the plot of the paper case and the example scenes'
// normal maps, error maps and their panel.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "eval/plot.h"
#include "evaluate/evaluate.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/io.h"

namespace evaluate {

using nf::plot::drawText;
using nf::plot::Series;
using nf::plot::writeLinePlot;

void writePlot(const std::string& path, const std::vector<CaseResult>& results,
               const Options& options) {
  std::vector<Series> series = {
      {"noisy input", cv::Scalar(140, 140, 140), 2, {}},
      {"bilateral (paper), best", cv::Scalar(60, 160, 40), 2, {}}};
  const std::vector<cv::Scalar> peer_colours = {
      cv::Scalar(200, 120, 30), cv::Scalar(30, 140, 230),
      cv::Scalar(180, 60, 160), cv::Scalar(40, 190, 200)};
  for (int f = 1; f < numFamilies(); ++f) {
    series.push_back({familyName(f) + ", best",
                      peer_colours[(f - 1) % peer_colours.size()],
                      2,
                      {}});
  }
  series.push_back({"regularizer", cv::Scalar(30, 30, 210), 3, {}});
  std::vector<double> sigmas;
  for (const CaseResult& r : results) {
    sigmas.push_back(r.sigma);
    series[0].psnr_db.push_back(r.rows[0].mean.valid.psnr_db);
    for (int f = 0; f < numFamilies(); ++f) {
      series[1 + f].psnr_db.push_back(
          r.rows[r.first_filter_row + f].mean.valid.psnr_db);
    }
    series.back().psnr_db.push_back(
        r.rows[r.regularizer_row].mean.valid.psnr_db);
  }
  writeLinePlot(path,
                "PSNR of the normals vs noise level (" +
                    std::to_string(options.scenes.size()) + " scene(s), " +
                    std::to_string(options.width) + "x" +
                    std::to_string(options.height) + "; filters at their best)",
                "noise sigma", sigmas, 1, series);
}
namespace {

/// File-name form of a method name: lower case, '_' for anything else.
std::string slug(const std::string& text) {
  std::string out;
  for (char c : text) {
    if (std::isalnum(static_cast<unsigned char>(c))) {
      out.push_back(
          static_cast<char>(std::tolower(static_cast<unsigned char>(c))));
    } else if (!out.empty() && out.back() != '_') {
      out.push_back('_');
    }
  }
  while (!out.empty() && out.back() == '_') out.pop_back();
  return out;
}

/// A picture with a caption bar above it.
cv::Mat captioned(const cv::Mat& picture, const std::string& line1,
                  const std::string& line2) {
  const int bar = 44;
  cv::Mat out(picture.rows + bar, picture.cols, CV_8UC3,
              cv::Scalar(255, 255, 255));
  picture.copyTo(out(cv::Rect(0, bar, picture.cols, picture.rows)));
  // Each line as large as fits the width, 0.5 at most.
  const auto fitted = [&](const std::string& text) {
    int baseline = 0;
    const cv::Size size =
        cv::getTextSize(text, cv::FONT_HERSHEY_SIMPLEX, 1.0, 1, &baseline);
    return std::min(0.5, (picture.cols - 8.0) / std::max(size.width, 1));
  };
  drawText(&out, line1, {4, 18}, fitted(line1), cv::Scalar(0, 0, 0));
  drawText(&out, line2, {4, 38}, fitted(line2), cv::Scalar(60, 60, 60));
  return out;
}

cv::Mat readBack(const std::string& path) {
  cv::Mat picture = cv::imread(path, cv::IMREAD_COLOR);
  if (picture.empty()) throw nf::InputError("cannot read back '" + path + "'");
  return picture;
}

/// The grid of the panels (3 columns) and, when asked, a colour bar of the
/// error scale.
cv::Mat panelOf(const std::vector<cv::Mat>& panels, bool error_bar = true) {
  // Grid of 3 columns and a colour bar of the error scale.
  const int columns = 3;
  // Cells at most kMaxCellWidth wide, so a large image's panel stays small.
  constexpr int kMaxCellWidth = 400;
  const double cell_scale =
      std::min(1.0, static_cast<double>(kMaxCellWidth) / panels[0].cols);
  const int cell_w = static_cast<int>(std::lround(panels[0].cols * cell_scale));
  const int cell_h = static_cast<int>(std::lround(panels[0].rows * cell_scale));
  const int gap = 6;
  const int rows = (static_cast<int>(panels.size()) + columns - 1) / columns;
  const int bar_h = error_bar ? 64 : 0;
  cv::Mat canvas(rows * (cell_h + gap) + bar_h + gap,
                 columns * (cell_w + gap) + gap, CV_8UC3,
                 cv::Scalar(255, 255, 255));
  for (std::size_t p = 0; p < panels.size(); ++p) {
    const int r = static_cast<int>(p) / columns,
              c = static_cast<int>(p) % columns;
    cv::Mat cell;
    cv::resize(panels[p], cell, cv::Size(cell_w, cell_h), 0, 0,
               cell_scale < 1.0 ? cv::INTER_AREA : cv::INTER_LINEAR);
    cell.copyTo(canvas(cv::Rect(gap + c * (cell_w + gap),
                                gap + r * (cell_h + gap), cell_w, cell_h)));
  }
  if (!error_bar) return canvas;
  // Colour bar: 0 .. kHeatmapMaxDeg degrees.
  const int bar_x = gap + 10, bar_y = rows * (cell_h + gap) + gap;
  const int bar_w = canvas.cols - 2 * bar_x;
  cv::Mat ramp(1, bar_w, CV_8UC1);
  for (int x = 0; x < bar_w; ++x) {
    ramp.at<unsigned char>(0, x) =
        static_cast<unsigned char>(std::lround(255.0 * x / (bar_w - 1)));
  }
  cv::Mat ramp_colour;
  cv::applyColorMap(ramp, ramp_colour, cv::COLORMAP_INFERNO);
  cv::resize(ramp_colour, ramp_colour, cv::Size(bar_w, 16), 0, 0,
             cv::INTER_NEAREST);
  ramp_colour.copyTo(canvas(cv::Rect(bar_x, bar_y, bar_w, 16)));
  for (int deg = 0; deg <= static_cast<int>(kHeatmapMaxDeg); deg += 15) {
    const int x = bar_x + static_cast<int>(
                              std::lround(deg / kHeatmapMaxDeg * (bar_w - 1)));
    drawText(&canvas, std::to_string(deg), {std::max(0, x - 8), bar_y + 34},
             0.45, cv::Scalar(0, 0, 0));
  }
  drawText(&canvas, "angular error, degrees (black: no normal)",
           {bar_x + bar_w / 2 - 150, bar_y + 56}, 0.45, cv::Scalar(0, 0, 0));
  return canvas;
}

}  // namespace

std::vector<std::string> writeExamples(const std::string& dir,
                                       const Example& example,
                                       const CaseResult& result,
                                       const Options& options) {
  std::vector<std::string> files;
  if (!example.taken) return files;
  const std::string& tag = example.tag;
  const std::string stem =
      (std::filesystem::path(dir) / ("example_" + tag + "_")).string();
  const auto add = [&](const std::string& name) {
    files.push_back(stem + name);
    return stem + name;
  };
  nf::io::writeImage(add("image.png"), example.image);
  nf::io::writeNormalPicture(add("gt.png"), example.gt);
  // The methods: input, each filter at its best setting for this sigma, the
  // regularizer.
  std::vector<std::pair<std::string, nf::NormalMap>> methods;
  std::vector<std::string> settings;
  methods.push_back({example.input_name, example.input});
  settings.push_back(example.input_setting);
  for (int f = 0; f < numFamilies(); ++f) {
    const Candidate& best = result.best[f];
    methods.push_back({familyName(f) + " best",
                       applyCandidate(best, example.input, example.image,
                                      options.settings.num_threads)});
    settings.push_back(candidateLabel(best, result.variant_names));
  }
  methods.push_back({"regularizer", example.regularizer});
  settings.push_back("default settings");
  std::vector<cv::Mat> panels;
  panels.push_back(captioned(readBack(files[0]), "image", "guide"));
  panels.push_back(
      captioned(readBack(files[1]), "ground truth", "normals (colour-coded)"));
  std::vector<cv::Mat> normal_panels = panels;
  for (std::size_t m = 0; m < methods.size(); ++m) {
    const std::string name = slug(methods[m].first);
    nf::io::writeNormalPicture(add(name + ".png"), methods[m].second);
    normal_panels.push_back(
        captioned(readBack(files.back()), methods[m].first, settings[m]));
    const std::string error_path = add("error_" + name + ".png");
    nf::io::writeHeatmap(error_path,
                         nf::angularErrorMap(methods[m].second, example.gt),
                         0.0, kHeatmapMaxDeg);
    const nf::AngularErrorStats stats =
        nf::angularError(methods[m].second, example.gt);
    panels.push_back(captioned(
        readBack(error_path),
        methods[m].first + ": mean " + fixed(stats.mean_deg, 1) + " deg",
        settings[m]));
  }
  const cv::Mat canvas = panelOf(panels);
  const std::string panel_path =
      (std::filesystem::path(dir) / ("errors_" + tag + ".png")).string();
  if (!cv::imwrite(panel_path, canvas)) {
    throw nf::InputError("cannot write '" + panel_path + "'");
  }
  files.insert(files.begin(), panel_path);
  if (example.normals_panel) {
    const std::string normals_path =
        (std::filesystem::path(dir) / ("normals_" + tag + ".png")).string();
    if (!cv::imwrite(normals_path, panelOf(normal_panels, false))) {
      throw nf::InputError("cannot write '" + normals_path + "'");
    }
    files.insert(files.begin() + 1, normals_path);
  }
  return files;
}

}  // namespace evaluate
