// Optional constant-velocity filter over PoseDelta's frame-to-reference
// estimates, ROS-free (docs/pose_delta.md#filter).
//
// Contract: poses follow the PoseDelta convention (p_cur = T * p_ref, metres,
// radians; covariances of left increments ordered tx, ty, tz, rx, ry, rz,
// se3.h). The state is the pose and its velocity (a twist on the same left
// side, m/s and rad/s) with a 12x12 covariance; between measurements the
// velocity is constant up to white acceleration noise (a spectral density per
// axis, the `*_acceleration_noise` params). An update takes a raw estimate
// with its covariance at a time stamp (seconds, one clock); a stamp that does
// not advance, or a gap beyond max_gap_s, restarts the filter at the
// measurement (its velocity unknown). Not thread-safe; throws nothing.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

struct PoseFilterParams
{
  // Spectral density of the white acceleration, per axis: m/s^2/sqrt(Hz) and
  // rad/s^2/sqrt(Hz). From the wind jitter of the simulator's arm (10 mm and
  // 1 deg per axis at 0.6-1.0 Hz): its acceleration, up to 0.4 m/s^2 and
  // 0.7 rad/s^2, changes the velocity by about 0.013 m/s and 0.022 rad/s
  // per 1/30 s frame, i.e. densities of 0.07 and 0.12; with margin:
  double acceleration_noise = 0.1;
  double angular_acceleration_noise = 0.15;
  // Velocity 1-sigma at a (re)start (m/s, rad/s): as good as unknown.
  double initial_velocity_sigma = 0.1;
  double initial_angular_velocity_sigma = 0.2;
  double max_gap_s = 0.5;
};

class PoseFilter
{
public:
  explicit PoseFilter(const PoseFilterParams& params = PoseFilterParams()) : params_(params) {}

  void setParams(const PoseFilterParams& params) { params_ = params; }
  // Forgets everything.
  void reset() { started_ = false; }
  // A new reference at the current pose: the pose becomes the identity
  // (exactly known), the velocity and its uncertainty stay.
  void relock();
  bool started() const { return started_; }

  // Prediction to `stamp_s` and update with the measurement; returns false
  // (and restarts at the measurement) when the stamp does not fit.
  bool update(double stamp_s, const Eigen::Isometry3d& measured, const Matrix6d& measured_covariance);
  // The state predicted to `stamp_s` without a measurement (an invalid
  // frame): the pose and its covariance; false before the first update or
  // when the stamp does not fit (nothing changes then).
  bool predict(double stamp_s, Eigen::Isometry3d* pose, Matrix6d* covariance) const;

  const Eigen::Isometry3d& pose() const { return pose_; }
  Matrix6d poseCovariance() const { return P_.topLeftCorner<6, 6>(); }
  const Vector6d& velocity() const { return velocity_; }

private:
  using Matrix12d = Eigen::Matrix<double, 12, 12>;
  bool fits(double stamp_s) const;
  // Transition and process noise over dt seconds.
  void model(double dt, Matrix12d* F, Matrix12d* Q) const;
  void restart(double stamp_s, const Eigen::Isometry3d& measured, const Matrix6d& measured_covariance);

  PoseFilterParams params_;
  bool started_ = false;
  double stamp_s_ = 0.0;
  Eigen::Isometry3d pose_ = Eigen::Isometry3d::Identity();
  Vector6d velocity_ = Vector6d::Zero();
  Matrix12d P_ = Matrix12d::Identity();
};

}  // namespace structured_light_stabilizer
