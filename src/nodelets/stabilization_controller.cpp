// StabilizationController nodelet: closes the loop from the pose estimate to
// the arm (docs/stabilization.md).
//
// Wiring only: pose_delta (PoseDelta: transform, covariance, valid, status)
// -> StabilizationController (core) -> stabilizer/cmd_twist
// (geometry_msgs/TwistStamped, the camera-frame velocity of moveit_servo's
// delta_twist_cmds, stamped now) and stabilizer/error (the error acted on,
// stamped with the estimate: rqt_plot-ready). A watchdog timer publishes a
// zero command while no fresh estimate comes. Why it holds is logged at
// once for each new kind of reason, then at most every 5 s.
#include <memory>
#include <mutex>
#include <string>

#include <boost/make_shared.hpp>
#include <boost/thread/recursive_mutex.hpp>
#include <dynamic_reconfigure/server.h>
#include <geometry_msgs/TwistStamped.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>

#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/StabilizationControllerConfig.h"
#include "structured_light_stabilizer/control/stabilization_controller.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"

namespace structured_light_stabilizer
{

namespace
{

using Config = structured_light_stabilizer::StabilizationControllerConfig;

StabilizationControllerParams paramsFromConfig(const Config& c)
{
  StabilizationControllerParams p;
  p.fromConfig(c);
  return p;
}

StabilizationEstimate estimateFromMsg(const PoseDelta& msg)
{
  StabilizationEstimate e;
  e.stamp = msg.header.stamp.toSec();
  e.transform = isometryFromTransform(msg.transform);
  for (int i = 0; i < 36; ++i)
    e.covariance(i / 6, i % 6) = msg.covariance[i];
  e.valid = msg.valid;
  e.status = msg.status;
  return e;
}

geometry_msgs::TwistStampedPtr twistMsg(const Vector6d& v, const ros::Time& stamp, const std::string& frame)
{
  auto msg = boost::make_shared<geometry_msgs::TwistStamped>();
  msg->header.stamp = stamp;
  msg->header.frame_id = frame;
  msg->twist.linear.x = v[0];
  msg->twist.linear.y = v[1];
  msg->twist.linear.z = v[2];
  msg->twist.angular.x = v[3];
  msg->twist.angular.y = v[4];
  msg->twist.angular.z = v[5];
  return msg;
}

}  // namespace

class StabilizationControllerNodelet : public NodeletBase
{
public:
  StabilizationControllerNodelet() : NodeletBase("StabilizationController") {}
  ~StabilizationControllerNodelet() override
  {
    watchdog_.stop();
    stopCallbacks();
  }

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readLazyParam();
    pnh.param("camera_frame", camera_frame_param_, std::string());
    double watchdog_rate = pnh.param("watchdog_rate", 30.0);
    if (!(watchdog_rate > 0.0))
    {
      NODELET_ERROR("StabilizationController: ~watchdog_rate %g Hz is not positive; using 30 Hz", watchdog_rate);
      watchdog_rate = 30.0;
    }
    pnh.param("diagnostic_min_rate", min_frequency_, 1.0);
    pnh.param("diagnostic_max_rate", max_frequency_, 200.0);
    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });

    setUpDiagnostics("none");
    addFrequencyStatus();
    diagnostics_->add("stabilization", this, &StabilizationControllerNodelet::diagnose);
    startDiagnostics(1.0);

    pub_cmd_ = advertise<geometry_msgs::TwistStamped>(nh, "stabilizer/cmd_twist", 10);
    pub_error_ = advertise<geometry_msgs::TwistStamped>(nh, "stabilizer/error", 10);
    watchdog_ = nh.createTimer(ros::Duration(1.0 / watchdog_rate), &StabilizationControllerNodelet::watchdogCb, this);
    startSubscriptions(
        "input (pose_delta) is subscribed on demand, while stabilizer/cmd_twist or stabilizer/error has subscribers");
  }

  void subscribe() override
  {
    sub_pose_ = getNodeHandle().subscribe("pose_delta", 10, &StabilizationControllerNodelet::poseCb, this);
  }
  void unsubscribe() override { sub_pose_.shutdown(); }

  // The server holds config_mutex_ while calling; the controller's own mutex
  // hands the accepted parameters to the callbacks.
  void configCb(Config& config, uint32_t /*level*/)
  {
    const StabilizationControllerParams params = paramsFromConfig(config);
    const std::string why = params.validate();
    if (!why.empty())
    {
      NODELET_ERROR("StabilizationController: rejected parameters (%s); keeping the previous ones", why.c_str());
      return;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    controller_.setParams(params);
    if (enabled_ && !config.enabled)
      NODELET_INFO("StabilizationController: disabled; holding (zero command, integrator frozen)");
    enabled_ = config.enabled;
  }

  void poseCb(const PoseDeltaConstPtr& msg)
  {
    guarded(
        [&]
        {
          // The clock is read under the lock: the pose and watchdog callbacks
          // may run on two threads, and the commands must go out in the
          // order of their stamps (the rate limiter's time base).
          std::lock_guard<std::mutex> lock(mutex_);
          // Never before the estimate: under /use_sim_time this process may
          // not have seen the newest /clock yet when the estimate comes (the
          // simulator's lockstep advances it at every IMU sample), and a
          // stale "now" would freeze the rate limiter (dt = 0) and shift
          // the Smith predictor's history.
          const ros::Time now = std::max(ros::Time::now(), msg->header.stamp);
          frame_ = !camera_frame_param_.empty()    ? camera_frame_param_
                   : !msg->header.frame_id.empty() ? msg->header.frame_id
                                                   : std::string("camera_optical_frame");
          StabilizationEstimate estimate = estimateFromMsg(*msg);
          if (!enabled_)
          {
            // Disabled: the same hold as an invalid estimate, said once.
            estimate.valid = false;
            estimate.status = "disabled by ~enabled";
          }
          const StabilizationCommand c = controller_.update(estimate, now.toSec());
          ++estimates_;
          publish(c, now, msg->header.stamp);
        });
  }

  void watchdogCb(const ros::TimerEvent&)
  {
    guarded(
        [&]
        {
          std::lock_guard<std::mutex> lock(mutex_);  // the clock under the lock: see poseCb
          const ros::Time now = ros::Time::now();
          const StabilizationCommand c = controller_.tick(now.toSec());
          // Only a hold for want of estimates is sent from here; the commands
          // themselves go out with each estimate.
          if (c.hold == HoldReason::kNoEstimate)
            publish(c, now, ros::Time());
        });
  }

  // Called with mutex_ held. estimate_stamp zero: a watchdog hold.
  void publish(const StabilizationCommand& c, const ros::Time& now, const ros::Time& estimate_stamp)
  {
    pub_cmd_.publish(twistMsg(c.twist, now, frame_));
    if (!estimate_stamp.isZero())
      pub_error_.publish(twistMsg(c.error, estimate_stamp, frame_));
    frequency_->tick();
    ++commands_;
    last_ = c;
    if (c.hold != HoldReason::kNone)
    {
      ++holds_;
      int suppressed = 0;
      // Each reason is said at once, then at most every 5 s (DropLog: the
      // numbers in it do not make a new kind).
      if (hold_log_.shouldLog(c.reason, &suppressed))
        NODELET_WARN("StabilizationController: holding (zero command, integrator frozen): %s%s", c.reason.c_str(),
                     suppressed > 0 ? (" (" + std::to_string(suppressed) + " more holds like it)").c_str() : "");
    }
    else
    {
      latency_sum_s_ += c.latency_s;
      ++latency_count_;
      if (!c.reason.empty())
      {
        int suppressed = 0;
        if (hold_log_.shouldLog(c.reason, &suppressed))
          NODELET_WARN("StabilizationController: %s", c.reason.c_str());
      }
    }
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (last_.hold == HoldReason::kNone)
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, last_.reason.empty() ? "commanding all axes" : last_.reason);
    else
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "holding: " + last_.reason);
    stat.add("estimates", estimates_);
    stat.add("commands", commands_);
    stat.add("holds", holds_);
    stat.add("mean latency, exposure to command (ms)",
             latency_count_ > 0 ? 1e3 * latency_sum_s_ / latency_count_ : 0.0);
    const Vector6d& u = last_.twist;
    stat.add("linear command (mm/s)", 1e3 * u.head<3>().norm());
    stat.add("angular command (deg/s)", u.tail<3>().norm() * 180.0 / M_PI);
    stat.add("enabled", enabled_);
  }

  std::string camera_frame_param_;
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  ros::Publisher pub_cmd_, pub_error_;
  ros::Subscriber sub_pose_;
  ros::Timer watchdog_;

  // Controller state, under mutex_ (pose and timer callbacks may run on two threads).
  std::mutex mutex_;
  StabilizationController controller_;
  bool enabled_ = true;
  std::string frame_ = "camera_optical_frame";
  StabilizationCommand last_;
  DropLog hold_log_;
  int estimates_ = 0, commands_ = 0, holds_ = 0;
  double latency_sum_s_ = 0.0;
  int latency_count_ = 0;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::StabilizationControllerNodelet, nodelet::Nodelet)
