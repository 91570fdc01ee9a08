// LatencyProbe: a benchmark instrument, not a part of the pipeline. Loaded
// into the pipeline's manager (benchmark.launch, benchmark_replay.launch), it
// times each frame from the arrival of its camera/camera_info to the arrival
// of its pose_delta (paired by stamp) on the steady clock, on a callback
// queue and thread of its own, so that the figure is the pipeline's, not a
// measuring process's wake-up (nodes/benchmark_probe.py measures the same
// from another process, where the interpreter's and the scheduler's delays
// add to both ends). Intra-process publication hands it the messages as the
// pipeline's nodelets get them.
//
// Subscribes: camera/camera_info (sensor_msgs/CameraInfo), pose_delta
// (structured_light_stabilizer/PoseDelta).
// Parameters: ~out_file (YAML written every ~write_period_s and at unload;
// empty: only logged at unload), ~write_period_s (5.0),
// ~warmup_frames (30: frames before these are not timed).
// Writes: frames (camera_info seen), timed (frames with their pose_delta),
// latency_min_ms, latency_median_ms, latency_p90_ms, latency_p99_ms, latency_max_ms,
// p99_over_median.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>

#include <structured_light_stabilizer/PoseDelta.h>

namespace structured_light_stabilizer
{

class LatencyProbeNodelet : public nodelet::Nodelet
{
public:
  ~LatencyProbeNodelet() override
  {
    write_timer_.stop();
    if (spinner_)
      spinner_->stop();
    sub_info_.shutdown();
    sub_pose_.shutdown();
    const std::string summary = write();
    if (!summary.empty())
      NODELET_INFO("LatencyProbe: %s", summary.c_str());
  }

private:
  using Clock = std::chrono::steady_clock;

  void onInit() override
  {
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    pnh.param("out_file", out_file_, std::string());
    double period = 5.0;
    pnh.param("write_period_s", period, period);
    pnh.param("warmup_frames", warmup_frames_, warmup_frames_);
    if (!(period > 0.0))
    {
      NODELET_WARN("LatencyProbe: ~write_period_s %g is not positive; using 5 s", period);
      period = 5.0;
    }
    warmup_frames_ = std::max(warmup_frames_, 0);
    ros::NodeHandle nh = getNodeHandle();
    nh.setCallbackQueue(&queue_);
    sub_info_ =
        nh.subscribe("camera/camera_info", 100, &LatencyProbeNodelet::infoCb, this, ros::TransportHints().tcpNoDelay());
    sub_pose_ = nh.subscribe("pose_delta", 100, &LatencyProbeNodelet::poseCb, this, ros::TransportHints().tcpNoDelay());
    spinner_ = std::make_unique<ros::AsyncSpinner>(1, &queue_);
    spinner_->start();
    write_timer_ = getNodeHandle().createWallTimer(ros::WallDuration(period),
                                                   [this](const ros::WallTimerEvent&)
                                                   {
                                                     if (!out_file_.empty())
                                                       write();
                                                   });
  }

  void infoCb(const sensor_msgs::CameraInfoConstPtr& msg)
  {
    const Clock::time_point now = Clock::now();
    std::lock_guard<std::mutex> lock(mutex_);
    if (++frames_ <= warmup_frames_)
      return;
    arrived_[msg->header.stamp.toNSec()] = now;
    // Frames without a pose_delta within 2 s are forgotten (dropped frames).
    while (!arrived_.empty() && now - arrived_.begin()->second > std::chrono::seconds(2))
      arrived_.erase(arrived_.begin());
  }

  void poseCb(const PoseDeltaConstPtr& msg)
  {
    const Clock::time_point now = Clock::now();
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = arrived_.find(msg->header.stamp.toNSec());
    if (it == arrived_.end())
      return;
    latencies_ms_.push_back(std::chrono::duration<double, std::milli>(now - it->second).count());
    arrived_.erase(it);
  }

  // Writes the figures to ~out_file (when set); returns them on one line.
  std::string write()
  {
    std::vector<double> v;
    int frames = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      v = latencies_ms_;
      frames = frames_;
    }
    if (v.empty())
      return std::string();
    std::sort(v.begin(), v.end());
    const auto at = [&v](double q) { return v[std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5))]; };
    const double median = at(0.5), p90 = at(0.9), p99 = at(0.99);
    char line[512];
    std::snprintf(line, sizeof(line),
                  "frames: %d\ntimed: %zu\nlatency_min_ms: %.4f\nlatency_median_ms: %.4f\nlatency_p90_ms: %.4f\n"
                  "latency_p99_ms: %.4f\nlatency_max_ms: %.4f\np99_over_median: %.4f\n",
                  frames, v.size(), v.front(), median, p90, p99, v.back(), median > 0.0 ? p99 / median : 0.0);
    if (!out_file_.empty())
    {
      std::ofstream f(out_file_ + ".tmp");
      f << line;
      f.close();
      if (f)
        std::rename((out_file_ + ".tmp").c_str(), out_file_.c_str());
      else
        NODELET_WARN_THROTTLE(30.0, "LatencyProbe: cannot write %s", out_file_.c_str());
    }
    std::string summary(line);
    std::replace(summary.begin(), summary.end(), '\n', ' ');
    return summary;
  }

  std::string out_file_;
  int warmup_frames_ = 30;
  ros::CallbackQueue queue_;
  std::unique_ptr<ros::AsyncSpinner> spinner_;
  ros::Subscriber sub_info_, sub_pose_;
  ros::WallTimer write_timer_;
  std::mutex mutex_;
  int frames_ = 0;
  std::map<uint64_t, Clock::time_point> arrived_;
  std::vector<double> latencies_ms_;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::LatencyProbeNodelet, nodelet::Nodelet)
