// CameraDriver nodelet: publishes camera/image_raw + camera/camera_info from
// a frame source (frame_source.h: the built-in simulator, a V4L2 device, a
// video file or a folder of images; docs/interface.md, docs/simulator.md).
// This file keeps what is common to every source: pacing at ~rate, stamps,
// camera_info, the sensor window (binning, ROI), publishing in the encoding
// the source gives, diagnostics and the one retry policy. One worker
// thread acquires and publishes; it is joined in the destructor. Every
// failure of a source is logged (throttled) with what to fix and retried;
// nothing here may take the manager down.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include <boost/make_shared.hpp>
#include <boost/thread/recursive_mutex.hpp>
#include <camera_info_manager/camera_info_manager.h>
#include <cv_bridge/cv_bridge.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>

#include "structured_light_stabilizer/CameraDriverConfig.h"
#include "nodelets/frame_sources/frame_source.h"
#include "nodelets/common/nodelet_base.h"
#include "nodelets/common/param_reader.h"

namespace structured_light_stabilizer
{

class CameraDriverNodelet : public NodeletBase
{
public:
  CameraDriverNodelet() : NodeletBase("CameraDriver") {}

  ~CameraDriverNodelet() override
  {
    running_ = false;
    if (worker_.joinable())
      worker_.join();
    stopCallbacks();
  }

private:
  using Config = structured_light_stabilizer::CameraDriverConfig;

  void onInit() override;
  void readParams();
  void readWindowParams();
  void loadCameraInfoUrl();
  SourceContext sourceContext();
  void configCb(Config& config, uint32_t level);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  // Worker.
  void run();
  bool openSource();
  GrabResult tick(double rate);
  bool publishFrame(const std_msgs::Header& header, const Frame& frame, std::string* why);
  sensor_msgs::CameraInfoPtr infoFor(const std_msgs::Header& header, const cv::Mat& image);
  void setWindow(sensor_msgs::CameraInfo* info) const;
  bool acquisitionStamp(ros::Time* stamp);
  void reportProblem(const std::string& why, const char* suffix);
  void noteError(const std::string& what);
  void noteFramePeriod(double period_s, double rate, double render_ms);

  double currentRate()
  {
    boost::recursive_mutex::scoped_lock lock(config_mutex_);
    return rate_;
  }

  void setExpectedRate(double rate)
  {
    // The tolerance of the frequency status applies on top of these bounds.
    min_frequency_ = 0.9 * rate;
    max_frequency_ = 1.1 * rate;
  }

  // Sleeps until `t`, waking every 50 ms to honour shutdown; false on shutdown.
  bool sleepUntil(const ros::WallTime& t)
  {
    while (running_ && ros::ok())
    {
      const ros::WallTime now = ros::WallTime::now();
      if (now >= t)
        return true;
      ros::WallDuration(std::min((t - now).toSec(), 0.05)).sleep();
    }
    return false;
  }

  bool sleepFor(double seconds) { return sleepUntil(ros::WallTime::now() + ros::WallDuration(seconds)); }

  // Paces the loop: the next tick one period later. A worker more than a
  // period behind gives up the ticks it missed (returned; the schedule keeps
  // its phase) and catches up by one tick at most, no burst after a stall.
  static int64_t advance(ros::WallTime* next, double rate)
  {
    const double period = 1.0 / rate;
    *next += ros::WallDuration(period);
    const double behind = (ros::WallTime::now() - *next).toSec() - period;
    if (behind <= 0.0)
      return 0;
    const int64_t ticks = static_cast<int64_t>(std::floor(behind / period)) + 1;
    *next += ros::WallDuration(ticks * period);
    return ticks;
  }

  // Parameters.
  std::string source_name_, frame_id_, camera_info_url_, camera_name_;
  double rate_ = 30.0;  // Hz; under config_mutex_ once running
  bool calibrated_from_url_ = false;
  SensorWindow window_;  // ~binning_x/y, ~roi_*: what part of each frame is published

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::CameraPublisher pub_camera_;
  image_transport::Publisher pub_ambient_;  // projector-off frames of a strobed source
  std::unique_ptr<camera_info_manager::CameraInfoManager> camera_info_manager_;
  FrameSourceHandle source_;

  // After source_: the server (its callback uses the source) goes first.
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;

  // Status for diagnostics.
  std::mutex status_mutex_;
  std::string last_error_;
  ros::WallTime last_error_time_;
  uint64_t frames_published_ = 0;
  double processing_ms_ = 0.0;
  double mean_period_s_ = 0.0;  // rendered sources: running mean of the publish period
  cv::Size last_size_;
  std::string last_encoding_;
  DropLog problem_log_{10.0};  // source failures and unusable camera_info, per kind

  // Worker thread only: the publish period of a rendered source is measured
  // between frames published on consecutive ticks.
  bool consecutive_ = false;
  ros::WallTime previous_publish_;

  std::atomic<bool> running_{false};
  std::thread worker_;
};

// ---------------------------------------------------------------------
// Set-up

void CameraDriverNodelet::onInit()
{
  readParams();
  if (source_name_ == "none")
  {
    NODELET_INFO("CameraDriver: ~source is 'none': publishing nothing (images come from a bag or another driver)");
    return;
  }
  if (!isFrameSource(source_name_))
  {
    NODELET_ERROR("CameraDriver: unknown ~source '%s' (expected %s or none); publishing nothing", source_name_.c_str(),
                  frameSourceNames().c_str());
    return;
  }
  ros::NodeHandle& nh = getNodeHandle();
  it_.reset(new image_transport::ImageTransport(nh));
  // Five frames queued per subscriber before the oldest is dropped: a
  // recorder in another process on a loaded machine fell behind by more
  // than two (strobe_replay.test recorded 32 of ~43 projector-on frames).
  pub_camera_ = it_->advertiseCamera("camera/image_raw", 5);
  pub_ambient_ = it_->advertise("camera/image_ambient", 5);
  camera_info_manager_.reset(new camera_info_manager::CameraInfoManager(ros::NodeHandle(nh, "camera"), camera_name_));
  if (!camera_info_url_.empty())
    loadCameraInfoUrl();

  source_ = makeFrameSource(source_name_, sourceContext());
  if (!source_)
    return;  // the source said why

  setUpDiagnostics(source_name_);
  diagnostics_->add("CameraDriver", this, &CameraDriverNodelet::diagnose);
  addFrequencyStatus();
  setExpectedRate(rate_);
  startDiagnostics(1.0, DiagnosticsClock::kWallTime);

  reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, getPrivateNodeHandle()));
  reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });

  running_ = true;
  worker_ = std::thread(&CameraDriverNodelet::run, this);
}

void CameraDriverNodelet::readParams()
{
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  source_name_ = pnh.param<std::string>("source", "sim");
  frame_id_ = pnh.param<std::string>("frame_id", "camera_optical_frame");
  camera_info_url_ = pnh.param<std::string>("camera_info_url", "");
  camera_name_ = pnh.param<std::string>("camera_name", "camera");
  rate_ = pnh.param("rate", 30.0);
  if (!(rate_ > 0.0))
  {
    NODELET_ERROR("~rate = %g Hz is not positive; using 30 Hz", rate_);
    rate_ = 30.0;
    pnh.setParam("rate", rate_);
  }
  readWindowParams();
}

// The sensor window, as a camera driver with binning and ROI settings has
// it (names of sensor_msgs/CameraInfo): each frame is cut to the ROI and
// binned before it is published; camera_info keeps the full sensor's K and
// says binning and ROI (REP 104). Checked against each frame's size.
void CameraDriverNodelet::readWindowParams()
{
  const ParamReader read(getPrivateNodeHandle(),
                         [this](const std::string& m) { NODELET_ERROR("CameraDriver: %s", m.c_str()); });
  read.integer("binning_x", &window_.binning_x);
  read.integer("binning_y", &window_.binning_y);
  read.integer("roi_x_offset", &window_.x_offset);
  read.integer("roi_y_offset", &window_.y_offset);
  read.integer("roi_width", &window_.width);
  read.integer("roi_height", &window_.height);
  // CameraInfo's convention: binning 0 means none.
  window_.binning_x = std::max(1, window_.binning_x);
  window_.binning_y = std::max(1, window_.binning_y);
  if (window_.binning_x > 1 || window_.binning_y > 1 || window_.width > 0 || window_.height > 0)
    NODELET_INFO("CameraDriver: publishing the ROI %dx%d+%d+%d (0x0: the whole frame) binned %dx%d", window_.width,
                 window_.height, window_.x_offset, window_.y_offset, window_.binning_x, window_.binning_y);
}

void CameraDriverNodelet::loadCameraInfoUrl()
{
  // What is published instead: the simulator knows its own intrinsics.
  const char* instead = source_name_ == "sim" ? "using the simulator's own intrinsics"
                                              : "publishing an uncalibrated camera_info (K = 0) until it is fixed";
  const char* url = camera_info_url_.c_str();
  if (!camera_info_manager_->validateURL(camera_info_url_))
    NODELET_ERROR(
        "CameraDriver: ~camera_info_url '%s' is not a valid camera_info_manager URL (file:///path.yaml or "
        "package://pkg/path.yaml); %s",
        url, instead);
  else if (!camera_info_manager_->loadCameraInfo(camera_info_url_))
    NODELET_ERROR(
        "CameraDriver: ~camera_info_url '%s' could not be loaded (missing or malformed file, see the "
        "parser's message above); %s",
        url, instead);
  else if (!camera_info_manager_->isCalibrated())
    NODELET_ERROR("CameraDriver: ~camera_info_url '%s' has no intrinsics (camera_matrix K[0] = 0); %s", url, instead);
  else
    calibrated_from_url_ = true;
}

SourceContext CameraDriverNodelet::sourceContext()
{
  SourceContext ctx;
  ctx.nh = getNodeHandle();
  ctx.pnh = getPrivateNodeHandle();
  ctx.info = [this](const std::string& m) { NODELET_INFO("CameraDriver: %s", m.c_str()); };
  ctx.warn = [this](const std::string& m) { NODELET_WARN("CameraDriver: %s", m.c_str()); };
  ctx.error = [this](const std::string& m) { NODELET_ERROR("CameraDriver: %s", m.c_str()); };
  ctx.stamp = [this](ros::Time* stamp) { return acquisitionStamp(stamp); };
  ctx.image_subscribers = [this] { return pub_camera_.getNumSubscribers() + pub_ambient_.getNumSubscribers(); };
  ctx.running = [this] { return running_.load() && ros::ok(); };
  ctx.camera_info_url = camera_info_url_;
  ctx.window = window_;
  if (calibrated_from_url_)
    ctx.url_calibration = std::make_shared<const sensor_msgs::CameraInfo>(camera_info_manager_->getCameraInfo());
  return ctx;
}

void CameraDriverNodelet::configCb(Config& config, uint32_t /*level*/)
{
  // Called with config_mutex_ held.
  source_->reconfigure(config);
  rate_ = config.rate;
  setExpectedRate(rate_);
}

// ---------------------------------------------------------------------
// Worker: opens the source (the retry policy), paces it, publishes its frames.

void CameraDriverNodelet::run()
{
  bool opened = false;
  ros::WallTime next;
  while (running_ && ros::ok())
  {
    if (!opened)
    {
      if (!(opened = openSource()))
      {
        sleepFor(kRetryPeriodS);
        continue;
      }
      next = ros::WallTime::now();
    }
    const double rate = currentRate();
    if (source_->paced())
    {
      if (!sleepUntil(next))
        return;
      if (const int64_t ticks = advance(&next, rate))
        source_->skipped(ticks);
    }
    const GrabResult r = tick(rate);
    switch (r.status)
    {
      case GrabStatus::kFrame:
        break;
      case GrabStatus::kSkip:
        if (!r.message.empty())
        {
          noteError(r.message);
          dropFrame(r.message);
        }
        break;
      case GrabStatus::kBackOff:
        sleepFor(kRetryPeriodS);
        break;
      case GrabStatus::kLost:
        reportProblem(r.message, "; retrying every 2 s");
        source_->close();
        opened = false;
        sleepFor(kRetryPeriodS);
        break;
      case GrabStatus::kEnd:
        NODELET_INFO("CameraDriver: %s", r.message.c_str());
        while (sleepFor(0.5))
        {
        }
        return;
    }
  }
}

// Opens the source; a failure is reported (throttled) for a retry.
bool CameraDriverNodelet::openSource()
{
  std::string why;
  try
  {
    if (source_->open(&why))
    {
      const std::string description = source_->describe(currentRate());
      if (!description.empty())
        NODELET_INFO("CameraDriver: %s", description.c_str());
      return true;
    }
  }
  catch (const std::exception& e)
  {
    why = source_name_ + " source failed: " + e.what();
  }
  reportProblem(why, "; retrying every 2 s");
  source_->close();
  return false;
}

// Grabs and publishes one frame. Nothing may escape the thread (it would
// terminate the manager): an exception counts as a lost source.
GrabResult CameraDriverNodelet::tick(double rate)
{
  try
  {
    Frame frame;
    const GrabResult r = source_->grab(rate, &frame);
    if (r.status != GrabStatus::kFrame)
    {
      consecutive_ = false;
      return r;
    }
    std_msgs::Header header;
    header.stamp = frame.stamp;
    header.frame_id = frame_id_;
    std::string why;
    if (!publishFrame(header, frame, &why))
    {
      consecutive_ = false;
      return {GrabStatus::kSkip, why};
    }
    source_->published(header);
    // A source that is not paced (the simulator in lockstep) runs at the
    // pipeline's pace, not ~rate: nothing to warn about.
    if (source_->rendered() && source_->paced())
    {
      const ros::WallTime now = ros::WallTime::now();
      if (consecutive_)
        noteFramePeriod((now - previous_publish_).toSec(), rate, frame.processing_ms);
      previous_publish_ = now;
      consecutive_ = true;
    }
    return r;
  }
  catch (const std::exception& e)
  {
    consecutive_ = false;
    return {GrabStatus::kLost, source_name_ + " source failed: " + e.what()};
  }
}

// Publishes the frame (through the sensor window) in the encoding the
// source gave; false with *why when the window does not fit it.
bool CameraDriverNodelet::publishFrame(const std_msgs::Header& header, const Frame& frame, std::string* why)
{
  cv::Mat image = frame.image;
  if (!frame.windowed && !applyWindow(frame.image, frame.encoding, window_, &image, why))
    return false;
  sensor_msgs::CameraInfoPtr info;
  if (frame.ambient)
    pub_ambient_.publish(cv_bridge::CvImage(header, frame.encoding, image).toImageMsg());
  else if (const sensor_msgs::CameraInfo* own = source_->cameraInfo())
  {
    info = boost::make_shared<sensor_msgs::CameraInfo>(*own);
    info->header = header;
  }
  else
    info = infoFor(header, frame.image);
  if (info)
  {
    setWindow(info.get());
    pub_camera_.publish(cv_bridge::CvImage(header, frame.encoding, image).toImageMsg(), info);
  }
  frequency_->tick();
  std::lock_guard<std::mutex> lock(status_mutex_);
  ++frames_published_;
  processing_ms_ = frame.processing_ms;
  last_size_ = cv::Size(image.cols, image.rows);
  last_encoding_ = frame.encoding;
  return true;
}

// binning_x/y and roi of the published camera_info (its K, D, width and
// height stay the full sensor's).
void CameraDriverNodelet::setWindow(sensor_msgs::CameraInfo* info) const
{
  if (window_.isFullSensor(static_cast<int>(info->width), static_cast<int>(info->height)))
    return;
  const cv::Rect roi = window_.roi(static_cast<int>(info->width), static_cast<int>(info->height));
  info->binning_x = static_cast<uint32_t>(window_.binning_x);
  info->binning_y = static_cast<uint32_t>(window_.binning_y);
  info->roi.x_offset = static_cast<uint32_t>(roi.x);
  info->roi.y_offset = static_cast<uint32_t>(roi.y);
  info->roi.width = static_cast<uint32_t>(roi.width);
  info->roi.height = static_cast<uint32_t>(roi.height);
}

// camera_info for a frame of a real source: the loaded calibration when it
// fits the frame, otherwise an uncalibrated one (K = 0) of the frame's size.
sensor_msgs::CameraInfoPtr CameraDriverNodelet::infoFor(const std_msgs::Header& header, const cv::Mat& image)
{
  auto info = boost::make_shared<sensor_msgs::CameraInfo>(camera_info_manager_->getCameraInfo());
  if (calibrated_from_url_ &&
      (static_cast<int>(info->width) != image.cols || static_cast<int>(info->height) != image.rows))
  {
    reportProblem("~camera_info_url '" + camera_info_url_ + "' is for " + std::to_string(info->width) + "x" +
                      std::to_string(info->height) + " images but the " + source_name_ + " source gives " +
                      std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                      "; publishing an uncalibrated camera_info (K = 0)",
                  "");
    info = boost::make_shared<sensor_msgs::CameraInfo>();
  }
  info->header = header;
  info->width = image.cols;
  info->height = image.rows;
  return info;
}

// Acquisition time of a frame; false while ROS time is not running yet
// (use_sim_time without a clock).
bool CameraDriverNodelet::acquisitionStamp(ros::Time* stamp)
{
  *stamp = ros::Time::now();
  if (stamp->isZero())
  {
    NODELET_WARN_THROTTLE(10.0, "CameraDriver: ROS time is zero (use_sim_time without /clock?); waiting");
    return false;
  }
  return true;
}

// The one report of a source problem: kept for diagnostics, logged as an
// error at once and then at most every 10 s per kind of problem.
void CameraDriverNodelet::reportProblem(const std::string& why, const char* suffix)
{
  noteError(why);
  int suppressed = 0;
  if (problem_log_.shouldLog(why, &suppressed))
    NODELET_ERROR("CameraDriver: %s%s", why.c_str(), suffix);
}

void CameraDriverNodelet::noteError(const std::string& what)
{
  std::lock_guard<std::mutex> lock(status_mutex_);
  last_error_ = what;
  last_error_time_ = ros::WallTime::now();
}

// Keeps a running mean of the publish period; when rendering cannot keep
// up, the loop publishes as fast as it can (no catch-up burst, see
// advance()) and says so.
void CameraDriverNodelet::noteFramePeriod(double period_s, double rate, double render_ms)
{
  double hz;
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    mean_period_s_ = mean_period_s_ > 0.0 ? 0.9 * mean_period_s_ + 0.1 * period_s : period_s;
    hz = 1.0 / mean_period_s_;
  }
  if (hz < 0.9 * rate)
    NODELET_WARN_THROTTLE(30.0, "CameraDriver: rendering at %.1f Hz < requested %.1f Hz (%.1f ms per render)", hz, rate,
                          render_ms);
}

// ---------------------------------------------------------------------
// Diagnostics

void CameraDriverNodelet::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
{
  const double rate = currentRate();  // before status_mutex_: one lock at a time
  const bool rendered = source_->rendered();
  std::lock_guard<std::mutex> lock(status_mutex_);
  const bool recent_error = !last_error_.empty() && (ros::WallTime::now() - last_error_time_).toSec() < 10.0;
  const double reached_hz = mean_period_s_ > 0.0 ? 1.0 / mean_period_s_ : 0.0;
  if (recent_error)
    stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, last_error_);
  else if (frames_published_ == 0)
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no frame published yet");
  else if (rendered && reached_hz > 0.0 && reached_hz < 0.9 * rate)
    stat.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "rendering at %.1f Hz < requested %.1f Hz", reached_hz,
                  rate);
  else
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "publishing");
  if (rendered)
    stat.add("publish rate reached (Hz)", reached_hz);
  stat.add("source", source_name_);
  stat.add("frame_id", frame_id_);
  stat.add("frames published", frames_published_);
  stat.add("image size", std::to_string(last_size_.width) + "x" + std::to_string(last_size_.height));
  stat.add("encoding", last_encoding_);
  stat.add(rendered ? "render time (ms)" : "acquisition time (ms)", processing_ms_);
  stat.add("camera_info",
           calibrated_from_url_ ? camera_info_url_ : (source_->cameraInfo() ? "simulator" : "uncalibrated"));
  stat.add("last error", last_error_);
}

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::CameraDriverNodelet, nodelet::Nodelet)
