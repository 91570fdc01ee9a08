// Small geometric helpers shared by the chessboard calibration files (not a
// public API). Poses map board points into the camera optical frame; a pose
// increment (w, v) rotates by exp(w) in the camera frame and then translates
// by v: R' = exp(w) R, t' = exp(w) t + v, i.e. the increment is applied on
// the camera side, so its derivatives do not depend on where the board's
// origin is.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"

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

// The least-squares point closest to all the lines (origin, direction of
// any length); false when they are (nearly) parallel.
inline bool closestPointToLines(const std::vector<BeamRay>& lines, Eigen::Vector3d* point)
{
  Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (const BeamRay& r : lines)
  {
    const Eigen::Vector3d d = r.direction.normalized();
    const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d * d.transpose();
    A += P;
    b += P * r.origin;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(A);
  if (!(es.eigenvalues()(0) > 1e-9 * std::max(1.0, es.eigenvalues()(2))))
    return false;
  *point = A.ldlt().solve(b);
  return point->allFinite();
}

inline double distanceToLine(const Eigen::Vector3d& p, const BeamRay& r)
{
  const Eigen::Vector3d d = r.direction.normalized();
  const Eigen::Vector3d w = p - r.origin;
  return (w - w.dot(d) * d).norm();
}

// One Levenberg-Marquardt iteration from the normal equations (H, g) of the
// current state: steps with falling damping are tried (`solveStep(lambda)`
// returns the step for H with its diagonal scaled by 1 + lambda,
// `tryStep(step, &cost)` the cost of the stepped state, storing it as the
// candidate) until one lowers *cost, then `accept()` keeps it. Returns false
// when none does; *converged when the decrease is negligible.
template <class SolveStep, class TryStep, class Accept>
bool levenbergMarquardtIteration(double* cost, double* lambda, SolveStep solveStep, TryStep tryStep, Accept accept,
                                 bool* converged)
{
  for (int tries = 0; tries < 12; ++tries)
  {
    const auto step = solveStep(*lambda);
    double c = 0.0;
    if (step.allFinite() && tryStep(step, &c) && c < *cost)
    {
      *converged = *cost - c < 1e-10 * *cost || step.norm() < 1e-12;
      *cost = c;
      *lambda = std::max(1e-12, *lambda * 0.3);
      accept();
      return true;
    }
    *lambda *= 10.0;
  }
  return false;
}

}  // namespace detail
}  // namespace structured_light_stabilizer
