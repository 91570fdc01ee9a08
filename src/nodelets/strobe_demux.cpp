// StrobeDemux nodelet: a camera whose strobe output fires the projector on
// every second exposure sends one stream (strobed/image_raw +
// strobed/camera_info); this splits it into camera/image_raw +
// camera/camera_info (projector on) and camera/image_ambient (projector off,
// its own stamp), the topics of a strobed pipeline (pipeline.launch
// strobe:=true, docs/daylight.md). By parity (the phase checked on the
// images) or by the projector's pulse times (strobed/trigger,
// sensor_msgs/TimeReference: header.stamp = the pulse). The decision is in
// the core (strobe_demux.h).
//
// Always subscribed (no ~lazy): the alternation can only be followed by
// seeing every frame. Bad input (no camera_info yet, an image cv_bridge
// cannot read) drops the frame with a throttled reason.
#include <algorithm>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <boost/make_shared.hpp>
#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/TimeReference.h>

#include "structured_light_stabilizer/detection/strobe_demux.h"
#include "nodelets/common/nodelet_base.h"

namespace structured_light_stabilizer
{

class StrobeDemuxNodelet : public NodeletBase
{
public:
  StrobeDemuxNodelet() : NodeletBase("StrobeDemux") {}
  ~StrobeDemuxNodelet() override { stopCallbacks(); }

private:
  void onInit() override;
  bool readParams(StrobeDemuxParams* p);
  void imageCb(const sensor_msgs::ImageConstPtr& msg);
  void infoCb(const sensor_msgs::CameraInfoConstPtr& msg);
  void triggerCb(const sensor_msgs::TimeReferenceConstPtr& msg);
  void publish(const std::vector<StrobedFrame>& frames, const std::vector<StrobedFrame>& dropped);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::CameraPublisher pub_raw_;
  image_transport::Publisher pub_ambient_;
  image_transport::Subscriber sub_image_;
  ros::Subscriber sub_info_, sub_trigger_;

  std::mutex mutex_;  // the demux, the messages it holds and the counts
  std::unique_ptr<StrobeDemux> demux_;
  std::string mode_name_;
  // The messages of the frames the demux holds, by arrival index: a frame
  // is republished as it came (zero copy), only its topic chosen.
  std::vector<std::pair<int, sensor_msgs::ImageConstPtr>> held_;
  sensor_msgs::CameraInfoConstPtr info_;
  uint64_t on_ = 0, ambient_ = 0;
  int pushed_ = 0;  // frames given to the demux: its arrival index
};

void StrobeDemuxNodelet::onInit()
{
  ros::NodeHandle& nh = getNodeHandle();
  StrobeDemuxParams params;
  if (!readParams(&params))
    return;
  demux_.reset(new StrobeDemux(params));
  it_.reset(new image_transport::ImageTransport(nh));
  pub_raw_ = it_->advertiseCamera("camera/image_raw", 2);
  pub_ambient_ = it_->advertise("camera/image_ambient", 2);
  setUpDiagnostics("strobe demux");
  diagnostics_->add("StrobeDemux", this, &StrobeDemuxNodelet::diagnose);
  addFrequencyStatus();
  startDiagnostics(1.0);
  sub_info_ = nh.subscribe("strobed/camera_info", 2, &StrobeDemuxNodelet::infoCb, this);
  if (params.mode == StrobeMode::kTrigger)
    sub_trigger_ = nh.subscribe("strobed/trigger", 20, &StrobeDemuxNodelet::triggerCb, this);
  sub_image_ = it_->subscribe("strobed/image_raw", 4, &StrobeDemuxNodelet::imageCb, this,
                              image_transport::TransportHints("raw", ros::TransportHints(), getPrivateNodeHandle()));
  NODELET_INFO("StrobeDemux: %s -> camera/image_raw (projector on) + camera/image_ambient, by %s",
               sub_image_.getTopic().c_str(), mode_name_.c_str());
}

// False (said why) when the parameters cannot work: the nodelet then does nothing.
bool StrobeDemuxNodelet::readParams(StrobeDemuxParams* p)
{
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  mode_name_ = pnh.param<std::string>("mode", "parity");
  if (mode_name_ != "parity" && mode_name_ != "trigger")
  {
    NODELET_ERROR("StrobeDemux: unknown ~mode '%s' (parity | trigger); doing nothing", mode_name_.c_str());
    return false;
  }
  p->mode = mode_name_ == "trigger" ? StrobeMode::kTrigger : StrobeMode::kParity;
  p->phase = pnh.param("phase", p->phase);
  p->auto_phase = pnh.param("auto_phase", p->auto_phase);
  p->votes = pnh.param("votes", p->votes);
  p->stamp_gaps = pnh.param("stamp_gaps", p->stamp_gaps);
  p->tolerance_s = pnh.param("trigger_tolerance", p->tolerance_s);
  p->wait_s = pnh.param("trigger_wait", p->wait_s);
  const std::string why = p->validate();
  if (!why.empty())
  {
    NODELET_ERROR("StrobeDemux: %s; doing nothing", why.c_str());
    return false;
  }
  if (p->mode == StrobeMode::kParity)
    mode_name_ += p->auto_phase ? " (phase checked on the images)" : " (phase " + std::to_string(p->phase) + ")";
  return true;
}

void StrobeDemuxNodelet::infoCb(const sensor_msgs::CameraInfoConstPtr& msg)
{
  std::lock_guard<std::mutex> lock(mutex_);
  info_ = msg;
}

void StrobeDemuxNodelet::imageCb(const sensor_msgs::ImageConstPtr& msg)
{
  guarded(
      [&]
      {
        // The images are only compared (parity) or held (trigger): share the message's data.
        const cv::Mat image = cv_bridge::toCvShare(msg)->image;
        std::vector<StrobedFrame> out, dropped;
        {
          std::lock_guard<std::mutex> lock(mutex_);
          held_.emplace_back(pushed_++, msg);
          out = demux_->push(image, msg->header.stamp.toSec(), &dropped);
        }
        publish(out, dropped);
      });
}

void StrobeDemuxNodelet::triggerCb(const sensor_msgs::TimeReferenceConstPtr& msg)
{
  guarded(
      [&]
      {
        std::vector<StrobedFrame> out, dropped;
        {
          std::lock_guard<std::mutex> lock(mutex_);
          out = demux_->addPulse(msg->header.stamp.toSec(), &dropped);
        }
        publish(out, dropped);
      });
}

// The decided frames on their topics, the given-up ones reported.
void StrobeDemuxNodelet::publish(const std::vector<StrobedFrame>& frames, const std::vector<StrobedFrame>& dropped)
{
  for (const StrobedFrame& f : dropped)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    held_.erase(std::remove_if(held_.begin(), held_.end(), [&](const auto& h) { return h.first == f.index; }),
                held_.end());
    dropFrame("no projector pulse time reached this frame within ~trigger_wait (is strobed/trigger publishing?)");
  }
  for (const StrobedFrame& f : frames)
  {
    sensor_msgs::ImageConstPtr msg;
    sensor_msgs::CameraInfoPtr info;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = std::find_if(held_.begin(), held_.end(), [&](const auto& h) { return h.first == f.index; });
      if (it == held_.end())
        continue;
      msg = it->second;
      held_.erase(it);
      (f.projector_on ? on_ : ambient_) += 1;
      if (f.projector_on && info_)
      {
        info = boost::make_shared<sensor_msgs::CameraInfo>(*info_);
        info->header = msg->header;
      }
    }
    if (!f.projector_on)
      pub_ambient_.publish(msg);
    else if (info)
      pub_raw_.publish(msg, info);
    else
    {
      dropFrame("no camera_info yet on strobed/camera_info: projector-on frame dropped");
      continue;
    }
    frequency_->tick();
  }
}

void StrobeDemuxNodelet::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
{
  std::lock_guard<std::mutex> lock(mutex_);
  if (on_ + ambient_ == 0)
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no frame yet on strobed/image_raw");
  else if (!info_)
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no camera_info yet on strobed/camera_info");
  else
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "splitting");
  stat.add("mode", mode_name_);
  stat.add("projector-on frames", on_);
  stat.add("ambient frames", ambient_);
  stat.add("frames dropped", framesDropped());
  stat.add("last drop", lastDropReason());
  stat.add("parity phase", demux_->phase());
  stat.add("exposures lost (stamp gaps)", demux_->missedExposures());
}

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::StrobeDemuxNodelet, nodelet::Nodelet)
