#include "sim/render/rig_motion.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

using Vector6 = Eigen::Matrix<double, 6, 1>;

// Incommensurate frequency multipliers and weights of the jitter sines
// (tx, ty, tz, rx, ry, rz); square roots keep them incommensurate.
constexpr double kJitterMul[6][3] = {{1.000, 2.414, 3.732}, {1.118, 2.618, 4.123}, {0.866, 2.236, 3.317},
                                     {1.272, 2.828, 4.359}, {0.941, 2.449, 3.606}, {1.189, 2.646, 3.873}};
constexpr double kJitterWeight[3] = {0.6, 0.3, 0.1};
// Sines per axis of the band-limited vibration: with one per log-spaced
// slice of the band (its frequency drawn inside the slice), 48 make a
// spectrum that looks continuous over a run of tens of seconds.
constexpr int kVibrationComponents = 48;

// A frequency rounded to a whole number of cycles per period (period > 0).
double periodic(double f, double period)
{
  return period > 0.0 ? std::max(1.0, std::round(f * period)) / period : f;
}

// Wind jitter of each axis (tx, ty, tz m; rx, ry, rz rad) at time tt; with a
// period, each frequency is rounded to a whole number of cycles per period.
Vector6 jitter(const RigMotionParams& m, double tt, double period)
{
  Vector6 xi = Vector6::Zero();
  for (int a = 0; a < 6; ++a)
  {
    const double amp = a < 3 ? m.jitter_translation_m : m.jitter_rotation_rad;
    if (amp == 0.0 || m.jitter_frequency_hz == 0.0)
      continue;
    for (int k = 0; k < 3; ++k)
    {
      const double f = periodic(m.jitter_frequency_hz * kJitterMul[a][k], period);
      xi[a] += amp * kJitterWeight[k] * std::sin(2.0 * detail::kPi * f * tt);
    }
  }
  return xi;
}

// Uniform in [0, 1) from (seed, axis, component, draw): splitmix64, the same
// numbers on every platform (std:: distributions are not).
double uniform(uint32_t seed, int axis, int k, int draw)
{
  uint64_t z = (uint64_t(seed) << 32) ^ (uint64_t(axis) << 24) ^ (uint64_t(k) << 8) ^ uint64_t(draw);
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return double(z >> 11) * (1.0 / 9007199254740992.0);
}

// Band-limited vibration: kVibrationComponents sines per axis, one in each
// log-spaced slice of [min, max] at a random frequency inside it, amplitude
// from the slice's share of the power (PSD ~ f^slope) and a random phase,
// scaled to the axis' RMS. min = max: one sine.
struct VibrationTable
{
  std::vector<double> f[6], amplitude[6], phase[6];  // per axis, per sine (amplitude: of a unit RMS)
  double rms[6] = {0, 0, 0, 0, 0, 0};
};

VibrationTable vibrationTable(const RigMotionParams& m, double period)
{
  VibrationTable table;
  const bool tone = m.vibration_max_hz <= m.vibration_min_hz;
  const int n = tone ? 1 : kVibrationComponents;
  const double span = tone ? 0.0 : std::log(m.vibration_max_hz / m.vibration_min_hz);
  for (int a = 0; a < 6; ++a)
  {
    const double rms = a < 3 ? m.vibration_translation_rms_m : m.vibration_rotation_rms_rad;
    table.rms[a] = rms;
    if (rms == 0.0)
      continue;
    double power = 0.0;
    std::vector<double> f(n), p(n);
    for (int k = 0; k < n; ++k)
    {
      f[k] = periodic(m.vibration_min_hz * std::exp(span * (k + uniform(m.seed, a, k, 0)) / n), period);
      // Power of the slice: PSD(f) * width, the width ~ f on a log scale.
      p[k] = tone ? 1.0 : std::pow(f[k], m.vibration_spectrum_slope) * f[k];
      power += p[k];
    }
    for (int k = 0; k < n; ++k)
    {
      table.f[a].push_back(f[k]);
      table.amplitude[a].push_back(std::sqrt(2.0 * p[k] / power));
      table.phase[a].push_back(uniform(m.seed, a, k, 1));
    }
  }
  return table;
}

// The table of the last parameters asked for, per thread: the IMU's
// kinematics evaluate the same disturbance thousands of times a second.
const VibrationTable& cachedVibrationTable(const RigMotionParams& m, double period)
{
  thread_local bool valid = false;
  thread_local double key[7];
  thread_local uint32_t key_seed = 0;
  thread_local VibrationTable table;
  const double now[7] = {m.vibration_translation_rms_m, m.vibration_rotation_rms_rad, m.vibration_min_hz,
                         m.vibration_max_hz,            m.vibration_spectrum_slope,   period,
                         0.0};
  if (!valid || key_seed != m.seed || !std::equal(now, now + 7, key))
  {
    table = vibrationTable(m, period);
    std::copy(now, now + 7, key);
    key_seed = m.seed;
    valid = true;
  }
  return table;
}

Vector6 vibration(const RigMotionParams& m, double tt, double period)
{
  const VibrationTable& table = cachedVibrationTable(m, period);
  Vector6 xi = Vector6::Zero();
  for (int a = 0; a < 6; ++a)
  {
    double sum = 0.0;
    for (size_t k = 0; k < table.f[a].size(); ++k)
      sum += table.amplitude[a][k] * std::sin(2.0 * detail::kPi * (table.f[a][k] * tt + table.phase[a][k]));
    xi[a] = table.rms[a] * sum;
  }
  return xi;
}

// Steps so far at time tt: whole steps, the last one ramping in over step_rise_s.
double stepCount(const RigMotionParams& m, double tt)
{
  if (m.step_period_s <= 0.0)
    return 0.0;
  const double count = std::floor(tt / m.step_period_s);
  if (count < 1.0 || m.step_rise_s <= 0.0)
    return count;
  const double u = (tt - count * m.step_period_s) / m.step_rise_s;
  return u >= 1.0 ? count : count - 1.0 + 0.5 * (1.0 - std::cos(detail::kPi * u));
}

}  // namespace

Eigen::Isometry3d rigMotion(const RigMotionParams& m, double t)
{
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
  // The vibration's value at t = 0 is taken off: the motion starts at the identity.
  Vector6 xi = jitter(m, tt, period) + vibration(m, tt, period) - vibration(m, 0.0, period);
  xi.head<3>() += m.drift_velocity_mps * ramp;
  xi.tail<3>() += m.drift_angular_velocity_radps * ramp;
  const double steps = stepCount(m, tt);
  xi.head<3>() += m.step_translation_m * steps;
  xi.tail<3>() += m.step_rotation_rad * steps;
  // Pose of the current camera in the reference camera frame: the rotation
  // turns about the pivot, then the translation.
  Eigen::Isometry3d T_ref_cur = Eigen::Isometry3d::Identity();
  const Eigen::Vector3d w = xi.tail<3>();
  if (w.norm() > 0.0)
    T_ref_cur.linear() = Eigen::AngleAxisd(w.norm(), w / w.norm()).toRotationMatrix();
  T_ref_cur.translation() = xi.head<3>() + m.pivot_m - T_ref_cur.linear() * m.pivot_m;
  return T_ref_cur.inverse();
}

std::string rigMotionProblems(const RigMotionParams& m)
{
  std::string why;
  const auto ok = [](double v) { return std::isfinite(v) && v >= 0.0; };
  if (!ok(m.vibration_translation_rms_m) || !ok(m.vibration_rotation_rms_rad))
    why += "vibration RMS must be finite and >= 0; ";
  if (!(m.vibration_min_hz > 0.0) || !(m.vibration_max_hz >= m.vibration_min_hz) || !std::isfinite(m.vibration_max_hz))
    why += "vibration band must be 0 < vibration_min_hz <= vibration_max_hz (finite); ";
  if (!std::isfinite(m.vibration_spectrum_slope))
    why += "vibration_spectrum_slope must be finite; ";
  if (!ok(m.step_rise_s) || !m.step_rotation_rad.allFinite() || !m.pivot_m.allFinite())
    why += "step_rise_s must be finite and >= 0, step_rotation and pivot finite; ";
  if (m.step_period_s > 0.0 && m.step_rise_s > m.step_period_s)
    why += "step_rise_s must not exceed step_period_s; ";
  return why;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
