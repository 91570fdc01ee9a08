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
// the estimate, by a model of the arm (a delay arm_delay, then a first-order
// lag arm_lag of its velocity), is subtracted from the measured error.
//
// Hold (command zero at once, integrator frozen, derivative and rate limiter
// restarted so that the command resumes from zero without a jump): an
// invalid estimate (unless only some axes are unobservable), a NaN or
// infinite number, an estimate older than timeout, a repeated or older
// stamp, no estimate for timeout (tick()), a re-lock of the reference (the
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

#include "structured_light_stabilizer/common/params.h"
#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

struct StabilizationControllerParams
{
#define SLS_PARAMS_STRUCT StabilizationControllerParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/control/stabilization_controller_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  double maxSigmaRotationRad() const { return max_sigma_rotation_deg * 3.14159265358979323846 / 180.0; }
  double maxJumpRotationRad() const { return max_jump_rotation_deg * 3.14159265358979323846 / 180.0; }
  // Axis a (tx, ty, tz, rx, ry, rz) is commanded at all.
  bool axisEnabled(int a) const
  {
    const bool enabled[6] = {enable_tx, enable_ty, enable_tz, enable_rx, enable_ry, enable_rz};
    return enabled[a];
  }

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

// The controller's settings for the fused loop (InertialFusion's estimates
// at IMU rate, config/stabilize_imu.yaml; a gtest keeps the two in step):
// the gains, the latency compensation and the limits tuned on the loop model
// (docs/stabilization.md, "Gains"). The defaults of the struct are the
// camera-only loop's: these gains on 30-120 Hz estimates 25-130 ms late
// would be unstable.
StabilizationControllerParams fusedLoopControllerParams();

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
  kNoEstimate,  // none yet, or none for timeout
  kInvalid,     // valid = false (the status says why)
  kNotFinite,   // NaN or infinite numbers in the transform or the covariance
  kStale,       // older than timeout when it arrived
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
  // estimate is older than timeout, else the last command).
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
