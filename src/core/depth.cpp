// Normals and confidence from depth: central differences and a plane fit in
// inverse depth (see depth.h for the equations).
#include "normal_fusion/depth.h"

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

/// exp(-q) for q >= 0 (NaN or q < 0 read as 0, q > 64 gives 0) in plain
/// arithmetic that vectorizes: e^-q = (e^(-q / 256))^256, the inner term by
/// its Taylor series to degree 5 (|q / 256| <= 1 / 4), then eight squarings
/// (relative error below 2e-5).
inline float expNeg(float q) {
  const float t = (q > 0.0f ? (q < 64.0f ? q : 64.0f) : 0.0f) * -(1.0f / 256);
  float p =
      1.0f +
      t * (1.0f + t * (0.5f + t * (1.0f / 6.0f +
                                   t * (1.0f / 24.0f + t * (1.0f / 120.0f)))));
  for (int k = 0; k < 8; ++k) p *= p;
  return q < 64.0f ? p : 0.0f;
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
  const float sigma2 = k.a2 * d * d * variance_unit;
  const float q = sigma2 * k.inv_s0_2;
  // min(1, |n . v| + sigma_n): the view factor of a noisy normal (|n . v| is
  // as uncertain as n itself).
  const float cos_view = std::min(
      std::abs(n_dot_r) / std::sqrt(r_norm2) + std::sqrt(sigma2), 1.0f);
  const float edge =
      k.edge_enabled ? std::min(edge_px * k.inv_edge, 1.0f) : 1.0f;
  const float c = expNeg(q) * cos_view * edge;
  // NaN (unknown normal or distance) -> 0.
  return (q == q && c >= 0.0f) ? c : 0.0f;
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
  const bool with_conf = conf != nullptr;
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
  }
  if (!with_conf) return;
  // The confidence in a loop of its own (it vectorizes apart).
  for (int x = 0; x < width; ++x) {
    const float u = static_cast<float>(x);
    const float rx = cam.xr(u, yr);
    const float n_dot_r = nx[x] * rx + ny[x] * yr + nz[x];
    const float d = -z_mid[x + 1] * n_dot_r;  // n . P_c = -d
    const float var = angularVariance(cam, u, v, s00, 0.0f, 0.0f, s11, 0.0f,
                                      s22, nx[x], ny[x], nz[x]);
    conf[x] =
        confidenceAt(k, var, d, n_dot_r, rx * rx + yr * yr + 1.0f, edge[x]);
  }
}

/// Pixels per block of the plane fit: the window sums of a block stay in
/// registers while the window's neighbours are added.
constexpr int kBlock = 16;

/// One row of plane fits. z, w: the padded depth and inverse depth at the
/// row's first pixel (rows `stride` apart, at least kBlock - 1 readable
/// columns after the row's last pixel). For each pixel: the least squares
/// A du + B dv + C' = w - w_c over the neighbours with |z - z_c| <= tau(z_c),
/// then g = K^T (A, B, C - A u - B v), n = -g / |g|, and the confidence.
// Over 80 lines: its passes share the block's sums, which stay in registers.
NF_MULTIVERSION
void planeFitRow(int width, int y, int R, std::ptrdiff_t stride,
                 const Camera& cam, float ratio, float noise_k,
                 const float* __restrict z, const float* __restrict w,
                 const float* __restrict edge, const ConfidenceConstants& k,
                 float* __restrict nx, float* __restrict ny,
                 float* __restrict nz, float* __restrict conf) {
  const float v = static_cast<float>(y);
  const float yr = cam.yr(v);
  const bool with_conf = conf != nullptr;
  for (int x0 = 0; x0 < width; x0 += kBlock) {
    float zc[kBlock], wc[kBlock], tau[kBlock];
    for (int j = 0; j < kBlock; ++j) {
      zc[j] = z[x0 + j];
      wc[j] = w[x0 + j];
      tau[j] = zc[j] * (ratio + noise_k * zc[j]);
    }
    // The sums of the normal equations: mask m and its du, dv moments, and
    // of w - w_c.
    float sn[kBlock] = {}, su[kBlock] = {}, sv[kBlock] = {};
    float suu[kBlock] = {}, suv[kBlock] = {}, svv[kBlock] = {};
    float sw[kBlock] = {}, suw[kBlock] = {}, svw[kBlock] = {};
    for (int dv = -R; dv <= R; ++dv) {
      const float fv = static_cast<float>(dv);
      for (int du = -R; du <= R; ++du) {
        const float fu = static_cast<float>(du);
        const float* zn = z + dv * stride + du + x0;
        const float* wn = w + dv * stride + du + x0;
        for (int j = 0; j < kBlock; ++j) {
          // |z - z_c| <= tau(z_c); false without depth at either.
          const bool in = std::abs(zn[j] - zc[j]) <= tau[j];
          const float m = in ? 1.0f : 0.0f;
          const float dw = in ? wn[j] - wc[j] : 0.0f;
          sn[j] += m;
          su[j] += m * fu;
          sv[j] += m * fv;
          suu[j] += m * (fu * fu);
          suv[j] += m * (fu * fv);
          svv[j] += m * (fv * fv);
          sw[j] += dw;
          suw[j] += fu * dw;
          svw[j] += fv * dw;
        }
      }
    }
    const int count = std::min(kBlock, width - x0);
    float ed[kBlock];
    for (int j = 0; j < kBlock; ++j) {
      ed[j] = j < count ? edge[x0 + j] : 1.0f;
    }
    // Solved for the whole block (lanes past the row's end are dropped),
    // confidence included.
    float ox[kBlock], oy[kBlock], oz[kBlock], oc[kBlock];
    for (int j = 0; j < kBlock; ++j) {
      const float u = static_cast<float>(x0 + j);
      // Adjugate of M = [suu suv su; suv svv sv; su sv n] (integer sums).
      const float n = sn[j], a_u = su[j], a_v = sv[j];
      const float a_uu = suu[j], a_uv = suv[j], a_vv = svv[j];
      const float c00 = a_vv * n - a_v * a_v, c01 = a_u * a_v - a_uv * n;
      const float c02 = a_uv * a_v - a_vv * a_u, c11 = a_uu * n - a_u * a_u;
      const float c12 = a_uv * a_u - a_uu * a_v;
      const float c22 = a_uu * a_vv - a_uv * a_uv;
      const float det = a_uu * c00 + a_uv * c01 + a_u * c02;
      // det(M) is a sum of squared doubled triangle areas of lattice
      // points: >= 1 unless the points used are collinear (the second term
      // bounds the rounding of large sums).
      const bool solvable = det > 0.5f + 1e-5f * a_uu * c00;
      const float inv_det = solvable ? 1.0f / det : 0.0f;
      const float A = (c00 * suw[j] + c01 * svw[j] + c02 * sw[j]) * inv_det;
      const float B = (c01 * suw[j] + c11 * svw[j] + c12 * sw[j]) * inv_det;
      const float C =
          (c02 * suw[j] + c12 * svw[j] + c22 * sw[j]) * inv_det + wc[j];
      // g = K^T (A, B, C - A u - B v).
      const float gx = cam.fx * A;
      const float gy = cam.s * A + cam.fy * B;
      const float gz = (cam.cx - u) * A + (cam.cy - v) * B + C;
      const float glen2 = gx * gx + gy * gy + gz * gz;
      // C is the fitted 1 / z at the pixel: > 0 for a plane in front.
      const bool ok = solvable && C > 0.0f && glen2 > 0.0f;
      const float inv_glen = ok ? 1.0f / std::sqrt(glen2) : kNaN;
      ox[j] = -gx * inv_glen;
      oy[j] = -gy * inv_glen;
      oz[j] = -gz * inv_glen;
      const float rx = cam.xr(u, yr);
      const float n_dot_r = ox[j] * rx + oy[j] * yr + oz[j];
      const float var = angularVariance(
          cam, u, v, c00 * inv_det, c01 * inv_det, c02 * inv_det, c11 * inv_det,
          c12 * inv_det, c22 * inv_det, ox[j], oy[j], oz[j]);
      // d = 1 / |g|.
      oc[j] = confidenceAt(k, var, inv_glen, n_dot_r, rx * rx + yr * yr + 1.0f,
                           ed[j]);
    }
    for (int j = 0; j < count; ++j) {
      nx[x0 + j] = ox[j];
      ny[x0 + j] = oy[j];
      nz[x0 + j] = oz[j];
      if (with_conf) conf[x0 + j] = oc[j];
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
  // kBlock more columns on the right: the plane fit reads whole blocks.
  const int Wp = W + 2 * pad + kBlock;
  z_pad_.resize(Wp, H + 2 * pad, 1);
  w_pad_.resize(Wp, H + 2 * pad, 1);
  z_pad_.fill(kNaN);
  w_pad_.fill(kNaN);
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
  const int W = Wp - 2 * pad_ - kBlock, H = z_pad_.height() - 2 * pad_;
  const float cap = static_cast<float>(settings_.edge_distance);
  const float ratio = static_cast<float>(settings_.discontinuity_ratio);
  const float noise_k =
      static_cast<float>(settings_.discontinuity_noise_sigmas * std::sqrt(2.0) *
                         settings_.noise_coefficient);
  edge_.resize(W, H, 1);
  float* e = edge_.plane(0);
  // A jump between two 4-neighbours with depth (|a - b| > tau(min(a, b)));
  // false where either has none (and at the NaN padding).
  const auto jump = [ratio, noise_k](float a, float b) {
    const float m = std::min(a, b);
    return std::abs(a - b) > m * (ratio + noise_k * m) ? 1 : 0;
  };
  // Pixels next to a jump are half a pixel from it.
  for (int y = 0; y < H; ++y) {
    const float* z =
        z_pad_.plane(0) + static_cast<std::ptrdiff_t>(y + pad_) * Wp + pad_;
    const float* up = z - Wp;
    const float* down = z + Wp;
    float* row = e + static_cast<std::size_t>(y) * W;
    for (int x = 0; x < W; ++x) {
      // Branch-free (it vectorizes): a sum of 0 / 1 instead of ||.
      const int jumps = jump(z[x], z[x + 1]) + jump(z[x], z[x - 1]) +
                        jump(z[x], up[x]) + jump(z[x], down[x]);
      row[x] = jumps > 0 ? 0.5f : cap;
    }
  }
  // City-block distance, separable: along the rows (two sweeps), then along
  // the columns (two sweeps, a row at a time).
  for (int y = 0; y < H; ++y) {
    float* row = e + static_cast<std::size_t>(y) * W;
    for (int x = 1; x < W; ++x) row[x] = std::min(row[x], row[x - 1] + 1.0f);
    for (int x = W - 2; x >= 0; --x) {
      row[x] = std::min(row[x], row[x + 1] + 1.0f);
    }
  }
  for (int y = 1; y < H; ++y) {
    float* row = e + static_cast<std::size_t>(y) * W;
    const float* prev = row - W;
    for (int x = 0; x < W; ++x) row[x] = std::min(row[x], prev[x] + 1.0f);
  }
  for (int y = H - 2; y >= 0; --y) {
    float* row = e + static_cast<std::size_t>(y) * W;
    const float* next = row + W;
    for (int x = 0; x < W; ++x) row[x] = std::min(row[x], next[x] + 1.0f);
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
  if (edge_enabled) {
    edgeDistance();
  } else {
    edge_.resize(W, H, 1);  // factor 1 (confidenceAt ignores it)
    edge_.fill(1.0f);
  }
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
  const int Wp = z_pad_.width();
  const float* zp = z_pad_.plane(0);
  const float* wp = w_pad_.plane(0);
  const float ratio = static_cast<float>(s.discontinuity_ratio);
  const float noise_k = static_cast<float>(
      s.discontinuity_noise_sigmas * std::sqrt(2.0) * s.noise_coefficient);
  const int R = s.window_radius;

#pragma omp parallel for num_threads(threads) schedule(static)
  for (int y = 0; y < H; ++y) {
    const std::size_t out = static_cast<std::size_t>(y) * W;
    const float* edge_row = edge_.plane(0) + out;
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
    planeFitRow(W, y, R, Wp, cam, ratio, noise_k, zp + row(0, 0),
                wp + row(0, 0), edge_row, cc, normals.plane(0) + out,
                normals.plane(1) + out, normals.plane(2) + out, conf_row);
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
