// Inertial fusion, ROS-free (docs/stabilization.md, "Inertial fusion"): the
// camera's offset from the locked reference propagated at IMU rate and
// corrected by PoseDelta's estimates at their exposure stamps.
//
// Contract. Inputs: IMU samples (gyro rad/s and specific force m/s^2 in the
// IMU's own frame, REP 145; each the mean over the period that ends at its
// stamp, as a MEMS IMU integrates) and camera estimates (PoseDelta's T with
// p_cur = T p_ref, its 6x6 covariance (tx, ty, tz, rx, ry, rz) of a
// left increment in the current camera frame (common/se3.h), valid, status
// and the exposure stamp). The mount (ImuMount) relates the two: p_camera =
// R_ci p_imu + lever_arm, and an IMU stamp + time_offset_s is camera time.
// Outputs (FusedEstimate): the same T and covariance as PoseDelta gives, for
// the controller at each IMU sample (addImu) and at each camera estimate's
// own stamp (addCamera: the posterior there, for the stabilised image).
//
// The filter: an error-state Kalman filter of 15 states (rotation of the
// camera in the reference frame, position and velocity of the IMU in it,
// gyro and accelerometer biases). Gravity in the reference frame is the mean
// specific force over gravity_window before the lock (its error is taken up
// by the accelerometer bias). A camera estimate is applied at its stamp, not
// at its arrival: the filter keeps its states for `history` seconds, goes
// back to the stamp, updates and replays the IMU samples since (so a 25-130 ms
// pipeline latency costs no accuracy). The lock ("reference locked on this
// frame" in a valid estimate's status) starts the filter at that stamp, or
// re-expresses it in the new reference (a re-lock).
//
// Validity of the output (valid = false with the reason in status):
// no lock yet; the last camera estimate invalid (at once: the controller
// holds within one frame) or older than camera_timeout; a camera estimate
// that finds the IMU silent for imu_timeout (addCamera then also returns an
// invalid estimate for the controller, the IMU giving none); after an IMU
// gap, until recovery_updates consistent camera estimates; after
// inconsistent_updates failed innovation tests in a row (a bias step),
// likewise. A partially valid estimate (status "unobservable: ...") is
// fused with its covariance and its status passed on (the controller
// commands the other axes).
//
// Times are seconds on the camera's clock except ImuMeasurement::stamp (the
// IMU's). Nothing throws except the constructor and setParams()
// (std::invalid_argument with the reason). Not thread-safe.
#pragma once

#include <deque>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/common/params.h"
#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

struct InertialFusionParams
{
#define SLS_PARAMS_STRUCT InertialFusionParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/control/inertial_fusion_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

// How the IMU sits on the camera (configured; the calibrate_imu tool
// estimates the rotation and the time offset from a recording).
struct ImuMount
{
  Eigen::Quaterniond rotation_camera_imu = Eigen::Quaterniond::Identity();  // R_ci: p_cam = R_ci p_imu + lever_arm
  Eigen::Vector3d lever_arm_m = Eigen::Vector3d::Zero();                    // the IMU's origin in the camera frame
  double time_offset_s = 0.0;                                               // camera time = IMU stamp + offset

  std::string validate() const;
};

struct ImuMeasurement
{
  double stamp = 0.0;                                            // the IMU's clock (s)
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero();     // rad/s, IMU frame
  Eigen::Vector3d linear_acceleration = Eigen::Vector3d::Zero();  // m/s^2, IMU frame, gravity included
};

struct CameraMeasurement
{
  double stamp = 0.0;                                           // exposure time (camera clock, s)
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();  // p_cur = T p_ref
  Matrix6d covariance = Matrix6d::Zero();
  bool valid = false;
  std::string status;
};

struct FusedEstimate
{
  double stamp = 0.0;                                           // camera clock (s)
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();  // p_cur = T p_ref
  Matrix6d covariance = Matrix6d::Identity();                   // (tx ty tz rx ry rz), left increment, current frame
  bool valid = false;
  std::string status;
};

// What addCamera() gives back.
struct CameraUpdate
{
  bool used = false;    // applied (or started the filter); false: not fused (`why` says why)
  FusedEstimate frame;  // the posterior at the estimate's stamp (valid only when used and the filter is)
  // The IMU was silent past imu_timeout: an invalid estimate stamped like
  // the camera's, for the controller (which otherwise hears nothing).
  bool silent_imu = false;
  FusedEstimate fused;
};

class InertialFusion
{
public:
  InertialFusion(const InertialFusionParams& params, const ImuMount& mount);

  // Throws std::invalid_argument with the reason; keeps the state.
  void setParams(const InertialFusionParams& params);
  const InertialFusionParams& params() const { return params_; }
  const ImuMount& mount() const { return mount_; }

  // One IMU sample: the fused estimate at its time (camera clock). False
  // with *why (and nothing fused) for non-finite values or a stamp not
  // after the last sample's.
  bool addImu(const ImuMeasurement& m, FusedEstimate* out, std::string* why);

  // One camera estimate, in any order of arrival: fused at its stamp. When
  // it cannot be (before the lock, older than the history, before the last
  // re-lock, non-finite numbers), `used` is false and *why says why.
  CameraUpdate addCamera(const CameraMeasurement& c, std::string* why);

  // Forgets everything (the next lock starts afresh).
  void reset();

  bool initialized() const { return initialized_; }
  // Current bias estimates (IMU frame), for diagnostics and tests.
  Eigen::Vector3d gyroBias() const;
  Eigen::Vector3d accelBias() const;
  // The last normalised innovation squared of a camera update (6 dof).
  double lastNis() const { return last_nis_; }

  using Matrix15d = Eigen::Matrix<double, 15, 15>;
  struct State
  {
    double t = 0.0;
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();  // camera orientation in the reference frame
    Eigen::Vector3d p = Eigen::Vector3d::Zero();      // the IMU's position in the reference frame
    Eigen::Vector3d v = Eigen::Vector3d::Zero();      // its velocity
    Eigen::Vector3d bg = Eigen::Vector3d::Zero();     // gyro bias (IMU frame)
    Eigen::Vector3d ba = Eigen::Vector3d::Zero();     // accelerometer bias (IMU frame)
    Eigen::Vector3d gravity = Eigen::Vector3d::Zero();  // in the reference frame (not estimated)
    Matrix15d P = Matrix15d::Identity();              // (dtheta, dp, dv, dbg, dba)
  };

private:
  enum class EventKind
  {
    kImu,
    kCamera,
    kLock
  };
  // A camera event is judged once, when it comes, and replayed as judged.
  enum class Decision
  {
    kPending,
    kApply,
    kReleaseApply,  // the state's velocity and biases released first (inconsistency, outage)
    kReject         // an outlier of the innovation test
  };
  struct Event
  {
    EventKind kind = EventKind::kImu;
    double t = 0.0;  // camera clock
    ImuMeasurement imu;
    CameraMeasurement camera;
    State state;  // after the event
    bool has_state = false;
    bool gap = false;  // an IMU sample after a silence: the state is released
    Decision decision = Decision::kPending;
    double nis = 0.0;
  };

  size_t insert(Event e);
  CameraUpdate addLock(const CameraMeasurement& c, CameraUpdate u, std::string* why);
  void tryPendingLock();
  void process(size_t from);
  void decideAndUpdate(Event* e, State* s);
  const ImuMeasurement* ratesFor(size_t index) const;
  void propagate(const ImuMeasurement& rates, double to, State* s) const;
  bool update(const CameraMeasurement& c, State* s, double* nis) const;
  void relock(State* s) const;
  State initialState(double t) const;
  FusedEstimate output(const State& s, const std::string& problem) const;
  std::string invalidReason(const State& s) const;
  bool inImuGap(double t) const;
  void prune();

  InertialFusionParams params_;
  ImuMount mount_;
  Eigen::Matrix3d R_ci_;
  std::deque<Event> events_;  // by time; states from the first lock on
  bool initialized_ = false;
  bool pending_lock_ = false;  // locked, waiting for IMU data for gravity
  bool announce_lock_ = false;  // the next valid output carries the lock phrase
  Eigen::Vector3d gravity_ = Eigen::Vector3d::Zero();  // in the first reference frame
  double last_imu_t_ = -1e300;
  double last_lock_t_ = -1e300;
  double last_good_camera_t_ = -1e300;  // the last camera estimate applied
  std::string camera_problem_;  // why the camera makes the output invalid ("" : it does not)
  std::string partial_status_;  // "unobservable: ..." of the last estimate when partial
  int rejected_in_row_ = 0;
  std::deque<double> recent_nis_;  // of the last nis_window updates applied
  int recovering_ = 0;  // consistent camera estimates still needed
  std::string recovery_reason_;
  double last_nis_ = 0.0;
};

}  // namespace structured_light_stabilizer
