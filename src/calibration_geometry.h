// Small geometric helpers shared by the chessboard calibration files (not a
// public API). Poses map board points into the camera optical frame; a pose
// increment (w, v) rotates by exp(w) in the camera frame and then translates
// by v: R' = exp(w) R, t' = exp(w) t + v, i.e. the increment is applied on
// the camera side, so its derivatives do not depend on where the board's
// origin is.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/camera_model.h"

namespace structured_light_stabilizer
{
namespace detail
{

inline Eigen::Matrix3d expRotation(const Eigen::Vector3d& w)
{
  const double angle = w.norm();
  if (angle < 1e-15)
    return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
}

inline Eigen::Isometry3d applyPoseIncrement(const Eigen::Isometry3d& pose, const Eigen::Matrix<double, 6, 1>& inc)
{
  const Eigen::Matrix3d dR = expRotation(inc.head<3>());
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.linear() = dR * pose.linear();
  out.translation() = dR * pose.translation() + inc.tail<3>();
  return out;
}

inline Eigen::Vector2d toVec(const cv::Point2d& p)
{
  return Eigen::Vector2d(p.x, p.y);
}

// Where the line o + s d meets the board plane of `pose` (its z = 0 plane),
// in the camera frame; false when parallel or, with `forward_only`, behind
// the line's origin (s <= 0).
inline bool linePlaneHit(const Eigen::Isometry3d& pose, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                         Eigen::Vector3d* hit, bool forward_only = true)
{
  const Eigen::Vector3d n = pose.linear().col(2);
  const double denom = n.dot(d);
  if (std::abs(denom) < 1e-12)
    return false;
  const double s = n.dot(pose.translation() - o) / denom;
  if (forward_only && !(s > 0.0))
    return false;
  *hit = o + s * d;
  return true;
}

}  // namespace detail
}  // namespace structured_light_stabilizer
