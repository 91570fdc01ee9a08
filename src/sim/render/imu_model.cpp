#include "structured_light_stabilizer/sim/render/imu_model.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

namespace
{

// Step of the central differences of the disturbance (s): its fastest
// content (8-14 Hz) has a relative error (2 pi f h)^2 / 6 < 1e-5 at this
// step, and the round-off of metre-scale poses stays below 1e-11 m/s.
constexpr double kDifferenceStepS = 1e-4;

uint64_t splitmix(uint64_t* state)
{
  uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

bool nonNegative(double v)
{
  return std::isfinite(v) && v >= 0.0;
}

// (R^T dR/dt) as a vector: the body rate of a rotation known at t +- h.
Eigen::Vector3d bodyRate(const Eigen::Matrix3d& before, const Eigen::Matrix3d& after, double h)
{
  return logSO3(before.transpose() * after) / (2.0 * h);
}

}  // namespace

Eigen::Quaterniond bodyAxesImuMount()
{
  // Columns: the IMU's x, y, z in the camera frame.
  Eigen::Matrix3d R;
  R << 0.0, -1.0, 0.0,  //
      0.0, 0.0, -1.0,   //
      1.0, 0.0, 0.0;
  return Eigen::Quaterniond(R);
}

Eigen::Quaterniond simulatedImuRotation()
{
  return Eigen::Quaterniond(bodyAxesImuMount().toRotationMatrix() * expSO3(Eigen::Vector3d(0.006, -0.004, 0.008)));
}

std::string ImuModelParams::validate() const
{
  std::ostringstream why;
  if (!(std::isfinite(rate_hz) && rate_hz >= 10.0 && rate_hz <= 10000.0))
    why << "rate_hz must be in [10, 10000]; ";
  if (!rotation_camera_imu.coeffs().allFinite() || std::abs(rotation_camera_imu.norm() - 1.0) > 1e-6)
    why << "rotation_camera_imu must be a unit quaternion; ";
  if (!lever_arm_m.allFinite() || !gravity_m_s2.allFinite() || !gyro_bias.allFinite() || !accel_bias.allFinite() ||
      !gyro_bias_step.allFinite() || !accel_bias_step.allFinite())
    why << "lever arm, gravity and biases must be finite; ";
  if (!nonNegative(gyro_noise_density) || !nonNegative(gyro_bias_random_walk) || !nonNegative(accel_noise_density) ||
      !nonNegative(accel_bias_random_walk))
    why << "noise densities and random walks must be finite and >= 0; ";
  if (!std::isfinite(time_offset_s))
    why << "time_offset_s must be finite; ";
  std::string s = why.str();
  if (!s.empty())
    s.resize(s.size() - 2);
  return s;
}

CameraKinematics cameraKinematics(const RigMotionParams& disturbance, const ArmModel* arm, double t)
{
  // A = D^-1: the camera's pose in W from the disturbance alone.
  const auto A = [&](double at) { return disturbanceMotion(disturbance, at).inverse(); };
  // The disturbance starts at t = 0 (before it, its steps count backwards):
  // the differences stay on t >= 0.
  const double before = std::max(0.0, t - kDifferenceStepS), after = before + 2.0 * kDifferenceStepS;
  const Eigen::Isometry3d A0 = A(t), Am = A(before), Ap = A(after);
  const Eigen::Vector3d w_A = bodyRate(Am.linear(), Ap.linear(), kDifferenceStepS);  // body rate of A
  const Eigen::Vector3d v_A = (Ap.translation() - Am.translation()) / (2.0 * kDifferenceStepS);
  Eigen::Isometry3d C = Eigen::Isometry3d::Identity();
  Vector6d xi = Vector6d::Zero();
  if (arm)
  {
    C = arm->correction().inverse();
    xi = arm->velocity();
  }
  CameraKinematics k;
  k.t = t;
  k.pose = A0 * C;
  const Eigen::Matrix3d& R_C = C.linear();
  // T = A C: R = R_A R_C, so the body rate is R_C^T w_A + w_C; p = R_A t_C +
  // t_A, so dp/dt = R_A (w_A x t_C) + R_A R_C v_C + dt_A/dt.
  k.angular_velocity = R_C.transpose() * w_A + xi.tail<3>();
  k.velocity = A0.linear() * (w_A.cross(C.translation())) + A0.linear() * R_C * xi.head<3>() + v_A;
  return k;
}

ImuModel::ImuModel(const ImuModelParams& params) : params_(params)
{
  const std::string why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("IMU model: " + why);
  R_ci_ = params.rotation_camera_imu.normalized().toRotationMatrix();
  gyro_bias_ = params.gyro_bias;
  accel_bias_ = params.accel_bias;
  rng_state_ = 0x5DEECE66Dull ^ (uint64_t(params.seed) << 20);
}

double ImuModel::normal()
{
  // Box-Muller on two splitmix64 uniforms in (0, 1].
  const double u1 = (double(splitmix(&rng_state_) >> 11) + 1.0) * (1.0 / 9007199254740992.0);
  const double u2 = double(splitmix(&rng_state_) >> 11) * (1.0 / 9007199254740992.0);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * detail::kPi * u2);
}

double ImuModel::nextSampleTime(double t) const
{
  // The period's multiple after t, robust to rounding (a sample due at t is not repeated).
  const double period = 1.0 / params_.rate_hz;
  return (std::floor(t * params_.rate_hz + 1e-6) + 1.0) * period;
}

bool ImuModel::sample(const CameraKinematics& k, ImuSample* out)
{
  const Eigen::Matrix3d R_wi = k.pose.linear() * R_ci_;
  // The IMU's point moves with the camera: v_I = v_C + R_WC (w x r).
  const Eigen::Vector3d v_i = k.velocity + k.pose.linear() * k.angular_velocity.cross(params_.lever_arm_m);
  const bool first = !primed_;
  const double dt = k.t - t_prev_;
  const Eigen::Matrix3d R_prev = R_wi_prev_;
  const Eigen::Vector3d v_prev = v_prev_;
  primed_ = true;
  t_prev_ = k.t;
  R_wi_prev_ = R_wi;
  v_prev_ = v_i;
  if (first || !(dt > 0.0))
    return false;
  // The biases walk whether or not the IMU speaks.
  for (int a = 0; a < 3; ++a)
  {
    gyro_bias_[a] += params_.gyro_bias_random_walk * std::sqrt(dt) * normal();
    accel_bias_[a] += params_.accel_bias_random_walk * std::sqrt(dt) * normal();
  }
  if (!stepped_ && k.t >= params_.bias_step_time_s)
  {
    gyro_bias_ += params_.gyro_bias_step;
    accel_bias_ += params_.accel_bias_step;
    stepped_ = true;
  }
  const double gyro_sigma = params_.gyro_noise_density / std::sqrt(dt);
  const double accel_sigma = params_.accel_noise_density / std::sqrt(dt);
  Eigen::Vector3d gyro_noise, accel_noise;
  for (int a = 0; a < 3; ++a)
  {
    gyro_noise[a] = gyro_sigma * normal();
    accel_noise[a] = accel_sigma * normal();
  }
  if (k.t >= params_.silent_from_s && k.t < params_.silent_until_s)
    return false;
  const Eigen::Vector3d rotation = logSO3(R_prev.transpose() * R_wi);
  const Eigen::Matrix3d R_mid = R_prev * expSO3(0.5 * rotation);
  out->t = k.t;
  out->stamp = k.t - params_.time_offset_s;
  out->angular_velocity = rotation / dt + gyro_bias_ + gyro_noise;
  out->linear_acceleration =
      R_mid.transpose() * ((v_i - v_prev) / dt - params_.gravity_m_s2) + accel_bias_ + accel_noise;
  return true;
}

}  // namespace structured_light_stabilizer
