// SpotDetector nodelet: camera/image_raw -> spots (CentroidArray) and, only
// while someone listens, spots/debug_image. All the detection is in the core
// (spot_detector.h); this file subscribes, converts, calls and publishes.
#include <memory>
#include <mutex>
#include <string>

#include <boost/thread/recursive_mutex.hpp>
#include <cv_bridge/cv_bridge.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/SpotDetectorConfig.h"
#include "structured_light_stabilizer/spot_detector.h"
#include "conversions.h"
#include "nodelet_base.h"

namespace structured_light_stabilizer
{

namespace
{

using Config = structured_light_stabilizer::SpotDetectorConfig;

// ---- The core interface: dynamic_reconfigure <-> SpotDetectorParams, one
// function each way (the names of cfg/SpotDetector.cfg are the core's).

// config.method must be valid (spotMethodFromName).
SpotDetectorParams paramsFromConfig(const Config& config)
{
  SpotDetectorParams p;
  spotMethodFromName(config.method, &p.method);
  BaselineParams& b = p.baseline;  // the study's chain
  b.blur_kernel = config.blur_kernel;
  b.h_min = config.h_min;
  b.h_max = config.h_max;
  b.s_min = config.s_min;
  b.s_max = config.s_max;
  b.v_min = config.v_min;
  b.v_max = config.v_max;
  b.erosions = config.erosions;
  b.dilations = config.dilations;
  b.min_area = config.min_area;
  b.max_area = config.max_area;
  b.baseline_weight = config.baseline_weight == 1 ? BaselineWeight::kValue : BaselineWeight::kSaturation;
  FastParams& f = p.fast;  // the fast detector
  f.red_weight = config.red_weight;
  f.detect_threshold = config.detect_threshold;
  f.min_peak = config.min_peak;
  f.mono_threshold = config.mono_threshold;
  f.min_pixels = config.min_pixels;
  f.coarse_threshold = config.coarse_threshold;
  f.window_radius_px = config.window_radius_px;
  f.subtract_rock_texture = config.subtract_rock_texture;
  f.min_sigma_px = config.min_sigma_px;
  f.max_sigma_px = config.max_sigma_px;
  f.colour_test.led_red_ratio = config.led_red_ratio;
  f.colour_test.led_blue_ratio = config.led_blue_ratio;
  f.colour_test.max_red_excess = config.max_red_excess;
  f.colour_test.max_red_deficit = config.max_red_deficit;
  f.colour_test.max_chroma_error = config.max_chroma_error;
  f.saturation_level = config.saturation_level;
  FrameCheckParams& fc = f.frame_checks;  // the fast detector's frame-level tests
  fc.min_sigma_fraction = config.min_sigma_fraction;
  fc.max_sigma_factor = config.max_sigma_factor;
  fc.max_contrast_factor = config.max_contrast_factor;
  fc.min_energy_fraction = config.min_energy_fraction;
  fc.size_band_low = config.size_band_low;
  fc.size_band_high = config.size_band_high;
  fc.energy_band_low = config.energy_band_low;
  fc.energy_band_high = config.energy_band_high;
  fc.consistency_min_spots = config.consistency_min_spots;
  return p;
}

void configFromParams(const SpotDetectorParams& p, Config* config)
{
  config->method = spotMethodName(p.method);
  const BaselineParams& b = p.baseline;
  config->blur_kernel = b.blur_kernel;
  config->h_min = b.h_min;
  config->h_max = b.h_max;
  config->s_min = b.s_min;
  config->s_max = b.s_max;
  config->v_min = b.v_min;
  config->v_max = b.v_max;
  config->erosions = b.erosions;
  config->dilations = b.dilations;
  config->min_area = b.min_area;
  config->max_area = b.max_area;
  config->baseline_weight = b.baseline_weight == BaselineWeight::kValue ? 1 : 0;
  const FastParams& f = p.fast;
  config->red_weight = f.red_weight;
  config->detect_threshold = f.detect_threshold;
  config->min_peak = f.min_peak;
  config->mono_threshold = f.mono_threshold;
  config->min_pixels = f.min_pixels;
  config->coarse_threshold = f.coarse_threshold;
  config->window_radius_px = f.window_radius_px;
  config->subtract_rock_texture = f.subtract_rock_texture;
  config->min_sigma_px = f.min_sigma_px;
  config->max_sigma_px = f.max_sigma_px;
  config->led_red_ratio = f.colour_test.led_red_ratio;
  config->led_blue_ratio = f.colour_test.led_blue_ratio;
  config->max_red_excess = f.colour_test.max_red_excess;
  config->max_red_deficit = f.colour_test.max_red_deficit;
  config->max_chroma_error = f.colour_test.max_chroma_error;
  config->saturation_level = f.saturation_level;
  const FrameCheckParams& fc = f.frame_checks;
  config->min_sigma_fraction = fc.min_sigma_fraction;
  config->max_sigma_factor = fc.max_sigma_factor;
  config->max_contrast_factor = fc.max_contrast_factor;
  config->min_energy_fraction = fc.min_energy_fraction;
  config->size_band_low = fc.size_band_low;
  config->size_band_high = fc.size_band_high;
  config->energy_band_low = fc.energy_band_low;
  config->energy_band_high = fc.energy_band_high;
  config->consistency_min_spots = fc.consistency_min_spots;
}

// Why an image message cannot be read as `format` (empty when it can):
// style weak spot 2, refuse with a clear message instead of an OpenCV abort.
std::string inconsistency(const sensor_msgs::Image& msg, PixelFormat format)
{
  const size_t row_bytes = static_cast<size_t>(msg.width) * channelCount(format);
  const std::string what = std::to_string(msg.width) + "x" + std::to_string(msg.height) + " " + msg.encoding;
  if (msg.width == 0 || msg.height == 0)
    return "inconsistent image (" + what + "): empty; frame dropped";
  if (msg.step < row_bytes)
    return "inconsistent image (" + what + "): step " + std::to_string(msg.step) + " < width * channels " +
           std::to_string(row_bytes) + "; frame dropped";
  const size_t needed = static_cast<size_t>(msg.step) * (msg.height - 1) + row_bytes;
  if (msg.data.size() < needed)
    return "inconsistent image (" + what + ", step " + std::to_string(msg.step) + "): truncated, " +
           std::to_string(msg.data.size()) + " data bytes of the " + std::to_string(needed) + " needed; frame dropped";
  return "";
}

}  // namespace

class SpotDetectorNodelet : public NodeletBase
{
public:
  SpotDetectorNodelet() : NodeletBase("SpotDetector") {}
  ~SpotDetectorNodelet() override { stopCallbacks(); }

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readLazyParam();
    pnh.param("projector_rows", projector_rows_, 10);
    pnh.param("projector_cols", projector_cols_, 10);
    if (projector_rows_ < 1 || projector_cols_ < 1)
    {
      NODELET_WARN("SpotDetector: projector_rows/cols must be >= 1 (got %d x %d); using 10 x 10", projector_rows_,
                   projector_cols_);
      projector_rows_ = projector_cols_ = 10;
    }
    it_.reset(new image_transport::ImageTransport(nh));

    setUpDiagnostics("structured_light_stabilizer/SpotDetector");
    addFrequencyStatus();
    diagnostics_->add("detector", this, &SpotDetectorNodelet::diagnose);
    startDiagnostics(1.0);

    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });

    pub_spots_ = advertise<CentroidArray>(nh, "spots", 10);
    pub_debug_ = advertiseImage(*it_, "spots/debug_image", 1);
    startSubscriptions(
        "camera/image_raw is subscribed on demand (~lazy = true): only while spots or "
        "spots/debug_image has a subscriber");
  }

  void subscribe() override
  {
    const image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
    sub_image_ = it_->subscribe("camera/image_raw", 1, &SpotDetectorNodelet::imageCb, this, hints);
  }

  void unsubscribe() override { sub_image_.shutdown(); }

  void configCb(Config& config, uint32_t /*level*/)
  {
    // Runs with config_mutex_ held by the server: validate and copy only.
    SpotMethod method;
    if (!spotMethodFromName(config.method, &method))
    {
      // The last good value stays in force (the default before any).
      NODELET_WARN("SpotDetector: unknown method '%s' (fast | baseline); keeping %s", config.method.c_str(),
                   spotMethodName(params_.method));
      config.method = spotMethodName(params_.method);
    }
    SpotDetectorParams p = paramsFromConfig(config);
    p.projector_rows = projector_rows_;
    p.projector_cols = projector_cols_;
    for (const std::string& change : p.sanitize())
      NODELET_WARN("SpotDetector: %s", change.c_str());
    configFromParams(p, &config);  // rqt_reconfigure shows the values actually used
    params_ = p;
    enabled_ = config.enabled;
    params_changed_ = true;
  }

  void imageCb(const sensor_msgs::ImageConstPtr& msg)
  {
    guarded([&] { process(msg); });
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
      NODELET_WARN(
          "SpotDetector: mono8 input: no colour, so dots are found by intensity only (green clutter and "
          "bright rock are not rejected); use a colour camera for the real thing");
    }
    const std::string bad = inconsistency(*msg, format);
    if (!bad.empty())
    {
      dropFrame(bad);
      return;
    }
    // Zero copy: a header over the message's buffer, honouring its step.
    const cv::Mat image(static_cast<int>(msg->height), static_cast<int>(msg->width),
                        CV_MAKETYPE(CV_8U, channelCount(format)), const_cast<uint8_t*>(msg->data.data()), msg->step);

    const bool want_debug = pub_debug_.getNumSubscribers() > 0;
    SpotDetectorDebug debug;
    SpotDetectorTimings timings;
    const SpotDetectionResult result = detector_.detect(image, format, want_debug ? &debug : nullptr, &timings);
    if (!result.ok)
    {
      dropFrame("frame dropped: " + result.error);
      return;
    }
    publishSpots(*msg, result.spots, timings.total_ms);
    if (want_debug)
    {
      cv_bridge::CvImage dbg(msg->header, sensor_msgs::image_encodings::BGR8,
                             drawSpotDebugImage(image, format, result.spots, debug));
      pub_debug_.publish(dbg.toImageMsg());
    }
  }

  void publishSpots(const sensor_msgs::Image& image, const Spots& spots, double processing_ms)
  {
    CentroidArrayPtr out(new CentroidArray);
    out->header = image.header;
    out->image_width = image.width;
    out->image_height = image.height;
    spotsToMsg(spots, out.get());
    pub_spots_.publish(out);
    frequency_->tick();
    std::lock_guard<std::mutex> lock(stats_mutex_);
    last_ms_ = processing_ms;
    mean_ms_ = frames_ == 0 ? processing_ms : 0.95 * mean_ms_ + 0.05 * processing_ms;
    last_spots_ = static_cast<int>(spots.size());
    ++frames_;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::string method;
    {
      boost::recursive_mutex::scoped_lock lock(config_mutex_);
      method = spotMethodName(params_.method);
    }
    const std::string last_drop = lastDropReason();
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
    stat.add("frames dropped (bad input)", framesDropped());
    stat.add("dots in last frame", last_spots_);
    stat.add("processing time last frame (ms)", last_ms_);
    stat.add("processing time mean (ms)", mean_ms_);
    if (!last_drop.empty())
      stat.add("last drop reason", last_drop);
  }

  // Parameters fixed at start-up.
  int projector_rows_ = 10, projector_cols_ = 10;

  // dynamic_reconfigure: the server holds config_mutex_ while calling
  // configCb(); the frame callback copies params_ under it.
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  SpotDetectorParams params_;
  bool enabled_ = true;
  bool params_changed_ = true;

  // Only the frame callback touches the detector (one image queue).
  SpotDetector detector_;
  bool mono_warned_ = false;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber sub_image_;
  ros::Publisher pub_spots_;
  image_transport::Publisher pub_debug_;

  // Statistics for diagnostics.
  std::mutex stats_mutex_;
  double last_ms_ = 0.0, mean_ms_ = 0.0;
  int last_spots_ = 0, frames_ = 0;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::SpotDetectorNodelet, nodelet::Nodelet)
