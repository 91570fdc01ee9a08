// SpotDetector nodelet: camera/image_raw -> spots (CentroidArray) and, only
// while someone listens, spots/debug_image. With ~strobe it also takes the
// projector-off frames of camera/image_ambient (a message_filters cache) and
// hands the nearest one by stamp to the core with each frame. All the
// detection is in the core (spot_detector.h); this file subscribes,
// converts, calls and publishes.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>
#include <deque>
#include <mutex>
#include <string>
#include <vector>

#include <boost/thread/recursive_mutex.hpp>
#include <cv_bridge/cv_bridge.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <image_transport/subscriber_filter.h>
#include <message_filters/cache.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/SpotDetectorConfig.h"
#include "structured_light_stabilizer/detection/ambient_compensation.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/detection/spot_search_planner.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"

namespace structured_light_stabilizer
{

namespace
{

using Config = structured_light_stabilizer::SpotDetectorConfig;

// ---- The core interface: dynamic_reconfigure <-> SpotDetectorParams and
// SpotSearchParams, the fields of their .def files (common/params.h).

// config.method and config.projector_color must be valid (configCb()).
SpotDetectorParams paramsFromConfig(const Config& config)
{
  SpotDetectorParams p;
  p.fromConfig(config);
  return p;
}

SpotSearchParams searchParamsFromConfig(const Config& config)
{
  SpotSearchParams p;
  p.fromConfig(config);
  return p;
}

// The share of the frame's pixels in the regions (which may overlap a little).
double searchedFraction(const std::vector<cv::Rect>& regions, const cv::Size& frame)
{
  double n = 0;
  for (const cv::Rect& r : mergeSearchRegions(regions, frame))
    n += r.area();
  return std::min(1.0, n / std::max(1.0, static_cast<double>(frame.area())));
}

// The mosaic of a frame for the ambient compensation.
AmbientLayout ambientLayout(PixelFormat format)
{
  switch (format)
  {
    case PixelFormat::kBayerRggb8:
      return AmbientLayout::kBayerRggb;
    case PixelFormat::kBayerBggr8:
      return AmbientLayout::kBayerBggr;
    case PixelFormat::kBayerGbrg8:
      return AmbientLayout::kBayerGbrg;
    case PixelFormat::kBayerGrbg8:
      return AmbientLayout::kBayerGrbg;
    default:
      return AmbientLayout::kInterleaved;
  }
}

}  // namespace

class SpotDetectorNodelet : public NodeletBase
{
public:
  SpotDetectorNodelet() : NodeletBase("SpotDetector") {}
  ~SpotDetectorNodelet() override
  {
    release_timer_.stop();
    stopCallbacks();
  }

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
    pnh.param("queue_size", queue_size_, 2);
    if (queue_size_ < 1)
    {
      NODELET_WARN("SpotDetector: ~queue_size must be >= 1 (got %d); using 1", queue_size_);
      queue_size_ = 1;
    }
    pnh.param("strobe", strobe_, false);
    pnh.param("ambient_max_gap_s", ambient_max_gap_s_, 0.25);
    if (!(ambient_max_gap_s_ > 0.0))
    {
      NODELET_WARN("SpotDetector: ~ambient_max_gap_s must be > 0 (got %g); using 0.25", ambient_max_gap_s_);
      ambient_max_gap_s_ = 0.25;
    }
    pnh.param("ambient_wait", ambient_wait_, true);
    if (strobe_ && ambient_wait_)
      release_timer_ = nh.createWallTimer(ros::WallDuration(0.5 * ambient_max_gap_s_),
                                          [this](const ros::WallTimerEvent&) { releaseStale(); });
    it_.reset(new image_transport::ImageTransport(nh));

    setUpDiagnostics("structured_light_stabilizer/SpotDetector");
    addFrequencyStatus();
    diagnostics_->add("detector", this, &SpotDetectorNodelet::diagnose);
    startDiagnostics(1.0);

    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });

    pub_spots_ = advertise<CentroidArray>(nh, "spots", 10);
    pub_debug_ = advertiseImage(*it_, "spots/debug_image", 1);
    if (strobe_)
      NODELET_INFO(
          "SpotDetector: strobe mode: each frame of camera/image_raw is paired with the projector-off frames "
          "of camera/image_ambient around it (within %.3f s)%s",
          ambient_max_gap_s_, ambient_wait_ ? ", waiting for the one after it" : "");
    startSubscriptions(std::string("camera/image_raw") + (strobe_ ? " and camera/image_ambient are" : " is") +
                       " subscribed on demand (~lazy = true): only while spots or spots/debug_image has a subscriber");
  }

  void subscribe() override
  {
    const image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
    sub_image_ = it_->subscribe("camera/image_raw", queue_size_, &SpotDetectorNodelet::imageCb, this, hints);
    if (strobe_)
    {
      // Ten projector-off frames (0.67 s of a 30 Hz strobe, 60 MB at bgr16):
      // a bag recorded on a loaded machine replays a projector-on frame up
      // to 0.46 s after the projector-off frames of its time (measured), and
      // four let them go before it came.
      constexpr int kAmbientFrames = 10;
      sub_ambient_.subscribe(*it_, "camera/image_ambient", kAmbientFrames, hints);
      ambient_cache_.reset(new message_filters::Cache<sensor_msgs::Image>(sub_ambient_, kAmbientFrames));
      ambient_cache_->registerCallback(&SpotDetectorNodelet::ambientCb, this);
    }
  }

  void unsubscribe() override
  {
    sub_image_.shutdown();
    if (strobe_)
    {
      sub_ambient_.unsubscribe();
      ambient_cache_.reset();
      std::lock_guard<std::mutex> lock(pending_mutex_);
      pending_.clear();
    }
  }

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
    ProjectorColor color;
    if (!projectorColorFromName(config.projector_color, &color))
    {
      NODELET_WARN("SpotDetector: unknown projector_color '%s' (green | red | blue | nir | white); keeping %s",
                   config.projector_color.c_str(), projectorColorName(params_.projector_color));
      config.projector_color = projectorColorName(params_.projector_color);
    }
    SpotDetectorParams p = paramsFromConfig(config);
    p.projector_rows = projector_rows_;
    p.projector_cols = projector_cols_;
    for (const std::string& change : p.sanitize())
      NODELET_WARN("SpotDetector: %s", change.c_str());
    p.toConfig(&config);  // rqt_reconfigure shows the values actually used
    SpotSearchParams search = searchParamsFromConfig(config);
    for (const std::string& change : search.sanitize())
      NODELET_WARN("SpotDetector: %s", change.c_str());
    search.toConfig(&config);
    params_ = p;
    search_params_ = search;
    enabled_ = config.enabled;
    params_changed_ = true;
  }

  void imageCb(const sensor_msgs::ImageConstPtr& msg)
  {
    if (!strobe_ || !ambient_wait_)
    {
      processGuarded(msg);
      return;
    }
    // Strobe mode: a frame whose following projector-off frame has not come
    // yet waits for it (interpolation beats extrapolation from the two
    // before), at most until kMaxPending newer frames have come: a bag
    // recorded on a loaded machine can replay a projector-off frame after
    // the next projector-on one. A projector-off frame after this one is
    // after those waiting too: then they all go, in order.
    constexpr size_t kMaxPending = 2;
    const bool after = ambientAfter(msg->header.stamp);  // takes connect_mutex_: not under pending_mutex_
    std::vector<sensor_msgs::ImageConstPtr> ready;
    {
      std::lock_guard<std::mutex> lock(pending_mutex_);
      pending_.push_back({msg, ros::WallTime::now()});
      while (!pending_.empty() && (after || pending_.size() > kMaxPending))
      {
        ready.push_back(pending_.front().msg);
        pending_.pop_front();
      }
    }
    for (const sensor_msgs::ImageConstPtr& m : ready)
      processGuarded(m);
  }

  // A projector-off frame came (already in the cache): the frames waiting
  // for one after them go.
  void ambientCb(const sensor_msgs::ImageConstPtr& amb)
  {
    std::vector<sensor_msgs::ImageConstPtr> ready;
    {
      std::lock_guard<std::mutex> lock(pending_mutex_);
      while (!pending_.empty() && pending_.front().msg->header.stamp <= amb->header.stamp)
      {
        ready.push_back(pending_.front().msg);
        pending_.pop_front();
      }
    }
    for (const sensor_msgs::ImageConstPtr& m : ready)
      processGuarded(m);
  }

  // Frames that waited longer than ~ambient_max_gap_s (wall clock) go with
  // the frames before them (the projector-off stream stopped).
  void releaseStale()
  {
    std::vector<sensor_msgs::ImageConstPtr> ready;
    {
      const ros::WallTime limit = ros::WallTime::now() - ros::WallDuration(ambient_max_gap_s_);
      std::lock_guard<std::mutex> lock(pending_mutex_);
      while (!pending_.empty() && pending_.front().arrived < limit)
      {
        ready.push_back(pending_.front().msg);
        pending_.pop_front();
      }
    }
    for (const sensor_msgs::ImageConstPtr& m : ready)
      processGuarded(m);
  }

  bool ambientAfter(const ros::Time& stamp)
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    return ambient_cache_ && ambient_cache_->getElemAfterTime(stamp);
  }

  // Frames now come from three callbacks: one at a time through the detector.
  void processGuarded(const sensor_msgs::ImageConstPtr& msg)
  {
    guarded(
        [&]
        {
          std::lock_guard<std::mutex> lock(process_mutex_);
          process(msg);
        });
  }

  // The cached projector-off frames around `stamp` usable for it: the
  // nearest one after it (when it has already arrived, e.g. in a replay)
  // and the nearest ones before it, within ~ambient_max_gap_s of each
  // other, nearest first.
  std::vector<sensor_msgs::ImageConstPtr> ambientsAround(const ros::Time& stamp)
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    std::vector<sensor_msgs::ImageConstPtr> out;
    if (!ambient_cache_)
      return out;
    const ros::Duration reach(3.0 * ambient_max_gap_s_);
    for (const sensor_msgs::ImageConstPtr& m : ambient_cache_->getInterval(stamp - reach, stamp + reach))
      out.push_back(m);
    std::sort(out.begin(), out.end(),
              [&](const sensor_msgs::ImageConstPtr& x, const sensor_msgs::ImageConstPtr& y)
              { return std::abs((x->header.stamp - stamp).toSec()) < std::abs((y->header.stamp - stamp).toSec()); });
    if (!out.empty() && std::abs((out.front()->header.stamp - stamp).toSec()) > ambient_max_gap_s_)
      out.clear();
    return out;
  }

  // Why `amb` cannot serve as the ambient frame of `frame` (empty: it can).
  std::string ambientMismatch(const sensor_msgs::Image& amb, const sensor_msgs::Image& frame, PixelFormat format)
  {
    if (amb.encoding != frame.encoding || amb.width != frame.width || amb.height != frame.height)
      return "camera/image_ambient is " + std::to_string(amb.width) + "x" + std::to_string(amb.height) + " " +
             amb.encoding + ", the frame " + std::to_string(frame.width) + "x" + std::to_string(frame.height) + " " +
             frame.encoding;
    return imageInconsistency(amb, format);
  }

  // The ambient image for this frame in strobe mode: two projector-off frames
  // motion-compensated to the frame's time (compensateAmbient: interpolated
  // when the one after is already here, else extrapolated from the two
  // before, with no wait), or the nearest one as it is when compensation is
  // not possible. Empty (with a throttled warning) when there is none fit to
  // use: detection goes on without it.
  cv::Mat ambientFor(const sensor_msgs::Image& frame, PixelFormat format, const std::vector<cv::Rect>& regions)
  {
    std::vector<sensor_msgs::ImageConstPtr> near = ambientsAround(frame.header.stamp);
    std::string why =
        near.empty() ? "no camera/image_ambient frame within " + std::to_string(ambient_max_gap_s_) + " s of the frame"
                     : ambientMismatch(*near.front(), frame, format);
    if (!why.empty())
    {
      ++frames_without_ambient_;
      NODELET_WARN_THROTTLE(5.0, "SpotDetector: strobe mode: %s; detecting without the ambient frame", why.c_str());
      return cv::Mat();
    }
    AmbientFrame a{imageView(*near.front(), format, &ambient_swapped_), near.front()->header.stamp.toSec()};
    AmbientFrame b;
    if (near.size() > 1 && ambientMismatch(*near[1], frame, format).empty())
      b = AmbientFrame{imageView(*near[1], format, &ambient_swapped_b_), near[1]->header.stamp.toSec()};
    AmbientCompensationParams params;
    params.max_gap_s = 2.0 * ambient_max_gap_s_;
    params.layout = ambientLayout(format);
    params.regions = regions;  // only what the detector will read
    params.unrounded = true;   // 8-bit interleaved frames: the blend as float, for the detector
    const AmbientEstimate estimate =
        compensateAmbient(frame.header.stamp.toSec(), a, b, params, nullptr, &ambient_pyramids_);
    ++(estimate.valid ? frames_compensated_ : frames_nearest_ambient_);
    if (!estimate.valid)
      NODELET_DEBUG_THROTTLE(5.0, "SpotDetector: ambient frame not compensated (%s); using the nearest",
                             estimate.status.c_str());
    ambient_msg_ = near.front();  // keeps the buffer alive while a view of it is used
    return estimate.valid ? estimate.image : a.image;
  }

  void process(const sensor_msgs::ImageConstPtr& msg)
  {
    bool enabled;
    {
      boost::recursive_mutex::scoped_lock lock(config_mutex_);
      enabled = enabled_;
      if (params_changed_)
      {
        detector_.setParams(params_);        // applies from this frame on
        planner_.setParams(search_params_);  // and a full search with them
        params_changed_ = false;
      }
    }
    if (!enabled)
    {
      planner_.reset();  // the dots may be anywhere when frames come again
      return;
    }
    PixelFormat format;
    if (!pixelFormatFromEncoding(msg->encoding, &format))
    {
      dropFrame("unsupported image encoding '" + msg->encoding + "' (accepted: " + acceptedEncodings() +
                "); frame dropped");
      return;
    }
    warnOnceAboutFormat(format);
    const std::string bad = imageInconsistency(*msg, format);
    if (!bad.empty())
    {
      dropFrame(bad + "; frame dropped");
      return;
    }
    const cv::Mat image = imageView(*msg, format, &swapped_);
    // The fast method searches where the dots can be (SpotSearchPlanner);
    // the study's chain the whole frame. Strobed colour frames are searched
    // whole when the matched filter's noise statistics are due. In strobe
    // mode the ambient image is made for the searched regions only (the
    // detector's merge of them).
    const bool track = detector_.canSearchRegions();
    std::string why;
    if (track && !detector_.hasRegionStatistics(strobe_, format, image.size(), &why))
      planner_.requestFullSearch(why);
    const std::vector<cv::Rect> regions = track ? planner_.plan(image.size()) : std::vector<cv::Rect>();
    const cv::Mat ambient =
        strobe_ ? ambientFor(*msg, format, regions.empty() ? regions : mergeSearchRegions(regions, image.size()))
                : cv::Mat();
    const bool want_debug = pub_debug_.getNumSubscribers() > 0;
    SpotDetectorDebug debug;
    SpotDetectorTimings timings;
    const SpotDetectionResult result =
        detector_.detectIn(image, ambient, format, regions, want_debug ? &debug : nullptr, &timings);
    if (track)
    {
      planner_.update(result);
      full_searches_ = planner_.fullSearches();
      std::lock_guard<std::mutex> lock(stats_mutex_);
      full_reason_ = planner_.lastFullReason();
    }
    searched_fraction_ = regions.empty() ? 1.0 : searchedFraction(regions, image.size());
    ambient_msg_.reset();
    if (!result.ok)
    {
      dropFrame("frame dropped: " + result.error);
      return;
    }
    if (!result.note.empty())
    {
      ++frames_partial_;
      warnPartial(result.note);
    }
    publishSpots(*msg, result.spots, timings.total_ms, !ambient.empty());
    if (want_debug)
    {
      cv_bridge::CvImage dbg(msg->header, sensor_msgs::image_encodings::BGR8,
                             drawSpotDebugImage(image, format, result.spots, debug));
      pub_debug_.publish(dbg.toImageMsg());
    }
  }

  void warnOnceAboutFormat(PixelFormat format)
  {
    if (hasColour(format) || mono_warned_)
      return;
    mono_warned_ = true;
    NODELET_WARN(
        "SpotDetector: %s input: no colour, so dots are found by intensity over the local background (clutter "
        "of a dot's size and brightness is left to the Triangulator's geometry; in daylight the rock texture "
        "under a dot is only removed with ~strobe's ambient frames)",
        encodingName(format));
  }

  void publishSpots(const sensor_msgs::Image& image, const Spots& spots, double processing_ms, bool with_ambient)
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
    frames_with_ambient_ += with_ambient ? 1 : 0;
    ++frames_;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::string method, color;
    bool track;
    {
      boost::recursive_mutex::scoped_lock lock(config_mutex_);
      track = search_params_.track;
      method = spotMethodName(params_.method);
      color = projectorColorName(params_.projector_color);
    }
    const std::string last_drop = lastDropReason();
    std::lock_guard<std::mutex> lock(stats_mutex_);
    const int expected = projector_rows_ * projector_cols_;
    if (frames_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "no frame processed yet (input is subscribed on demand)");
    else if (last_spots_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no dot found in the last frame");
    else if (strobe_ && frames_without_ambient_ > 0 && frames_with_ambient_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "strobe mode, but no usable camera/image_ambient frame");
    else
      stat.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "%d dots found (%d beams)", last_spots_, expected);
    stat.add("method", method);
    stat.add("projector colour", color);
    stat.add("strobe", strobe_);
    stat.add("frames processed", frames_);
    if (strobe_)
    {
      stat.add("frames with an ambient frame", frames_with_ambient_);
      stat.add("frames without one", frames_without_ambient_.load());
      stat.add("ambient frames motion-compensated", frames_compensated_.load());
      stat.add("ambient frames used as they are (nearest)", frames_nearest_ambient_.load());
    }
    stat.add("frames dropped (bad input)", framesDropped());
    stat.add("frames with candidates left out (more than the pattern holds)", frames_partial_.load());
    stat.add("dots in last frame", last_spots_);
    stat.add("tracking (search windows)", track && method == "fast");
    stat.addf("share of the frame searched last frame (%)", "%.1f", 100.0 * searched_fraction_.load());
    stat.add("full searches", full_searches_.load());
    stat.add("reason of the last full search", full_reason_);
    stat.add("processing time last frame (ms)", last_ms_);
    stat.add("processing time mean (ms)", mean_ms_);
    if (!last_drop.empty())
      stat.add("last drop reason", last_drop);
  }

  // Parameters fixed at start-up.
  int projector_rows_ = 10, projector_cols_ = 10;
  int queue_size_ = 2;  // camera/image_raw frames queued while the detector is busy (~queue_size)
  bool strobe_ = false;
  double ambient_max_gap_s_ = 0.25;
  bool ambient_wait_ = true;  // strobe mode: a frame waits for the projector-off frame after it

  // dynamic_reconfigure: the server holds config_mutex_ while calling
  // configCb(); the frame callback copies params_ under it.
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  SpotDetectorParams params_;
  SpotSearchParams search_params_;
  bool enabled_ = true;
  bool params_changed_ = true;

  // Only process() touches the detector and these buffers, under process_mutex_.
  std::mutex process_mutex_;
  SpotDetector detector_;
  SpotSearchPlanner planner_;
  bool mono_warned_ = false;
  cv::Mat swapped_, ambient_swapped_, ambient_swapped_b_;
  AmbientTrackingCache ambient_pyramids_;  // each projector-off frame's tracking pyramid, built once
  sensor_msgs::ImageConstPtr ambient_msg_;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber sub_image_;
  // Strobe mode: the projector-off frames, cached by stamp (under connect_mutex_).
  image_transport::SubscriberFilter sub_ambient_;
  std::unique_ptr<message_filters::Cache<sensor_msgs::Image>> ambient_cache_;
  // Strobe mode with ~ambient_wait: frames waiting for their following projector-off frame.
  struct Pending
  {
    sensor_msgs::ImageConstPtr msg;
    ros::WallTime arrived;
  };
  std::mutex pending_mutex_;
  std::deque<Pending> pending_;
  ros::WallTimer release_timer_;
  ros::Publisher pub_spots_;
  image_transport::Publisher pub_debug_;

  // Statistics for diagnostics.
  std::mutex stats_mutex_;
  double last_ms_ = 0.0, mean_ms_ = 0.0;
  int last_spots_ = 0, frames_ = 0, frames_with_ambient_ = 0;
  std::atomic<int> frames_without_ambient_{0};
  std::atomic<int> frames_compensated_{0}, frames_nearest_ambient_{0};  // how the ambient frame was made
  std::atomic<double> searched_fraction_{1.0};                          // of the last frame's pixels
  std::atomic<long> full_searches_{0};
  std::atomic<long> frames_partial_{0};
  std::string full_reason_;  // under stats_mutex_
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::SpotDetectorNodelet, nodelet::Nodelet)
