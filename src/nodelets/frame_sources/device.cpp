// CameraDriver source "device": a V4L2 camera through OpenCV. The camera
// paces the frames; ~width, ~height, ~fps are requested when set (> 0).
#include <algorithm>
#include <cctype>

#include <opencv2/videoio.hpp>

#include "nodelets/frame_sources/frame_source.h"

namespace structured_light_stabilizer
{

namespace
{

class DeviceSource : public FrameSource
{
public:
  explicit DeviceSource(const SourceContext& ctx) : ctx_(ctx)
  {
    // ~device: an index (0 = /dev/video0) or a path.
    XmlRpc::XmlRpcValue value;
    if (ctx.pnh.getParam("device", value))
    {
      if (value.getType() == XmlRpc::XmlRpcValue::TypeInt)
        device_ = std::to_string(static_cast<int>(value));
      else if (value.getType() == XmlRpc::XmlRpcValue::TypeString)
        device_ = static_cast<std::string>(value);
    }
    width_ = ctx.pnh.param("width", 0);
    height_ = ctx.pnh.param("height", 0);
    fps_ = ctx.pnh.param("fps", 0.0);
  }

  bool open(std::string* why) override
  {
    const bool numeric = !device_.empty() && std::all_of(device_.begin(), device_.end(), ::isdigit);
    const bool opened =
        numeric ? capture_.open(std::stoi(device_), cv::CAP_V4L2) : capture_.open(device_, cv::CAP_V4L2);
    if (!opened || !capture_.isOpened())
    {
      *why = "cannot open V4L2 device '" + device_ + "' (not connected, busy, or no permission on /dev/video*)";
      return false;
    }
    if (width_ > 0)
      capture_.set(cv::CAP_PROP_FRAME_WIDTH, width_);
    if (height_ > 0)
      capture_.set(cv::CAP_PROP_FRAME_HEIGHT, height_);
    if (fps_ > 0)
      capture_.set(cv::CAP_PROP_FPS, fps_);
    return true;
  }

  void close() override { capture_.release(); }

  std::string describe(double /*rate*/) const override
  {
    return stringf("opened device '%s' (%gx%g at %g Hz)", device_.c_str(), capture_.get(cv::CAP_PROP_FRAME_WIDTH),
                   capture_.get(cv::CAP_PROP_FRAME_HEIGHT), capture_.get(cv::CAP_PROP_FPS));
  }

  GrabResult grab(double /*rate*/, Frame* frame) override
  {
    cv::Mat raw;
    const auto t0 = std::chrono::steady_clock::now();
    if (!capture_.read(raw) || raw.empty())
      return {GrabStatus::kLost, "device '" + device_ + "' stopped delivering frames (unplugged?)"};
    // Stamped when read() returns: the frame has just arrived.
    if (!ctx_.stamp(&frame->stamp))
      return {GrabStatus::kSkip, ""};
    frame->processing_ms = millisecondsSince(t0);
    frame->image = asPublished(raw, &frame->encoding);
    return {GrabStatus::kFrame, ""};
  }

  bool paced() const override { return false; }

private:
  SourceContext ctx_;
  std::string device_ = "0";
  int width_ = 0, height_ = 0;
  double fps_ = 0.0;
  cv::VideoCapture capture_;
};

}  // namespace

std::unique_ptr<FrameSource> makeDeviceSource(const SourceContext& ctx)
{
  return std::make_unique<DeviceSource>(ctx);
}

}  // namespace structured_light_stabilizer
