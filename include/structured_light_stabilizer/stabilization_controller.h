// The stabilisation controller, ROS-free: from PoseDelta estimates to a
// camera-frame velocity command that moves the camera back to the locked
// reference pose (docs/stabilization.md).
//
// Contract. Input per estimate (StabilizationEstimate): the PoseDelta
// transform T (p_cur = T p_ref, docs/interface.md), its 6x6 covariance in the
// order (tx, ty, tz, rx, ry, rz) (m^2, rad^2), the valid flag, the status
// string and the estimate's stamp (the exposure time, s). T is where the
// reference camera is seen from the current one, so the error is
// e = (t, log R) of T: translation in metres and a rotation vector in radians,
// both in the current camera optical frame (REP-103: x right, y down,
// z forward). Output (StabilizationCommand): a body twist of the camera,
// (vx, vy, vz) m/s and (wx, wy, wz) rad/s in the camera optical frame (the
// convention of moveit_servo's delta_twist_cmds with header.frame_id = the
// camera frame); commanding u moves the error by de/dt = -u (to first order),
// so u = +K e drives e to zero.
//
// The law, per axis: PI(D) on the error with a continuous dead band, the
// derivative on the measurement through a first-order filter, conditional
// integration (anti-windup), then a velocity limit and a rate (acceleration)
// limit on each group (translation, rotation), as vectors so the direction is
// kept. Optional latency compensation (a Smith predictor for the arm's
// integrating response): the motion already commanded but not yet visible in
// the estimate, the integral of the commands from (stamp - arm_delay_s) to
// now, is subtracted from the measured error.
//
// Hold (command zero at once, integrator frozen, derivative and rate limiter
// restarted so that the command resumes from zero without a jump): an
// invalid estimate (unless only some axes are unobservable), a NaN or
// infinite number, an estimate older than timeout_s, a repeated or older
// stamp, no estimate for timeout_s (tick()), a re-lock of the reference (the
// status says "reference locked on this frame") or a jump of the estimate
// beyond max_jump_* between two estimates (a re-lock or an outlier; the next
// estimate is compared with the new one). Axis gating: an axis whose 1-sigma
// exceeds max_sigma_*, that the status names unobservable, or that is
// disabled is never commanded (zero at once, not ramped down; its integrator
// frozen).
//
// Times are seconds on one clock (ROS time in the nodelet). Nothing throws
// except setParams() (std::invalid_argument with the reason). Not
// thread-safe: one caller at a time.
#pragma once

#include <array>
#include <deque>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/se3.h"

namespace structured_light_stabilizer
{

struct StabilizationControllerParams
{
  // Gains per group: kp in 1/s (m/s per m, rad/s per rad), ki in 1/s^2, kd
  // dimensionless. For the arm's integrating response (velocity in, pose
  // out) the crossover is about kp rad/s; with the loop's dead time tau
  // (exposure to arm motion, ~0.1 s at 30 Hz) the phase margin is about
  // 90 deg - kp * tau (docs/stabilization.md, "Gains").
  double kp_translation = 4.0;
  double ki_translation = 4.0;
  double kd_translation = 0.0;
  double kp_rotation = 4.0;
  double ki_rotation = 4.0;
  double kd_rotation = 0.0;
  double derivative_filter_s = 0.05;  // time constant of the derivative's low-pass
  // Output limits (norm of each group) and rate limits (norm of the change
  // of each group per second).
  double max_linear_velocity_mps = 0.05;
  double max_angular_velocity_radps = 0.2;
  double max_linear_acceleration_mps2 = 0.5;
  double max_angular_acceleration_radps2 = 2.0;
  // Continuous dead band on the norm of each group's error: |e| below it
  // gives no command, above it |e| - dead_band is used.
  double dead_band_translation_m = 0.0;
  double dead_band_rotation_rad = 0.0;
  // An estimate older than this (now - stamp), or none for this long: hold.
  double timeout_s = 0.2;
  // Latency compensation with the estimate's stamp (see above).
  bool latency_compensation = false;
  double arm_delay_s = 0.04;  // command to visible motion: the arm's delay plus its lag time constant
  // Axis gating from the covariance (1-sigma bounds; PoseDelta's validity
  // bounds by default) and per-axis enables (tx, ty, tz, rx, ry, rz).
  double max_sigma_translation_m = 1.5e-3;
  double max_sigma_rotation_rad = 0.075 * 3.14159265358979323846 / 180.0;
  std::array<bool, 6> axis_enabled{{true, true, true, true, true, true}};
  // An estimate that is invalid only because some axes are unobservable
  // (status "unobservable: ..."): command the other axes (true) or hold all.
  bool command_observable_axes = true;
  // A change of the estimate by more than this between two consecutive
  // estimates is a re-lock or an outlier: hold for that estimate.
  double max_jump_translation_m = 0.02;
  double max_jump_rotation_rad = 1.0 * 3.14159265358979323846 / 180.0;

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

// One PoseDelta estimate as the controller needs it.
struct StabilizationEstimate
{
  double stamp = 0.0;                                           // exposure time of the frame (s)
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();  // p_cur = T p_ref
  Matrix6d covariance = Matrix6d::Zero();                       // (tx, ty, tz, rx, ry, rz)
  bool valid = false;
  std::string status;
};

// Why the controller holds (kNone: it commands at least one axis).
enum class HoldReason
{
  kNone,
  kNoEstimate,  // none yet, or none for timeout_s
  kInvalid,     // valid = false (the status says why)
  kNotFinite,   // NaN or infinite numbers in the transform or the covariance
  kStale,       // older than timeout_s when it arrived
  kOutOfOrder,  // a stamp not newer than the last one
  kRelocked,    // the reference was re-locked on this frame
  kJump,        // the estimate jumped (re-lock or outlier)
  kAllGated     // every axis unobservable or disabled
};

struct StabilizationCommand
{
  Vector6d twist = Vector6d::Zero();  // (vx vy vz wx wy wz), camera optical frame, m/s and rad/s
  Vector6d error = Vector6d::Zero();  // the error acted on (after compensation and dead band), m and rad
  std::array<bool, 6> active{};       // axes commanded
  HoldReason hold = HoldReason::kNoEstimate;
  std::string reason;      // why holding, or which axes are gated; empty when all six are commanded
  double latency_s = 0.0;  // now - stamp of the estimate used (0 when none)
};

// The reason's short name ("invalid estimate", "stale estimate", ...).
const char* holdReasonName(HoldReason reason);

class StabilizationController
{
public:
  explicit StabilizationController(const StabilizationControllerParams& params = StabilizationControllerParams());

  // Throws std::invalid_argument with the reason when the params are unusable.
  // Keeps the integrator and the history (live tuning).
  void setParams(const StabilizationControllerParams& params);
  const StabilizationControllerParams& params() const { return params_; }

  // One estimate, received at time `now`: the command to send.
  StabilizationCommand update(const StabilizationEstimate& estimate, double now);
  // No estimate at time `now`: the command to send (zero once the last
  // estimate is older than timeout_s, else the last command).
  StabilizationCommand tick(double now);
  // Forgets everything (integrator, history): the next estimate starts afresh.
  void reset();

  const Vector6d& integrator() const { return integral_; }

private:
  StabilizationCommand hold(HoldReason reason, const std::string& why, double now);
  // Why the estimate cannot be used at all (kNone when it can).
  HoldReason screen(const StabilizationEstimate& estimate, double now, std::string* why) const;
  std::array<bool, 6> gate(const StabilizationEstimate& estimate, std::string* gated) const;
  bool jumped(const Vector6d& measured, std::string* why);
  Vector6d predictedError(const Vector6d& measured, double stamp, double now) const;
  Vector6d law(const Vector6d& error, const std::array<bool, 6>& active, double dt);
  Vector6d limit(const Vector6d& raw, const std::array<bool, 6>& active, double now) const;
  void remember(const Vector6d& twist, double now);

  struct Sent
  {
    double time;
    Vector6d twist;
  };

  StabilizationControllerParams params_;
  Vector6d integral_ = Vector6d::Zero();       // integral of the error (m s, rad s)
  Vector6d derivative_ = Vector6d::Zero();     // filtered derivative of the error
  Vector6d last_error_ = Vector6d::Zero();     // of the last estimate used by the law
  bool have_error_ = false;                    // last_error_ usable for the derivative
  Vector6d last_measured_ = Vector6d::Zero();  // of the last screened estimate (jump test)
  bool have_measured_ = false;
  double last_stamp_ = -1e300;  // of the last estimate received
  bool have_estimate_ = false;
  StabilizationCommand last_command_;
  double last_command_time_ = -1e300;
  std::deque<Sent> sent_;  // commands sent, for the latency compensation
};

}  // namespace structured_light_stabilizer
