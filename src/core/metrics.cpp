// Accuracy metrics of normal maps: PSNR (the paper's) and angular-error
// statistics (the NYUv2 convention).
#include "normal_fusion/metrics.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kRadToDeg = 180.0 / kPi;
/// d_max of the PSNR: the largest distance between two unit vectors.
constexpr double kMaxDistance = 2.0;

std::string sizeText(const PlanarImage& image) {
  std::ostringstream text;
  text << image.width() << "x" << image.height() << "x" << image.channels();
  return text.str();
}

/// Throws InputError unless both maps are 3-plane maps of one size and the mask
/// is empty or a 1-plane map of that size.
void checkInputs(const char* what, const NormalMap& estimate,
                 const NormalMap& ground_truth, const ScalarMap* mask) {
  if (estimate.channels() != 3 || ground_truth.channels() != 3) {
    throw InputError(
        std::string(what) + ": expected 3-plane normal maps, got estimate " +
        sizeText(estimate) + " and ground truth " + sizeText(ground_truth));
  }
  if (!estimate.sameSize(ground_truth)) {
    throw InputError(
        std::string(what) + ": estimate and ground truth differ in size (" +
        sizeText(estimate) + " vs " + sizeText(ground_truth) + ")");
  }
  if (mask != nullptr && !mask->empty() &&
      (mask->channels() != 1 || !mask->sameSize(estimate))) {
    throw InputError(std::string(what) + ": expected a 1-plane mask of " +
                     std::to_string(estimate.width()) + "x" +
                     std::to_string(estimate.height()) + ", got " +
                     sizeText(*mask));
  }
}

void throwNothingEvaluated(const char* what) {
  throw InputError(std::string(what) +
                   ": no pixel is evaluated (expected at least one pixel "
                   "valid in both maps and selected by the mask)");
}

/// True when pixel i is valid in both maps and selected by the mask.
inline bool evaluated(const NormalMap& a, const NormalMap& b,
                      const ScalarMap& mask, std::size_t i) {
  if (!mask.empty() && !(mask.data()[i] > 0.5f)) return false;
  return isValidNormal(a.plane(0)[i], a.plane(1)[i], a.plane(2)[i]) &&
         isValidNormal(b.plane(0)[i], b.plane(1)[i], b.plane(2)[i]);
}

/// Angle in degrees between a(i) and b(i), in double precision.
inline double angleDegAt(const NormalMap& a, const NormalMap& b,
                         std::size_t i) {
  const double ax = a.plane(0)[i], ay = a.plane(1)[i], az = a.plane(2)[i];
  const double bx = b.plane(0)[i], by = b.plane(1)[i], bz = b.plane(2)[i];
  // |a x b| = |a||b| sin(angle), accurate near 0 and 180 degrees.
  const double cx = ay * bz - az * by;
  const double cy = az * bx - ax * bz;
  const double cz = ax * by - ay * bx;
  const double sine = std::sqrt(cx * cx + cy * cy + cz * cz);
  // a . b = |a||b| cos(angle); atan2 needs neither normalization nor clamping.
  const double cosine = ax * bx + ay * by + az * bz;
  return std::atan2(sine, cosine) * kRadToDeg;
}

}  // namespace

double psnr(const NormalMap& estimate, const NormalMap& ground_truth,
            const ScalarMap& mask) {
  checkInputs("psnr", estimate, ground_truth, &mask);
  double sum_squared = 0.0;
  std::size_t count = 0;
  for (std::size_t i = 0; i < estimate.pixelCount(); ++i) {
    if (!evaluated(estimate, ground_truth, mask, i)) continue;
    // |n - n_gt|^2 accumulated in double.
    for (int c = 0; c < 3; ++c) {
      const double d = static_cast<double>(estimate.plane(c)[i]) -
                       static_cast<double>(ground_truth.plane(c)[i]);
      sum_squared += d * d;
    }
    ++count;
  }
  if (count == 0) throwNothingEvaluated("psnr");
  // MSE = mean over the evaluated pixels.
  const double mse = sum_squared / static_cast<double>(count);
  // Identical maps: the ratio d_max^2 / 0 is unbounded, report +infinity.
  if (mse <= 0.0) return std::numeric_limits<double>::infinity();
  // PSNR = 10 log10(d_max^2 / MSE).
  return 10.0 * std::log10(kMaxDistance * kMaxDistance / mse);
}

AngularErrorStats angularError(const NormalMap& estimate,
                               const NormalMap& ground_truth,
                               const ScalarMap& mask) {
  checkInputs("angularError", estimate, ground_truth, &mask);
  std::vector<double> angles_deg;
  angles_deg.reserve(estimate.pixelCount());
  double sum_deg = 0.0;
  std::size_t within_11_25 = 0, within_22_5 = 0, within_30 = 0;
  for (std::size_t i = 0; i < estimate.pixelCount(); ++i) {
    if (!evaluated(estimate, ground_truth, mask, i)) continue;
    const double angle_deg = angleDegAt(estimate, ground_truth, i);
    angles_deg.push_back(angle_deg);
    sum_deg += angle_deg;
    within_11_25 += angle_deg <= 11.25 ? 1 : 0;
    within_22_5 += angle_deg <= 22.5 ? 1 : 0;
    within_30 += angle_deg <= 30.0 ? 1 : 0;
  }
  if (angles_deg.empty()) throwNothingEvaluated("angularError");

  AngularErrorStats stats;
  const std::size_t n = angles_deg.size();
  const double count = static_cast<double>(n);
  stats.pixel_count = static_cast<int>(n);
  stats.mean_deg = sum_deg / count;
  // Exact median: the middle element, or the mean of the two middle ones.
  const auto upper = angles_deg.begin() + static_cast<std::ptrdiff_t>(n / 2);
  std::nth_element(angles_deg.begin(), upper, angles_deg.end());
  if (n % 2 == 1) {
    stats.median_deg = *upper;
  } else {
    // After nth_element every element before `upper` is <= *upper.
    const double lower = *std::max_element(angles_deg.begin(), upper);
    stats.median_deg = 0.5 * (lower + *upper);
  }
  stats.within_11_25 = static_cast<double>(within_11_25) / count;
  stats.within_22_5 = static_cast<double>(within_22_5) / count;
  stats.within_30 = static_cast<double>(within_30) / count;
  return stats;
}

ScalarMap angularErrorMap(const NormalMap& estimate,
                          const NormalMap& ground_truth) {
  checkInputs("angularErrorMap", estimate, ground_truth, nullptr);
  ScalarMap error_deg(estimate.width(), estimate.height(), 1,
                      std::numeric_limits<float>::quiet_NaN());
  const ScalarMap no_mask;
  for (std::size_t i = 0; i < estimate.pixelCount(); ++i) {
    if (!evaluated(estimate, ground_truth, no_mask, i)) continue;
    error_deg.data()[i] =
        static_cast<float>(angleDegAt(estimate, ground_truth, i));
  }
  return error_deg;
}

}  // namespace normal_fusion
