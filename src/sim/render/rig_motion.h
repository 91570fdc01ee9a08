// Motion of the camera + projector rig relative to the rock, the disturbance
// a rover arm sees (docs/stabilization.md, "The disturbance"): a
// deterministic function of time and RigMotionParams::seed made of wind sway
// (a few incommensurate sines), a band-limited vibration with a given
// spectrum, a slow drift and steps that ramp in (a wheel sinking or
// slipping), the rotations turning the camera about a pivot. The closed loop's
// arm (sim/arm_model.h) acts on top of it, on the current-frame side.
#pragma once

#include <string>

#include <Eigen/Geometry>

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// True camera motion since t = 0 as p_cur = delta * p_ref (the PoseDelta
// convention); the identity at t = 0 and, with a return period, at every
// multiple of it.
Eigen::Isometry3d rigMotion(const RigMotionParams& motion, double t);

// What is wrong with the disturbance's own fields (vibration, step rotation
// and rise, pivot), each followed by "; ", or "" (SimulatorParams::validate).
std::string rigMotionProblems(const RigMotionParams& motion);

}  // namespace sim
}  // namespace structured_light_stabilizer
