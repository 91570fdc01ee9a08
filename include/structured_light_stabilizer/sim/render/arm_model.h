// The simulated arm of the closed loop (docs/stabilization.md): it moves the
// camera by the velocity commands it receives, the way a velocity-controlled
// arm (moveit_servo, a Cartesian velocity controller) does, with a command
// delay, a first-order lag of the velocity, and velocity and acceleration
// limits.
//
// Contract. A command is a body twist of the camera received at simulated
// time t: (vx, vy, vz) m/s and (wx, wy, wz) rad/s in the camera optical
// frame (moveit_servo's delta_twist_cmds with header.frame_id = the camera
// frame). It takes effect at t + delay_s and holds until the next one; a
// command older than command_timeout_s at its effective time is replaced by
// zero (moveit_servo's incoming_command_timeout). The arm's velocity follows
// the effective command through a first-order lag of bandwidth_hz, its change
// limited by the acceleration limits and its value by the velocity limits
// (each on the norm of the translation / rotation group). The camera pose
// relative to where the disturbance alone would put it, C, integrates the
// velocity on its own (body) side, C <- C Exp(xi dt) (the screw motion of a
// twist held over the step), in steps of step_s.
// correction() is C^-1, the Simulator's FrameRequest::arm_correction
// (delta = arm_correction * motion(t), p_cur = delta p_ref).
//
// Simulated time only (seconds); commands must come in non-decreasing time
// (an older one is taken at the time of the last). Nothing throws except the
// constructor (std::invalid_argument with the reason). Not thread-safe.
#pragma once

#include <deque>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{

struct ArmModelParams
{
  double bandwidth_hz = 10.0;  // first-order lag of the velocity tracking (-3 dB)
  double delay_s = 0.02;       // command to the start of the motion (transport + servo cycle)
  double max_linear_velocity_mps = 0.1;
  double max_angular_velocity_radps = 0.5;
  double max_linear_acceleration_mps2 = 1.0;
  double max_angular_acceleration_radps2 = 5.0;
  double command_timeout_s = 0.25;  // no newer command for this long: stop
  double step_s = 0.001;            // integration step

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

class ArmModel
{
public:
  explicit ArmModel(const ArmModelParams& params = ArmModelParams());

  // A command received at simulated time t (see the contract).
  void command(double t, const Vector6d& twist);
  // Integrates the motion up to simulated time t (no-op when t is not later
  // than the time reached).
  void advance(double t);

  // The Simulator's FrameRequest::arm_correction (C^-1).
  Eigen::Isometry3d correction() const { return correction_; }
  // The arm's velocity now (body twist, camera frame).
  const Vector6d& velocity() const { return velocity_; }
  double time() const { return t_; }
  const ArmModelParams& params() const { return params_; }

private:
  struct Pending
  {
    double effective;  // received + delay
    double received;
    Vector6d twist;
  };
  // The velocity the arm aims at, at time t (command in force, or zero).
  Vector6d target(double t);
  void step(double dt);

  ArmModelParams params_;
  double t_ = 0.0;
  Vector6d velocity_ = Vector6d::Zero();
  Eigen::Isometry3d correction_ = Eigen::Isometry3d::Identity();
  std::deque<Pending> pending_;  // commands not yet in force, by effective time
  Pending current_{-1e300, -1e300, Vector6d::Zero()};
};

// The closed loop's default disturbance: a rover parked on soft ground, its
// arm holding the camera 1.5 m from the rock in a light wind (slow drift,
// wheel-sink steps turning the rover about a wheel, wind sway, a little
// structural vibration). docs/stabilization.md ("The disturbance") says what
// each part is based on; config/stabilize.yaml holds the same values (a
// gtest keeps them in step).
RigMotionParams roverArmDisturbance();

// The same rover on Earth in a 5-10 m/s wind (air 60x denser than on Mars):
// sway 1 mm and 0.2 mrad, structural vibration 0.1 mm and 0.05 mrad RMS per
// axis (config/disturbance_earth_wind.yaml).
RigMotionParams earthWindDisturbance();

// An arm that vibrates: the default with its vibration raised to 3 mm and
// 0.3 deg RMS per axis over 1-8 Hz, an arm's first structural modes and a
// rover's mechanisms (config/disturbance_vibration.yaml).
RigMotionParams vibrationHeavyDisturbance();

// The disturbance alone at time t (what Simulator::motion(t) gives for these
// params), p_cur = delta p_ref with ref = t 0; for models of the loop
// without rendering.
Eigen::Isometry3d disturbanceMotion(const RigMotionParams& motion, double t);

}  // namespace structured_light_stabilizer
