// results.md sections 7 - 11: textured scenes, curved objects, depth
// cameras, rendered stereo and Middlebury Aloe.
#include <sstream>

#include "evaluate/evaluate.h"

namespace evaluate {
namespace {

std::string subTables(const std::vector<CaseResult>& cases,
                      const std::string& number) {
  std::ostringstream md;
  for (std::size_t k = 0; k < cases.size(); ++k) {
    md << "\n"
       << caseTables(cases[k], "### " + number +
                                   std::string(1, static_cast<char>('a' + k)) +
                                   ". ");
  }
  return md.str();
}

std::string texturedText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (!options.run_textured) return md.str();
  md << "\n## 7. Textured scenes: strong textures on planes, weak creases\n\n"
     << "Scenes " << nf::synthetic::kTexturedRoomScene << " and "
     << nf::synthetic::kTexturedCornerScene << " at " << options.width << "x"
     << options.height
     << ": checkerboards of 5, 12 and 30 cm cells on walls, floor and boxes, "
        "posters, a high-contrast random texture, and creases of weak "
        "contrast (boxes turned by 45 degrees whose two faces share albedo "
        "and light). Input: normals of structured-light depth ("
     << cameraText(nf::synthetic::structuredLightCamera())
     << ") by depth::depthToNormals, plane_fit and central_difference.\n"
     << subTables(r.textured, "7");
  return md.str();
}

std::string curvedText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (!options.run_curved) return md.str();
  md << "\n## 8. Curved objects: cylinders, spheres, tori\n\n"
     << "Scenes " << nf::synthetic::kCurvedLargeScene << " (objects of 0.2 - "
     << "0.6 m) and " << nf::synthetic::kCurvedSmallScene
     << " (0.04 - 0.2 m on a table), tori lying and standing. Inputs: the "
        "paper's noise at sigma "
     << fixed(options.curved_sigma, 2)
     << ", and plane_fit normals of structured-light depth.\n"
     << subTables(r.curved, "8");
  return md.str();
}

std::string depthCameraText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (!options.run_depthcam) return md.str();
  md << "\n## 9. Depth cameras at realistic levels\n\n"
     << "The rooms of --scenes (";
  for (std::size_t s = 0; s < options.scenes.size(); ++s) {
    md << (s ? "," : "") << options.scenes[s];
  }
  md << ") as two depth cameras deliver them, normals by "
        "depth::depthToNormals (central_difference, plane_fit; the camera's "
        "noise coefficient, otherwise the defaults):\n\n"
     << "- " << cameraText(nf::synthetic::structuredLightCamera()) << "\n"
     << "- " << cameraText(nf::synthetic::timeOfFlightCamera()) << "\n"
     << "\nFlying pixels: a pixel next to a depth jump takes a random mix of "
        "its depth and the neighbour's across the jump; losses fade in "
        "linearly below the thresholds.\n"
     << subTables(r.depthcam, "9");
  return md.str();
}

std::string stereoText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (!options.run_stereo || !r.stereo.ran) return md.str();
  const StereoOutcome& s = r.stereo;
  md << "\n## 10. Stereo: semi-global matching of a rendered pair\n\n"
     << "Scenes " << kStereoScenes[0] << ", " << kStereoScenes[1] << ", "
     << kStereoScenes[2] << " rendered at " << options.width << "x"
     << options.height << " from the left camera and from one moved "
     << fixed(options.stereo_baseline_m * 100.0, 0)
     << " cm to its right, matched at twice that size as a stereo camera "
        "matches at its sensor's resolution: OpenCV StereoSGBM (3-way, "
        "block 5, P1 8 x 25, P2 32 x 25, uniqueness 10, speckle window 100, "
        "a search range of 16-pixel blocks over the largest true disparity) "
        "on the luminance in 8 bits, the disparity reduced to the evaluated "
        "size (a 2x2 block's mean where all four have one within a pixel of "
        "each other); z = f b / d; plane_fit normals with the noise "
        "coefficient 0.3 px / (f b). SGBM gives a disparity at "
     << percent(s.depth_share)
     << " of the pixels (none in the left band the search range covers, "
        "at occlusions and on weak texture).\n\n"
     << "Stereo noise is correlated over many pixels: a wrong match moves a "
        "whole block (blobs, streaks along the rows), where a depth "
        "camera's noise is per pixel. The correlation of the depth error "
        "(over z^2) between pixels k apart along a row, mean over the "
        "scenes:\n\n"
     << "| depth | k = 1 | k = 4 | k = 16 |\n|---|---:|---:|---:|\n"
     << "| SGBM | " << fixed(s.correlation_stereo[0], 2) << " | "
     << fixed(s.correlation_stereo[1], 2) << " | "
     << fixed(s.correlation_stereo[2], 2) << " |\n"
     << "| structured light (section 9) | " << fixed(s.correlation_camera[0], 2)
     << " | " << fixed(s.correlation_camera[1], 2) << " | "
     << fixed(s.correlation_camera[2], 2) << " |\n"
     << "\nThe error pictures (example_stereo_*) show the same: patches of "
        "one wrong tilt, not speckle.\n\n"
     << caseTables(s.result, "### 10a. ");
  return md.str();
}

std::string aloeText(const Options& options, const Results& r) {
  std::ostringstream md;
  if (!options.run_aloe) return md.str();
  const AloeOutcome& a = r.aloe;
  md << "\n## 11. Real stereo: Middlebury Aloe\n\n";
  if (!a.ran) {
    md << "The Aloe case was " << a.note << ".\n";
    return md.str();
  }
  const nf::aloe::AloeSettings settings;
  md << "Middlebury 2006 Aloe (Debian's opencv-doc: aloeL.jpg, aloeR.jpg, "
        "aloeGT.png, 1282x1110) reduced by "
     << settings.downscale << " to " << a.width << "x" << a.height
     << ". The files carry no calibration: f = "
     << fixed(settings.focal_full_px, 0)
     << " px at full size (Middlebury's 2005 / 2006 rig), z = f b / d with "
        "no disparity offset, b = "
     << fixed(settings.baseline_m * 1000.0, 0) << " mm: depths "
     << fixed(a.depth_min_m, 2) << " - " << fixed(a.depth_max_m, 2)
     << " m (the baseline only scales the depth; the normals depend on f "
        "and on the missing offset). Ground-truth normals: the library's "
        "plane fit over "
     << 2 * settings.gt_window_radius + 1 << "x"
     << 2 * settings.gt_window_radius + 1
     << " pixels of the ground-truth disparity (whole pixels at full size, "
        "half pixels here; a reduced pixel whose block spans more than one "
        "step is unknown). The steps make terraces: a window inside one "
        "tread sees a face of constant disparity, one across a riser a "
        "steeper one, so the fit's normals wave across slanted faces; the "
        "fit over half the window differs from it by "
     << fixed(a.gt_window_change_deg, 2)
     << " deg on average. The same steps, reduction and fit on the textured "
        "room rendered at the full size (a baseline giving Aloe's largest "
        "disparity) leave "
     << fixed(a.gt_floor_deg, 2)
     << " deg of mean error against its exact normals: the ground truth's "
        "own error, which no method's score can go below. "
     << percent(a.gt_share) << " of the pixels have ground truth, "
     << percent(a.depth_share)
     << " of them an SGBM disparity (the rest: the left band, occlusions, "
        "scored as fill-in). Input: plane_fit normals of SGBM depth (as in "
        "section 10).\n\n"
     << caseTables(a.result, "### 11a. ");
  return md.str();
}

}  // namespace

std::string robotCasesText(const Options& options, const Results& results) {
  return texturedText(options, results) + curvedText(options, results) +
         depthCameraText(options, results) + stereoText(options, results) +
         aloeText(options, results);
}

}  // namespace evaluate
