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
// Subscribes: camera/camera_info (sensor_msgs/CameraInfo), spots
// (structured_light_stabilizer/CentroidArray), points (sensor_msgs/PointCloud2),
// pose_delta (structured_light_stabilizer/PoseDelta): the stages between
// them are the SpotDetector's, the Triangulator's and PoseDelta's (each with
// its wait in the manager's queue and its publication).
// Parameters: ~out_file (YAML written every ~write_period_s and at unload;
// empty: only logged at unload), ~write_period_s (5.0),
// ~warmup_frames (30: frames before these are not timed).
// Writes: frames (camera_info seen), timed (frames with their pose_delta),
// latency_min_ms, latency_median_ms, latency_p90_ms, latency_p99_ms, latency_max_ms,
// p99_over_median, and per stage (detector, triangulator, pose_delta; of the
// frames whose spots and points came too) <stage>_median_ms, <stage>_p99_ms
// and <stage>_in_slowest_ms: its mean over the slowest 2 % of those frames
// (where the tail comes from).
#include <algorithm>
#include <array>
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
#include <sensor_msgs/PointCloud2.h>

#include <structured_light_stabilizer/CentroidArray.h>
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
    sub_spots_.shutdown();
    sub_points_.shutdown();
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
    const boost::function<void(const CentroidArrayConstPtr&)> on_spots = [this](const CentroidArrayConstPtr& m)
    { stageCb(m->header, 1); };
    const boost::function<void(const sensor_msgs::PointCloud2ConstPtr&)> on_points =
        [this](const sensor_msgs::PointCloud2ConstPtr& m) { stageCb(m->header, 2); };
    sub_spots_ = nh.subscribe<CentroidArray>("spots", 100, on_spots);
    sub_points_ = nh.subscribe<sensor_msgs::PointCloud2>("points", 100, on_points);
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
    arrived_[msg->header.stamp.toNSec()].at[0] = now;
    // Frames without a pose_delta within 2 s are forgotten (dropped frames).
    while (!arrived_.empty() && now - arrived_.begin()->second.at[0] > std::chrono::seconds(2))
      arrived_.erase(arrived_.begin());
  }

  // The spots (stage 1) or points (stage 2) of a frame whose camera_info came.
  void stageCb(const std_msgs::Header& header, int stage)
  {
    const Clock::time_point now = Clock::now();
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = arrived_.find(header.stamp.toNSec());
    if (it != arrived_.end())
    {
      it->second.at[stage] = now;
      it->second.seen[stage] = true;
    }
  }

  void poseCb(const PoseDeltaConstPtr& msg)
  {
    const Clock::time_point now = Clock::now();
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = arrived_.find(msg->header.stamp.toNSec());
    if (it == arrived_.end())
      return;
    const Arrivals& a = it->second;
    const auto ms = [](Clock::time_point from, Clock::time_point to)
    { return std::chrono::duration<double, std::milli>(to - from).count(); };
    latencies_ms_.push_back(ms(a.at[0], now));
    if (a.seen[1] && a.seen[2])
      stages_ms_.push_back({ms(a.at[0], now), ms(a.at[0], a.at[1]), ms(a.at[1], a.at[2]), ms(a.at[2], now)});
    arrived_.erase(it);
  }

  // Writes the figures to ~out_file (when set); returns them on one line.
  std::string write()
  {
    std::vector<double> v;
    std::vector<std::array<double, 4>> stages;
    int frames = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      v = latencies_ms_;
      stages = stages_ms_;
      frames = frames_;
    }
    if (v.empty())
      return std::string();
    std::sort(v.begin(), v.end());
    const double median = quantile(v, 0.5), p90 = quantile(v, 0.9), p99 = quantile(v, 0.99);
    char line[512];
    std::snprintf(line, sizeof(line),
                  "frames: %d\ntimed: %zu\nlatency_min_ms: %.4f\nlatency_median_ms: %.4f\nlatency_p90_ms: %.4f\n"
                  "latency_p99_ms: %.4f\nlatency_max_ms: %.4f\np99_over_median: %.4f\n",
                  frames, v.size(), v.front(), median, p90, p99, v.back(), median > 0.0 ? p99 / median : 0.0);
    std::string text(line);
    text += stageFigures(stages);
    if (!out_file_.empty())
    {
      std::ofstream f(out_file_ + ".tmp");
      f << text;
      f.close();
      if (f)
        std::rename((out_file_ + ".tmp").c_str(), out_file_.c_str());
      else
        NODELET_WARN_THROTTLE(30.0, "LatencyProbe: cannot write %s", out_file_.c_str());
    }
    std::string summary(text);
    std::replace(summary.begin(), summary.end(), '\n', ' ');
    return summary;
  }

  // Per stage (detector, triangulator, pose_delta): median, p99 and the mean
  // over the slowest 2 % of the frames by their total; YAML lines.
  static std::string stageFigures(std::vector<std::array<double, 4>> s)
  {
    if (s.empty())
      return std::string();
    std::sort(s.begin(), s.end(), [](const auto& a, const auto& b) { return a[0] < b[0]; });
    const size_t slow = std::max<size_t>(1, s.size() / 50);
    std::string out;
    const char* names[] = {"", "detector", "triangulator", "pose_delta"};
    for (int k = 1; k <= 3; ++k)
    {
      std::vector<double> v;
      v.reserve(s.size());
      double tail = 0.0;
      for (size_t i = 0; i < s.size(); ++i)
      {
        v.push_back(s[i][k]);
        if (i >= s.size() - slow)
          tail += s[i][k];
      }
      std::sort(v.begin(), v.end());
      char line[256];
      std::snprintf(line, sizeof(line), "%s_median_ms: %.4f\n%s_p99_ms: %.4f\n%s_in_slowest_ms: %.4f\n", names[k],
                    quantile(v, 0.5), names[k], quantile(v, 0.99), names[k], tail / slow);
      out += line;
    }
    return out;
  }

  static double quantile(const std::vector<double>& sorted, double q)
  {
    return sorted[std::min(sorted.size() - 1, static_cast<size_t>(q * (sorted.size() - 1) + 0.5))];
  }

  // Arrival of a frame's camera_info (0), spots (1), points (2).
  struct Arrivals
  {
    std::array<Clock::time_point, 3> at;
    std::array<bool, 3> seen = {true, false, false};
  };

  std::string out_file_;
  int warmup_frames_ = 30;
  ros::CallbackQueue queue_;
  std::unique_ptr<ros::AsyncSpinner> spinner_;
  ros::Subscriber sub_info_, sub_spots_, sub_points_, sub_pose_;
  ros::WallTimer write_timer_;
  std::mutex mutex_;
  int frames_ = 0;
  std::map<uint64_t, Arrivals> arrived_;
  std::vector<double> latencies_ms_;
  std::vector<std::array<double, 4>> stages_ms_;  // total, detector, triangulator, pose_delta
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::LatencyProbeNodelet, nodelet::Nodelet)
