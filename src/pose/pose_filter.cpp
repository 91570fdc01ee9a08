#include "structured_light_stabilizer/pose/pose_filter.h"

#include <cmath>

#include <Eigen/Cholesky>

namespace structured_light_stabilizer
{

namespace
{
// The pose increment that takes `from` to `to` on the left: to = Exp(d) from.
Vector6d leftDifference(const Eigen::Isometry3d& to, const Eigen::Isometry3d& from)
{
  const Eigen::Isometry3d D = to * from.inverse();
  Vector6d d;
  d << D.translation(), logSO3(D.linear());
  return d;
}
}  // namespace

void PoseFilter::relock()
{
  pose_ = Eigen::Isometry3d::Identity();
  P_.topLeftCorner<6, 6>().setZero();
  P_.topRightCorner<6, 6>().setZero();
  P_.bottomLeftCorner<6, 6>().setZero();
}

bool PoseFilter::fits(double stamp_s) const
{
  return started_ && std::isfinite(stamp_s) && stamp_s > stamp_s_ && stamp_s - stamp_s_ <= params_.max_gap_s;
}

void PoseFilter::model(double dt, Matrix12d* F, Matrix12d* Q) const
{
  F->setIdentity();
  F->topRightCorner<6, 6>() = dt * Matrix6d::Identity();
  Q->setZero();
  // White acceleration of density q^2 integrated over dt (the discrete
  // Wiener-process acceleration model).
  for (int a = 0; a < 6; ++a)
  {
    const double q = a < 3 ? params_.acceleration_noise : params_.angular_acceleration_noise;
    const double q2 = q * q;
    (*Q)(a, a) = q2 * dt * dt * dt / 3.0;
    (*Q)(a, a + 6) = (*Q)(a + 6, a) = q2 * dt * dt / 2.0;
    (*Q)(a + 6, a + 6) = q2 * dt;
  }
}

void PoseFilter::restart(double stamp_s, const Eigen::Isometry3d& measured, const Matrix6d& measured_covariance)
{
  started_ = std::isfinite(stamp_s);
  stamp_s_ = stamp_s;
  pose_ = measured;
  velocity_.setZero();
  P_.setZero();
  P_.topLeftCorner<6, 6>() = measured_covariance;
  for (int a = 0; a < 6; ++a)
  {
    const double s = a < 3 ? params_.initial_velocity_sigma : params_.initial_angular_velocity_sigma;
    P_(a + 6, a + 6) = s * s;
  }
}

bool PoseFilter::update(double stamp_s, const Eigen::Isometry3d& measured, const Matrix6d& measured_covariance)
{
  if (!fits(stamp_s) || !measured_covariance.allFinite())
  {
    restart(stamp_s, measured, measured_covariance);
    return false;
  }
  const double dt = stamp_s - stamp_s_;
  Matrix12d F, Q;
  model(dt, &F, &Q);
  // Prediction: the pose moves by the velocity (an increment on the left).
  const Eigen::Isometry3d predicted = applyIncrement(velocity_ * dt, pose_);
  const Matrix12d P = F * P_ * F.transpose() + Q;
  // Update with the pose measurement (H = [I 0]), in the left increment of the prediction.
  const Vector6d innovation = leftDifference(measured, predicted);
  const Matrix6d S = P.topLeftCorner<6, 6>() + measured_covariance;
  const Eigen::LDLT<Matrix6d> ldlt(S);
  if (ldlt.info() != Eigen::Success)
  {
    restart(stamp_s, measured, measured_covariance);
    return false;
  }
  const Eigen::Matrix<double, 12, 6> K = P.leftCols<6>() * ldlt.solve(Matrix6d::Identity());
  const Eigen::Matrix<double, 12, 1> dx = K * innovation;
  pose_ = applyIncrement(dx.head<6>(), predicted);
  velocity_ += dx.tail<6>();
  Eigen::Matrix<double, 12, 12> IKH = Matrix12d::Identity();
  IKH.leftCols<6>() -= K;
  // Joseph form: stays symmetric and positive.
  P_ = IKH * P * IKH.transpose() + K * measured_covariance * K.transpose();
  stamp_s_ = stamp_s;
  return true;
}

bool PoseFilter::predict(double stamp_s, Eigen::Isometry3d* pose, Matrix6d* covariance) const
{
  if (!fits(stamp_s))
    return false;
  const double dt = stamp_s - stamp_s_;
  Matrix12d F, Q;
  model(dt, &F, &Q);
  *pose = applyIncrement(velocity_ * dt, pose_);
  *covariance = (F * P_ * F.transpose() + Q).topLeftCorner<6, 6>();
  return true;
}

}  // namespace structured_light_stabilizer
