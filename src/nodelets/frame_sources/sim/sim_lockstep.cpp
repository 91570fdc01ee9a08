// The sim source's lockstep mode (sim_closed_loop.h): simulated time advances
// event by event and waits for the pipeline at each step; a modelled latency
// replaces the machine's.
#include <chrono>
#include <cmath>
#include <cstdlib>

#include <boost/function.hpp>
#include <rosgraph_msgs/Clock.h>

#include "nodelets/common/param_reader.h"
#include "nodelets/frame_sources/sim/sim_closed_loop.h"

namespace structured_light_stabilizer
{

namespace
{

// Longest wait for the connections at start-up (wall s).
constexpr double kReadyTimeoutS = 60.0;

}  // namespace

void SimClosedLoop::setUpLockstep()
{
  const ParamReader read(ctx_.pnh, ctx_.error);
  read.number("lockstep_latency", &latency_s_);
  read.number("lockstep_latency_jitter", &latency_jitter_s_);
  read.number("lockstep_imu_latency", &imu_latency_s_);
  read.number("lockstep_timeout", &wait_timeout_s_);
  int seed = 5;
  read.integer("lockstep_seed", &seed);
  read.boolean("lockstep_controller", &wait_controller_);
  read.boolean("lockstep_wait_for_truth", &wait_truth_);
  const auto ok = [](double v) { return std::isfinite(v) && v >= 0.0; };
  if (!ok(latency_s_) || !ok(latency_jitter_s_) || !ok(imu_latency_s_) || !(wait_timeout_s_ > 0.0))
  {
    ctx_.error("~lockstep_latency, ~lockstep_latency_jitter, ~lockstep_imu_latency must be >= 0 and "
               "~lockstep_timeout > 0; using 0.025, 0.06, 0.001 and 5 s");
    latency_s_ = 0.025, latency_jitter_s_ = 0.06, imu_latency_s_ = 0.001, wait_timeout_s_ = 5.0;
  }
  wait_fusion_ = imu_ != nullptr;
  latency_rng_.seed(static_cast<uint32_t>(seed));
  // Simulated t = 0 at a whole second of the wall clock: stamps that look like a real run's.
  epoch_s_ = std::floor(ros::WallTime::now().toSec());
  bool sim_time = false;
  if (!ros::param::get("/use_sim_time", sim_time) || !sim_time)
    ctx_.warn("~lockstep without /use_sim_time: the other nodes will not follow the simulated clock");
  pub_clock_ = ctx_.nh.advertise<rosgraph_msgs::Clock>("/clock", 10);
  pub_relay_ = ctx_.nh.advertise<PoseDelta>("sim/lockstep/pose_delta", 20);
  if (wait_controller_)
    sub_error_ = ctx_.nh.subscribe<geometry_msgs::TwistStamped>(
        "stabilizer/error", 200,
        boost::function<void(const geometry_msgs::TwistStampedConstPtr&)>(
            [this](const geometry_msgs::TwistStampedConstPtr&)
            {
              std::lock_guard<std::mutex> lock(mutex_);
              ++errors_;
              answered_.notify_all();
            }));
  if (wait_fusion_)
  {
    const auto count = [this](int64_t* n)
    {
      return boost::function<void(const PoseDeltaConstPtr&)>(
          [this, n](const PoseDeltaConstPtr&)
          {
            std::lock_guard<std::mutex> lock(mutex_);
            ++*n;
            answered_.notify_all();
          });
    };
    sub_fused_ = ctx_.nh.subscribe<PoseDelta>("pose_fused", 200, count(&fused_));
    sub_frames_ = ctx_.nh.subscribe<PoseDelta>("pose_fused/frames", 50, count(&frames_));
  }
  ctx_.info(stringf("lockstep: simulated time on /clock from %.0f s; estimates handed on %.0f ms + 0-%.0f ms after "
                    "their exposure (seed %d), IMU samples %.1f ms after theirs; waiting for %s%s",
                    epoch_s_, latency_s_ * 1e3, latency_jitter_s_ * 1e3, seed, imu_latency_s_ * 1e3,
                    wait_fusion_ ? "InertialFusion, " : "", wait_controller_ ? "the controller" : "no controller"));
}

void SimClosedLoop::publishClock(double t)
{
  if (t <= clock_t_)
    return;
  clock_t_ = t;
  rosgraph_msgs::Clock c;
  c.clock = lockstepStamp(t);
  pub_clock_.publish(c);
}

bool SimClosedLoop::waitUntil(const std::function<bool()>& done, const char* what)
{
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                             std::chrono::duration<double>(wait_timeout_s_));
  std::unique_lock<std::mutex> lock(mutex_);
  const auto t0 = std::chrono::steady_clock::now();
  struct Said
  {
    std::chrono::steady_clock::time_point t0;
    const char* what;
    double sim;
    ~Said()
    {
      const double ms = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() * 1e3;
      if (getenv("SLS_LOCKSTEP_DEBUG") && ms > 20.0)
        ROS_INFO("lockstep debug: waited %.0f ms for %s at t %.4f", ms, what, sim);
    }
  } said{t0, what, clock_t_};
  while (!done())
  {
    if (!ctx_.running())
      return false;
    if (std::chrono::steady_clock::now() > deadline)
    {
      ++timeouts_;
      ctx_.pnh.setParam("lockstep_timeouts", timeouts_);
      ROS_WARN_THROTTLE(5.0,
                        "CameraDriver (sim): lockstep: no %s within %.1f s (wall); going on without it (%d so far: "
                        "the run is no longer independent of the machine's load)",
                        what, wait_timeout_s_, timeouts_);
      return true;
    }
    answered_.wait_for(lock, std::chrono::milliseconds(100));
  }
  return true;
}

// The pipeline connected (the lazy chain wakes when PoseDelta is listened
// to): the image, the estimates and every answer the steps wait for.
bool SimClosedLoop::ready()
{
  const auto start = std::chrono::steady_clock::now();
  double said = 0.0;
  while (ctx_.running())
  {
    std::string missing;
    if (ctx_.image_subscribers() == 0)
      missing += " camera/image_raw's subscriber,";
    if (sub_lock_.getNumPublishers() == 0)
      missing += " pose_delta's publisher,";
    if ((wait_controller_ || wait_fusion_) && pub_relay_.getNumSubscribers() == 0)
      missing += " sim/lockstep/pose_delta's subscriber,";
    if (wait_controller_ && (sub_error_.getNumPublishers() == 0 || sub_command_.getNumPublishers() == 0))
      missing += " the controller,";
    if (wait_fusion_ && (pub_imu_.getNumSubscribers() == 0 || sub_fused_.getNumPublishers() == 0 ||
                         sub_frames_.getNumPublishers() == 0))
      missing += " InertialFusion,";
    if (wait_truth_ && pub_offset_.getNumSubscribers() == 0)
      missing += " sim/ground_truth/offset's subscriber,";
    const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (missing.empty() || waited > kReadyTimeoutS)
    {
      if (!missing.empty())
        ctx_.warn("lockstep: starting without" + missing.substr(0, missing.size() - 1));
      // The last links of the lazy chain settle.
      ros::WallDuration(0.5).sleep();
      std::lock_guard<std::mutex> lock(mutex_);
      errors_ = fused_ = frames_ = 0;
      return true;
    }
    if (waited - said > 5.0)
    {
      ctx_.info("lockstep: waiting for" + missing.substr(0, missing.size() - 1));
      said = waited;
    }
    ros::WallDuration(0.1).sleep();
  }
  return false;
}

bool SimClosedLoop::lockstepTo(double t)
{
  if (!started_)
  {
    publishClock(0.0);
    if (!ready())
      return false;
    started_ = true;
  }
  // The pipeline is idle when a frame goes out: the last frame's estimate in first.
  if (awaiting_)
  {
    const ros::Time stamp = awaited_;
    if (!waitUntil([&] { return estimates_.count(stamp) > 0 || !awaiting_; }, "PoseDelta estimate of the last frame"))
      return false;
    awaiting_ = false;
  }
  if (imu_)
    for (; next_imu_t_ <= t + 1e-9; next_imu_t_ = imu_->nextSampleTime(next_imu_t_))
      events_.emplace(next_imu_t_, Event());
  while (!events_.empty() && events_.begin()->first <= t + 1e-12)
  {
    const double at = events_.begin()->first;
    const Event e = events_.begin()->second;
    events_.erase(events_.begin());
    if (!process(at, e))
      return false;
  }
  publishClock(t);
  return true;
}

bool SimClosedLoop::process(double t, const Event& e)
{
  publishClock(t);
  switch (e.kind)
  {
    case Event::kImuSample:
    {
      std::lock_guard<std::mutex> arm_lock(arm_mutex_);
      Event delivery;
      delivery.kind = Event::kImuDelivery;
      if (sampleImu(t, &delivery.imu))
        events_.emplace(t + imu_latency_s_, delivery);
      return true;
    }
    case Event::kImuDelivery:
      return deliverImu(t, e.imu);
    case Event::kEstimate:
      return deliverEstimate(t, e.stamp);
  }
  return true;
}

bool SimClosedLoop::deliverImu(double t, const ImuSample& s)
{
  int64_t fused = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    fused = fused_;
  }
  publishImu(s, lockstepStamp(s.stamp));
  if (!waitUntil([&] { return fused_ > fused; }, "pose_fused from InertialFusion"))
    return false;
  if (wait_controller_ && !waitUntil([&] { return errors_ >= fused_; }, "answer of the controller"))
    return false;
  applyCommand(t);
  return true;
}

bool SimClosedLoop::deliverEstimate(double t, const ros::Time& stamp)
{
  if (!waitUntil([&] { return estimates_.count(stamp) > 0; }, "PoseDelta estimate"))
    return false;
  PoseDeltaConstPtr estimate;
  int64_t errors = 0, frames = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = estimates_.find(stamp);
    if (it != estimates_.end())
      estimate = it->second;
    estimates_.erase(estimates_.begin(), it == estimates_.end() ? it : std::next(it));
    if (awaiting_ && awaited_ == stamp)
      awaiting_ = false;
    errors = errors_;
    frames = frames_;
  }
  if (!estimate)
    return true;  // timed out: said so
  pub_relay_.publish(estimate);
  if (wait_fusion_)
  {
    if (!waitUntil([&] { return frames_ > frames; }, "pose_fused/frames from InertialFusion"))
      return false;
    if (wait_controller_ && !waitUntil([&] { return errors_ >= fused_; }, "answer of the controller"))
      return false;
  }
  else if (wait_controller_ && !waitUntil([&] { return errors_ > errors; }, "answer of the controller"))
    return false;
  applyCommand(t);
  return true;
}

void SimClosedLoop::applyCommand(double t)
{
  Vector6d v;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!new_command_)
      return;
    v = latest_command_;
    new_command_ = false;
  }
  std::lock_guard<std::mutex> arm_lock(arm_mutex_);
  if (!arm_)
    return;
  arm_->advance(t);
  arm_->command(t, v);
}

}  // namespace structured_light_stabilizer
