// Hand-drawn pictures of the evaluation (OpenCV drawing): text and a line
// plot of PSNR against one variable.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace normal_fusion {
namespace plot {

/// One curve of a plot.
struct Series {
  std::string label;
  cv::Scalar colour;  ///< BGR
  int thickness;
  std::vector<double> psnr_db;
};

/// Text in OpenCV's Hershey simplex font, anti-aliased.
void drawText(cv::Mat* canvas, const std::string& text, cv::Point origin,
              double scale, const cv::Scalar& colour, int thickness = 1);

/// A line plot of PSNR (dB) against x, one curve per series, markers at the
/// xs (ticks labelled with x_digits decimals), the legend right of the axes.
/// Throws InputError when the file cannot be written.
void writeLinePlot(const std::string& path, const std::string& title,
                   const std::string& x_label, const std::vector<double>& xs,
                   int x_digits, const std::vector<Series>& series);

}  // namespace plot
}  // namespace normal_fusion
