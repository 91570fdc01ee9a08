#include "structured_light_stabilizer/sim/simulator.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <opencv2/core/hal/hal.hpp>

namespace structured_light_stabilizer
{

namespace
{

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

// dot_to_sun_ratio refers to a beam of this divergence hitting the rock at
// this distance at normal incidence; a narrower beam concentrates the same
// power on a smaller footprint.
constexpr double kRefBeamSigmaRad = LightingParams::kReferenceBeamSigmaRad;
constexpr double kRefDistanceM = LightingParams::kReferenceDistanceM;

// Relative response of the B, G, R pixels of a Bayer sensor to 520 nm light:
// mostly green, with the usual cross-talk into blue and a little into red.
constexpr double kDotResponseBgr[3] = {0.22, 1.0, 0.08};

// Reflectance of the terrain behind the rock (B, G, R), lit like the rock.
constexpr double kBackgroundBgr[3] = {0.015, 0.025, 0.045};

// Rendering of the rock pixels: robust ray casts on a coarse pixel lattice,
// Newton refinement from the interpolated depth in between.
constexpr int kCoarseStep = 8;
// A lattice cell whose corner ray parameters spread more than this (per unit
// of the ray direction's z, i.e. in metres of depth) straddles a silhouette
// or an edge: its pixels get a robust cast each.
constexpr double kCoarseSpreadM = 0.05;

// Incommensurate frequency multipliers and weights of the jitter sines
// (tx, ty, tz, rx, ry, rz); square roots keep them incommensurate.
constexpr double kJitterMul[6][3] = {{1.000, 2.414, 3.732}, {1.118, 2.618, 4.123}, {0.866, 2.236, 3.317},
                                     {1.272, 2.828, 4.359}, {0.941, 2.449, 3.606}, {1.189, 2.646, 3.873}};
constexpr double kJitterWeight[3] = {0.6, 0.3, 0.1};

// ---------------------------------------------------------------------------
// Deterministic noise: own hashes, independent of the standard library's
// distributions (whose output differs between implementations).

inline uint32_t hash32(int32_t x, int32_t y, uint32_t seed)
{
  uint32_t h = seed * 0x9E3779B1u;
  h ^= static_cast<uint32_t>(x) * 0x85EBCA77u;
  h = (h << 13) | (h >> 19);
  h ^= static_cast<uint32_t>(y) * 0xC2B2AE3Du;
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  h *= 0x297A2D39u;
  h ^= h >> 15;
  return h;
}

inline uint64_t splitmix64(uint64_t* state)
{
  uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

// Smooth value noise in [-1, 1] with a unit lattice.
double valueNoise(double x, double y, uint32_t seed)
{
  const double fx = std::floor(x), fy = std::floor(y);
  const int32_t ix = static_cast<int32_t>(fx), iy = static_cast<int32_t>(fy);
  const double tx = x - fx, ty = y - fy;
  const double sx = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0);
  const double sy = ty * ty * ty * (ty * (ty * 6.0 - 15.0) + 10.0);
  auto v = [&](int32_t a, int32_t b) { return hash32(a, b, seed) * (2.0 / 4294967295.0) - 1.0; };
  const double a = v(ix, iy) + sx * (v(ix + 1, iy) - v(ix, iy));
  const double b = v(ix, iy + 1) + sx * (v(ix + 1, iy + 1) - v(ix, iy + 1));
  return a + sy * (b - a);
}

// Sum of value-noise octaves of the given feature sizes (m) and weights; each
// octave is rotated so that the lattice does not show as a grid.
double fractalNoise(double x, double y, uint32_t seed, const std::vector<std::pair<double, double>>& octaves)
{
  double sum = 0.0, wsum = 0.0;
  for (size_t k = 0; k < octaves.size(); ++k)
  {
    const double a = 0.61 + 1.37 * k;
    const double c = std::cos(a), s = std::sin(a);
    const double u = (c * x - s * y) / octaves[k].first;
    const double v = (s * x + c * y) / octaves[k].first;
    sum += octaves[k].second * valueNoise(u, v, seed + 7919u * static_cast<uint32_t>(k + 1));
    wsum += octaves[k].second;
  }
  return wsum > 0.0 ? sum / wsum : 0.0;
}

// Inverse of the standard normal CDF (Acklam's rational approximation,
// relative error 1.2e-9), used once to build the noise table.
double inverseNormalCdf(double p)
{
  static const double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,  -2.759285104469687e+02,
                             1.383577518672690e+02,  -3.066479806614716e+01, 2.506628277459239e+00};
  static const double b[] = {-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
                             6.680131188771972e+01, -1.328068155288572e+01};
  static const double c[] = {-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
                             -2.549732539343734e+00, 4.374664141464968e+00,  2.938163982698783e+00};
  static const double d[] = {7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
                             3.754408661907416e+00};
  const double plow = 0.02425;
  if (p < plow)
  {
    const double q = std::sqrt(-2.0 * std::log(p));
    return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  if (p > 1.0 - plow)
  {
    const double q = std::sqrt(-2.0 * std::log(1.0 - p));
    return -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  const double q = p - 0.5;
  const double r = q * q;
  return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
         (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
}

// Standard normal deviates as 4096 equiprobable quantiles indexed by 12
// random bits: one 64-bit draw gives five, from a table that stays in L1.
// The tails end at +-3.67 sigma and the variance is 0.9997 (both far below
// what an 8-bit frame shows).
constexpr int kNormalTableSize = 4096;
const std::vector<float>& normalTable()
{
  static const std::vector<float> table = []
  {
    std::vector<float> t(kNormalTableSize);
    for (int i = 0; i < kNormalTableSize; ++i)
      t[i] = static_cast<float>(inverseNormalCdf((i + 0.5) / kNormalTableSize));
    return t;
  }();
  return table;
}

uint64_t doubleBits(double v)
{
  uint64_t u;
  std::memcpy(&u, &v, sizeof(u));
  return u;
}

struct ClutterItem
{
  double x, y;      // rock frame, m
  double radius_m;  // Gaussian sigma of the patch on the surface
  double refl[3];   // B, G, R reflectance
  bool flat_top;    // mineral patches: a soft-edged disc rather than a Gaussian
};

}  // namespace

// ---------------------------------------------------------------------------

struct Simulator::Impl
{
  // Height field and its smooth gradient on a regular vertex grid over the
  // rock extent; vertex (i, j) at (x0 + i * cell, y0 + j * cell).
  int nx = 0, ny = 0;  // cells
  double cell = 0.004, inv_cell = 250.0, x0 = 0.0, y0 = 0.0, half_w = 1.0, half_h = 1.0;
  std::vector<float> h, gx, gy;
  std::vector<float> refl;    // B, G, R reflectance per vertex
  std::vector<float> sunlit;  // B, G, R reflectance * (sun cosine + sky) per vertex
  // Sunlit B, G, R and height interleaved per vertex: what a rock pixel
  // reads, in one or two cache lines, and one SIMD register per vertex.
  std::vector<float> hs;
  double hmin = 0.0, hmax = 0.0;
  double lip_x = 0.0, lip_y = 0.0;  // Lipschitz bounds of the bilinear surface
  // Per block of kBlock x kBlock cells: lowest vertex and slope bounds, for
  // the ray caster's empty-space skipping.
  static constexpr int kBlock = 8;
  struct BlockBound
  {
    double hmin, lip_x, lip_y;
  };
  int nbx = 0, nby = 0;
  std::vector<BlockBound> blocks;
  Eigen::Vector3d sun_dir = Eigen::Vector3d(0.0, 0.0, -1.0);  // rock frame, towards the sun (unit)
  double sky = 0.0;
  Eigen::Isometry3d T_rock_cam0 = Eigen::Isometry3d::Identity();
  // Rock sample lattice: sample (i, j) is the ray through pixel
  // (sub * i + (sub - 1) / 2, sub * j + (sub - 1) / 2).
  int sub = 1, rw = 0, rh = 0;
  std::vector<float> ray_lut;  // (x/z, y/z) per rock sample, only with lens distortion
  // Full-resolution pixel u -> samples i0, i1 and the weight of i1 (same for rows).
  std::vector<int> up_i0, up_i1, up_j0, up_j1;
  std::vector<float> up_wx, up_wy;
  std::vector<ClutterItem> clutter;

  int vertex(int i, int j) const { return j * (nx + 1) + i; }

  bool inside(double x, double y) const { return std::abs(x) <= half_w && std::abs(y) <= half_h; }

  void locate(double x, double y, int* i, int* j, double* fx, double* fy) const
  {
    double u = (x - x0) * inv_cell, v = (y - y0) * inv_cell;
    u = std::min(std::max(u, 0.0), static_cast<double>(nx));
    v = std::min(std::max(v, 0.0), static_cast<double>(ny));
    *i = std::min(static_cast<int>(u), nx - 1);
    *j = std::min(static_cast<int>(v), ny - 1);
    *fx = u - *i;
    *fy = v - *j;
  }

  // Bilinear height and the exact gradient of the bilinear patch (the
  // surface the ray caster intersects).
  double height(double x, double y, double* dhdx = nullptr, double* dhdy = nullptr) const
  {
    int i, j;
    double fx, fy;
    locate(x, y, &i, &j, &fx, &fy);
    const float* r0 = &h[vertex(i, j)];
    const float* r1 = r0 + (nx + 1);
    const double h00 = r0[0], h10 = r0[1], h01 = r1[0], h11 = r1[1];
    const double a = h00 + fx * (h10 - h00);
    const double b = h01 + fx * (h11 - h01);
    if (dhdx)
    {
      *dhdx = ((h10 - h00) * (1.0 - fy) + (h11 - h01) * fy) * inv_cell;
      *dhdy = (b - a) * inv_cell;
    }
    return a + fy * (b - a);
  }

  // Smooth outward normal (towards the camera side, -z), from the
  // interpolated central-difference gradient: used for shading and incidence.
  Eigen::Vector3d normal(double x, double y) const
  {
    int i, j;
    double fx, fy;
    locate(x, y, &i, &j, &fx, &fy);
    const int k = vertex(i, j);
    auto bil = [&](const std::vector<float>& g)
    {
      const double a = g[k] + fx * (g[k + 1] - g[k]);
      const double b = g[k + nx + 1] + fx * (g[k + nx + 2] - g[k + nx + 1]);
      return a + fy * (b - a);
    };
    return Eigen::Vector3d(bil(gx), bil(gy), -1.0).normalized();
  }

  void lookup3(const std::vector<float>& grid, double x, double y, float out[3]) const
  {
    int i, j;
    double fx, fy;
    locate(x, y, &i, &j, &fx, &fy);
    const float* p00 = &grid[3 * vertex(i, j)];
    const float* p01 = p00 + 3 * (nx + 1);
    const float w00 = static_cast<float>((1 - fx) * (1 - fy)), w10 = static_cast<float>(fx * (1 - fy));
    const float w01 = static_cast<float>((1 - fx) * fy), w11 = static_cast<float>(fx * fy);
    for (int c = 0; c < 3; ++c)
      out[c] = w00 * p00[c] + w10 * p00[3 + c] + w01 * p01[c] + w11 * p01[3 + c];
  }

  // First intersection of o + s d (rock frame, s >= 0) with the rock. Returns
  // false on a miss; *wall is set when the ray enters through a side wall of
  // the slab rather than the height field. Conservative Lipschitz steps never
  // skip the first root (occlusion and self-shadowing come out right); Newton
  // refines it to 1e-12 m once close.
  bool cast(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* s_hit, bool* wall) const
  {
    *wall = false;
    if (!(d.z() > 1e-12))
      return false;
    double s0 = std::max(0.0, (hmin - o.z()) / d.z());
    double s1 = (hmax - o.z()) / d.z();
    if (s1 < 0.0)
      return false;
    bool entered_by_wall = false;
    const double half[2] = {half_w, half_h};
    for (int a = 0; a < 2; ++a)
    {
      if (std::abs(d[a]) < 1e-15)
      {
        if (std::abs(o[a]) > half[a])
          return false;
        continue;
      }
      const double ta = (-half[a] - o[a]) / d[a], tb = (half[a] - o[a]) / d[a];
      const double lo = std::min(ta, tb), hi = std::max(ta, tb);
      if (lo > s0)
      {
        s0 = lo;
        entered_by_wall = true;
      }
      s1 = std::min(s1, hi);
    }
    if (s0 > s1)
      return false;
    // Rate at which the gap h - z can shrink per unit of s.
    const double k = d.z() + lip_x * std::abs(d.x()) + lip_y * std::abs(d.y());
    double s = s0;
    double gap = height(o.x() + s * d.x(), o.y() + s * d.y()) - (o.z() + s * d.z());
    if (gap <= 0.0)
    {
      if (entered_by_wall && s0 > 0.0)
      {
        *s_hit = s0;
        *wall = true;
        return true;
      }
      return false;  // starts inside the rock
    }
    // March over blocks of kBlock x kBlock cells: inside a block the ray
    // cannot meet the surface while it is below the block's lowest vertex,
    // and from there Lipschitz steps with the block's own slope bound (the
    // global one is set by the steepest spot of the whole rock) never skip
    // the first root; a step never leaves the block.
    const double block_m = kBlock * cell;
    int it = 0;
    for (; it < 4000 && gap > 2e-4; ++it)
    {
      const double px = o.x() + s * d.x(), py = o.y() + s * d.y();
      const int bi = std::min(std::max(static_cast<int>(std::floor((px - x0) / block_m)), 0), nbx - 1);
      const int bj = std::min(std::max(static_cast<int>(std::floor((py - y0) / block_m)), 0), nby - 1);
      double s_exit = s1;
      if (d.x() > 1e-15)
        s_exit = std::min(s_exit, (x0 + (bi + 1) * block_m - o.x()) / d.x());
      else if (d.x() < -1e-15)
        s_exit = std::min(s_exit, (x0 + bi * block_m - o.x()) / d.x());
      if (d.y() > 1e-15)
        s_exit = std::min(s_exit, (y0 + (bj + 1) * block_m - o.y()) / d.y());
      else if (d.y() < -1e-15)
        s_exit = std::min(s_exit, (y0 + bj * block_m - o.y()) / d.y());
      s_exit = std::max(s_exit, s);  // rounding at a boundary
      const BlockBound& bb = blocks[static_cast<size_t>(bj) * nbx + bi];
      const double s_reach = (bb.hmin - o.z()) / d.z();  // below the block's lowest vertex before this
      double next;
      if (s_reach >= s_exit)
        next = s_exit + 1e-9;  // passes over the whole block
      else if (s_reach > s)
        next = s_reach;  // the gap is measured again there
      else
        next = std::min(s + gap / (d.z() + bb.lip_x * std::abs(d.x()) + bb.lip_y * std::abs(d.y())), s_exit + 1e-9);
      // Progress at least as fast as the global bound allows.
      s = std::max(next, s + gap / k);
      if (s > s1)
        return false;
      gap = height(o.x() + s * d.x(), o.y() + s * d.y()) - (o.z() + s * d.z());
    }
    if (gap > 2e-4)
      return false;  // skims the surface for too long: count as a miss
    for (int n = 0; n < 20; ++n)
    {
      double hx, hy;
      const double x = o.x() + s * d.x(), y = o.y() + s * d.y();
      gap = height(x, y, &hx, &hy) - (o.z() + s * d.z());
      if (std::abs(gap) < 1e-12)
        break;
      const double slope = hx * d.x() + hy * d.y() - d.z();
      if (slope >= -1e-9)
      {
        s += std::max(gap, 0.0) / k;  // grazing: keep the safe step
        continue;
      }
      s -= gap / slope;
    }
    if (!(std::abs(gap) < 1e-9) || s > s1 + 1e-9)
      return false;
    *s_hit = s;
    return true;
  }
};

// ---------------------------------------------------------------------------

std::string SimulatorParams::validate() const
{
  std::ostringstream why;
  const std::string cam = sensor.camera.validate();
  if (!cam.empty())
    why << "camera: " << cam << "; ";
  auto finite_pos = [](double v) { return std::isfinite(v) && v > 0.0; };
  auto finite_nonneg = [](double v) { return std::isfinite(v) && v >= 0.0; };
  if (!finite_pos(sensor.pixel_size_m) || !finite_pos(sensor.focal_length_m) || !finite_pos(sensor.aperture_diameter_m))
    why << "pixel size, focal length and aperture must be positive; ";
  if (!(sensor.focus_distance_m > sensor.focal_length_m) || !std::isfinite(sensor.focus_distance_m))
    why << "focus distance " << sensor.focus_distance_m << " m must exceed the focal length; ";
  if (!finite_nonneg(sensor.read_noise_dn))
    why << "read_noise_dn must be >= 0; ";
  if (!finite_pos(sensor.gain_dn_per_electron))
    why << "gain_dn_per_electron must be > 0; ";
  if (!(rock.distance_m >= 0.2 && rock.distance_m <= 20.0))
    why << "rock distance " << rock.distance_m << " m is outside [0.2, 20]; ";
  if (!(rock.width_m > 0.0 && rock.width_m <= 5.0 && rock.height_m > 0.0 && rock.height_m <= 5.0))
    why << "rock size " << rock.width_m << " x " << rock.height_m << " m is outside (0, 5]; ";
  if (!(rock.relief_m >= 0.0 && rock.relief_m <= 1.0))
    why << "rock relief " << rock.relief_m << " m is outside [0, 1]; ";
  if (!std::isfinite(rock.step_height_m) || !std::isfinite(rock.step_x_m) || std::abs(rock.step_height_m) > 1.0)
    why << "rock step height must be finite and within [-1, 1] m; ";
  if (!(rock.relief_m + std::abs(rock.step_height_m) < 0.8 * rock.distance_m))
    why << "rock relief must stay well in front of the camera (< 0.8 x distance); ";
  if (!(rock.albedo_min >= 0.0 && rock.albedo_min <= rock.albedo_max && rock.albedo_max <= 1.0))
    why << "albedo range [" << rock.albedo_min << ", " << rock.albedo_max << "] must satisfy 0 <= min <= max <= 1; ";
  if (!(rock.texture_scale_m >= 0.002 && rock.texture_scale_m <= 1.0))
    why << "texture_scale_m " << rock.texture_scale_m << " is outside [0.002, 1]; ";
  if (!(std::abs(rock.tilt_x_rad) < 1.2 && std::abs(rock.tilt_y_rad) < 1.2))
    why << "rock tilt must stay below 1.2 rad; ";
  if (projector.rows < 1 || projector.cols < 1 || projector.rows > 100 || projector.cols > 100)
    why << "projector grid " << projector.rows << " x " << projector.cols << " is outside [1, 100]; ";
  if (!projector.origin_m.allFinite() || !std::isfinite(projector.pitch_x_rad) ||
      !std::isfinite(projector.pitch_y_rad) || !std::isfinite(projector.roll_rad))
    why << "projector origin, pitch and roll must be finite; ";
  if (!finite_pos(projector.converge_distance_m))
    why << "projector converge distance must be positive; ";
  if (!finite_nonneg(projector.beam_sigma_rad) || projector.beam_sigma_rad > 0.1)
    why << "beam_sigma_rad " << projector.beam_sigma_rad << " is outside [0, 0.1]; ";
  if (!finite_nonneg(projector.power_scale))
    why << "power_scale must be >= 0; ";
  if (!finite_nonneg(lighting.sun_level) || !finite_nonneg(lighting.dot_to_sun_ratio) || !finite_pos(lighting.exposure))
    why << "sun_level, dot_to_sun_ratio must be >= 0 and exposure > 0; ";
  if (!lighting.sun_direction.allFinite() || !(lighting.sun_direction.norm() > 1e-9) ||
      !finite_nonneg(lighting.sky_ambient) || lighting.sky_ambient > 1.0)
    why << "sun_direction must be a finite non-zero vector and sky_ambient in [0, 1]; ";
  if (!finite_nonneg(motion.jitter_translation_m) || !finite_nonneg(motion.jitter_rotation_rad) ||
      !finite_nonneg(motion.jitter_frequency_hz) || !finite_nonneg(motion.step_period_s) ||
      !finite_nonneg(motion.return_period_s) || !motion.drift_velocity_mps.allFinite() ||
      !motion.drift_angular_velocity_radps.allFinite() || !motion.step_translation_m.allFinite())
    why << "motion amplitudes, frequency and periods must be finite and >= 0; ";
  if (rock_subsample < 1 || rock_subsample > 4)
    why << "rock_subsample " << rock_subsample << " is outside [1, 4]; ";
  if (clutter.green_specks < 0 || clutter.olive_minerals < 0 || clutter.green_blobs < 0 ||
      clutter.green_specks > 100000 || clutter.olive_minerals > 100000 || clutter.green_blobs > 100000)
    why << "clutter counts must be in [0, 100000]; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

Simulator::Simulator(const SimulatorParams& config) : params_(config)
{
  const std::string why = config.validate();
  if (!why.empty())
    throw std::invalid_argument("invalid simulator config: " + why);

  const ProjectorParams& pc = config.projector;
  const Eigen::Vector3d centre = Eigen::Vector3d(0.0, 0.0, pc.converge_distance_m) - pc.origin_m;
  if (!(centre.z() > 0.0))
    throw std::invalid_argument("invalid simulator config: the projector's central beam must point forward");
  projector_ = makeGridProjector(pc.rows, pc.cols, pc.origin_m, centre, pc.pitch_x_rad, pc.pitch_y_rad, pc.roll_rad);
  const std::string pwhy = projector_.validate();
  if (!pwhy.empty())
    throw std::invalid_argument("invalid simulator config: projector: " + pwhy);

  auto impl = std::make_shared<Impl>();
  const RockParams& rc = config.rock;
  impl->half_w = 0.5 * rc.width_m;
  impl->half_h = 0.5 * rc.height_m;
  impl->cell = std::min(std::max(rc.texture_scale_m / 5.0, 0.002), 0.005);
  impl->nx = std::max(2, static_cast<int>(std::ceil(rc.width_m / impl->cell)));
  impl->ny = std::max(2, static_cast<int>(std::ceil(rc.height_m / impl->cell)));
  impl->cell = std::max(rc.width_m / impl->nx, rc.height_m / impl->ny);
  impl->inv_cell = 1.0 / impl->cell;
  impl->x0 = -0.5 * impl->nx * impl->cell;
  impl->y0 = -0.5 * impl->ny * impl->cell;
  const int vx = impl->nx + 1, vy = impl->ny + 1;
  const size_t nv = static_cast<size_t>(vx) * vy;
  impl->h.resize(nv);
  impl->gx.resize(nv);
  impl->gy.resize(nv);
  impl->refl.resize(3 * nv);
  impl->sunlit.resize(3 * nv);

  // Relief: smooth 10-40 cm features (what a 5 cm dot spacing samples) plus a
  // millimetre roughness, scaled to the requested peak-to-peak.
  const uint32_t seed = rc.seed;
  const std::vector<std::pair<double, double>> smooth = {{0.40, 1.0}, {0.22, 0.55}, {0.12, 0.30}};
  const std::vector<std::pair<double, double>> rough = {{0.02, 1.0}, {0.011, 0.6}};
  std::vector<double> raw(nv);
  double rmin = 1e300, rmax = -1e300;
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const double x = impl->x0 + i * impl->cell, y = impl->y0 + j * impl->cell;
      const double v = fractalNoise(x, y, seed, smooth) + 0.015 * fractalNoise(x, y, seed ^ 0xA5A5u, rough);
      raw[static_cast<size_t>(j) * vx + i] = v;
      rmin = std::min(rmin, v);
      rmax = std::max(rmax, v);
    }
  }
  const double span = rmax - rmin;
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const size_t k = static_cast<size_t>(j) * vx + i;
      double z = span > 0.0 ? rc.relief_m * ((raw[k] - rmin) / span - 0.5) : 0.0;
      if (rc.step_height_m != 0.0)
        z += (impl->x0 + i * impl->cell > rc.step_x_m ? 0.5 : -0.5) * rc.step_height_m;
      impl->h[k] = static_cast<float>(z);
    }
  }
  impl->hmin = 1e300;
  impl->hmax = -1e300;
  double lx = 0.0, ly = 0.0;
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const int k = impl->vertex(i, j);
      impl->hmin = std::min(impl->hmin, static_cast<double>(impl->h[k]));
      impl->hmax = std::max(impl->hmax, static_cast<double>(impl->h[k]));
      if (i < impl->nx)
        lx = std::max(lx, std::abs(static_cast<double>(impl->h[k + 1]) - impl->h[k]));
      if (j < impl->ny)
        ly = std::max(ly, std::abs(static_cast<double>(impl->h[k + vx]) - impl->h[k]));
      const int il = std::max(i - 1, 0), ir = std::min(i + 1, impl->nx);
      const int jd = std::max(j - 1, 0), ju = std::min(j + 1, impl->ny);
      impl->gx[k] =
          static_cast<float>((impl->h[impl->vertex(ir, j)] - impl->h[impl->vertex(il, j)]) / ((ir - il) * impl->cell));
      impl->gy[k] =
          static_cast<float>((impl->h[impl->vertex(i, ju)] - impl->h[impl->vertex(i, jd)]) / ((ju - jd) * impl->cell));
    }
  }
  // Float storage rounds the heights; widen the bounds by a hair so the slab
  // test never clips a true hit.
  impl->hmin -= 1e-6;
  impl->hmax += 1e-6;
  impl->lip_x = lx / impl->cell * 1.001 + 1e-9;
  impl->lip_y = ly / impl->cell * 1.001 + 1e-9;
  // Block bounds over the vertices of each block's cells (its border
  // included): the bilinear surface lies above the lowest vertex of its cell
  // and its slope is bounded by the steepest cell edge.
  impl->nbx = (impl->nx + Impl::kBlock - 1) / Impl::kBlock;
  impl->nby = (impl->ny + Impl::kBlock - 1) / Impl::kBlock;
  impl->blocks.assign(static_cast<size_t>(impl->nbx) * impl->nby, {1e300, 0.0, 0.0});
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const int k = impl->vertex(i, j);
      const double dxh = i < impl->nx ? std::abs(static_cast<double>(impl->h[k + 1]) - impl->h[k]) : 0.0;
      const double dyh = j < impl->ny ? std::abs(static_cast<double>(impl->h[k + vx]) - impl->h[k]) : 0.0;
      // A vertex on a block border belongs to the blocks on both sides.
      for (int bj = std::max(0, (j - 1) / Impl::kBlock); bj <= std::min(impl->nby - 1, j / Impl::kBlock); ++bj)
        for (int bi = std::max(0, (i - 1) / Impl::kBlock); bi <= std::min(impl->nbx - 1, i / Impl::kBlock); ++bi)
        {
          Impl::BlockBound& b = impl->blocks[static_cast<size_t>(bj) * impl->nbx + bi];
          b.hmin = std::min(b.hmin, static_cast<double>(impl->h[k]) - 1e-6);
          b.lip_x = std::max(b.lip_x, dxh / impl->cell * 1.001 + 1e-9);
          b.lip_y = std::max(b.lip_y, dyh / impl->cell * 1.001 + 1e-9);
        }
    }
  }

  impl->sun_dir = config.lighting.sun_direction.normalized();
  impl->sky = config.lighting.sky_ambient;

  // Albedo: reddish (R > G > B), features from 25 cm down to texture_scale_m,
  // R in [albedo_min, albedo_max]; G and B follow with a slowly varying hue.
  std::vector<std::pair<double, double>> tex;
  for (double s = 0.25, w = 1.0; s >= rc.texture_scale_m * 0.999; s *= 0.5, w *= 0.75)
    tex.push_back({s, w});
  if (tex.empty())
    tex.push_back({rc.texture_scale_m, 1.0});
  tex.push_back({rc.texture_scale_m, 0.6});
  const std::vector<std::pair<double, double>> hue = {{0.30, 1.0}, {0.08, 0.5}};
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const int k = impl->vertex(i, j);
      const double x = impl->x0 + i * impl->cell, y = impl->y0 + j * impl->cell;
      const double n = fractalNoise(x, y, seed ^ 0x51ED27u, tex);
      const double a01 = 0.5 + 0.5 * std::tanh(3.0 * n);
      const double r = rc.albedo_min + (rc.albedo_max - rc.albedo_min) * a01;
      const double g = r * (0.55 + 0.10 * fractalNoise(x, y, seed ^ 0x3C6EF3u, hue));
      const double b = r * (0.36 + 0.08 * fractalNoise(x, y, seed ^ 0x1B873593u, hue));
      float* rf = &impl->refl[3 * static_cast<size_t>(k)];
      rf[0] = static_cast<float>(b);
      rf[1] = static_cast<float>(g);
      rf[2] = static_cast<float>(r);
      const Eigen::Vector3d nrm = Eigen::Vector3d(impl->gx[k], impl->gy[k], -1.0).normalized();
      const double shade = std::max(0.0, nrm.dot(impl->sun_dir)) + impl->sky;
      for (int c = 0; c < 3; ++c)
        impl->sunlit[3 * static_cast<size_t>(k) + c] = static_cast<float>(rf[c] * shade);
    }
  }

  impl->hs.resize(4 * nv);
  for (size_t k = 0; k < nv; ++k)
  {
    for (int c = 0; c < 3; ++c)
      impl->hs[4 * k + c] = impl->sunlit[3 * k + c];
    impl->hs[4 * k + 3] = impl->h[k];
  }

  const Eigen::Matrix3d R_tilt = (Eigen::AngleAxisd(rc.tilt_x_rad, Eigen::Vector3d::UnitX()) *
                                  Eigen::AngleAxisd(rc.tilt_y_rad, Eigen::Vector3d::UnitY()))
                                     .toRotationMatrix();
  Eigen::Isometry3d T_cam0_rock = Eigen::Isometry3d::Identity();
  T_cam0_rock.linear() = R_tilt;
  T_cam0_rock.translation() = Eigen::Vector3d(0.0, 0.0, rc.distance_m);
  impl->T_rock_cam0 = T_cam0_rock.inverse();

  const CameraModel& cam = config.sensor.camera;
  impl->sub = config.rock_subsample;
  impl->rw = (cam.width + impl->sub - 1) / impl->sub;
  impl->rh = (cam.height + impl->sub - 1) / impl->sub;
  const double offset = 0.5 * (impl->sub - 1);
  if (cam.hasDistortion())
  {
    impl->ray_lut.resize(2 * static_cast<size_t>(impl->rw) * impl->rh);
    for (int j = 0; j < impl->rh; ++j)
      for (int i = 0; i < impl->rw; ++i)
      {
        const Eigen::Vector2d n = cam.normalize(cv::Point2d(impl->sub * i + offset, impl->sub * j + offset));
        float* p = &impl->ray_lut[2 * (static_cast<size_t>(j) * impl->rw + i)];
        p[0] = static_cast<float>(n.x());
        p[1] = static_cast<float>(n.y());
      }
  }
  // Bilinear upsampling of the samples, clamped at the borders.
  auto upsample = [&](int n, int samples, std::vector<int>* i0, std::vector<int>* i1, std::vector<float>* w)
  {
    i0->resize(n);
    i1->resize(n);
    w->resize(n);
    for (int u = 0; u < n; ++u)
    {
      const double x = (u - offset) / impl->sub;
      int a = static_cast<int>(std::floor(x));
      double f = x - a;
      if (a < 0)
      {
        a = 0;
        f = 0.0;
      }
      if (a >= samples - 1)
      {
        a = samples - 1;
        f = 0.0;
      }
      (*i0)[u] = a;
      (*i1)[u] = std::min(a + 1, samples - 1);
      (*w)[u] = static_cast<float>(f);
    }
  };
  upsample(cam.width, impl->rw, &impl->up_i0, &impl->up_i1, &impl->up_wx);
  upsample(cam.height, impl->rh, &impl->up_j0, &impl->up_j1, &impl->up_wy);

  // Clutter on the rock surface, fixed in the rock frame.
  std::mt19937 rng(seed * 2654435761u + 17u);
  std::uniform_real_distribution<double> ux(-impl->half_w, impl->half_w), uy(-impl->half_h, impl->half_h),
      u01(0.0, 1.0);
  const ClutterParams& cl = config.clutter;
  for (int n = 0; n < cl.green_specks; ++n)
    impl->clutter.push_back({ux(rng), uy(rng), 0.0008 + 0.0012 * u01(rng), {0.10, 0.40, 0.10}, false});
  for (int n = 0; n < cl.olive_minerals; ++n)
  {
    // Olive / green-brown: R = G > B (hue 60 deg, between the rock's ~20 deg
    // and a dot's 85-115 deg), half saturated, darker than a dot.
    const double v = 0.10 + 0.08 * u01(rng);
    impl->clutter.push_back({ux(rng), uy(rng), 0.006 + 0.012 * u01(rng), {0.45 * v, 1.0 * v, 1.0 * v}, true});
  }
  for (int n = 0; n < cl.green_blobs; ++n)
    impl->clutter.push_back({ux(rng), uy(rng), 0.0025 + 0.0015 * u01(rng), {0.14, 0.60, 0.08}, false});

  normalTable();
  impl_ = impl;
}

double LightingParams::sceneDotToSunRatio(RadiometryModel model)
{
  // analyseScene() integrates spectra: compute each model once.
  static const double study = dotToSunRatio(SceneInputs(), RadiometryModel::kStudyAsStated,
                                            kReferenceBeamSigmaRad * kReferenceDistanceM);
  static const double corrected =
      dotToSunRatio(SceneInputs(), RadiometryModel::kCorrected, kReferenceBeamSigmaRad * kReferenceDistanceM);
  return model == RadiometryModel::kStudyAsStated ? study : corrected;
}

void Simulator::updateLive(const SimulatorParams& config)
{
  SimulatorParams c = params_;
  c.lighting = config.lighting;
  c.lighting.sun_direction = params_.lighting.sun_direction;  // baked into the rock's shading
  c.lighting.sky_ambient = params_.lighting.sky_ambient;
  c.motion = config.motion;
  c.sensor.read_noise_dn = config.sensor.read_noise_dn;
  c.sensor.shot_noise = config.sensor.shot_noise;
  c.sensor.gain_dn_per_electron = config.sensor.gain_dn_per_electron;
  c.noise_seed = config.noise_seed;
  c.keep_linear = config.keep_linear;
  c.projector.power_scale = config.projector.power_scale;
  const std::string why = c.validate();
  if (!why.empty())
    throw std::invalid_argument("invalid simulator config: " + why);
  params_ = c;
}

double Simulator::diameterOfConfusion(double r) const
{
  const SensorParams& s = params_.sensor;
  const double rf = s.focus_distance_m, f = s.focal_length_m;
  return s.aperture_diameter_m * std::abs(r - rf) / r * f / (rf - f);
}

Eigen::Isometry3d Simulator::motion(double t) const
{
  const RigMotionParams& m = params_.motion;
  const double period = m.return_period_s;
  double tt = t;
  if (period > 0.0)
  {
    tt = std::fmod(t, period);
    if (tt < 0.0)
      tt += period;
  }
  // Drift goes out and, with a return period, comes back (a triangle wave).
  const double ramp = period > 0.0 ? (tt < 0.5 * period ? tt : period - tt) : tt;
  Eigen::Matrix<double, 6, 1> xi = Eigen::Matrix<double, 6, 1>::Zero();
  for (int a = 0; a < 6; ++a)
  {
    const double amp = a < 3 ? m.jitter_translation_m : m.jitter_rotation_rad;
    if (amp == 0.0 || m.jitter_frequency_hz == 0.0)
      continue;
    for (int k = 0; k < 3; ++k)
    {
      double f = m.jitter_frequency_hz * kJitterMul[a][k];
      if (period > 0.0)
        f = std::max(1.0, std::round(f * period)) / period;
      xi[a] += amp * kJitterWeight[k] * std::sin(2.0 * kPi * f * tt);
    }
  }
  xi.head<3>() += m.drift_velocity_mps * ramp;
  xi.tail<3>() += m.drift_angular_velocity_radps * ramp;
  if (m.step_period_s > 0.0)
    xi.head<3>() += m.step_translation_m * std::floor(tt / m.step_period_s);
  // Pose of the current camera in the reference camera frame.
  Eigen::Isometry3d T_ref_cur = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d w = xi.tail<3>();
  if (w.norm() > 0.0)
    T_ref_cur.linear() = Eigen::AngleAxisd(w.norm(), w / w.norm()).toRotationMatrix();
  T_ref_cur.translation() = xi.head<3>();
  return T_ref_cur.inverse();
}

Eigen::Isometry3d Simulator::cameraPose(double t) const
{
  return impl_->T_rock_cam0 * motion(t).inverse();
}

double Simulator::surfaceOffset(const Eigen::Vector3d& p) const
{
  if (!impl_->inside(p.x(), p.y()))
    return kNaN;
  return p.z() - impl_->height(p.x(), p.y());
}

bool Simulator::intersect(double t, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                          Eigen::Vector3d* hit) const
{
  const Eigen::Isometry3d T_rc = cameraPose(t);
  const Eigen::Vector3d o = T_rc * origin;
  const Eigen::Vector3d d = T_rc.linear() * direction;
  double s;
  bool wall;
  if (!impl_->cast(o, d, &s, &wall) || wall)
    return false;
  *hit = T_rc.inverse() * (o + s * d);
  return true;
}

namespace
{

// 2x3 Jacobian of the (distorted) projection at a camera-frame point.
Eigen::Matrix<double, 2, 3> projectionJacobian(const CameraModel& cam, const Eigen::Vector3d& X)
{
  Eigen::Matrix<double, 2, 3> J;
  const double step = 1e-6 * std::max(X.norm(), 1e-3);
  for (int a = 0; a < 3; ++a)
  {
    Eigen::Vector3d e = Eigen::Vector3d::Zero();
    e[a] = step;
    const cv::Point2d p = cam.project(X + e), m = cam.project(X - e);
    J(0, a) = (p.x - m.x) / (2.0 * step);
    J(1, a) = (p.y - m.y) / (2.0 * step);
  }
  return J;
}

// An image-space Gaussian (inverse covariance a, b, c in px^-2 about the
// centre cx, cy), cut where q = a dx^2 + 2 b dx dy + c dy^2 exceeds q_max:
// a projector dot (added) or a clutter patch (blended over the rock).
struct Splat
{
  double cx = 0.0, cy = 0.0;
  double a = 0.0, b = 0.0, c = 0.0;
  double q_max = 0.0;
  int v0 = 0, v1 = -1;    // rows it touches (inclusive)
  float value[3] = {0.0f, 0.0f, 0.0f};  // B, G, R amplitude (dot) or radiance (patch)
  bool blend = false;     // patch: out = (1 - w) out + w value
  bool flat_top = false;  // patch: w = min(1, 2.5 g), a soft-edged disc
};

// Sets the inverse covariance and the rows of a splat of covariance S (px^2);
// false when it is degenerate or outside the image.
bool setSplatShape(Splat* sp, const Eigen::Matrix2d& S, double q_max, int height)
{
  const double det = S.determinant();
  if (!(det > 0.0) || !std::isfinite(sp->cx) || !std::isfinite(sp->cy))
    return false;
  const Eigen::Matrix2d Si = S.inverse();
  sp->a = Si(0, 0);
  sp->b = Si(0, 1);
  sp->c = Si(1, 1);
  sp->q_max = q_max;
  // The ellipse q <= q_max spans +-sqrt(q_max S_yy) rows.
  const double half = std::sqrt(q_max * S(1, 1));
  sp->v0 = static_cast<int>(std::max(0.0, std::ceil(sp->cy - half)));
  sp->v1 = static_cast<int>(std::min(height - 1.0, std::floor(sp->cy + half)));
  return sp->v0 <= sp->v1;
}

// Applies a splat to row v (CV_32FC3 pixels, `width` of them). The pixels of
// the row inside q <= q_max solve a quadratic; along them exp(-q/2) follows
// the recurrence g(u+1) = g(u) r(u), r(u+1) = r(u) exp(-a), three exp() per
// row instead of one per pixel (S always holds the pixel box, so a <= 12 and
// the factors stay far from under- or overflow).
void applySplatRow(const Splat& sp, int v, int width, float* row)
{
  const double dy = v - sp.cy;
  const double disc = sp.b * sp.b * dy * dy - sp.a * (sp.c * dy * dy - sp.q_max);
  if (!(disc >= 0.0))
    return;
  const double root = std::sqrt(disc);
  const double ua = std::max(0.0, std::ceil(sp.cx + (-sp.b * dy - root) / sp.a));
  const double ub = std::min(width - 1.0, std::floor(sp.cx + (-sp.b * dy + root) / sp.a));
  if (!(ua <= ub))
    return;
  const int u0 = static_cast<int>(ua), u1 = static_cast<int>(ub);
  const double dx0 = u0 - sp.cx;
  double g = std::exp(-0.5 * (sp.a * dx0 * dx0 + 2.0 * sp.b * dx0 * dy + sp.c * dy * dy));
  double r = std::exp(-0.5 * (sp.a * (2.0 * dx0 + 1.0) + 2.0 * sp.b * dy));
  const double k = std::exp(-sp.a);
  float* px = row + 3 * u0;
  if (!sp.blend)
  {
    for (int u = u0; u <= u1; ++u, px += 3, g *= r, r *= k)
      for (int ch = 0; ch < 3; ++ch)
        px[ch] += static_cast<float>(sp.value[ch] * g);
    return;
  }
  for (int u = u0; u <= u1; ++u, px += 3, g *= r, r *= k)
  {
    const double w = sp.flat_top ? std::min(1.0, 2.5 * g) : g;
    if (w < 1e-3)
      continue;
    for (int ch = 0; ch < 3; ++ch)
      px[ch] = static_cast<float>((1.0 - w) * px[ch] + w * sp.value[ch]);
  }
}

}  // namespace

SimFrame Simulator::render(double t) const
{
  const Impl& im = *impl_;
  const CameraModel& cam = params_.sensor.camera;
  const LightingParams& light = params_.lighting;
  const SensorParams& sc = params_.sensor;
  const int W = cam.width, H = cam.height;
  const bool lut = !im.ray_lut.empty();
  const bool vignetting = sc.natural_vignetting;

  SimFrame frame;
  frame.t = t;
  frame.delta = motion(t);
  const Eigen::Isometry3d T_rc = im.T_rock_cam0 * frame.delta.inverse();
  const Eigen::Isometry3d T_cr = T_rc.inverse();
  const Eigen::Matrix3d R = T_rc.linear();
  const Eigen::Vector3d o = T_rc.translation();
  const double sun = light.sun_level * LightingParams::kSunFullScaleDn * light.exposure;

  // Normalised image coordinates of rock sample (i, j).
  const int Wr = im.rw, Hr = im.rh;
  const double sample_offset = 0.5 * (im.sub - 1);
  auto normalized = [&](int i, int j, double* x, double* y)
  {
    if (lut)
    {
      const float* p = &im.ray_lut[2 * (static_cast<size_t>(j) * Wr + i)];
      *x = p[0];
      *y = p[1];
    }
    else
    {
      *x = (im.sub * i + sample_offset - cam.cx) / cam.fx;
      *y = (im.sub * j + sample_offset - cam.cy) / cam.fy;
    }
  };
  auto occluded = [&](const Eigen::Vector3d& X_rock)
  {
    const Eigen::Vector3d d = X_rock - o;
    double s;
    bool wall;
    if (!im.cast(o, d, &s, &wall))
      return false;
    return s * d.norm() < d.norm() - 5e-4;
  };
  auto vignette_at = [&](const Eigen::Vector3d& X_cam)
  {
    if (!vignetting)
      return 1.0;
    const double q = 1.0 + (X_cam.x() * X_cam.x() + X_cam.y() * X_cam.y()) / (X_cam.z() * X_cam.z());
    return 1.0 / (q * q);
  };
  const double pixel_box_var = 1.0 / 12.0;

  // The frame is rendered row by row in one pass (rock, clutter, dots, noise,
  // quantisation in a row buffer that stays in cache). Clutter patches and
  // dots are prepared first as splats, in the order they apply to a pixel.
  std::vector<Splat> splats;

  // --- Clutter (reflectance patches on the rock, lit by the sun) --------
  if (sun > 0.0)
  {
    for (const ClutterItem& item : im.clutter)
    {
      const Eigen::Vector3d X_rock(item.x, item.y, im.height(item.x, item.y));
      const Eigen::Vector3d X = T_cr * X_rock;
      if (!(X.z() > 0.0))
        continue;
      const cv::Point2d p = cam.project(X);
      if (!(p.x > -20 && p.y > -20 && p.x < W + 20 && p.y < H + 20) || occluded(X_rock))
        continue;
      const Eigen::Vector3d n_rock = im.normal(item.x, item.y);
      const Eigen::Vector3d n = T_cr.linear() * n_rock;
      const Eigen::Matrix3d Ss = item.radius_m * item.radius_m * (Eigen::Matrix3d::Identity() - n * n.transpose());
      const Eigen::Matrix<double, 2, 3> J = projectionJacobian(cam, X);
      const Eigen::Matrix2d S = J * Ss * J.transpose() + pixel_box_var * Eigen::Matrix2d::Identity();
      const double shade = (std::max(0.0, n_rock.dot(im.sun_dir)) + im.sky) * sun * vignette_at(X);
      Splat sp;
      sp.cx = p.x;
      sp.cy = p.y;
      sp.blend = true;
      sp.flat_top = item.flat_top;
      for (int c = 0; c < 3; ++c)
        sp.value[c] = static_cast<float>(item.refl[c] * shade);
      // Patches end where their weight drops below 1e-3.
      if (setSplatShape(&sp, S, -2.0 * std::log(item.flat_top ? 1e-3 / 2.5 : 1e-3), H))
        splats.push_back(sp);
    }
  }

  // --- Projector dots ------------------------------------------------------
  const int nb = projector_.beamCount();
  frame.points.assign(nb, Eigen::Vector3d::Constant(kNaN));
  frame.pixels.assign(nb, cv::Point2d(kNaN, kNaN));
  frame.blur_sigma_px.assign(nb, kNaN);
  frame.visible.assign(nb, 0);
  frame.peak_dn.assign(nb, 0.0);
  // Diffraction: Gaussian approximation of the Airy core, sigma = 0.42 lambda N
  // with the working f-number N = image distance / aperture.
  const double image_dist = 1.0 / (1.0 / sc.focal_length_m - 1.0 / sc.focus_distance_m);
  const double sigma_diff_px =
      0.42 * params_.projector.wavelength_nm * 1e-9 * image_dist / sc.aperture_diameter_m / sc.pixel_size_m;
  const double dot_gain = light.dot_to_sun_ratio * LightingParams::kSunFullScaleDn * light.exposure *
                          params_.projector.power_scale * kRefDistanceM * kRefDistanceM * kRefBeamSigmaRad *
                          kRefBeamSigmaRad;
  for (int b = 0; b < nb; ++b)
  {
    const BeamRay& beam = projector_.beams[b];
    const Eigen::Vector3d ob = T_rc * beam.origin, db = R * beam.direction;
    double s;
    bool wall;
    if (!im.cast(ob, db, &s, &wall) || wall)
      continue;
    const Eigen::Vector3d X_rock = ob + s * db;
    const Eigen::Vector3d X = T_cr * X_rock;
    if (!(X.z() > 0.0))
      continue;
    const cv::Point2d p = cam.project(X);
    if (!(p.x >= 0.0 && p.y >= 0.0 && p.x <= W - 1 && p.y <= H - 1) || occluded(X_rock))
      continue;
    frame.points[b] = X;
    frame.pixels[b] = p;
    frame.visible[b] = 1;

    // Footprint: the beam's cross-section (sigma per unit distance, isotropic
    // about the beam) pushed along the beam onto the tangent plane, then
    // through the projection. G is that footprint for unit sigma * distance.
    const Eigen::Vector3d n = T_cr.linear() * im.normal(X_rock.x(), X_rock.y());
    const Eigen::Vector3d bd = beam.direction;
    const double cos_i = std::max(0.02, -n.dot(bd));
    const Eigen::Matrix3d M = Eigen::Matrix3d::Identity() - bd * n.transpose() / n.dot(bd);
    const Eigen::Matrix3d C = M * (Eigen::Matrix3d::Identity() - bd * bd.transpose()) * M.transpose();
    const Eigen::Matrix<double, 2, 3> J = projectionJacobian(cam, X);
    const Eigen::Matrix2d G = J * C * J.transpose();
    const double sigma_beam = params_.projector.beam_sigma_rad * s;
    const double z_blur = diameterOfConfusion(X.z()) / 4.0 / sc.pixel_size_m;
    const Eigen::Matrix2d S =
        sigma_beam * sigma_beam * G +
        (z_blur * z_blur + sigma_diff_px * sigma_diff_px + pixel_box_var) * Eigen::Matrix2d::Identity();
    // Energy of the dot in the image: peak radiance (ratio * sunlit * cos_i *
    // (d_ref/d)^2 * (sigma_ref/sigma)^2) times the footprint area 2 pi
    // sqrt(det(sigma^2 d^2 G)); the beam's sigma and distance cancel.
    float refl[3];
    im.lookup3(im.refl, X_rock.x(), X_rock.y(), refl);
    const double energy =
        dot_gain * refl[1] * cos_i * 2.0 * kPi * std::sqrt(std::max(0.0, G.determinant())) * vignette_at(X);
    const double peak = energy / (2.0 * kPi * std::sqrt(S.determinant()));
    frame.peak_dn[b] = peak;
    frame.blur_sigma_px[b] = std::sqrt(0.5 * S.trace());
    Splat sp;
    sp.cx = p.x;
    sp.cy = p.y;
    for (int c = 0; c < 3; ++c)
      sp.value[c] = static_cast<float>(peak * kDotResponseBgr[c]);
    if (peak > 0.0 && setSplatShape(&sp, S, 50.0, H))  // exp(-25): below any DN
      splats.push_back(sp);
  }

  // Splats per band of rows, in order.
  constexpr int kBand = 16;
  std::vector<std::vector<int>> band_splats((H + kBand - 1) / kBand);
  for (size_t k = 0; k < splats.size(); ++k)
    for (int band = splats[k].v0 / kBand; band <= splats[k].v1 / kBand; ++band)
      band_splats[band].push_back(static_cast<int>(k));

  // --- Rock: robust ray casts on a coarse pixel lattice --------------------
  const int ncx = (Wr - 1 + kCoarseStep - 1) / kCoarseStep + 1;
  const int ncy = (Hr - 1 + kCoarseStep - 1) / kCoarseStep + 1;
  const bool lattice = ncx >= 2 && ncy >= 2;
  std::vector<double> coarse(static_cast<size_t>(ncx) * ncy, kNaN);
  auto coarse_pos = [&](int i, int n) { return std::min(i * kCoarseStep, n - 1); };
  if (sun > 0.0 && lattice)
  {
    cv::parallel_for_(cv::Range(0, ncy),
                      [&](const cv::Range& range)
                      {
                        for (int j = range.start; j < range.end; ++j)
                        {
                          for (int i = 0; i < ncx; ++i)
                          {
                            double x, y, s;
                            bool wall;
                            normalized(coarse_pos(i, Wr), coarse_pos(j, Hr), &x, &y);
                            const Eigen::Vector3d d = R * Eigen::Vector3d(x, y, 1.0);
                            if (im.cast(o, d, &s, &wall) && !wall)
                              coarse[static_cast<size_t>(j) * ncx + i] = s;
                          }
                        }
                      });
  }

  // Robust path of one pixel: its own ray cast, in double.
  auto robust_pixel = [&](int u, int v, float* out)
  {
    double xn, yn;
    normalized(u, v, &xn, &yn);
    const Eigen::Vector3d d = R * Eigen::Vector3d(xn, yn, 1.0);
    double scale = sun;
    if (vignetting)
    {
      const double q = 1.0 + xn * xn + yn * yn;
      scale /= q * q;
    }
    double s;
    bool wall;
    if (im.cast(o, d, &s, &wall))
    {
      float rad[3];
      im.lookup3(im.sunlit, o.x() + s * d.x(), o.y() + s * d.y(), rad);
      if (wall)
        scale *= 0.5;  // side walls face away from the sun more often than not
      for (int c = 0; c < 3; ++c)
        out[c] = static_cast<float>(rad[c] * scale);
    }
    else
    {
      for (int c = 0; c < 3; ++c)
        out[c] = static_cast<float>(kBackgroundBgr[c] * (im.sky + 0.5) * scale);
    }
  };

  // Fast path: the depth interpolated in a lattice cell whose corners agree,
  // refined by Newton on the bilinear height field, in float (1e-7 m is far
  // below the 4 mm texture cell); everything else takes the robust path.
  struct RowScratch
  {
    std::vector<float> s, dx, dy, dz, vig;
    std::vector<uint8_t> state;
    explicit RowScratch(int n) : s(n), dx(n), dy(n), dz(n), vig(n), state(n) {}
  };
  auto rock_row = [&](int v, float* row, RowScratch* scratch)
  {
    // Locals, not captures: the stores to row would otherwise force a reload
    // of every captured constant after each pixel (they might alias).
    const float Rf[9] = {static_cast<float>(R(0, 0)), static_cast<float>(R(0, 1)), static_cast<float>(R(0, 2)),
                         static_cast<float>(R(1, 0)), static_cast<float>(R(1, 1)), static_cast<float>(R(1, 2)),
                         static_cast<float>(R(2, 0)), static_cast<float>(R(2, 1)), static_cast<float>(R(2, 2))};
    const float ox = static_cast<float>(o.x()), oy = static_cast<float>(o.y()), oz = static_cast<float>(o.z());
    const float ic = static_cast<float>(1.0 / im.cell);
    const float gx0 = static_cast<float>(im.x0), gy0 = static_cast<float>(im.y0);
    const float nxf = static_cast<float>(im.nx), nyf = static_cast<float>(im.ny);
    const float half_w = static_cast<float>(im.half_w), half_h = static_cast<float>(im.half_h);
    const float sunf = static_cast<float>(sun);
    const float ifx = static_cast<float>(im.sub / cam.fx);
    const float fcx = static_cast<float>((cam.cx - sample_offset) / im.sub);
    const float* hs = im.hs.data();
    const int stride = im.nx + 1;
    const bool vig = vignetting, use_lut = lut;
    const int nx = im.nx, ny = im.ny;
    if (!lattice)
    {
      for (int u = 0; u < Wr; ++u)
        robust_pixel(u, v, row + 3 * u);
      return;
    }
    const int j = std::min(v / kCoarseStep, ncy - 2);
    const int cv0 = coarse_pos(j, Hr), cv1 = coarse_pos(j + 1, Hr);
    const double fy = cv1 > cv0 ? static_cast<double>(v - cv0) / (cv1 - cv0) : 0.0;
    const float yn_row = static_cast<float>((im.sub * v + sample_offset - cam.cy) / cam.fy);
    const float* lut_row = use_lut ? &im.ray_lut[2 * static_cast<size_t>(v) * Wr] : nullptr;
    float* S = scratch->s.data();
    float* DX = scratch->dx.data();
    float* DY = scratch->dy.data();
    float* DZ = scratch->dz.data();
    float* VG = scratch->vig.data();
    uint8_t* state = scratch->state.data();  // 0 converged, 1 more Newton, 2 robust
    // Simple passes over the row with few, predictable branches, so that the
    // samples' latency chains (load, divide) overlap.
    for (int i = 0; i + 1 < ncx; ++i)
    {
      const int u0 = coarse_pos(i, Wr), u1 = coarse_pos(i + 1, Wr);
      const int uend = i + 2 == ncx ? u1 : u1 - 1;
      const double* c0 = &coarse[static_cast<size_t>(j) * ncx + i];
      const double* c1 = c0 + ncx;
      const double smin = std::min(std::min(c0[0], c0[1]), std::min(c1[0], c1[1]));
      const double smax = std::max(std::max(c0[0], c0[1]), std::max(c1[0], c1[1]));
      // NaN corners fail this test: misses and edges take the robust path.
      const bool smooth = smax - smin <= kCoarseSpreadM;
      const float sa = smooth ? static_cast<float>(c0[0] + fy * (c1[0] - c0[0])) : 1.0f;
      const float sd = smooth ? static_cast<float>(c0[1] + fy * (c1[1] - c0[1])) - sa : 0.0f;
      const float inv_len = u1 > u0 ? 1.0f / static_cast<float>(u1 - u0) : 0.0f;
      for (int u = u0; u <= uend; ++u)
      {
        S[u] = sa + static_cast<float>(u - u0) * inv_len * sd;
        state[u] = smooth ? 0 : 2;
      }
    }
    for (int u = 0; u < Wr; ++u)
    {
      const float xn = use_lut ? lut_row[2 * u] : (static_cast<float>(u) - fcx) * ifx;
      const float yn = use_lut ? lut_row[2 * u + 1] : yn_row;
      DX[u] = Rf[0] * xn + Rf[1] * yn + Rf[2];
      DY[u] = Rf[3] * xn + Rf[4] * yn + Rf[5];
      DZ[u] = Rf[6] * xn + Rf[7] * yn + Rf[8];
      const float q = 1.0f + xn * xn + yn * yn;
      VG[u] = vig ? sunf / (q * q) : sunf;
    }
    // Newton on the bilinear height field from the interpolated depth, in
    // float (1e-7 m is far below the 4 mm texture cell). One step is enough
    // almost everywhere (the next would move the point by < 1e-4 m).
    auto newton = [&](int u, float s, float* step_out)
    {
      const float dx = DX[u], dy = DY[u], dz = DZ[u];
      const float gxf = (ox + s * dx - gx0) * ic, gyf = (oy + s * dy - gy0) * ic;
      const bool inside = gxf >= 0.0f && gyf >= 0.0f && gxf < nxf && gyf < nyf;
      const int ci = inside ? static_cast<int>(gxf) : 0, cj = inside ? static_cast<int>(gyf) : 0;
      const float tx = gxf - ci, ty = gyf - cj;
      const float* r0 = hs + 4 * (cj * stride + ci) + 3;
      const float* r1 = r0 + 4 * stride;
      const float h00 = r0[0], h10 = r0[4], h01 = r1[0], h11 = r1[4];
      const float a = h00 + tx * (h10 - h00), b = h01 + tx * (h11 - h01);
      const float gap = a + ty * (b - a) - (oz + s * dz);
      const float slope = (((h10 - h00) * (1.0f - ty) + (h11 - h01) * ty) * dx + (b - a) * dy) * ic - dz;
      const bool good = inside && slope < -1e-6f && std::abs(gap) <= 0.05f;
      *step_out = good ? gap / slope : 0.0f;
      return good;
    };
    for (int u = 0; u < Wr; ++u)
    {
      float step;
      const bool good = newton(u, S[u], &step);
      S[u] -= step;
      const uint8_t next = good ? (std::abs(step) < 5e-4f ? 0 : 1) : 2;
      state[u] = std::max(state[u], next);
    }
    for (int u = 0; u < Wr; ++u)
    {
      if (state[u] != 1)
        continue;
      state[u] = 2;  // unless it converges within three more steps
      for (int n = 0; n < 3; ++n)
      {
        float step;
        if (!newton(u, S[u], &step))
          break;
        S[u] -= step;
        if (std::abs(step) < 5e-4f)
        {
          state[u] = 0;
          break;
        }
      }
    }
    for (int u = 0; u < Wr; ++u)
    {
      float* out = row + 3 * u;
      const float px = ox + S[u] * DX[u], py = oy + S[u] * DY[u];
      if (state[u] != 0 || !(std::abs(px) <= half_w && std::abs(py) <= half_h))
      {
        robust_pixel(u, v, out);
        continue;
      }
      const float gxf = (px - gx0) * ic, gyf = (py - gy0) * ic;
      const int ci = std::min(std::max(static_cast<int>(gxf), 0), nx - 1);
      const int cj = std::min(std::max(static_cast<int>(gyf), 0), ny - 1);
      const float tx = gxf - ci, ty = gyf - cj;
      const float scale = VG[u];
      const float* p00 = hs + 4 * (cj * stride + ci);
      const float* p01 = p00 + 4 * stride;
      const float w00 = (1 - tx) * (1 - ty) * scale, w10 = tx * (1 - ty) * scale;
      const float w01 = (1 - tx) * ty * scale, w11 = tx * ty * scale;
      // All four lanes (B, G, R, h) in one go; the fourth lands on the next
      // pixel's B, which is written after it (rows have one float of slack).
      for (int c = 0; c < 4; ++c)
        out[c] = w00 * p00[c] + w10 * p00[4 + c] + w01 * p01[c] + w11 * p01[4 + c];
    }
  };

  // --- One pass per row: rock, splats, noise, quantisation ----------------
  // Rows are independent (the noise is seeded per row), so the pass runs in
  // parallel with the same result for any thread count.
  const std::vector<float>& table = normalTable();
  const float read_var = static_cast<float>(sc.read_noise_dn * sc.read_noise_dn);
  const float gain = sc.shot_noise ? static_cast<float>(sc.gain_dn_per_electron) : 0.0f;
  const bool noisy = read_var > 0.0f || gain > 0.0f;
  uint64_t frame_state = 0x243F6A8885A308D3ull ^ (static_cast<uint64_t>(params_.noise_seed) << 32) ^ doubleBits(t);
  const uint64_t frame_key = splitmix64(&frame_state);
  // Rock samples first (rows independent); the row pass interpolates them.
  // Rows of 3 Wr floats plus one of slack; kept per thread between frames
  // (a fresh 3 MB buffer per frame costs its page faults).
  const size_t rock_stride = 3 * static_cast<size_t>(Wr) + 1;
  static thread_local std::vector<float> rock_buffer;
  if (sun > 0.0)
    rock_buffer.resize(rock_stride * Hr);
  // A plain pointer: inside the parallel body, rock_buffer would name the
  // worker thread's own (empty) instance.
  float* const rock = rock_buffer.data();
  if (sun > 0.0)
  {
    cv::parallel_for_(cv::Range(0, Hr),
                      [&](const cv::Range& range)
                      {
                        RowScratch scratch(Wr);
                        for (int j = range.start; j < range.end; ++j)
                          rock_row(j, rock + rock_stride * j, &scratch);
                      });
  }
  // Bilinear upsampling: the two sample rows blended first (a plain loop that
  // vectorises), then along the row; sub = 2 has fixed weights 1/4, 3/4.
  const int n3 = 3 * W, nr3 = 3 * Wr;
  auto rock_to_row = [&](int v, float* L, float* T)
  {
    const float* A = rock + rock_stride * im.up_j0[v];
    if (im.sub == 1)
    {
      std::memcpy(L, A, sizeof(float) * n3);
      return;
    }
    const float* B = rock + rock_stride * im.up_j1[v];
    const float wy = im.up_wy[v];
    for (int k = 0; k < nr3; ++k)
      T[k] = A[k] + wy * (B[k] - A[k]);
    if (im.sub == 2)
    {
      // Pixel 0 sits left of sample 0 (clamped); pixels 2i+1, 2i+2 lie at
      // 1/4 and 3/4 between samples i and i+1; an even W ends on a clamp.
      for (int c = 0; c < 3; ++c)
        L[c] = T[c];
      const int pairs = (W - 1) / 2;
      for (int i = 0; i < pairs; ++i)
      {
        const float* t0 = T + 3 * i;
        float* l = L + 3 * (2 * i + 1);
        for (int c = 0; c < 3; ++c)
        {
          l[c] = 0.75f * t0[c] + 0.25f * t0[3 + c];
          l[3 + c] = 0.25f * t0[c] + 0.75f * t0[3 + c];
        }
      }
      for (int u = 1 + 2 * pairs; u < W; ++u)
        for (int c = 0; c < 3; ++c)
          L[3 * u + c] = T[3 * im.up_i0[u] + c] + im.up_wx[u] * (T[3 * im.up_i1[u] + c] - T[3 * im.up_i0[u] + c]);
      return;
    }
    for (int u = 0; u < W; ++u)
    {
      const int a = 3 * im.up_i0[u], b = 3 * im.up_i1[u];
      const float wx = im.up_wx[u];
      for (int c = 0; c < 3; ++c)
        L[3 * u + c] = T[a + c] + wx * (T[b + c] - T[a + c]);
    }
  };
  if (params_.keep_linear)
    frame.linear.create(H, W, CV_32FC3);
  frame.image.create(H, W, CV_8UC3);
  cv::parallel_for_(cv::Range(0, H),
                    [&](const cv::Range& range)
                    {
                      std::vector<float> buf(n3 + 5), normal(n3 + 5), deviation(n3), blend(nr3);
                      float* L = buf.data();
                      float* N = normal.data();
                      float* sd = deviation.data();
                      for (int v = range.start; v < range.end; ++v)
                      {
                        if (sun > 0.0)
                          rock_to_row(v, L, blend.data());
                        else
                          std::fill(buf.begin(), buf.end(), 0.0f);
                        for (int k : band_splats[v / kBand])
                          if (v >= splats[k].v0 && v <= splats[k].v1)
                            applySplatRow(splats[k], v, W, L);
                        if (params_.keep_linear)
                          std::memcpy(frame.linear.ptr<float>(v), L, sizeof(float) * n3);
                        if (noisy)
                        {
                          uint64_t state = frame_key ^ (0xD1B54A32D192ED03ull * static_cast<uint64_t>(v + 1));
                          for (int k = 0; k < n3; k += 5)
                          {
                            const uint64_t r = splitmix64(&state);
                            for (int q = 0; q < 5; ++q)
                              N[k + q] = table[(r >> (12 * q)) & (kNormalTableSize - 1)];
                          }
                          // Simple loops that vectorise: clip, standard
                          // deviation (shot + read), the noisy value.
                          for (int k = 0; k < n3; ++k)
                            L[k] = std::max(L[k], 0.0f);
                          for (int k = 0; k < n3; ++k)
                            sd[k] = L[k] * gain + read_var;
                          cv::hal::sqrt32f(sd, sd, n3);
                          for (int k = 0; k < n3; ++k)
                            L[k] += sd[k] * N[k];
                        }
                        cv::Mat(1, n3, CV_32F, L).convertTo(cv::Mat(1, n3, CV_8U, frame.image.ptr<uint8_t>(v)), CV_8U);
                      }
                    });
  return frame;
}

}  // namespace structured_light_stabilizer
