// SpotDetector nodelet: camera/image_raw -> spots (CentroidArray) and, only
// while someone listens, spots/debug_image. All the detection is in the core
// (spot_detector.h); this file subscribes, converts, calls and publishes.
#include <atomic>
#include <memory>
#include <mutex>
#include <string>

#include <boost/thread/recursive_mutex.hpp>
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/update_functions.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/SpotDetectorConfig.h"
#include "conversions.h"
#include "structured_light_stabilizer/spot_detector.h"
#include "drop_log.h"

namespace structured_light_stabilizer
{

class SpotDetectorNodelet : public nodelet::Nodelet
{
public:
  ~SpotDetectorNodelet() override
  {
    // Stop callbacks before the members they use go away, then tear down in
    // dependency order (the updater refers to freq_, the server to
    // config_mutex_).
    diag_timer_.stop();
    image_sub_.shutdown();
    updater_.reset();
    freq_.reset();
    reconfigure_.reset();
  }

private:
  using Config = structured_light_stabilizer::SpotDetectorConfig;

  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    pnh.param("lazy", lazy_, true);
    pnh.param("projector_rows", projector_rows_, 10);
    pnh.param("projector_cols", projector_cols_, 10);
    if (projector_rows_ < 1 || projector_cols_ < 1)
    {
      NODELET_WARN("SpotDetector: projector_rows/cols must be >= 1 (got %d x %d); using 10 x 10", projector_rows_,
                   projector_cols_);
      projector_rows_ = projector_cols_ = 10;
    }

    it_.reset(new image_transport::ImageTransport(nh));

    updater_.reset(new diagnostic_updater::Updater(nh, pnh, getName()));
    updater_->setHardwareID("structured_light_stabilizer/SpotDetector");
    freq_.reset(new diagnostic_updater::FrequencyStatus(
        diagnostic_updater::FrequencyStatusParam(&freq_min_, &freq_max_, 0.1, 10)));
    updater_->add(*freq_);
    updater_->add("detector", this, &SpotDetectorNodelet::diagnose);
    diag_timer_ = nh.createTimer(ros::Duration(1.0), [this](const ros::TimerEvent&) { updater_->update(); });

    reconfigure_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_->setCallback([this](Config& config, uint32_t level) { reconfigure(config, level); });

    // Advertise under the lock: a connect callback may fire at once.
    std::lock_guard<std::mutex> lock(connect_mutex_);
    auto connect = [this](const ros::SingleSubscriberPublisher&) { connectCb(); };
    auto image_connect = [this](const image_transport::SingleSubscriberPublisher&) { connectCb(); };
    spots_pub_ = nh.advertise<CentroidArray>("spots", 10, connect, connect);
    debug_pub_ = it_->advertise("spots/debug_image", 1, image_connect, image_connect);
    if (lazy_)
      NODELET_INFO("SpotDetector: camera/image_raw is subscribed on demand (~lazy = true): only while spots or "
                   "spots/debug_image has a subscriber");
    else
      subscribe();
  }

  void connectCb()
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    if (!lazy_)
      return;
    const bool wanted = spots_pub_.getNumSubscribers() > 0 || debug_pub_.getNumSubscribers() > 0;
    if (!wanted && image_sub_)
      image_sub_.shutdown();
    else if (wanted && !image_sub_)
      subscribe();
  }

  void subscribe()
  {
    const image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
    image_sub_ = it_->subscribe("camera/image_raw", 1, &SpotDetectorNodelet::imageCb, this, hints);
  }

  void reconfigure(Config& config, uint32_t /*level*/)
  {
    // Runs with config_mutex_ held by the server: validate and copy only.
    SpotDetectorParams p;
    if (config.method == "baseline")
      p.method = SpotMethod::kBaseline;
    else if (config.method == "fast")
      p.method = SpotMethod::kFast;
    else
    {
      // The last good value stays in force (the default before any).
      p.method = params_.method;
      const char* kept = p.method == SpotMethod::kBaseline ? "baseline" : "fast";
      NODELET_WARN("SpotDetector: unknown method '%s' (fast | baseline); keeping %s", config.method.c_str(), kept);
      config.method = kept;
    }
    p.blur_kernel = config.blur_kernel;
    p.h_min = config.h_min;
    p.h_max = config.h_max;
    p.s_min = config.s_min;
    p.s_max = config.s_max;
    p.v_min = config.v_min;
    p.v_max = config.v_max;
    p.erosions = config.erosions;
    p.dilations = config.dilations;
    p.min_area = config.min_area;
    p.max_area = config.max_area;
    p.baseline_weight = config.baseline_weight == 1 ? BaselineWeight::kValue : BaselineWeight::kSaturation;
    p.projector_rows = projector_rows_;
    p.projector_cols = projector_cols_;
    p.red_weight = config.red_weight;
    p.detect_threshold = config.detect_threshold;
    p.min_peak = config.min_peak;
    p.mono_threshold = config.mono_threshold;
    p.min_pixels = config.min_pixels;
    p.coarse_threshold = config.coarse_threshold;
    p.window_radius_px = config.window_radius_px;
    p.subtract_rock_texture = config.subtract_rock_texture;
    p.min_sigma_px = config.min_sigma_px;
    p.max_sigma_px = config.max_sigma_px;
    p.led_red_ratio = config.led_red_ratio;
    p.led_blue_ratio = config.led_blue_ratio;
    p.max_red_excess = config.max_red_excess;
    p.max_red_deficit = config.max_red_deficit;
    p.max_chroma_error = config.max_chroma_error;
    p.saturation_level = config.saturation_level;
    p.min_sigma_fraction = config.min_sigma_fraction;
    p.max_sigma_factor = config.max_sigma_factor;
    p.max_contrast_factor = config.max_contrast_factor;
    p.min_energy_fraction = config.min_energy_fraction;
    p.size_band_low = config.size_band_low;
    p.size_band_high = config.size_band_high;
    p.energy_band_low = config.energy_band_low;
    p.energy_band_high = config.energy_band_high;
    p.consistency_min_spots = config.consistency_min_spots;
    for (const std::string& change : p.sanitize())
      NODELET_WARN("SpotDetector: %s", change.c_str());
    // Show the values actually used in rqt_reconfigure.
    config.blur_kernel = p.blur_kernel;
    config.h_min = p.h_min;
    config.h_max = p.h_max;
    config.s_min = p.s_min;
    config.s_max = p.s_max;
    config.v_min = p.v_min;
    config.v_max = p.v_max;
    config.min_area = p.min_area;
    config.max_area = p.max_area;
    config.min_sigma_px = p.min_sigma_px;
    config.max_sigma_px = p.max_sigma_px;
    config.max_sigma_factor = p.max_sigma_factor;
    config.size_band_high = p.size_band_high;
    config.energy_band_high = p.energy_band_high;
    params_ = p;
    enabled_ = config.enabled;
    params_changed_ = true;
  }

  void imageCb(const sensor_msgs::ImageConstPtr& msg)
  {
    try
    {
      process(msg);
    }
    catch (const std::exception& e)
    {
      // cv::Exception and cv_bridge::Exception included: a bad frame must not
      // take the manager down.
      dropFrame(std::string("frame dropped: ") + e.what());
    }
  }

  void process(const sensor_msgs::ImageConstPtr& msg)
  {
    bool enabled;
    {
      boost::recursive_mutex::scoped_lock lock(config_mutex_);
      enabled = enabled_;
      if (params_changed_)
      {
        detector_.setParams(params_);  // applies from this frame on
        params_changed_ = false;
      }
    }
    if (!enabled)
      return;

    PixelFormat format;
    if (!pixelFormatFromEncoding(msg->encoding, &format))
    {
      dropFrame("unsupported image encoding '" + msg->encoding +
                "' (accepted: bgr8, rgb8, bgra8, rgba8, mono8); frame dropped");
      return;
    }
    if (format == PixelFormat::kMono8 && !mono_warned_)
    {
      mono_warned_ = true;
      NODELET_WARN("SpotDetector: mono8 input: no colour, so dots are found by intensity only (green clutter and "
                   "bright rock are not rejected); use a colour camera for the real thing");
    }
    const size_t row_bytes = static_cast<size_t>(msg->width) * channelCount(format);
    const std::string what = std::to_string(msg->width) + "x" + std::to_string(msg->height) + " " + msg->encoding;
    if (msg->width == 0 || msg->height == 0)
    {
      dropFrame("inconsistent image (" + what + "): empty; frame dropped");
      return;
    }
    if (msg->step < row_bytes)
    {
      dropFrame("inconsistent image (" + what + "): step " + std::to_string(msg->step) + " < width * channels " +
                std::to_string(row_bytes) + "; frame dropped");
      return;
    }
    const size_t needed = static_cast<size_t>(msg->step) * (msg->height - 1) + row_bytes;
    if (msg->data.size() < needed)
    {
      dropFrame("inconsistent image (" + what + ", step " + std::to_string(msg->step) + "): truncated, " +
                std::to_string(msg->data.size()) + " data bytes of the " + std::to_string(needed) +
                " needed; frame dropped");
      return;
    }
    // Zero copy: a header over the message's buffer, honouring its step.
    const cv::Mat image(static_cast<int>(msg->height), static_cast<int>(msg->width),
                        CV_MAKETYPE(CV_8U, channelCount(format)), const_cast<uint8_t*>(msg->data.data()), msg->step);

    const bool want_debug = debug_pub_.getNumSubscribers() > 0;
    SpotDetectorDebug debug;
    SpotDetectorTimings timings;
    const SpotDetectionResult result = detector_.detect(image, format, want_debug ? &debug : nullptr, &timings);
    if (!result.ok)
    {
      dropFrame("frame dropped: " + result.error);
      return;
    }

    CentroidArrayPtr out(new CentroidArray);
    out->header = msg->header;
    out->image_width = msg->width;
    out->image_height = msg->height;
    spotsToMsg(result.spots, out.get());
    spots_pub_.publish(out);
    freq_->tick();
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      last_ms_ = timings.total_ms;
      mean_ms_ = frames_ == 0 ? timings.total_ms : 0.95 * mean_ms_ + 0.05 * timings.total_ms;
      last_spots_ = static_cast<int>(result.spots.size());
      ++frames_;
    }

    if (want_debug)
    {
      cv_bridge::CvImage dbg(msg->header, sensor_msgs::image_encodings::BGR8,
                             drawSpotDebugImage(image, format, result.spots, debug));
      debug_pub_.publish(dbg.toImageMsg());
    }
  }

  // Logs why a frame was dropped: each kind of problem at once, then at most
  // every 5 s (bad frames, even of alternating kinds, must not flood rosout).
  void dropFrame(const std::string& why)
  {
    ++dropped_;
    int suppressed = 0;
    if (drop_log_.shouldLog(why, &suppressed))
    {
      const std::string note =
          suppressed > 0 ? " (" + std::to_string(suppressed) + " more like it suppressed)" : "";
      NODELET_ERROR("SpotDetector: %s%s", why.c_str(), note.c_str());
    }
    std::lock_guard<std::mutex> lock(stats_mutex_);
    last_error_ = why;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::string method;
    {
      boost::recursive_mutex::scoped_lock lock(config_mutex_);
      method = params_.method == SpotMethod::kBaseline ? "baseline" : "fast";
    }
    std::lock_guard<std::mutex> lock(stats_mutex_);
    const int expected = projector_rows_ * projector_cols_;
    if (frames_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "no frame processed yet (input is subscribed on demand)");
    else if (last_spots_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no dot found in the last frame");
    else
      stat.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "%d dots found (%d beams)", last_spots_, expected);
    stat.add("method", method);
    stat.add("frames processed", frames_);
    stat.add("frames dropped (bad input)", dropped_.load());
    stat.add("dots in last frame", last_spots_);
    stat.add("processing time last frame (ms)", last_ms_);
    stat.add("processing time mean (ms)", mean_ms_);
    if (!last_error_.empty())
      stat.add("last drop reason", last_error_);
  }

  // Parameters.
  bool lazy_ = true;
  int projector_rows_ = 10, projector_cols_ = 10;

  // dynamic_reconfigure: the server holds config_mutex_ while calling
  // reconfigure(); the frame callback copies params_ under it.
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_;
  SpotDetectorParams params_;
  bool enabled_ = true;
  bool params_changed_ = true;

  // Only the frame callback touches the detector (one image queue).
  SpotDetector detector_;
  bool mono_warned_ = false;

  std::unique_ptr<image_transport::ImageTransport> it_;
  std::mutex connect_mutex_;
  image_transport::Subscriber image_sub_;
  ros::Publisher spots_pub_;
  image_transport::Publisher debug_pub_;

  // Diagnostics.
  std::unique_ptr<diagnostic_updater::FrequencyStatus> freq_;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  double freq_min_ = 1.0, freq_max_ = 1000.0;
  ros::Timer diag_timer_;
  std::mutex stats_mutex_;
  double last_ms_ = 0.0, mean_ms_ = 0.0;
  int last_spots_ = 0, frames_ = 0;
  std::string last_error_;
  DropLog drop_log_;
  std::atomic<int> dropped_{0};
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::SpotDetectorNodelet, nodelet::Nodelet)
