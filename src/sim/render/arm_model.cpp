#include "structured_light_stabilizer/sim/render/arm_model.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "structured_light_stabilizer/common/math.h"
#include "sim/render/rig_motion.h"

namespace structured_light_stabilizer
{

namespace
{

bool positive(double v)
{
  return std::isfinite(v) && v > 0.0;
}

Eigen::Vector3d clampNorm(const Eigen::Vector3d& v, double max)
{
  const double n = v.norm();
  return n > max ? Eigen::Vector3d(v * (max / n)) : v;
}

// Exp of a twist xi = (v, w) held for unit time: the screw motion it makes
// (SE(3) exponential), so a constant twist integrates exactly.
Eigen::Isometry3d expTwist(const Vector6d& xi)
{
  const Eigen::Vector3d w = xi.tail<3>();
  const double th = w.norm();
  const Eigen::Matrix3d K = skew(w);
  Eigen::Matrix3d V = Eigen::Matrix3d::Identity() + 0.5 * K;
  if (th > 1e-9)
    V = Eigen::Matrix3d::Identity() + (1.0 - std::cos(th)) / (th * th) * K +
        (th - std::sin(th)) / (th * th * th) * K * K;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = expSO3(w);
  T.translation() = V * xi.head<3>();
  return T;
}

}  // namespace

std::string ArmModelParams::validate() const
{
  std::ostringstream why;
  if (!positive(bandwidth_hz))
    why << "bandwidth_hz must be finite and > 0; ";
  if (!std::isfinite(delay_s) || delay_s < 0.0)
    why << "delay_s must be finite and >= 0; ";
  if (!positive(max_linear_velocity_mps) || !positive(max_angular_velocity_radps) ||
      !positive(max_linear_acceleration_mps2) || !positive(max_angular_acceleration_radps2))
    why << "velocity and acceleration limits must be finite and > 0; ";
  if (!positive(command_timeout_s))
    why << "command_timeout_s must be finite and > 0; ";
  if (!positive(step_s) || step_s > 0.01)
    why << "step_s must be in (0, 0.01] s; ";
  std::string s = why.str();
  if (!s.empty())
    s.resize(s.size() - 2);
  return s;
}

ArmModel::ArmModel(const ArmModelParams& params) : params_(params)
{
  const std::string why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("arm model: " + why);
}

void ArmModel::command(double t, const Vector6d& twist)
{
  const double received = std::max(t, pending_.empty() ? current_.received : pending_.back().received);
  // A non-finite command stops the arm (a real servo would refuse it).
  const Vector6d v = twist.allFinite() ? twist : Vector6d::Zero();
  pending_.push_back({received + params_.delay_s, received, v});
}

Vector6d ArmModel::target(double t)
{
  while (!pending_.empty() && pending_.front().effective <= t)
  {
    current_ = pending_.front();
    pending_.pop_front();
  }
  if (t - current_.effective > params_.command_timeout_s)
    return Vector6d::Zero();
  Vector6d v = current_.twist;
  v.head<3>() = clampNorm(v.head<3>(), params_.max_linear_velocity_mps);
  v.tail<3>() = clampNorm(v.tail<3>(), params_.max_angular_velocity_radps);
  return v;
}

void ArmModel::step(double dt)
{
  const Vector6d goal = target(t_);
  // First-order lag, exact for a constant goal over the step, then the
  // acceleration and velocity limits.
  Vector6d dv = (goal - velocity_) * (1.0 - std::exp(-2.0 * detail::kPi * params_.bandwidth_hz * dt));
  dv.head<3>() = clampNorm(dv.head<3>(), params_.max_linear_acceleration_mps2 * dt);
  dv.tail<3>() = clampNorm(dv.tail<3>(), params_.max_angular_acceleration_radps2 * dt);
  velocity_ += dv;
  velocity_.head<3>() = clampNorm(velocity_.head<3>(), params_.max_linear_velocity_mps);
  velocity_.tail<3>() = clampNorm(velocity_.tail<3>(), params_.max_angular_velocity_radps);
  // C <- C Exp(xi dt), i.e. correction = C^-1 <- Exp(-xi dt) C^-1.
  correction_ = expTwist(-velocity_ * dt) * correction_;
  correction_.linear() = Eigen::Quaterniond(correction_.linear()).normalized().toRotationMatrix();
  t_ += dt;
}

void ArmModel::advance(double t)
{
  if (!std::isfinite(t))
    return;
  while (t_ < t)
  {
    // At rest with nothing in force: skip to the next command.
    if (velocity_.isZero(0.0) && target(t_).isZero(0.0))
    {
      const double next = pending_.empty() ? t : std::min(t, pending_.front().effective);
      if (next > t_)
      {
        t_ = next;
        continue;
      }
    }
    step(std::min(params_.step_s, t - t_));
  }
}

RigMotionParams roverArmDisturbance()
{
  RigMotionParams m;
  // Wind sway: the arm's quasi-static deflection under Mars gusts (air 60x
  // thinner than on Earth: ~0.02 mm for 10 m/s gusts on a 2 kN/m arm; 0.1 mm
  // and 0.03 mrad per axis here, at 0.13-0.65 Hz: the jitter's
  // incommensurate multiples of 0.15 Hz).
  m.jitter_translation_m = 0.0001;
  m.jitter_rotation_rad = 0.00003;
  m.jitter_frequency_hz = 0.15;
  // Vibration from the rover's own mechanisms and the arm's first modes,
  // 2-8 Hz, flat spectrum: 0.05 mm and 0.025 mrad RMS per axis.
  m.vibration_translation_rms_m = 0.00005;
  m.vibration_rotation_rms_rad = 0.000025;
  m.vibration_min_hz = 2.0;
  m.vibration_max_hz = 8.0;
  m.vibration_spectrum_slope = 0.0;
  // Slow drift: soil creep under the wheels once the arm's load shifted,
  // thermal bending of the arm: 0.1 mm/s, 0.02 mrad/s.
  m.drift_velocity_mps = Eigen::Vector3d(0.00008, 0.00005, -0.00003);
  m.drift_angular_velocity_radps = Eigen::Vector3d(0.00002, -0.00001, 0.000005);
  // A wheel sinks every 4 s: 0.5 mm down (+y) and 0.5 mrad of pitch about
  // the wheel's contact patch, over 150 ms.
  m.step_period_s = 4.0;
  m.step_translation_m = Eigen::Vector3d(0.0, 0.0005, 0.0);
  m.step_rotation_rad = Eigen::Vector3d(0.0005, 0.0, 0.0);
  m.step_rise_s = 0.15;
  // Rotations turn about a wheel contact 0.3 m right, 0.8 m below and 1.2 m
  // behind the camera (optical frame: x right, y down, z forward).
  m.pivot_m = Eigen::Vector3d(0.3, 0.8, -1.2);
  m.seed = 1;
  return m;
}

RigMotionParams earthWindDisturbance()
{
  RigMotionParams m = roverArmDisturbance();
  m.jitter_translation_m = 0.001;
  m.jitter_rotation_rad = 0.0002;
  m.vibration_translation_rms_m = 0.0001;
  m.vibration_rotation_rms_rad = 0.00005;
  return m;
}

RigMotionParams vibrationHeavyDisturbance()
{
  RigMotionParams m = roverArmDisturbance();
  m.vibration_translation_rms_m = 0.003;
  m.vibration_rotation_rms_rad = 0.3 * detail::kPi / 180.0;
  m.vibration_min_hz = 1.0;
  m.vibration_max_hz = 8.0;
  return m;
}

Eigen::Isometry3d disturbanceMotion(const RigMotionParams& motion, double t)
{
  return sim::rigMotion(motion, t);
}

}  // namespace structured_light_stabilizer
