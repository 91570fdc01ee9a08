// Where the rig stands at one instant, in the form every stage of a frame
// uses it, and the camera's line of sight to a rock point.
#pragma once

#include <Eigen/Geometry>

#include "sim/render/rock_surface.h"

namespace structured_light_stabilizer
{
namespace sim
{

struct FrameGeometry
{
  explicit FrameGeometry(const Eigen::Isometry3d& T_rock_cam)
    : T_rc(T_rock_cam), T_cr(T_rock_cam.inverse()), R(T_rock_cam.linear()), o(T_rock_cam.translation())
  {
  }

  Eigen::Isometry3d T_rc;  // camera frame -> rock frame
  Eigen::Isometry3d T_cr;  // rock frame -> camera frame
  Eigen::Matrix3d R;       // rotation of T_rc (camera ray directions into the rock frame)
  Eigen::Vector3d o;       // camera centre in the rock frame
};

// True when the rock hides the rock point X_rock from the camera: the line of
// sight meets the surface more than 0.5 mm before it.
inline bool occludedFromCamera(const RockSurface& rock, const FrameGeometry& g, const Eigen::Vector3d& X_rock)
{
  const Eigen::Vector3d d = X_rock - g.o;
  double s;
  bool wall;
  if (!rock.cast(g.o, d, &s, &wall))
    return false;
  return s * d.norm() < d.norm() - 5e-4;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
