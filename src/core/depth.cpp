// Normals and confidence from depth: central differences and a plane fit in
// inverse depth (see depth.h for the equations).
#include "normal_fusion/depth.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>

#include "normal_fusion/detail/multiversion.h"
#include "normal_fusion/errors.h"

namespace normal_fusion {
namespace depth {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

void requireRange(const char* name, double value, double lo, double hi) {
  if (!(value >= lo && value <= hi)) {
    std::ostringstream msg;
    msg << "depth normals: " << name << " = " << value << " is out of range; "
        << "expected a value in [" << lo << ", " << hi << "]";
    throw ParameterError(msg.str());
  }
}

void checkLayout(const char* what, int width, int height,
                 std::size_t step_bytes, std::size_t bytes_per_pixel) {
  if (width < 1 || height < 1) {
    std::ostringstream msg;
    msg << what << ": expected a depth image of at least 1x1, got " << width
        << "x" << height;
    throw InputError(msg.str());
  }
  if (step_bytes < static_cast<std::size_t>(width) * bytes_per_pixel) {
    std::ostringstream msg;
    msg << what << ": step " << step_bytes << " is shorter than a row of "
        << width << " pixels (" << width * bytes_per_pixel << " bytes)";
    throw InputError(msg.str());
  }
}

/// The camera constants the row kernels need: r(u, v) = (xr, yr, 1) with
/// yr = (v - cy) / fy, xr = (u - cx - s yr) / fx.
struct Camera {
  float fx, fy, s, cx, cy;
  float xr(float u, float yr) const { return (u - cx - s * yr) / fx; }
  float yr(float v) const { return (v - cy) / fy; }
};

/// sigma_n^2 / (a^2 d^2) = tr(J S J^T) - m^T S m with J = K^T [1 0 0; 0 1 0;
/// -u -v 1], m = J^T n and S symmetric (s00 s01 s02 s11 s12 s22).
inline float angularVariance(const Camera& c, float u, float v, float s00,
                             float s01, float s02, float s11, float s12,
                             float s22, float nx, float ny, float nz) {
  const float e0 = c.cx - u, e1 = c.cy - v;
  // tr(J S J^T): the quadratic forms of J's rows (fx, 0, 0), (s, fy, 0),
  // (e0, e1, 1).
  const float trace =
      c.fx * c.fx * s00 +
      (c.s * c.s * s00 + 2.0f * c.s * c.fy * s01 + c.fy * c.fy * s11) +
      (e0 * e0 * s00 + e1 * e1 * s11 + s22 +
       2.0f * (e0 * e1 * s01 + e0 * s02 + e1 * s12));
  // m = J^T n.
  const float m0 = c.fx * nx + c.s * ny + e0 * nz;
  const float m1 = c.fy * ny + e1 * nz;
  const float m2 = nz;
  const float quad = m0 * m0 * s00 + m1 * m1 * s11 + m2 * m2 * s22 +
                     2.0f * (m0 * m1 * s01 + m0 * m2 * s02 + m1 * m2 * s12);
  return std::max(trace - quad, 0.0f);
}

/// The confidence of depth.h from sigma_n^2 / (a^2 d^2), the plane distance
/// d, the normal n, the ray r and d_edge; 0 where the normal is NaN.
struct ConfidenceConstants {
  float a2;        ///< noise_coefficient^2
  float inv_s0_2;  ///< 1 / s0^2
  float inv_edge;  ///< 1 / edge_distance (0: no edge factor)
  bool edge_enabled;
};

inline float confidenceAt(const ConfidenceConstants& k, float variance_unit,
                          float d, float n_dot_r, float r_norm2,
                          float edge_px) {
  // sigma_n^2 = a^2 d^2 (...), then exp(-(sigma_n / s0)^2).
  const float q = k.a2 * d * d * variance_unit * k.inv_s0_2;
  const float cos_view = std::min(std::abs(n_dot_r) / std::sqrt(r_norm2), 1.0f);
  const float edge =
      k.edge_enabled ? std::min(edge_px * k.inv_edge, 1.0f) : 1.0f;
  const float c = std::exp(-q) * cos_view * edge;
  return c >= 0.0f ? c : 0.0f;  // NaN (unknown normal) -> 0
}

/// One row of central differences (padded depth, pad 1): normals and, when
/// `conf` is given, confidence.
NF_MULTIVERSION
void centralDifferenceRow(int width, int y, const Camera& cam,
                          const float* __restrict z_up,
                          const float* __restrict z_mid,
                          const float* __restrict z_down,
                          const float* __restrict edge,
                          const ConfidenceConstants& k, float* __restrict nx,
                          float* __restrict ny, float* __restrict nz,
                          float* __restrict conf) {
  const float v = static_cast<float>(y);
  const float yr_up = cam.yr(v - 1.0f), yr = cam.yr(v),
              yr_down = cam.yr(v + 1.0f);
  // S of the four neighbours (+-1, 0), (0, +-1): diag(1/2, 1/2, 1/4).
  constexpr float s00 = 0.5f, s11 = 0.5f, s22 = 0.25f;
  for (int x = 0; x < width; ++x) {
    // Padded index x + 1 is pixel x.
    const float u = static_cast<float>(x);
    const float zc = z_mid[x + 1];
    const float zl = z_mid[x], zr = z_mid[x + 2];
    const float zu = z_up[x + 1], zd = z_down[x + 1];
    // a = P(u+1, v) - P(u-1, v), b = P(u, v+1) - P(u, v-1).
    const float ax = zr * cam.xr(u + 1.0f, yr) - zl * cam.xr(u - 1.0f, yr);
    const float ay = (zr - zl) * yr;
    const float az = zr - zl;
    const float bx = zd * cam.xr(u, yr_down) - zu * cam.xr(u, yr_up);
    const float by = zd * yr_down - zu * yr_up;
    const float bz = zd - zu;
    // n = a x b, normalized (NaN when a neighbour has no depth).
    float cx = ay * bz - az * by;
    float cy = az * bx - ax * bz;
    float cz = ax * by - ay * bx;
    const float inv_len = 1.0f / std::sqrt(cx * cx + cy * cy + cz * cz);
    const float rx = cam.xr(u, yr);
    // Face the camera: n . r <= 0; no depth at the centre: unknown.
    const float dot = (cx * rx + cy * yr + cz) * inv_len;
    const float sign = dot > 0.0f ? -inv_len : inv_len;
    const bool has_depth = zc == zc;
    cx = has_depth ? cx * sign : kNaN;
    cy = has_depth ? cy * sign : kNaN;
    cz = has_depth ? cz * sign : kNaN;
    nx[x] = cx;
    ny[x] = cy;
    nz[x] = cz;
    if (conf != nullptr) {
      const float n_dot_r = cx * rx + cy * yr + cz;
      const float d = -zc * n_dot_r;  // n . P_c = -d
      const float var = angularVariance(cam, u, v, s00, 0.0f, 0.0f, s11, 0.0f,
                                        s22, cx, cy, cz);
      conf[x] = confidenceAt(k, var, d, n_dot_r, rx * rx + yr * yr + 1.0f,
                             edge != nullptr ? edge[x] : 1.0f);
    }
  }
}

/// The row sums of the plane fit: mask m, m du, m dv, m du^2, m du dv,
/// m dv^2, and of w - w_c: sum, du-, dv-weighted.
enum Sum { kN, kU, kV, kUU, kUV, kVV, kW, kUW, kVW, kNumSums };

/// Adds neighbour (du, dv) of every pixel of one row to the sums.
NF_MULTIVERSION
void accumulateNeighbour(int width, float du, float dv, float ratio,
                         float noise_k, const float* __restrict z_centre,
                         const float* __restrict w_centre,
                         const float* __restrict z_neighbour,
                         const float* __restrict w_neighbour,
                         float* __restrict sums, int stride) {
  float* __restrict sn = sums;
  float* __restrict su = sums + stride;
  float* __restrict sv = sums + 2 * stride;
  float* __restrict suu = sums + 3 * stride;
  float* __restrict suv = sums + 4 * stride;
  float* __restrict svv = sums + 5 * stride;
  float* __restrict sw = sums + 6 * stride;
  float* __restrict suw = sums + 7 * stride;
  float* __restrict svw = sums + 8 * stride;
  for (int x = 0; x < width; ++x) {
    const float zc = z_centre[x];
    // |z - z_c| <= tau(z_c); false for a neighbour (or centre) without depth.
    const float tau = zc * (ratio + noise_k * zc);
    const bool in = std::abs(z_neighbour[x] - zc) <= tau;
    const float m = in ? 1.0f : 0.0f;
    const float dw = in ? w_neighbour[x] - w_centre[x] : 0.0f;
    sn[x] += m;
    su[x] += m * du;
    sv[x] += m * dv;
    suu[x] += m * (du * du);
    suv[x] += m * (du * dv);
    svv[x] += m * (dv * dv);
    sw[x] += dw;
    suw[x] += du * dw;
    svw[x] += dv * dw;
  }
}

/// Solves the row's fits: A du + B dv + C' = w - w_c in least squares, then
/// g = K^T (A, B, C - A u - B v), n = -g / |g|, and the confidence.
NF_MULTIVERSION
void solvePlaneRow(int width, int y, const Camera& cam,
                   const float* __restrict sums, int stride,
                   const float* __restrict w_centre,
                   const float* __restrict edge, const ConfidenceConstants& k,
                   float* __restrict nx, float* __restrict ny,
                   float* __restrict nz, float* __restrict conf) {
  const float v = static_cast<float>(y);
  const float yr = cam.yr(v);
  for (int x = 0; x < width; ++x) {
    const float u = static_cast<float>(x);
    const double n = sums[x], su = sums[stride + x], sv = sums[2 * stride + x];
    const double suu = sums[3 * stride + x], suv = sums[4 * stride + x];
    const double svv = sums[5 * stride + x];
    const double sw = sums[6 * stride + x], suw = sums[7 * stride + x];
    const double svw = sums[8 * stride + x];
    // Adjugate of M = [suu suv su; suv svv sv; su sv n].
    const double c00 = svv * n - sv * sv, c01 = su * sv - suv * n;
    const double c02 = suv * sv - svv * su, c11 = suu * n - su * su;
    const double c12 = suv * su - suu * sv, c22 = suu * svv - suv * suv;
    const double det = suu * c00 + suv * c01 + su * c02;
    // det(M) is a sum of squared doubled triangle areas of lattice points:
    // >= 1 unless the points used are collinear.
    const bool solvable = det > 0.5;
    const double inv_det = solvable ? 1.0 / det : 0.0;
    const double A = (c00 * suw + c01 * svw + c02 * sw) * inv_det;
    const double B = (c01 * suw + c11 * svw + c12 * sw) * inv_det;
    const double C = (c02 * suw + c12 * svw + c22 * sw) * inv_det + w_centre[x];
    // g = K^T (A, B, C - A u - B v) = (fx A, s A + fy B, (cx - u) A +
    // (cy - v) B + C).
    const double gx = cam.fx * A;
    const double gy = cam.s * A + cam.fy * B;
    const double gz = (cam.cx - u) * A + (cam.cy - v) * B + C;
    const double glen = std::sqrt(gx * gx + gy * gy + gz * gz);
    // C is the fitted 1 / z at the pixel: > 0 for a plane in front.
    const bool ok = solvable && C > 0.0 && glen > 0.0;
    const double inv_glen = ok ? -1.0 / glen : 0.0;
    const float ox = ok ? static_cast<float>(gx * inv_glen) : kNaN;
    const float oy = ok ? static_cast<float>(gy * inv_glen) : kNaN;
    const float oz = ok ? static_cast<float>(gz * inv_glen) : kNaN;
    nx[x] = ox;
    ny[x] = oy;
    nz[x] = oz;
    if (conf != nullptr) {
      const float rx = cam.xr(u, yr);
      const float n_dot_r = ox * rx + oy * yr + oz;
      const float d = ok ? static_cast<float>(1.0 / glen) : kNaN;
      const float var = angularVariance(
          cam, u, v, static_cast<float>(c00 * inv_det),
          static_cast<float>(c01 * inv_det), static_cast<float>(c02 * inv_det),
          static_cast<float>(c11 * inv_det), static_cast<float>(c12 * inv_det),
          static_cast<float>(c22 * inv_det), ox, oy, oz);
      conf[x] = confidenceAt(k, var, d, n_dot_r, rx * rx + yr * yr + 1.0f,
                             edge != nullptr ? edge[x] : 1.0f);
    }
  }
}

}  // namespace

NormalMethod normalMethodFromString(const std::string& name) {
  if (name == "central_difference") return NormalMethod::kCentralDifference;
  if (name == "plane_fit") return NormalMethod::kPlaneFit;
  throw ParameterError("depth normals: unknown method '" + name +
                       "'; expected central_difference or plane_fit");
}

std::string toString(NormalMethod method) {
  return method == NormalMethod::kCentralDifference ? "central_difference"
                                                    : "plane_fit";
}

void DepthNormalSettings::validate() const {
  if (method != NormalMethod::kCentralDifference &&
      method != NormalMethod::kPlaneFit) {
    throw ParameterError("depth normals: unknown method");
  }
  requireRange("window_radius", window_radius, 1, 10);
  requireRange("discontinuity_ratio", discontinuity_ratio, 1e-6, 1.0);
  requireRange("discontinuity_noise_sigmas", discontinuity_noise_sigmas, 0.0,
               100.0);
  requireRange("noise_coefficient", noise_coefficient, 0.0, 1.0);
  requireRange("normal_sigma_scale", normal_sigma_scale, 1e-6, 100.0);
  requireRange("edge_distance", edge_distance, 0.0, 1000.0);
  requireRange("num_threads", num_threads, 1, 256);
}

std::size_t depthFromMillimetres(const void* data, int width, int height,
                                 std::size_t step_bytes, ScalarMap& depth_m) {
  checkLayout("16UC1 depth", width, height, step_bytes, 2);
  depth_m.resize(width, height, 1);
  std::size_t valid = 0;
  const auto* bytes = static_cast<const std::uint8_t*>(data);
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* row = bytes + static_cast<std::size_t>(y) * step_bytes;
    float* out = depth_m.plane(0) + static_cast<std::size_t>(y) * width;
    for (int x = 0; x < width; ++x) {
      std::uint16_t mm;
      std::memcpy(&mm, row + 2 * x, sizeof(mm));
      // Millimetres to metres; 0 = no depth.
      out[x] = mm == 0 ? kNaN : static_cast<float>(mm * 1e-3);
      valid += mm != 0;
    }
  }
  return valid;
}

std::size_t depthFromMetres(const void* data, int width, int height,
                            std::size_t step_bytes, ScalarMap& depth_m) {
  checkLayout("32FC1 depth", width, height, step_bytes, 4);
  depth_m.resize(width, height, 1);
  std::size_t valid = 0;
  const auto* bytes = static_cast<const std::uint8_t*>(data);
  for (int y = 0; y < height; ++y) {
    const std::uint8_t* row = bytes + static_cast<std::size_t>(y) * step_bytes;
    float* out = depth_m.plane(0) + static_cast<std::size_t>(y) * width;
    for (int x = 0; x < width; ++x) {
      float z;
      std::memcpy(&z, row + 4 * x, sizeof(z));
      // NaN, 0, negative, +-Inf: no depth.
      const bool ok = std::isfinite(z) && z > 0.0f;
      out[x] = ok ? z : kNaN;
      valid += ok;
    }
  }
  return valid;
}

DepthNormalEstimator::DepthNormalEstimator(
    const DepthNormalSettings& settings) {
  setSettings(settings);
}

void DepthNormalEstimator::setSettings(const DepthNormalSettings& settings) {
  settings.validate();
  settings_ = settings;
}

void DepthNormalEstimator::prepare(const ScalarMap& depth_m, int pad) {
  const int W = depth_m.width(), H = depth_m.height();
  pad_ = pad;
  z_pad_.resize(W + 2 * pad, H + 2 * pad, 1);
  w_pad_.resize(W + 2 * pad, H + 2 * pad, 1);
  z_pad_.fill(kNaN);
  w_pad_.fill(kNaN);
  const int Wp = W + 2 * pad;
  for (int y = 0; y < H; ++y) {
    const float* in = depth_m.plane(0) + static_cast<std::size_t>(y) * W;
    const std::size_t row = static_cast<std::size_t>(y + pad) * Wp + pad;
    float* z = z_pad_.plane(0) + row;
    float* w = w_pad_.plane(0) + row;
    for (int x = 0; x < W; ++x) {
      const bool ok = std::isfinite(in[x]) && in[x] > 0.0f;
      z[x] = ok ? in[x] : kNaN;
      w[x] = ok ? 1.0f / in[x] : kNaN;
    }
  }
}

void DepthNormalEstimator::edgeDistance() {
  const int Wp = z_pad_.width();
  const int W = Wp - 2 * pad_, H = z_pad_.height() - 2 * pad_;
  const float cap = static_cast<float>(settings_.edge_distance);
  edge_.resize(W, H, 1);
  edge_.fill(cap);
  const auto z = [&](int y, int x) {
    return z_pad_.plane(0)[static_cast<std::size_t>(y + pad_) * Wp + x + pad_];
  };
  // A jump between two 4-neighbours with depth: both get 0.5 (half a pixel
  // to the jump).
  const auto jump = [&](float a, float b) {
    if (!(a == a) || !(b == b)) return false;
    return std::abs(a - b) > discontinuityThreshold(std::min(a, b), settings_);
  };
  float* e = edge_.plane(0);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      if (x + 1 < W && jump(z(y, x), z(y, x + 1))) {
        e[i] = std::min(e[i], 0.5f);
        e[i + 1] = std::min(e[i + 1], 0.5f);
      }
      if (y + 1 < H && jump(z(y, x), z(y + 1, x))) {
        e[i] = std::min(e[i], 0.5f);
        e[i + W] = std::min(e[i + W], 0.5f);
      }
    }
  }
  // City-block distance: a forward and a backward pass.
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      if (x > 0) e[i] = std::min(e[i], e[i - 1] + 1.0f);
      if (y > 0) e[i] = std::min(e[i], e[i - W] + 1.0f);
    }
  }
  for (int y = H - 1; y >= 0; --y) {
    for (int x = W - 1; x >= 0; --x) {
      const std::size_t i = static_cast<std::size_t>(y) * W + x;
      if (x + 1 < W) e[i] = std::min(e[i], e[i + 1] + 1.0f);
      if (y + 1 < H) e[i] = std::min(e[i], e[i + W] + 1.0f);
    }
  }
}

void DepthNormalEstimator::compute(const ScalarMap& depth_m,
                                   const CameraIntrinsics& K,
                                   NormalMap& normals, ScalarMap* confidence) {
  if (depth_m.channels() != 1 || depth_m.empty()) {
    std::ostringstream msg;
    msg << "depth normals: expected a non-empty depth map of 1 plane, got "
        << depth_m.width() << "x" << depth_m.height() << " with "
        << depth_m.channels() << " planes";
    throw InputError(msg.str());
  }
  const int W = depth_m.width(), H = depth_m.height();
  K.validateForImage(W, H);
  const auto& k = K.K;
  if (!(k[0] > 0.0 && k[4] > 0.0) || k[3] != 0.0 || k[6] != 0.0 ||
      k[7] != 0.0 || k[8] != 1.0) {
    std::ostringstream msg;
    msg << "depth normals: expected K with fx, fy > 0, K[1][0] = 0 and last "
           "row (0, 0, 1), got fx = "
        << k[0] << ", fy = " << k[4] << ", K[1][0] = " << k[3] << ", last row ("
        << k[6] << ", " << k[7] << ", " << k[8] << ")";
    throw InputError(msg.str());
  }
  const DepthNormalSettings& s = settings_;
  const bool plane_fit = s.method == NormalMethod::kPlaneFit;
  const int pad = plane_fit ? s.window_radius : 1;
  prepare(depth_m, pad);
  const bool with_confidence = confidence != nullptr;
  const bool edge_enabled = with_confidence && s.edge_distance > 0.0;
  if (edge_enabled) edgeDistance();
  normals.resize(W, H, 3);
  if (with_confidence) confidence->resize(W, H, 1);

  const Camera cam{static_cast<float>(k[0]), static_cast<float>(k[4]),
                   static_cast<float>(k[1]), static_cast<float>(k[2]),
                   static_cast<float>(k[5])};
  const ConfidenceConstants cc{
      static_cast<float>(s.noise_coefficient * s.noise_coefficient),
      static_cast<float>(1.0 / (s.normal_sigma_scale * s.normal_sigma_scale)),
      s.edge_distance > 0.0 ? static_cast<float>(1.0 / s.edge_distance) : 0.0f,
      edge_enabled};
  const int threads = s.num_threads;
  if (static_cast<int>(scratch_.size()) < threads) scratch_.resize(threads);
  const int Wp = W + 2 * pad;
  const float* zp = z_pad_.plane(0);
  const float* wp = w_pad_.plane(0);
  const float ratio = static_cast<float>(s.discontinuity_ratio);
  const float noise_k = static_cast<float>(
      s.discontinuity_noise_sigmas * std::sqrt(2.0) * s.noise_coefficient);
  const int R = s.window_radius;

#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t out = static_cast<std::size_t>(y) * W;
    const float* edge_row = edge_enabled ? edge_.plane(0) + out : nullptr;
    float* conf_row = with_confidence ? confidence->plane(0) + out : nullptr;
    auto row = [&](int dy, int dx) {
      return static_cast<std::size_t>(y + pad + dy) * Wp + pad + dx;
    };
    if (!plane_fit) {
      centralDifferenceRow(W, y, cam, zp + row(-1, -1), zp + row(0, -1),
                           zp + row(1, -1), edge_row, cc,
                           normals.plane(0) + out, normals.plane(1) + out,
                           normals.plane(2) + out, conf_row);
      continue;
    }
    PlanarImage& sums = scratch_[omp_get_thread_num()];
    sums.resize(W, kNumSums, 1);
    sums.fill(0.0f);
    for (int dv = -R; dv <= R; ++dv) {
      for (int du = -R; du <= R; ++du) {
        accumulateNeighbour(W, static_cast<float>(du), static_cast<float>(dv),
                            ratio, noise_k, zp + row(0, 0), wp + row(0, 0),
                            zp + row(dv, du), wp + row(dv, du), sums.data(), W);
      }
    }
    solvePlaneRow(W, y, cam, sums.data(), W, wp + row(0, 0), edge_row, cc,
                  normals.plane(0) + out, normals.plane(1) + out,
                  normals.plane(2) + out, conf_row);
  }
}

void depthToNormals(const ScalarMap& depth_m, const CameraIntrinsics& K,
                    const DepthNormalSettings& settings, NormalMap& normals,
                    ScalarMap* confidence) {
  DepthNormalEstimator estimator(settings);
  estimator.compute(depth_m, K, normals, confidence);
}

}  // namespace depth
}  // namespace normal_fusion
