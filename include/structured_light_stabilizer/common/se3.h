// Small rigid-motion helpers shared by the PoseDelta solver, the estimator's
// frame-to-frame chaining, the tests and the tools, ROS-free.
//
// Conventions: a pose increment is a 6-vector delta = (v, w): translation v in
// metres and a rotation vector w in radians, both in the current camera
// frame, applied on the left (T <- Exp(delta) * T). Covariances of poses use
// the same order (tx, ty, tz, rx, ry, rz), as the PoseDelta message does.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace structured_light_stabilizer
{

using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

// [v]x: skew(v) * u == v.cross(u).
Eigen::Matrix3d skew(const Eigen::Vector3d& v);

// Rotation vector <-> rotation matrix (angle in radians, |w| < pi on the way back).
Eigen::Matrix3d expSO3(const Eigen::Vector3d& w);
Eigen::Vector3d logSO3(const Eigen::Matrix3d& R);

// Exp(delta) * T with delta = (v, w) on the current-frame side; the rotation
// is re-orthonormalised.
Eigen::Isometry3d applyIncrement(const Vector6d& delta, const Eigen::Isometry3d& T);

// Adjoint of T for left perturbations ordered (v, w): Exp(Ad(T) d) T = T Exp(d),
// so a covariance C of the right factor becomes Ad C Ad^T on the left.
Matrix6d adjoint(const Eigen::Isometry3d& T);

}  // namespace structured_light_stabilizer
