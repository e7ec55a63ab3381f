// The problem's checks, the warm-start state carried between frames, and
// the energy of a given map (computeEnergy()).
#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>

#include "normal_fusion/detail/solver_internal.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/solver.h"

namespace normal_fusion {

using internal::PreparedLevel;

namespace {

std::string sizeText(const PlanarImage& image) {
  std::ostringstream s;
  s << image.width() << "x" << image.height() << "x" << image.channels();
  return s.str();
}

}  // namespace

void validateProblem(const FusionProblem& problem) {
  const ColorImage& image = problem.image;
  if (image.empty() || image.width() < 2 || image.height() < 2) {
    throw InputError("image: expected at least 2x2 pixels, got " +
                     sizeText(image));
  }
  if (image.channels() != 1 && image.channels() != 3) {
    throw InputError("image: expected 1 (grey) or 3 (RGB) channels, got " +
                     std::to_string(image.channels()));
  }
  // Every value finite (v - v is 0 exactly then, NaN otherwise); one
  // branch-free pass.
  const std::size_t total = image.pixelCount() * image.channels();
  const float* values = image.data();
  unsigned bad = 0;
  for (std::size_t i = 0; i < total; ++i) {
    bad |= values[i] - values[i] == 0.0f ? 0u : 1u;
  }
  if (bad != 0) {
    throw InputError(
        "image: expected finite intensities, found a non-finite value");
  }
  problem.K.validate();
  if (problem.inputs.empty()) {
    throw InputError(
        "inputs: expected at least one normal map (no data terms given)");
  }
  for (std::size_t l = 0; l < problem.inputs.size(); ++l) {
    const NormalInput& in = problem.inputs[l];
    const std::string name = "input " + std::to_string(l);
    if (in.normals.channels() != 3) {
      throw InputError(name + ": expected 3 channels (x, y, z), got " +
                       std::to_string(in.normals.channels()));
    }
    if (!in.normals.sameSize(image)) {
      throw InputError(name + ": expected the image's size " +
                       std::to_string(image.width()) + "x" +
                       std::to_string(image.height()) + ", got " +
                       sizeText(in.normals));
    }
    if (!in.confidence.empty() &&
        (in.confidence.channels() != 1 || !in.confidence.sameSize(image))) {
      throw InputError(
          name + ": expected a 1-channel confidence of the image's size, got " +
          sizeText(in.confidence));
    }
    if (!std::isfinite(in.weight) || in.weight < 0.0) {
      std::ostringstream msg;
      msg << name << ": weight = " << in.weight
          << ", expected a finite value >= 0";
      throw ParameterError(msg.str());
    }
    in.orientation.validate();
  }
}

bool SolverState::compatible(int width, int height, int num_inputs) const {
  return normals.width() == width && normals.height() == height &&
         normals.channels() == 3 && dual_h.sameSize(normals) &&
         dual_v.sameSize(normals) &&
         static_cast<int>(dual_data.size()) == num_inputs &&
         std::all_of(
             dual_data.begin(), dual_data.end(),
             [this](const PlanarImage& q) { return q.sameSize(normals); });
}

void SolverState::resize(int width, int height, int num_inputs) {
  normals.resize(width, height, 3);
  dual_h.resize(width, height, 3);
  dual_v.resize(width, height, 3);
  dual_data.resize(num_inputs);
  for (PlanarImage& q : dual_data) q.resize(width, height, 3);
}

void SolverState::clear() {
  normals = NormalMap();
  dual_h = PlanarImage();
  dual_v = PlanarImage();
  dual_data.clear();
  converging = false;
}

void SolverState::clearKeepingCapacity() {
  normals.resizeKeepingCapacity(0, 0, 3);
  dual_h.resizeKeepingCapacity(0, 0, 3);
  dual_v.resizeKeepingCapacity(0, 0, 3);
  for (PlanarImage& q : dual_data) q.resizeKeepingCapacity(0, 0, 3);
  converging = false;
}

std::size_t SolverState::bytesHeld() const {
  std::size_t bytes =
      normals.bytesHeld() + dual_h.bytesHeld() + dual_v.bytesHeld();
  for (const PlanarImage& q : dual_data) bytes += q.bytesHeld();
  return bytes;
}
double computeEnergy(const FusionProblem& problem,
                     const SolverSettings& settings, const NormalMap& normals) {
  settings.validate();
  const PreparedLevel level = internal::prepareFinest(problem, settings);
  if (normals.channels() != 3 || normals.width() != level.width ||
      normals.height() != level.height) {
    throw InputError(
        "computeEnergy: expected normals of the image's size with "
        "3 channels, got " +
        sizeText(normals));
  }
  return internal::energy(level, settings.huber_eps, settings.penalty, normals,
                          resolveThreadCount(settings.num_threads));
}

}  // namespace normal_fusion
