#include "nodelets/frame_sources/sim/sim_closed_loop.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include <boost/make_shared.hpp>
#include <rosgraph_msgs/Clock.h>
#include <sensor_msgs/Imu.h>

#include "structured_light_stabilizer/common/se3.h"
#include "nodelets/common/param_reader.h"

namespace structured_light_stabilizer
{

namespace
{

// PoseDelta's status phrase for the frame that became the reference (pose_delta.cpp).
constexpr const char* kLockedPhrase = "reference locked on this frame";
// Frames of truth kept to find the locked one (s of ROS time).
constexpr double kHistoryS = 5.0;

geometry_msgs::TwistStampedPtr offsetMsg(const std_msgs::Header& header, const Eigen::Isometry3d& T)
{
  auto msg = boost::make_shared<geometry_msgs::TwistStamped>();
  msg->header = header;
  const Eigen::Vector3d t = T.translation();
  const Eigen::Vector3d w = logSO3(T.linear());
  msg->twist.linear.x = t.x();
  msg->twist.linear.y = t.y();
  msg->twist.linear.z = t.z();
  msg->twist.angular.x = w.x();
  msg->twist.angular.y = w.y();
  msg->twist.angular.z = w.z();
  return msg;
}

}  // namespace

void readDisturbanceParams(const ros::NodeHandle& pnh, const std::function<void(const std::string&)>& error,
                           RigMotionParams* m)
{
  const ParamReader read(pnh, error);
  read.number("vibration_translation_rms", &m->vibration_translation_rms_m);
  read.number("vibration_rotation_rms", &m->vibration_rotation_rms_rad);
  read.number("vibration_min_frequency", &m->vibration_min_hz);
  read.number("vibration_max_frequency", &m->vibration_max_hz);
  read.number("vibration_spectrum_slope", &m->vibration_spectrum_slope);
  read.number("step_rise", &m->step_rise_s);
  read.vector3("step_rotation", &m->step_rotation_rad);
  read.vector3("motion_pivot", &m->pivot_m);
  read.integer("motion_seed", &m->seed);
}

SimClosedLoop::~SimClosedLoop()
{
  imu_timer_.stop();
  sub_command_.shutdown();
  sub_lock_.shutdown();
  sub_error_.shutdown();
  sub_fused_.shutdown();
  sub_frames_.shutdown();
}

bool SimClosedLoop::setUp(const SourceContext& ctx, std::function<RigMotionParams()> motion)
{
  ctx_ = ctx;
  motion_ = std::move(motion);
  const ParamReader read(ctx.pnh, ctx.error);
  // Opt-in: otherwise the subscription to pose_delta would wake the whole
  // lazy pipeline in every simulator run.
  bool closed_loop = false;
  read.boolean("closed_loop", &closed_loop);
  if (!closed_loop)
    return true;
  ArmModelParams p;
  read.number("arm_bandwidth", &p.bandwidth_hz);
  read.number("arm_delay", &p.delay_s);
  read.number("arm_max_linear_velocity", &p.max_linear_velocity_mps);
  read.number("arm_max_angular_velocity", &p.max_angular_velocity_radps);
  read.number("arm_max_linear_acceleration", &p.max_linear_acceleration_mps2);
  read.number("arm_max_angular_acceleration", &p.max_angular_acceleration_radps2);
  read.number("arm_command_timeout", &p.command_timeout_s);
  const std::string command_topic = ctx.pnh.param<std::string>("arm_command_topic", "stabilizer/cmd_twist");
  const std::string lock_topic = ctx.pnh.param<std::string>("lock_topic", "pose_delta");
  lock_from_topic_ = !lock_topic.empty();
  locked_ = !lock_from_topic_;
  pub_offset_ = ctx_.nh.advertise<geometry_msgs::TwistStamped>("sim/ground_truth/offset", 10);
  pub_disturbance_ = ctx_.nh.advertise<geometry_msgs::TwistStamped>("sim/ground_truth/disturbance", 10);
  read.boolean("lockstep", &lockstep_);
  if (lock_from_topic_)
    sub_lock_ = ctx_.nh.subscribe(lock_topic, 20, &SimClosedLoop::lockCb, this);
  setUpImu();
  if (lockstep_)
    setUpLockstep();
  if (command_topic.empty())
    return true;
  const std::string why = p.validate();
  if (!why.empty())
  {
    ctx.error("arm model parameters invalid (" + why + "); the simulated camera ignores velocity commands");
    return false;
  }
  arm_.reset(new ArmModel(p));
  sub_command_ = ctx_.nh.subscribe(command_topic, 50, &SimClosedLoop::commandCb, this);
  ctx.info(stringf("arm model on %s: bandwidth %.1f Hz, delay %.0f ms, limits %.0f mm/s %.1f deg/s, %.1f m/s^2",
                   ctx_.nh.resolveName(command_topic).c_str(), p.bandwidth_hz, p.delay_s * 1e3,
                   p.max_linear_velocity_mps * 1e3, p.max_angular_velocity_radps * 180.0 / M_PI,
                   p.max_linear_acceleration_mps2));
  return true;
}

void SimClosedLoop::setUpImu()
{
  bool imu = false;
  ParamReader(ctx_.pnh, ctx_.error).boolean("imu", &imu);
  if (!imu)
    return;
  ImuModelParams ip;
  readImuParams(ctx_.pnh, ctx_.error, &ip);
  imu_frame_ = ctx_.pnh.param<std::string>("imu_frame", imu_frame_);
  try
  {
    imu_.reset(new ImuModel(ip));
  }
  catch (const std::exception& e)
  {
    ctx_.error(stringf("%s; no simulated IMU", e.what()));
    return;
  }
  pub_imu_ = ctx_.nh.advertise<sensor_msgs::Imu>("imu/data", 200);
  if (!lockstep_)
    imu_timer_ = ctx_.nh.createWallTimer(ros::WallDuration(1.0 / ip.rate_hz), &SimClosedLoop::imuTimerCb, this);
  ctx_.info(stringf("simulated IMU on %s (%s): %.0f Hz, gyro %.2g rad/s/sqrt(Hz), accelerometer %.2g "
                    "m/s^2/sqrt(Hz), lever arm [%.3f %.3f %.3f] m",
                    ctx_.nh.resolveName("imu/data").c_str(), imu_frame_.c_str(), ip.rate_hz, ip.gyro_noise_density,
                    ip.accel_noise_density, ip.lever_arm_m.x(), ip.lever_arm_m.y(), ip.lever_arm_m.z()));
}

void SimClosedLoop::commandCb(const geometry_msgs::TwistStampedConstPtr& msg)
{
  const ros::Time arrival = ros::Time::now();
  Vector6d v;
  v << msg->twist.linear.x, msg->twist.linear.y, msg->twist.linear.z, msg->twist.angular.x, msg->twist.angular.y,
      msg->twist.angular.z;
  std::lock_guard<std::mutex> lock(mutex_);
  if (!v.allFinite() && !bad_command_logged_)
  {
    ctx_.warn("a velocity command with NaN or infinite values: the simulated arm stops instead");
    bad_command_logged_ = true;
  }
  if (lockstep_)
  {
    latest_command_ = v;
    new_command_ = true;
    return;
  }
  commands_.emplace_back(arrival, v);
}

Eigen::Isometry3d SimClosedLoop::correctionAt(double t, const ros::Time& stamp)
{
  std::lock_guard<std::mutex> arm_lock(arm_mutex_);
  if (!arm_)
    return Eigen::Isometry3d::Identity();
  if (lockstep_)
  {
    arm_->advance(t);  // lockstepTo() gave it the commands
    return arm_->correction();
  }
  if (!have_prev_)
  {
    t_prev_ = t;
    stamp_prev_ = stamp;
    have_prev_ = true;
  }
  std::deque<std::pair<ros::Time, Vector6d>> commands;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    commands.swap(commands_);
  }
  for (const auto& c : commands)
  {
    // Real time since the last frame's stamp, as simulated time after it.
    const double at = t_prev_ + std::max(0.0, (c.first - stamp_prev_).toSec());
    arm_->command(std::min(at, t), c.second);
  }
  arm_->advance(t);
  t_prev_ = t;
  stamp_prev_ = stamp;
  return arm_->correction();
}

// Wall mode: the IMU sampled at the simulated time that ROS time says (the
// frames' mapping), the commands received so far given to the arm first.
void SimClosedLoop::imuTimerCb(const ros::WallTimerEvent&)
{
  std::lock_guard<std::mutex> arm_lock(arm_mutex_);
  if (!have_prev_)
    return;
  const ros::Time now = ros::Time::now();
  const double t = t_prev_ + std::max(0.0, (now - stamp_prev_).toSec());
  if (arm_)
  {
    std::deque<std::pair<ros::Time, Vector6d>> commands;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      commands.swap(commands_);
    }
    for (const auto& c : commands)
      arm_->command(std::min(t, t_prev_ + std::max(0.0, (c.first - stamp_prev_).toSec())), c.second);
  }
  ImuSample s;
  if (sampleImu(t, &s))
    publishImu(s, stamp_prev_ + ros::Duration(s.stamp - t_prev_));
}

bool SimClosedLoop::sampleImu(double t, ImuSample* sample)
{
  if (!imu_)
    return false;
  if (arm_)
    arm_->advance(t);
  return imu_->sample(cameraKinematics(motion_(), arm_.get(), t), sample);
}

void SimClosedLoop::publishImu(const ImuSample& s, const ros::Time& stamp)
{
  auto msg = boost::make_shared<sensor_msgs::Imu>();
  msg->header.stamp = stamp;
  msg->header.frame_id = imu_frame_;
  msg->orientation_covariance[0] = -1.0;  // no orientation (REP 145)
  const ImuModelParams& p = imu_->params();
  const double gyro_var = p.gyro_noise_density * p.gyro_noise_density * p.rate_hz;
  const double accel_var = p.accel_noise_density * p.accel_noise_density * p.rate_hz;
  for (int a = 0; a < 3; ++a)
  {
    msg->angular_velocity_covariance[4 * a] = gyro_var;
    msg->linear_acceleration_covariance[4 * a] = accel_var;
  }
  msg->angular_velocity.x = s.angular_velocity.x();
  msg->angular_velocity.y = s.angular_velocity.y();
  msg->angular_velocity.z = s.angular_velocity.z();
  msg->linear_acceleration.x = s.linear_acceleration.x();
  msg->linear_acceleration.y = s.linear_acceleration.y();
  msg->linear_acceleration.z = s.linear_acceleration.z();
  pub_imu_.publish(msg);
}

void SimClosedLoop::lockCb(const PoseDeltaConstPtr& msg)
{
  std::lock_guard<std::mutex> lock(mutex_);
  if (lockstep_)
  {
    estimates_[msg->header.stamp] = msg;
    answered_.notify_all();
  }
  if (msg->status.find(kLockedPhrase) == std::string::npos)
    return;
  const auto it = history_.find(msg->header.stamp);
  if (it == history_.end())
  {
    ctx_.warn(
        stringf("PoseDelta locked on a frame stamped %.3f that the simulator does not remember; the truth "
                "offsets keep their previous reference",
                msg->header.stamp.toSec()));
    return;
  }
  lock_delta_ = it->second.first;
  lock_disturbance_ = it->second.second;
  if (!locked_)
    ctx_.info(stringf("truth offsets (sim/ground_truth/offset, .../disturbance) from the pose locked at %.3f",
                      msg->header.stamp.toSec()));
  locked_ = true;
}

void SimClosedLoop::published(const std_msgs::Header& header, double t, const Eigen::Isometry3d& delta,
                              const Eigen::Isometry3d& disturbance)
{
  Eigen::Isometry3d lock_delta, lock_disturbance;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (lock_from_topic_)
    {
      history_[header.stamp] = {delta, disturbance};
      while (!history_.empty() && (header.stamp - history_.begin()->first).toSec() > kHistoryS)
        history_.erase(history_.begin());
    }
    if (lockstep_)
    {
      // PoseDelta's estimate of this frame is handed on after the modelled latency.
      // In order, as a pipeline hands its estimates on.
      const double jitter =
          latency_jitter_s_ > 0.0 ? std::uniform_real_distribution<double>(0.0, latency_jitter_s_)(latency_rng_) : 0.0;
      last_delivery_ = std::max(t + latency_s_ + jitter, last_delivery_);
      Event e;
      e.kind = Event::kEstimate;
      e.stamp = header.stamp;
      events_.emplace(last_delivery_, e);
      awaited_ = header.stamp;
      awaiting_ = true;
    }
    if (!locked_)
      return;
    lock_delta = lock_delta_;
    lock_disturbance = lock_disturbance_;
  }
  // p_cur = delta p_0 and p_lock = lock p_0, so p_cur = delta lock^-1 p_lock.
  pub_offset_.publish(offsetMsg(header, delta * lock_delta.inverse()));
  pub_disturbance_.publish(offsetMsg(header, disturbance * lock_disturbance.inverse()));
}

}  // namespace structured_light_stabilizer
