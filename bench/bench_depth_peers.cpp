// Depth to normals, the library's estimators against OpenCV's RgbdNormals:
// time per frame (640x480 by default) of each on one thread, median of N
// runs, as a markdown table. The library's with a kept DepthNormalEstimator
// (normals alone and with the confidence); OpenCV's as the RgbdNormals call
// alone on its prepared input with a kept estimator, and as
// depth_peers::opencvDepthNormals per frame (the conversion, the
// estimator's set-up and the turn to face the camera included). Not a test:
// timings depend on the machine and its load, which are printed.
//
//   bench_depth_peers [--runs N] [--width W --height H]

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <vector>

#include "bench_util.h"
#include "eval/synthetic.h"
#include "normal_fusion/depth.h"
#ifdef NF_HAVE_RGBD
#include <opencv2/core.hpp>
#include <opencv2/rgbd.hpp>

#include "eval/depth_peers.h"
#endif

namespace nf = normal_fusion;
namespace nd = normal_fusion::depth;
namespace nb = normal_fusion::bench;

namespace {

/// Median milliseconds of `runs` calls of `work`, after one warm-up call.
double medianMs(int runs, const std::function<void()>& work) {
  return nb::median(nb::timesMs(runs, work));
}

void libraryRows(int runs, const nf::ScalarMap& depth,
                 const nf::CameraIntrinsics& K) {
  for (nd::NormalMethod method :
       {nd::NormalMethod::kCentralDifference, nd::NormalMethod::kPlaneFit}) {
    nd::DepthNormalSettings settings;
    settings.method = method;
    settings.num_threads = 1;
    nd::DepthNormalEstimator estimator(settings);
    nf::NormalMap normals;
    nf::ScalarMap confidence;
    const double alone =
        medianMs(runs, [&] { estimator.compute(depth, K, normals); });
    const double with_confidence = medianMs(
        runs, [&] { estimator.compute(depth, K, normals, &confidence); });
    const std::string name =
        nd::toString(method) +
        (method == nd::NormalMethod::kPlaneFit ? " (r = 2, default)" : "");
    std::printf("| %s | %.2f | %.2f | - |\n", name.c_str(), alone,
                with_confidence);
  }
}

#ifdef NF_HAVE_RGBD
void openCvRows(int runs, const nf::ScalarMap& depth,
                const nf::CameraIntrinsics& K) {
  namespace dp = nf::depth_peers;
  const int W = depth.width(), H = depth.height();
  cv::Mat depth_cv(H, W, CV_32FC1), points_cv(H, W, CV_32FC3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const float z = depth.at(0, y, x);
      depth_cv.at<float>(y, x) = z;
      points_cv.at<cv::Vec3f>(y, x) =
          cv::Vec3f(static_cast<float>(z * (x - K.cx()) / K.fx()),
                    static_cast<float>(z * (y - K.cy()) / K.fy()), z);
    }
  }
  const cv::Mat K_cv =
      (cv::Mat_<float>(3, 3) << K.fx(), 0, K.cx(), 0, K.fy(), K.cy(), 0, 0, 1);
  const int methods[] = {cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_FALS,
                         cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_LINEMOD,
                         cv::rgbd::RgbdNormals::RGBD_NORMALS_METHOD_SRI};
  const std::vector<dp::OpenCvNormalMethod> ours = dp::allOpenCvMethods();
  for (std::size_t m = 0; m < ours.size(); ++m) {
    cv::rgbd::RgbdNormals estimator(H, W, CV_32F, K_cv, dp::kDefaultWindow,
                                    methods[m]);
    const cv::Mat& input =
        ours[m] == dp::OpenCvNormalMethod::kLinemod ? depth_cv : points_cv;
    cv::Mat normals_cv;
    const double call = medianMs(runs, [&] { estimator(input, normals_cv); });
    const double wrapped =
        medianMs(runs, [&] { dp::opencvDepthNormals(depth, K, ours[m]); });
    std::printf("| OpenCV %s (window %d) | %.2f | - | %.2f |\n",
                dp::name(ours[m]).c_str(), dp::kDefaultWindow, call, wrapped);
  }
}
#endif

}  // namespace

int main(int argc, char** argv) {
  int runs = 30, width = 640, height = 480;
  for (int i = 1; i < argc; i += 2) {
    const std::string option = argv[i];
    const int value = i + 1 < argc ? std::atoi(argv[i + 1]) : 0;
    if (option == "--runs" && value > 0) {
      runs = value;
    } else if (option == "--width" && value >= 16) {
      width = value;
    } else if (option == "--height" && value >= 16) {
      height = value;
    } else {
      std::fprintf(stderr,
                   "usage: bench_depth_peers [--runs N] [--width W --height "
                   "H]\n");
      return 2;
    }
  }
#ifdef NF_HAVE_RGBD
  cv::setNumThreads(1);
#endif
  std::printf("%s\n", nb::machineLine().c_str());
  std::printf("frame %dx%d, one thread, median of %d runs\n\n", width, height,
              runs);
  // Scene 2 with depth-camera noise and dropout (the content barely changes
  // the work).
  const nf::synthetic::Frame frame =
      nf::synthetic::renderScene(2, width, height);
  const nf::ScalarMap noisy =
      nf::synthetic::addDepthNoise(frame.depth, 0.0015, 0.001, 0.02, 1);
  std::printf(
      "| estimator | normals (ms) | normals + confidence (ms) | "
      "opencvDepthNormals, set-up included (ms) |\n");
  std::printf("|---|---:|---:|---:|\n");
  libraryRows(runs, noisy, frame.K);
#ifdef NF_HAVE_RGBD
  openCvRows(runs, noisy, frame.K);
#else
  std::printf("\n(OpenCV's rgbd module was not found at build time)\n");
#endif
  return 0;
}
