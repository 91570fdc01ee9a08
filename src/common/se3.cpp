#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

Eigen::Matrix3d skew(const Eigen::Vector3d& v)
{
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Eigen::Matrix3d expSO3(const Eigen::Vector3d& w)
{
  const double angle = w.norm();
  if (angle < 1e-12)
    return Eigen::Matrix3d::Identity() + skew(w);
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

Eigen::Vector3d logSO3(const Eigen::Matrix3d& R)
{
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

Eigen::Isometry3d applyIncrement(const Vector6d& delta, const Eigen::Isometry3d& T)
{
  Eigen::Isometry3d D = Eigen::Isometry3d::Identity();
  D.linear() = expSO3(delta.tail<3>());
  D.translation() = delta.head<3>();
  Eigen::Isometry3d out = D * T;
  // Keep the rotation orthonormal over many chained updates.
  out.linear() = Eigen::Quaterniond(out.linear()).normalized().toRotationMatrix();
  return out;
}

Matrix6d adjoint(const Eigen::Isometry3d& T)
{
  Matrix6d A = Matrix6d::Zero();
  const Eigen::Matrix3d R = T.linear();
  A.topLeftCorner<3, 3>() = R;
  A.topRightCorner<3, 3>() = skew(T.translation()) * R;
  A.bottomRightCorner<3, 3>() = R;
  return A;
}

}  // namespace structured_light_stabilizer
