// Frame sources of the CameraDriver nodelet: where its images come from
// (the simulator, a V4L2 device, a video file, a folder of images). A source
// opens, grabs and describes; the nodelet does the rest the same way for
// every source: pacing at ~rate, stamps' header, publishing image +
// camera_info, diagnostics, and the one retry policy (a source that cannot
// open, or is lost, is reported throttled and opened again every
// kRetryPeriodS seconds).
//
// Adding a source: one file in src/nodelets/frame_sources/ with its class and
// its make<Name>Source() (declared below), and one line in the table of
// frame_source.cpp. What a source gives is published as it is (Frame::encoding:
// bgr8, mono8, mono16, ...; asPublished() for what OpenCV reads); the driver
// applies the sensor window (~binning_x/y, ~roi_*) to every source alike.
// A source with heavy dependencies of its own lives in a plugin library
// instead (the simulator: frame_sources/sim/, FrameSourceFactory below), so
// that the nodelets library does not link them.
//
// Threads: open, close, grab and published run on the driver's worker
// thread; reconfigure on dynamic_reconfigure's, with the driver's
// config_mutex_ held; a source guards what the two share.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include <opencv2/core.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_msgs/Header.h>

#include "structured_light_stabilizer/CameraDriverConfig.h"
#include "structured_light_stabilizer/calibration/camera_model.h"

namespace structured_light_stabilizer
{

// Wait between two attempts to open a source (s).
constexpr double kRetryPeriodS = 2.0;

// What a source may use of the driver.
struct SourceContext
{
  ros::NodeHandle nh;   // the driver's namespace (topics)
  ros::NodeHandle pnh;  // its private parameters
  // Log lines on the driver's logger; they add the "CameraDriver: " prefix.
  std::function<void(const std::string&)> info, warn, error;
  // Acquisition stamp of a frame taken now; false (after a throttled warning)
  // while ROS time is zero (use_sim_time without /clock): no frame then.
  std::function<bool(ros::Time*)> stamp;
  // Subscribers of camera/image_raw (a lazy source renders only for them).
  std::function<uint32_t()> image_subscribers;
  // False once the driver is stopping: a source that waits (the
  // simulator's lockstep mode) gives up.
  std::function<bool()> running;
  // ~camera_info_url and its intrinsics when they loaded with K != 0 (else null).
  std::string camera_info_url;
  std::shared_ptr<const sensor_msgs::CameraInfo> url_calibration;
  // The part of each frame that is published, binned (~binning_x/y,
  // ~roi_*; applyWindow()); a source that publishes pixel positions of its
  // own (the simulator's ground truth) maps them with window.toImage().
  SensorWindow window;
};

struct Frame
{
  cv::Mat image;
  std::string encoding = "bgr8";  // sensor_msgs/image_encodings name of `image` (full sensor, before the window)
  ros::Time stamp;                // acquisition time (SourceContext::stamp)
  double processing_ms = 0.0;     // render or acquisition time, for diagnostics
  // A projector-off frame of a strobed source: published on
  // camera/image_ambient (same camera_info, its own stamp) instead of
  // camera/image_raw (docs/daylight.md).
  bool ambient = false;
  // The source applied the sensor window itself (a simulator that renders
  // only the ROI): `image` is what is published, the driver leaves it as is.
  bool windowed = false;
};

enum class GrabStatus
{
  kFrame,    // publish the frame
  kSkip,     // nothing this tick; a non-empty message is a frame dropped (reported)
  kBackOff,  // nothing to give for now: wait kRetryPeriodS, then grab again
  kLost,     // the source failed (message says why): report, close, reopen after kRetryPeriodS
  kEnd       // no more frames (message logged once); the driver idles
};

struct GrabResult
{
  GrabStatus status;
  std::string message;
};

class FrameSource
{
public:
  virtual ~FrameSource() = default;

  // Opens the source (again after a loss). False with *why when it cannot.
  virtual bool open(std::string* why) = 0;
  // Releases what open() took.
  virtual void close() {}
  // One frame, taken now. `rate` (Hz) is ~rate for this tick.
  virtual GrabResult grab(double rate, Frame* frame) = 0;
  // The line logged after each successful open() (empty: nothing to add).
  virtual std::string describe(double rate) const = 0;

  // True when the driver paces grab() at ~rate; a device paces itself.
  virtual bool paced() const { return true; }
  // Paced sources: the driver's schedule let `ticks` frame periods pass
  // without a grab (the worker fell more than a period behind). A source
  // whose frames follow time (the simulator) moves on by as many frames.
  virtual void skipped(int64_t /*ticks*/) {}
  // True for a rendered source: diagnostics show the render time and the
  // publish rate reached, and warn when rendering cannot keep up.
  virtual bool rendered() const { return false; }
  // The source's own camera_info (a simulator knows its intrinsics); null:
  // ~camera_info_url's when it fits the frame, else an uncalibrated one.
  virtual const sensor_msgs::CameraInfo* cameraInfo() const { return nullptr; }
  // After a frame went out, with its header (the simulator publishes its
  // ground truth here, stamped like the frame).
  virtual void published(const std_msgs::Header& /*header*/) {}
  // Live settings: a source applies those that concern it and writes back
  // the values in force.
  virtual void reconfigure(CameraDriverConfig& /*config*/) {}
};

// A source built in a plugin library (pluginlib, base class
// structured_light_stabilizer::FrameSourceFactory, frame_source_plugins.xml):
// make() is the plugin's make<Name>Source().
class FrameSourceFactory
{
public:
  virtual ~FrameSourceFactory() = default;
  virtual std::unique_ptr<FrameSource> make(const SourceContext& ctx) = 0;
};

// A source and what keeps its code loaded (a plugin's library stays loaded
// until the source is deleted).
using FrameSourceHandle = std::unique_ptr<FrameSource, std::function<void(FrameSource*)>>;

// The sources built into the nodelets library, one file each. A factory
// returns null when the source cannot work with its parameters at all (said
// why on ctx.error).
std::unique_ptr<FrameSource> makeDeviceSource(const SourceContext& ctx);
std::unique_ptr<FrameSource> makeVideoSource(const SourceContext& ctx);
std::unique_ptr<FrameSource> makeImagesSource(const SourceContext& ctx);

// ~source names: "sim, device, video, images" (for messages).
std::string frameSourceNames();
bool isFrameSource(const std::string& name);
// The source called `name`; null when unknown, when its plugin cannot be
// loaded or when it cannot be set up (said why on ctx.error).
FrameSourceHandle makeFrameSource(const std::string& name, const SourceContext& ctx);

// What a capture or an image file gives, ready to publish as it is where
// sensor_msgs has an encoding the pipeline reads: 8-bit grey -> mono8, 16-bit
// grey -> mono16, 8-bit 3 channels -> bgr8 (OpenCV's order); 4 channels lose
// their alpha (bgr8); 16-bit colour is scaled full scale to full scale to
// bgr8; other depths (signed, float) their maximum to 255 (mono8 or bgr8).
cv::Mat asPublished(const cv::Mat& in, std::string* encoding);

// The sensor window applied to a full frame: the ROI cut out, then each
// binning_x x binning_y block averaged (a camera's digital binning; the
// image keeps its depth and range). Bayer mosaics and packed YUV cannot be
// binned that way: false with *why, as for a window that does not fit.
bool applyWindow(const cv::Mat& full, const std::string& encoding, const SensorWindow& window, cv::Mat* out,
                 std::string* why);

// printf into a std::string (messages of the sources).
std::string stringf(const char* format, ...) __attribute__((format(printf, 1, 2)));

// Milliseconds since t0 (steady clock).
double millisecondsSince(const std::chrono::steady_clock::time_point& t0);

}  // namespace structured_light_stabilizer
