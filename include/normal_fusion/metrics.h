// Accuracy metrics of normal maps against ground truth.
#pragma once

#include "normal_fusion/types.h"

namespace normal_fusion {

/// Angular-error statistics in degrees over the evaluated pixels.
struct AngularErrorStats {
  double mean_deg = 0.0;
  double median_deg = 0.0;
  double within_11_25 =
      0.0;  ///< share in [0, 1] of pixels with error <= 11.25 deg
  double within_22_5 = 0.0;
  double within_30 = 0.0;
  int pixel_count = 0;
};

/// Which pixels a metric evaluates: those where `mask` (1 plane) is > 0.5, or
/// all pixels where the estimate and the ground truth are both valid when the
/// mask is empty. Pixels where either map is invalid are always skipped.
/// PSNR = 10 log10(d_max^2 / MSE), d_max = 2, MSE the mean of |n - n_gt|^2.
/// Throws InputError on size or channel mismatch, or when no pixel is
/// evaluated.
double psnr(const NormalMap& estimate, const NormalMap& ground_truth,
            const ScalarMap& mask = ScalarMap());
AngularErrorStats angularError(const NormalMap& estimate,
                               const NormalMap& ground_truth,
                               const ScalarMap& mask = ScalarMap());
/// Per-pixel angle in degrees (NaN where either map is invalid).
ScalarMap angularErrorMap(const NormalMap& estimate,
                          const NormalMap& ground_truth);

}  // namespace normal_fusion
