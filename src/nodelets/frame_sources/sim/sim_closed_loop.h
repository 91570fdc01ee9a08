// The closed loop's side of the CameraDriver's sim source
// (docs/stabilization.md): the arm model driven by the velocity commands, the
// simulated IMU, the truth of the stabilisation, and the lockstep mode.
//
// All of it only with ~closed_loop:=true (config/stabilize.yaml); else the
// camera follows the disturbance alone and nothing is subscribed.
// - Subscribes ~arm_command_topic (default stabilizer/cmd_twist,
//   geometry_msgs/TwistStamped, camera-frame body twist as moveit_servo's
//   delta_twist_cmds; empty = no arm) and feeds the ArmModel
//   (sim/arm_model.h).
// - Subscribes ~lock_topic (default pose_delta) to learn which frame the
//   PoseDelta locked on ("reference locked on this frame" in its status) and
//   from then on publishes, per frame, stamped like it:
//     sim/ground_truth/offset       the camera's true offset from the locked
//                                   pose, the error the controller should see
//     sim/ground_truth/disturbance  the same for the disturbance alone (the
//                                   open loop of the same seed: the arm still)
//   as geometry_msgs/TwistStamped: linear = translation (m), angular =
//   rotation vector (rad) of T with p_cur = T p_lock (the PoseDelta
//   convention), camera optical frame. With ~lock_topic empty they are
//   relative to simulated t = 0 from the first frame.
// - ~imu: publishes imu/data (sensor_msgs/Imu, REP 145, frame ~imu_frame)
//   from the simulated IMU (sim/render/imu_model.h) at ~imu_rate, sampled
//   from the camera's true motion (sim_imu.cpp reads its parameters).
//
// Two clocks (docs/stabilization.md, "Lockstep"):
// - wall (default): frames are paced by the driver; a command received at
//   ROS time a counts at simulated time t_k + (a - stamp_k) after the last
//   frame k, so the pipeline's real latency is the loop's latency; the IMU
//   is sampled by a wall timer.
// - ~lockstep: the source publishes /clock (run with /use_sim_time) and
//   advances simulated time itself, event by event (IMU samples, frames,
//   estimates delivered), waiting for the pipeline at each step: PoseDelta's
//   estimate of a frame is taken in before the next frame goes out and
//   handed on (relayed on sim/lockstep/pose_delta) at its exposure + a
//   modelled latency (~lockstep_latency + uniform ~lockstep_latency_jitter,
//   seeded); an IMU sample goes out ~lockstep_imu_latency after its
//   instant; after each the source waits for the consumers' answers
//   (InertialFusion's pose_fused and pose_fused/frames, the controller's
//   stabilizer/error) and applies the command at that instant. The figures
//   then depend on the seeds alone, not on the machine's load.
//
// Threads: correctionAt(), lockstepTo() and published() run on the driver's
// worker thread, the subscriptions on ROS callback threads, the wall-mode
// IMU timer on its own; the shared state is guarded.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <utility>

#include <Eigen/Geometry>
#include <geometry_msgs/TwistStamped.h>
#include <ros/ros.h>

#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/sim/render/arm_model.h"
#include "structured_light_stabilizer/sim/render/imu_model.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"
#include "nodelets/frame_sources/frame_source.h"

namespace structured_light_stabilizer
{

// Reads the disturbance's own parameters (vibration, step rotation and rise,
// pivot, seed) over *motion; the rest of the motion is in the scene table.
void readDisturbanceParams(const ros::NodeHandle& pnh, const std::function<void(const std::string&)>& error,
                           RigMotionParams* motion);

// The simulated IMU's parameters (sim_imu.cpp): ~imu_rate, ~imu_rotation [x y
// z w], ~imu_lever_arm, ~imu_gravity, noise densities, biases, ~imu_seed,
// ~imu_time_offset and the faults ~imu_silent_from/_until,
// ~imu_bias_step_time (s of simulated time), ~imu_gyro_bias_step,
// ~imu_accel_bias_step.
void readImuParams(const ros::NodeHandle& pnh, const std::function<void(const std::string&)>& error,
                   ImuModelParams* imu);

class SimClosedLoop
{
public:
  // The subscriptions first: no callback may run into the members below.
  ~SimClosedLoop();

  // Reads the arm, IMU and lockstep parameters, subscribes and advertises.
  // `motion` gives the disturbance in force (live settings may change it).
  // False (said why) when the arm parameters are unusable: the source then
  // runs without arm.
  bool setUp(const SourceContext& ctx, std::function<RigMotionParams()> motion);

  bool lockstep() const { return lockstep_; }
  // Lockstep: the ROS time of simulated instant t (the /clock it publishes).
  ros::Time lockstepStamp(double t) const { return ros::Time(epoch_s_ + t); }
  // Lockstep: runs the world up to simulated time t, the next frame's
  // exposure (see above), and publishes /clock = t. False when the driver
  // stops meanwhile.
  bool lockstepTo(double t);

  // The arm's correction for the frame at simulated time t, stamped `stamp`
  // (the commands received so far applied).
  Eigen::Isometry3d correctionAt(double t, const ros::Time& stamp);

  // After a frame went out: its truth (delta = arm * disturbance) and the
  // disturbance alone; publishes the offsets from the locked pose and, in
  // lockstep, expects PoseDelta's estimate of it.
  void published(const std_msgs::Header& header, double t, const Eigen::Isometry3d& delta,
                 const Eigen::Isometry3d& disturbance);

private:
  // Lockstep: what happens at an instant of simulated time.
  struct Event
  {
    enum Kind
    {
      kImuSample,    // the IMU samples the motion
      kImuDelivery,  // the sample reaches the fusion
      kEstimate      // PoseDelta's estimate of a frame reaches its consumer
    } kind = kImuSample;
    ros::Time stamp;  // kEstimate: the frame's
    ImuSample imu;    // kImuDelivery
  };
  void setUpImu();
  void setUpLockstep();
  void commandCb(const geometry_msgs::TwistStampedConstPtr& msg);
  void lockCb(const PoseDeltaConstPtr& msg);
  void imuTimerCb(const ros::WallTimerEvent&);
  // Samples the IMU at simulated time t (arm advanced to t, arm_mutex_ held);
  // false while it is silent.
  bool sampleImu(double t, ImuSample* sample);
  void publishImu(const ImuSample& s, const ros::Time& stamp);
  // Lockstep (sim_lockstep.cpp).
  bool waitUntil(const std::function<bool()>& done, const char* what);
  bool ready();
  bool process(double t, const Event& e);
  bool deliverEstimate(double t, const ros::Time& stamp);
  bool deliverImu(double t, const ImuSample& s);
  void applyCommand(double t);
  void publishClock(double t);

  SourceContext ctx_;
  std::function<RigMotionParams()> motion_;
  ros::Subscriber sub_command_, sub_lock_, sub_error_, sub_fused_, sub_frames_;
  ros::Publisher pub_offset_, pub_disturbance_, pub_imu_, pub_clock_, pub_relay_;
  ros::WallTimer imu_timer_;
  bool lock_from_topic_ = true;

  // The arm and the IMU: the worker thread and the wall-mode IMU timer.
  std::mutex arm_mutex_;
  std::unique_ptr<ArmModel> arm_;
  std::unique_ptr<ImuModel> imu_;
  std::string imu_frame_ = "imu_link";
  double t_prev_ = 0.0;
  ros::Time stamp_prev_;
  bool have_prev_ = false;

  // Lockstep (worker thread unless noted).
  bool lockstep_ = false;
  bool wait_controller_ = true, wait_fusion_ = false, wait_truth_ = false;
  double latency_s_ = 0.025, latency_jitter_s_ = 0.06, imu_latency_s_ = 0.001, wait_timeout_s_ = 5.0;
  double epoch_s_ = 0.0;
  bool started_ = false;
  std::mt19937 latency_rng_;
  std::multimap<double, Event> events_;  // by simulated time; equal times in insertion order
  double next_imu_t_ = 0.0;
  double clock_t_ = -1.0;
  double last_delivery_ = -1.0;  // simulated time of the last estimate's delivery
  ros::Time awaited_;  // the last frame's stamp, whose estimate the next frame waits for
  bool awaiting_ = false;
  int timeouts_ = 0;

  std::mutex mutex_;  // guards what follows (callbacks <-> worker)
  std::condition_variable answered_;
  std::deque<std::pair<ros::Time, Vector6d>> commands_;  // (arrival, twist) not yet given to the arm
  bool bad_command_logged_ = false;
  Vector6d latest_command_ = Vector6d::Zero();
  bool new_command_ = false;
  std::map<ros::Time, PoseDeltaConstPtr> estimates_;  // lockstep: PoseDelta's, by stamp, until relayed
  int64_t errors_ = 0, fused_ = 0, frames_ = 0;       // lockstep: answers counted
  // Truth of the recent frames (delta, disturbance) by stamp, to find the locked one.
  std::map<ros::Time, std::pair<Eigen::Isometry3d, Eigen::Isometry3d>> history_;
  std::map<ros::Time, double> frame_times_;  // simulated time by stamp
  bool locked_ = false;
  Eigen::Isometry3d lock_delta_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d lock_disturbance_ = Eigen::Isometry3d::Identity();
};

}  // namespace structured_light_stabilizer
