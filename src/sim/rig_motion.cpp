#include "rig_motion.h"

#include <algorithm>
#include <cmath>

#include "structured_light_stabilizer/detail/math.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

// Incommensurate frequency multipliers and weights of the jitter sines
// (tx, ty, tz, rx, ry, rz); square roots keep them incommensurate.
constexpr double kJitterMul[6][3] = {{1.000, 2.414, 3.732}, {1.118, 2.618, 4.123}, {0.866, 2.236, 3.317},
                                     {1.272, 2.828, 4.359}, {0.941, 2.449, 3.606}, {1.189, 2.646, 3.873}};
constexpr double kJitterWeight[3] = {0.6, 0.3, 0.1};

// Wind jitter of each axis (tx, ty, tz m; rx, ry, rz rad) at time tt; with a
// period, each frequency is rounded to a whole number of cycles per period.
Eigen::Matrix<double, 6, 1> jitter(const RigMotionParams& m, double tt, double period)
{
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
      xi[a] += amp * kJitterWeight[k] * std::sin(2.0 * detail::kPi * f * tt);
    }
  }
  return xi;
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
  Eigen::Matrix<double, 6, 1> xi = jitter(m, tt, period);
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

}  // namespace sim
}  // namespace structured_light_stabilizer
