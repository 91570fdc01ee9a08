// Plumbing shared by the package's nodelets, written once (the model is
// opencv_apps' opencv_apps::Nodelet): lazy subscription, the diagnostic
// updater with its frequency status, the per-kind drop log, and the exception
// boundary of the frame callbacks.
//
// A nodelet derives from NodeletBase and, in onInit():
//   readLazyParam();                       // ~lazy, before advertising
//   pub_x_ = advertise<Msg>(nh, "x", 10);  // outputs whose subscribers start the inputs
//   setUpDiagnostics(...); addFrequencyStatus(); startDiagnostics(1.0);
//   startSubscriptions("input is subscribed on demand ...");
// implements subscribe() / unsubscribe() (called with connect_mutex_ held),
// wraps each frame callback's work in guarded(), reports a dropped frame with
// dropFrame(why), and calls stopCallbacks() first in its destructor.
//
// The same member names in every nodelet (image_pipeline's habit): onInit,
// connectCb, <input>Cb (imageCb, spotsCb, cloudCb, infoCb), configCb,
// process (the one place that calls the core), pub_*_, sub_*_, srv_*_,
// connect_mutex_, config_mutex_ (the dynamic_reconfigure server's),
// reconfigure_server_, diagnostics_.
//
// Thread-safety: connectCb() may run on any callback thread (it takes
// connect_mutex_); dropFrame() and the drop counters may be used from any
// thread; the rest is for onInit() and the destructor.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/update_functions.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include "nodelets/common/drop_log.h"

namespace structured_light_stabilizer
{

// Which clock paces the diagnostics. ROS time for the processing nodelets
// (a replayed bag's clock; polled by a wall timer, see startDiagnostics);
// wall time for the CameraDriver, which must report even while ROS time
// stands still (use_sim_time without /clock).
enum class DiagnosticsClock
{
  kRosTime,
  kWallTime
};

class NodeletBase : public nodelet::Nodelet
{
public:
  // `label` starts each log line of the nodelet ("SpotDetector: ...").
  explicit NodeletBase(std::string label) : label_(std::move(label)) {}

protected:
  const std::string& label() const { return label_; }

  // ---- Lazy subscription (style weak spot 4: say so at start-up, ~lazy).

  // Reads ~lazy (default true). Call before advertising.
  void readLazyParam();

  // Advertises an output; while any output has a subscriber (or always, with
  // ~lazy false) the inputs are subscribed.
  template <class M>
  ros::Publisher advertise(ros::NodeHandle& nh, const std::string& topic, uint32_t queue_size);
  image_transport::Publisher advertiseImage(image_transport::ImageTransport& it, const std::string& topic,
                                            uint32_t queue_size);

  // Call last in onInit(): logs `on_demand_note` when lazy, then subscribes
  // the inputs if they are wanted already.
  void startSubscriptions(const std::string& on_demand_note);

  // Subscribes or unsubscribes the inputs as the outputs' subscribers come
  // and go. Runs on connect/disconnect callbacks; takes connect_mutex_.
  void connectCb();

  // The nodelet's inputs; called with connect_mutex_ held, only on a change.
  virtual void subscribe() {}
  virtual void unsubscribe() {}

  bool lazy_ = true;
  std::mutex connect_mutex_;  // guards the input subscribers and subscribed_
  bool subscribed_ = false;

  // ---- Diagnostics: one updater per nodelet, named after it.

  void setUpDiagnostics(const std::string& hardware_id);
  // The standard frequency status over [min_frequency_, max_frequency_]
  // (10 % tolerance, 10-update window), ticked with frequency_->tick().
  void addFrequencyStatus();
  // Updates every period_s; an exception in a task is logged, not thrown.
  void startDiagnostics(double period_s, DiagnosticsClock clock = DiagnosticsClock::kRosTime);

  double min_frequency_ = 1.0, max_frequency_ = 1000.0;  // Hz; read by the frequency status at each update
  std::unique_ptr<diagnostic_updater::FrequencyStatus> frequency_;
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;  // after frequency_: destroyed first

  // ---- Dropped frames and the exception boundary (style weak spot 1).

  // Counts the frame and logs why (see drop_log.h: each kind at once, then at
  // most every 5 s with the number suppressed meanwhile).
  void dropFrame(const std::string& why);
  // A frame kept but processed in part (say what was left out): a WARN with
  // the same throttling per kind as dropFrame().
  void warnPartial(const std::string& what);
  int framesDropped() const { return frames_dropped_.load(); }
  std::string lastDropReason() const;

  // Runs a frame callback's work; an exception (cv::Exception, cv_bridge's,
  // anything) drops the frame with its message instead of killing the manager.
  // The thread CPU time of the work is added to the "callback CPU" status
  // (setUpDiagnostics): the nodelet's own share of the manager's CPU, message
  // transport and deserialisation excluded (scripts/benchmark).
  template <class Work>
  void guarded(Work&& work)
  {
    const int64_t start_ns = threadCpuNs();
    try
    {
      work();
    }
    catch (const std::exception& e)
    {
      dropFrame(std::string("frame dropped: ") + e.what());
    }
    catch (...)
    {
      dropFrame("frame dropped: unknown exception");
    }
    callback_cpu_ns_ += threadCpuNs() - start_ns;
    ++callbacks_;
  }
  static int64_t threadCpuNs();

  // First thing in a derived destructor: stops the diagnostics timer and the
  // inputs, so that no callback runs into the members being destroyed.
  void stopCallbacks();

private:
  std::string label_;
  std::vector<std::function<uint32_t()>> output_subscribers_;  // under connect_mutex_
  bool stopped_ = false;                                       // under connect_mutex_
  ros::WallTimer diagnostics_wall_timer_;
  DropLog drop_log_;
  DropLog partial_log_;
  std::atomic<int64_t> callback_cpu_ns_{0};
  std::atomic<int64_t> callbacks_{0};
  std::atomic<int> frames_dropped_{0};
  mutable std::mutex drop_mutex_;
  std::string last_drop_reason_;  // under drop_mutex_
};

template <class M>
ros::Publisher NodeletBase::advertise(ros::NodeHandle& nh, const std::string& topic, uint32_t queue_size)
{
  const ros::SubscriberStatusCallback cb = [this](const ros::SingleSubscriberPublisher&) { connectCb(); };
  // Under the lock: a connect callback may fire as soon as it is advertised.
  std::lock_guard<std::mutex> lock(connect_mutex_);
  ros::Publisher pub = nh.advertise<M>(topic, queue_size, cb, cb);
  output_subscribers_.push_back([pub] { return pub.getNumSubscribers(); });
  return pub;
}

}  // namespace structured_light_stabilizer
