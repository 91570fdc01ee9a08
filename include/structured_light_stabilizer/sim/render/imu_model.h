// The simulated IMU of the closed loop (docs/stabilization.md, "The IMU"): a
// gyroscope and an accelerometer rigidly mounted near the camera, sampled
// from the camera's true motion (the disturbance and the arm model).
//
// Contract. World frame W: the camera optical frame at simulated t = 0 (the
// disturbance's reference, fixed to the rock: inertial; REP-103 optical axes,
// x right, y down, z forward), metres and seconds. The IMU's body frame I sits
// at lever_arm_m in the camera frame with its axes rotation_camera_imu from
// it: p_camera = R_ci p_imu + lever_arm (REP 145: the data are in the sensor's
// own frame). A sample stamped t_k reports what a real MEMS IMU's internal
// integrator reports for its sample period (t_{k-1}, t_k]:
//   angular_velocity     = log(R_WI(t_{k-1})^T R_WI(t_k)) / dt + gyro bias + white noise   (rad/s)
//   linear_acceleration  = R_WI(mid)^T ((v_I(t_k) - v_I(t_{k-1})) / dt - gravity) + accel bias + noise  (m/s^2)
// so at rest the accelerometer reads -gravity (REP 145: gravity is not
// removed; +g along the up axis). The noise is white with the given spectral
// densities (per-sample sigma = density * sqrt(rate)); each bias starts at
// its initial value and walks (sigma per sample = random walk * sqrt(dt)).
// The stamp is t_k - time_offset_s (the IMU's own clock). Faults for the tests:
// silence over [silent_from_s, silent_until_s) and a bias step at
// bias_step_time_s.
//
// Deterministic in the seed (splitmix64 normals, the same on every platform).
// Nothing throws except the constructor (std::invalid_argument with the
// reason). Not thread-safe.
#pragma once

#include <cstdint>
#include <limits>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/sim/render/arm_model.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{

// A common mount: the IMU's x forward (camera z), y left (camera -x), z up
// (camera -y), i.e. REP-103 body axes beside an optical frame.
Eigen::Quaterniond bodyAxesImuMount();
// The simulated IMU's true mount: bodyAxesImuMount() turned by a small
// misalignment (0.6 deg, as a bracket is assembled).
Eigen::Quaterniond simulatedImuRotation();

struct ImuModelParams
{
  double rate_hz = 400.0;
  // Mount: p_camera = rotation_camera_imu * p_imu + lever_arm_m, 5 cm from
  // the optical centre.
  Eigen::Quaterniond rotation_camera_imu = simulatedImuRotation();
  Eigen::Vector3d lever_arm_m = Eigen::Vector3d(0.04, -0.025, -0.015);
  // Gravity in the world frame (m/s^2, pointing down): Mars, the camera level.
  Eigen::Vector3d gravity_m_s2 = Eigen::Vector3d(0.0, 3.711, 0.0);
  // An industrial MEMS IMU (datasheet class of a tactical-grade part):
  // gyro 0.009 deg/s/sqrt(Hz), accelerometer 40 ug/sqrt(Hz).
  double gyro_noise_density = 1.5e-4;     // rad/s/sqrt(Hz)
  double gyro_bias_random_walk = 3e-6;    // rad/s^2/sqrt(Hz)
  double accel_noise_density = 4e-4;      // m/s^2/sqrt(Hz)
  double accel_bias_random_walk = 6e-5;   // m/s^3/sqrt(Hz)
  Eigen::Vector3d gyro_bias = Eigen::Vector3d(0.002, -0.0015, 0.001);  // rad/s at t = 0
  Eigen::Vector3d accel_bias = Eigen::Vector3d(0.02, -0.015, 0.01);    // m/s^2 at t = 0
  double time_offset_s = 0.0;  // stamp = t - time_offset_s
  uint32_t seed = 3;
  // Faults (tests): no sample in [silent_from_s, silent_until_s); the biases
  // jump by the steps at bias_step_time_s.
  double silent_from_s = std::numeric_limits<double>::infinity();
  double silent_until_s = std::numeric_limits<double>::infinity();
  double bias_step_time_s = std::numeric_limits<double>::infinity();
  Eigen::Vector3d gyro_bias_step = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_bias_step = Eigen::Vector3d::Zero();

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

// The camera's true motion at one instant, world frame W as above.
struct CameraKinematics
{
  double t = 0.0;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();   // T_W_camera
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero();  // body rate, camera frame (rad/s)
  Eigen::Vector3d velocity = Eigen::Vector3d::Zero();          // of the optical centre, world frame (m/s)
};

// The camera's motion at t from the disturbance and, when not null, the arm
// (advanced to t): T_W_camera = D(t)^-1 * C with D the disturbance
// (disturbanceMotion) and C = arm->correction()^-1. The disturbance's rates by
// central differences (it is smooth; h = 0.1 ms), the arm's exactly (its
// velocity over its last step).
CameraKinematics cameraKinematics(const RigMotionParams& disturbance, const ArmModel* arm, double t);

struct ImuSample
{
  double t = 0.0;      // true end of the sample period (s)
  double stamp = 0.0;  // the IMU's stamp (t - time_offset_s)
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero();     // IMU frame, rad/s
  Eigen::Vector3d linear_acceleration = Eigen::Vector3d::Zero();  // IMU frame, m/s^2 (specific force)
};

class ImuModel
{
public:
  explicit ImuModel(const ImuModelParams& params = ImuModelParams());

  // The motion at the end of the next sample period; the first call only
  // starts the integration (false). False too while the IMU is silent (the
  // biases walk on). Calls must come in increasing t, normally every
  // 1 / rate_hz (the period is the time since the last call).
  bool sample(const CameraKinematics& k, ImuSample* out);

  // The time of the next sample after t (multiples of 1 / rate_hz).
  double nextSampleTime(double t) const;
  // The biases in force now (truth for the tests).
  const Eigen::Vector3d& gyroBias() const { return gyro_bias_; }
  const Eigen::Vector3d& accelBias() const { return accel_bias_; }
  const ImuModelParams& params() const { return params_; }

private:
  double normal();

  ImuModelParams params_;
  Eigen::Matrix3d R_ci_;
  bool primed_ = false;
  bool stepped_ = false;
  double t_prev_ = 0.0;
  Eigen::Matrix3d R_wi_prev_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d v_prev_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d gyro_bias_, accel_bias_;
  uint64_t rng_state_;
};

}  // namespace structured_light_stabilizer
