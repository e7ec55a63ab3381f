#include "eval/plot.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace plot {
namespace {

/// A tick label: `digits` decimals.
std::string fixed(double value, int digits) {
  if (std::isnan(value)) return "-";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  std::ostringstream text;
  text << std::fixed << std::setprecision(digits) << value;
  return text.str();
}

/// The axes' ranges and the canvas layout of a plot.
struct Layout {
  double x_min = 0.0, x_max = 1.0;
  double y_min = 0.0, y_max = 1.0, y_step = 1.0;
  int legend_w = 250;
  int width = 0, height = 600;
  int left = 80, right = 0, top = 50, bottom = 70;

  int px(double x) const {
    return left + static_cast<int>(std::lround((x - x_min) / (x_max - x_min) *
                                               (width - left - right)));
  }
  int py(double psnr_db) const {
    return height - bottom -
           static_cast<int>(std::lround((psnr_db - y_min) / (y_max - y_min) *
                                        (height - top - bottom)));
  }
};

/// Data ranges, padded; y ticks on a step of 1, 2, 5 or 10 dB; the legend
/// as wide as its longest label.
Layout layoutOf(const std::vector<double>& xs,
                const std::vector<Series>& series) {
  Layout l;
  double y_min = std::numeric_limits<double>::infinity();
  double y_max = -y_min;
  for (const Series& s : series) {
    for (double v : s.psnr_db) {
      if (!std::isfinite(v)) continue;
      y_min = std::min(y_min, v);
      y_max = std::max(y_max, v);
    }
  }
  if (!std::isfinite(y_min)) {
    y_min = 0.0;
    y_max = 1.0;
  }
  double step = 1.0;
  for (double candidate : {1.0, 2.0, 5.0, 10.0, 20.0}) {
    step = candidate;
    if ((y_max - y_min) / candidate <= 10.0) break;
  }
  l.y_min = std::floor(y_min / step) * step;
  l.y_max = std::ceil(y_max / step) * step;
  if (l.y_max <= l.y_min) l.y_max = l.y_min + step;
  l.y_step = step;
  // x padded by half the smallest spacing of the xs.
  double pad = 0.5;
  for (std::size_t i = 1; i < xs.size(); ++i) {
    pad = std::min(pad, 0.5 * std::abs(xs[i] - xs[i - 1]));
  }
  l.x_min = *std::min_element(xs.begin(), xs.end()) - pad;
  l.x_max = *std::max_element(xs.begin(), xs.end()) + pad;
  // The legend sits right of the axes, clear of the curves.
  for (const Series& s : series) {
    int baseline = 0;
    const cv::Size text =
        cv::getTextSize(s.label, cv::FONT_HERSHEY_SIMPLEX, 0.5, 1, &baseline);
    l.legend_w = std::max(l.legend_w, text.width + 70);
  }
  l.width = 900 + l.legend_w;
  l.right = 30 + l.legend_w;
  return l;
}

/// Grid, ticks (x at every xs, y every step), axes, their labels, the title.
void drawAxes(const Layout& l, const std::string& title,
              const std::string& x_label, const std::vector<double>& xs,
              int x_digits, cv::Mat* canvas) {
  const cv::Scalar black(0, 0, 0), grid(225, 225, 225);
  const int width = l.width, height = l.height;
  for (double value : xs) {
    const int x = l.px(value);
    cv::line(*canvas, {x, l.top}, {x, height - l.bottom}, grid, 1);
    cv::line(*canvas, {x, height - l.bottom}, {x, height - l.bottom + 6}, black,
             1);
    drawText(canvas, fixed(value, x_digits), {x - 12, height - l.bottom + 24},
             0.5, black);
  }
  for (double v = l.y_min; v <= l.y_max + 1e-9; v += l.y_step) {
    const int y = l.py(v);
    cv::line(*canvas, {l.left, y}, {width - l.right, y}, grid, 1);
    cv::line(*canvas, {l.left - 6, y}, {l.left, y}, black, 1);
    drawText(canvas, fixed(v, 0), {l.left - 40, y + 5}, 0.5, black);
  }
  cv::line(*canvas, {l.left, l.top}, {l.left, height - l.bottom}, black, 2);
  cv::line(*canvas, {l.left, height - l.bottom},
           {width - l.right, height - l.bottom}, black, 2);
  drawText(canvas, x_label, {(width + l.left) / 2 - 50, height - 20}, 0.6,
           black);
  // The y label, drawn horizontally then turned by 90 degrees.
  cv::Mat label(30, 120, CV_8UC3, cv::Scalar(255, 255, 255));
  drawText(&label, "PSNR (dB)", {5, 22}, 0.6, black);
  cv::rotate(label, label, cv::ROTATE_90_COUNTERCLOCKWISE);
  label.copyTo((*canvas)(
      cv::Rect(8, (height - label.rows) / 2, label.cols, label.rows)));
  drawText(canvas, title, {l.left, 32}, 0.6, black, 1);
}

/// Curves with markers, then the legend right of the axes.
void drawSeries(const Layout& l, const std::vector<double>& xs,
                const std::vector<Series>& series, cv::Mat* canvas) {
  for (const Series& s : series) {
    for (std::size_t i = 0; i < xs.size(); ++i) {
      if (!std::isfinite(s.psnr_db[i])) continue;
      const cv::Point p(l.px(xs[i]), l.py(s.psnr_db[i]));
      cv::circle(*canvas, p, 4, s.colour, cv::FILLED, cv::LINE_AA);
      if (i + 1 < xs.size() && std::isfinite(s.psnr_db[i + 1])) {
        cv::line(*canvas, p, {l.px(xs[i + 1]), l.py(s.psnr_db[i + 1])},
                 s.colour, s.thickness, cv::LINE_AA);
      }
    }
  }
  const int row_h = 24;
  const cv::Scalar black(0, 0, 0);
  const cv::Point corner(l.width - l.legend_w - 20, l.top + 10);
  const cv::Rect legend_box(corner.x, corner.y, l.legend_w,
                            row_h * static_cast<int>(series.size()) + 10);
  cv::rectangle(*canvas, legend_box, cv::Scalar(255, 255, 255), cv::FILLED);
  cv::rectangle(*canvas, legend_box, black, 1);
  for (std::size_t i = 0; i < series.size(); ++i) {
    const int y = corner.y + 18 + row_h * static_cast<int>(i);
    cv::line(*canvas, {corner.x + 10, y - 5}, {corner.x + 45, y - 5},
             series[i].colour, series[i].thickness, cv::LINE_AA);
    cv::circle(*canvas, {corner.x + 27, y - 5}, 4, series[i].colour, cv::FILLED,
               cv::LINE_AA);
    drawText(canvas, series[i].label, {corner.x + 55, y}, 0.5, black);
  }
}

}  // namespace

void drawText(cv::Mat* canvas, const std::string& text, cv::Point origin,
              double scale, const cv::Scalar& colour, int thickness) {
  cv::putText(*canvas, text, origin, cv::FONT_HERSHEY_SIMPLEX, scale, colour,
              thickness, cv::LINE_AA);
}

void writeLinePlot(const std::string& path, const std::string& title,
                   const std::string& x_label, const std::vector<double>& xs,
                   int x_digits, const std::vector<Series>& series) {
  const Layout layout = layoutOf(xs, series);
  cv::Mat canvas(layout.height, layout.width, CV_8UC3,
                 cv::Scalar(255, 255, 255));
  drawAxes(layout, title, x_label, xs, x_digits, &canvas);
  drawSeries(layout, xs, series, &canvas);
  if (!cv::imwrite(path, canvas)) {
    throw InputError("cannot write '" + path + "'");
  }
}

}  // namespace plot
}  // namespace normal_fusion
