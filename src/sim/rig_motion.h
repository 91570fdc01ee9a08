// Motion of the camera + projector rig relative to the rock: a deterministic
// function of time (wind jitter, drift, steps; periodic when asked). An arm
// model (e.g. one driven by a velocity command) would replace or extend this.
#pragma once

#include <Eigen/Geometry>

#include "structured_light_stabilizer/sim/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// True camera motion since t = 0 as p_cur = delta * p_ref (the PoseDelta
// convention); the identity at t = 0 and, with a return period, at every
// multiple of it.
Eigen::Isometry3d rigMotion(const RigMotionParams& motion, double t);

}  // namespace sim
}  // namespace structured_light_stabilizer
