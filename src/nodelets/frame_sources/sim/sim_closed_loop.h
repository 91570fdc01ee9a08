// The closed loop's side of the CameraDriver's sim source
// (docs/stabilization.md): the arm model driven by the velocity commands, the
// disturbance's parameters, and the truth of the stabilisation.
//
// All of it only with ~closed_loop:=true (config/stabilize.yaml); else the
// camera follows the disturbance alone and nothing is subscribed.
// - Subscribes ~arm_command_topic (default stabilizer/cmd_twist,
//   geometry_msgs/TwistStamped, camera-frame body twist as moveit_servo's
//   delta_twist_cmds; empty = no arm) and feeds the ArmModel
//   (sim/arm_model.h). A command received at ROS time a counts at simulated
//   time t_k + (a - stamp_k) after the last frame k (clamped to the next
//   frame's time), so the pipeline's real latency is the loop's latency.
// - Subscribes ~lock_topic (default pose_delta) only to learn which frame the
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
//
// Threads: correctionAt() and published() run on the driver's worker thread,
// the subscriptions on ROS callback threads; the shared state is guarded.
#pragma once

#include <deque>
#include <map>
#include <mutex>
#include <string>
#include <utility>

#include <Eigen/Geometry>
#include <geometry_msgs/TwistStamped.h>
#include <ros/ros.h>

#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/sim/render/arm_model.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"
#include "nodelets/frame_sources/frame_source.h"

namespace structured_light_stabilizer
{

// Reads the disturbance's own parameters (vibration, step rotation and rise,
// pivot, seed) over *motion; the rest of the motion is in the scene table.
void readDisturbanceParams(const ros::NodeHandle& pnh, const std::function<void(const std::string&)>& error,
                           RigMotionParams* motion);

class SimClosedLoop
{
public:
  // The subscriptions first: no callback may run into the members below.
  ~SimClosedLoop()
  {
    sub_command_.shutdown();
    sub_lock_.shutdown();
  }

  // Reads the arm parameters, subscribes and advertises. False (said why)
  // when the arm parameters are unusable: the source then runs without arm.
  bool setUp(const SourceContext& ctx);

  // The arm's correction for the frame at simulated time t, stamped `stamp`
  // (the commands received so far applied).
  Eigen::Isometry3d correctionAt(double t, const ros::Time& stamp);

  // After a frame went out: its truth (delta = arm * disturbance) and the
  // disturbance alone; publishes the offsets from the locked pose.
  void published(const std_msgs::Header& header, const Eigen::Isometry3d& delta, const Eigen::Isometry3d& disturbance);

private:
  void commandCb(const geometry_msgs::TwistStampedConstPtr& msg);
  void lockCb(const PoseDeltaConstPtr& msg);

  SourceContext ctx_;
  std::unique_ptr<ArmModel> arm_;  // worker thread only
  ros::Subscriber sub_command_, sub_lock_;
  ros::Publisher pub_offset_, pub_disturbance_;
  bool lock_from_topic_ = true;
  double t_prev_ = 0.0;
  ros::Time stamp_prev_;
  bool have_prev_ = false;

  std::mutex mutex_;                                     // guards what follows
  std::deque<std::pair<ros::Time, Vector6d>> commands_;  // (arrival, twist) not yet given to the arm
  bool bad_command_logged_ = false;
  // Truth of the recent frames (delta, disturbance) by stamp, to find the locked one.
  std::map<ros::Time, std::pair<Eigen::Isometry3d, Eigen::Isometry3d>> history_;
  bool locked_ = false;
  Eigen::Isometry3d lock_delta_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d lock_disturbance_ = Eigen::Isometry3d::Identity();
};

}  // namespace structured_light_stabilizer
