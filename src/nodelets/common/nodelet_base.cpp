#include "nodelets/common/nodelet_base.h"

#include <time.h>

namespace structured_light_stabilizer
{

void NodeletBase::readLazyParam()
{
  getPrivateNodeHandle().param("lazy", lazy_, true);
}

image_transport::Publisher NodeletBase::advertiseImage(image_transport::ImageTransport& it, const std::string& topic,
                                                       uint32_t queue_size)
{
  const image_transport::SubscriberStatusCallback cb = [this](const image_transport::SingleSubscriberPublisher&)
  { connectCb(); };
  std::lock_guard<std::mutex> lock(connect_mutex_);
  image_transport::Publisher pub = it.advertise(topic, queue_size, cb, cb);
  output_subscribers_.push_back([pub] { return pub.getNumSubscribers(); });
  return pub;
}

void NodeletBase::startSubscriptions(const std::string& on_demand_note)
{
  if (lazy_)
    NODELET_INFO("%s: %s", label_.c_str(), on_demand_note.c_str());
  connectCb();
}

void NodeletBase::connectCb()
{
  std::lock_guard<std::mutex> lock(connect_mutex_);
  if (stopped_)
    return;
  bool wanted = !lazy_;
  for (const auto& subscribers : output_subscribers_)
    wanted = wanted || subscribers() > 0;
  if (wanted && !subscribed_)
    subscribe();
  else if (!wanted && subscribed_)
    unsubscribe();
  subscribed_ = wanted;
}

void NodeletBase::setUpDiagnostics(const std::string& hardware_id)
{
  diagnostics_.reset(new diagnostic_updater::Updater(getNodeHandle(), getPrivateNodeHandle(), getName()));
  diagnostics_->setHardwareID(hardware_id);
  diagnostics_->add("callback CPU",
                    [this](diagnostic_updater::DiagnosticStatusWrapper& stat)
                    {
                      const int64_t n = callbacks_.load(), ns = callback_cpu_ns_.load();
                      stat.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "%.3f ms of thread CPU per callback",
                                    n > 0 ? 1e-6 * ns / n : 0.0);
                      stat.add("callbacks", n);
                      stat.addf("thread CPU total (s)", "%.6f", 1e-9 * ns);
                      stat.addf("thread CPU per callback (ms)", "%.4f", n > 0 ? 1e-6 * ns / n : 0.0);
                    });
}

int64_t NodeletBase::threadCpuNs()
{
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1000000000LL + ts.tv_nsec;
}

void NodeletBase::addFrequencyStatus()
{
  frequency_.reset(new diagnostic_updater::FrequencyStatus(
      diagnostic_updater::FrequencyStatusParam(&min_frequency_, &max_frequency_, 0.1, 10)));
  diagnostics_->add(*frequency_);
}

void NodeletBase::startDiagnostics(double period_s, DiagnosticsClock clock)
{
  // Wall time: force_update, since Updater::update compares ROS time with its
  // next publication time and, while ROS time stands still (use_sim_time
  // without /clock), would never publish.
  const bool wall = clock == DiagnosticsClock::kWallTime;
  const auto update = [this, wall]
  {
    try
    {
      if (wall)
        diagnostics_->force_update();
      else
        diagnostics_->update();
    }
    catch (const std::exception& e)
    {
      NODELET_ERROR_THROTTLE(10.0, "%s: diagnostics failed: %s", label_.c_str(), e.what());
    }
  };
  // ROS time: a wall timer at half the period asks the updater, which
  // publishes once `period_s` of ROS time has passed (Updater::update), so a
  // replayed bag's clock paces the diagnostics. Not a ROS-time timer: under
  // use_sim_time roscpp polls ROS-time timers every millisecond, about 25 ms
  // of CPU per second in a manager on this machine (docs/performance.md).
  ros::NodeHandle& nh = getNodeHandle();
  const double wall_period_s = wall ? period_s : 0.5 * period_s;
  diagnostics_wall_timer_ =
      nh.createWallTimer(ros::WallDuration(wall_period_s), [update](const ros::WallTimerEvent&) { update(); });
}

void NodeletBase::dropFrame(const std::string& why)
{
  ++frames_dropped_;
  int suppressed = 0;
  if (drop_log_.shouldLog(why, &suppressed))
  {
    const std::string note = suppressed > 0 ? " (" + std::to_string(suppressed) + " more like it suppressed)" : "";
    NODELET_ERROR("%s: %s%s", label_.c_str(), why.c_str(), note.c_str());
  }
  std::lock_guard<std::mutex> lock(drop_mutex_);
  last_drop_reason_ = why;
}

void NodeletBase::warnPartial(const std::string& what)
{
  int suppressed = 0;
  if (partial_log_.shouldLog(what, &suppressed))
  {
    const std::string note = suppressed > 0 ? " (" + std::to_string(suppressed) + " more like it suppressed)" : "";
    NODELET_WARN("%s: %s%s", label_.c_str(), what.c_str(), note.c_str());
  }
}

std::string NodeletBase::lastDropReason() const
{
  std::lock_guard<std::mutex> lock(drop_mutex_);
  return last_drop_reason_;
}

void NodeletBase::stopCallbacks()
{
  diagnostics_wall_timer_.stop();
  std::lock_guard<std::mutex> lock(connect_mutex_);
  stopped_ = true;
  if (subscribed_)
    unsubscribe();
  subscribed_ = false;
}

}  // namespace structured_light_stabilizer
