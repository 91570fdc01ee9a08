// ImageStabilizer nodelet: the camera image warped into the locked reference
// view (docs/stabilization.md, "The stabilised image").
//
// Wiring only: camera/image_raw + camera/camera_info (the latest), points
// (the locked frame's map) and pose_delta (PoseDelta at the frames' stamps:
// PoseDelta's own, or InertialFusion's pose_fused/frames remapped onto it)
// -> ImageStabilizer (core, control/image_stabilizer.h) ->
// stabilizer/image_stabilized (sensor_msgs/Image, the input's encoding; a
// Bayer mosaic is demosaicked to bgr8) with stabilizer/camera_info (the
// input's, as image_transport's CameraPublisher pairs them) and
// stabilizer/image_stabilized/pose (the PoseDelta each image was warped
// with). An image waits for the pose of its stamp (~max_pending images); a
// frame whose pose is invalid is not published. The reference is the map of
// the frame whose pose says "reference locked on this frame". Lazy: nothing
// is subscribed or computed without a subscriber.
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include <boost/make_shared.hpp>
#include <boost/thread/recursive_mutex.hpp>
#include <cv_bridge/cv_bridge.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/image_encodings.h>

#include "structured_light_stabilizer/ImageStabilizerConfig.h"
#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/control/image_stabilizer.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"

namespace structured_light_stabilizer
{

namespace
{

using Config = structured_light_stabilizer::ImageStabilizerConfig;
constexpr const char* kLockedPhrase = "reference locked on this frame";
// Clouds kept to find the locked one (s of stamps).
constexpr double kCloudHistoryS = 2.0;

}  // namespace

class ImageStabilizerNodelet : public NodeletBase
{
public:
  ImageStabilizerNodelet() : NodeletBase("ImageStabilizer") {}
  ~ImageStabilizerNodelet() override { stopCallbacks(); }

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readLazyParam();
    max_pending_ = std::max(1, pnh.param("max_pending", 10));
    pnh.param("diagnostic_min_rate", min_frequency_, 1.0);
    pnh.param("diagnostic_max_rate", max_frequency_, 500.0);
    it_.reset(new image_transport::ImageTransport(nh));
    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });
    setUpDiagnostics("none");
    addFrequencyStatus();
    diagnostics_->add("stabilised image", this, &ImageStabilizerNodelet::diagnose);
    startDiagnostics(1.0);
    pub_image_ = advertiseImage(*it_, "stabilizer/image_stabilized", 5);
    pub_info_ = advertise<sensor_msgs::CameraInfo>(nh, "stabilizer/camera_info", 5);
    pub_pose_ = advertise<PoseDelta>(nh, "stabilizer/image_stabilized/pose", 10);
    startSubscriptions(
        "inputs (camera/image_raw, camera/camera_info, points, pose_delta) are subscribed on demand, "
        "while stabilizer/image_stabilized or its pose has subscribers");
  }

  void subscribe() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
    sub_image_ = it_->subscribe("camera/image_raw", 5, &ImageStabilizerNodelet::imageCb, this, hints);
    sub_info_ = nh.subscribe("camera/camera_info", 5, &ImageStabilizerNodelet::infoCb, this);
    sub_points_ = nh.subscribe("points", 10, &ImageStabilizerNodelet::pointsCb, this);
    sub_pose_ = nh.subscribe("pose_delta", 20, &ImageStabilizerNodelet::poseCb, this);
  }
  void unsubscribe() override
  {
    sub_image_.shutdown();
    sub_info_.shutdown();
    sub_points_.shutdown();
    sub_pose_.shutdown();
  }

  void configCb(Config& config, uint32_t /*level*/)
  {
    ImageStabilizerParams params;
    params.fromConfig(config);
    const std::string why = params.validate();
    if (!why.empty())
    {
      NODELET_ERROR("ImageStabilizer: rejected parameters (%s); keeping the previous ones", why.c_str());
      return;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    params_ = params;  // used from the next lock on
  }

  void infoCb(const sensor_msgs::CameraInfoConstPtr& msg)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    info_ = msg;
    if (!pending_lock_.isZero())
      setReference(pending_lock_);
  }

  void pointsCb(const sensor_msgs::PointCloud2ConstPtr& msg)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    clouds_[msg->header.stamp] = msg;
    while (!clouds_.empty() && (msg->header.stamp - clouds_.begin()->first).toSec() > kCloudHistoryS)
      clouds_.erase(clouds_.begin());
    // The lock's pose can come before its cloud (they travel on two topics,
    // in a multi-threaded manager on two callbacks): it waits for it.
    if (msg->header.stamp == pending_lock_)
      setReference(pending_lock_);
  }

  void imageCb(const sensor_msgs::ImageConstPtr& msg)
  {
    guarded(
        [&]
        {
          std::lock_guard<std::mutex> lock(mutex_);
          images_.push_back(msg);
          while (static_cast<int>(images_.size()) > max_pending_)
          {
            ++frames_without_pose_;
            images_.pop_front();
          }
          serve();
        });
  }

  void poseCb(const PoseDeltaConstPtr& msg)
  {
    guarded(
        [&]
        {
          std::lock_guard<std::mutex> lock(mutex_);
          if (msg->status.find(kLockedPhrase) != std::string::npos)
            setReference(msg->header.stamp);
          else if (!stabilizer_ && (pending_lock_.isZero() || lockCloudMissed()) && msg->valid)
            adoptReference(*msg);
          poses_[msg->header.stamp] = msg;
          while (poses_.size() > 50)
            poses_.erase(poses_.begin());
          serve();
        });
  }

  // The pending lock's cloud will not come: a later cloud is here and
  // clouds arrive in order (it went out before the points subscription
  // connected). The reference is then adopted from a later frame.
  bool lockCloudMissed() const
  {
    return !clouds_.empty() && clouds_.rbegin()->first > pending_lock_ && clouds_.count(pending_lock_) == 0;
  }

  // Subscribed after the lock (lazy: the lock came before a subscriber):
  // the reference surface from a later valid frame's map, moved into the
  // reference camera frame with that frame's pose (p_ref = T^-1 p_cur).
  void adoptReference(const PoseDelta& pose)
  {
    const auto cloud = clouds_.find(pose.header.stamp);
    if (cloud == clouds_.end() || !info_)
      return;
    const Eigen::Isometry3d cur_from_ref = isometryFromTransform(pose.transform);
    pending_lock_ = ros::Time();
    buildReference(*cloud->second, &cur_from_ref, pose.header.stamp);
  }

  // The locked frame's map becomes the reference (mutex_ held). Until its
  // cloud and a camera_info are here the lock waits (pending_lock_).
  void setReference(const ros::Time& stamp)
  {
    // The poses from this lock on are relative to the new reference: the
    // old one warps none of them.
    if (stamp != pending_lock_)
      stabilizer_.reset();
    pending_lock_ = stamp;
    const auto cloud = clouds_.find(stamp);
    if (cloud == clouds_.end() || !info_)
      return;
    pending_lock_ = ros::Time();
    buildReference(*cloud->second, nullptr, stamp);
  }

  // The stabilizer from a beam map (cur_from_ref: the map's frame from the
  // reference's; null: the map is the reference's own).
  void buildReference(const sensor_msgs::PointCloud2& cloud, const Eigen::Isometry3d* cur_from_ref,
                      const ros::Time& stamp)
  {
    std::string why;
    CameraModel camera;
    int rows = 0, cols = 0;
    std::vector<Eigen::Vector3d> points;
    std::vector<float> intensity;
    ReferenceSurface surface;
    if (!cameraModelFromInfo(*info_, &camera, &why))
      why = "camera_info unusable: " + why;
    else if (!readBeamCloud(cloud, &rows, &cols, &points, &intensity, &why))
      why = "the locked cloud is unreadable: " + why;
    else
    {
      moveToReference(cur_from_ref, &points);
      auto stabilizer = std::make_shared<ImageStabilizer>(params_);
      if (surface.build(rows, cols, points, params_.surface, &why) && stabilizer->setReference(camera, surface, &why))
      {
        stabilizer_ = stabilizer;
        NODELET_INFO("ImageStabilizer: reference locked at %.3f (%d points, %dx%d image)", stamp.toSec(),
                     static_cast<int>(points.size()), camera.width, camera.height);
        return;
      }
    }
    dropFrame("no stabilised image until the next lock: " + why);
  }

  // p_ref = T^-1 p_cur for each measured point (nothing when the map is the reference's own).
  static void moveToReference(const Eigen::Isometry3d* cur_from_ref, std::vector<Eigen::Vector3d>* points)
  {
    if (!cur_from_ref)
      return;
    const Eigen::Isometry3d ref_from_cur = cur_from_ref->inverse();
    for (Eigen::Vector3d& p : *points)
      if (p.allFinite())
        p = ref_from_cur * p;
  }

  // Warps every buffered image whose pose has come (mutex_ held).
  void serve()
  {
    while (!images_.empty())
    {
      const sensor_msgs::ImageConstPtr image = images_.front();
      const auto pose = poses_.find(image->header.stamp);
      if (pose == poses_.end())
      {
        // Poses come in order: once a later one is here, this one never comes.
        if (!poses_.empty() && poses_.rbegin()->first > image->header.stamp)
        {
          ++frames_without_pose_;
          images_.pop_front();
          continue;
        }
        return;
      }
      images_.pop_front();
      if (pose->second->valid && stabilizer_)
        publish(image, pose->second);
      else
        ++frames_invalid_;
    }
  }

  void publish(const sensor_msgs::ImageConstPtr& image, const PoseDeltaConstPtr& pose)
  {
    const bool bayer = sensor_msgs::image_encodings::isBayer(image->encoding);
    const cv_bridge::CvImageConstPtr in =
        bayer ? cv_bridge::toCvCopy(image, sensor_msgs::image_encodings::BGR8) : cv_bridge::toCvShare(image);
    cv_bridge::CvImage out(image->header, in->encoding, cv::Mat());
    std::string why;
    if (!stabilizer_->warp(in->image, isometryFromTransform(pose->transform), &out.image, &why))
    {
      dropFrame("frame dropped: " + why);
      return;
    }
    pub_image_.publish(out.toImageMsg());
    if (info_)
    {
      auto info = boost::make_shared<sensor_msgs::CameraInfo>(*info_);
      info->header = image->header;
      pub_info_.publish(info);
    }
    pub_pose_.publish(pose);
    frequency_->tick();
    ++frames_published_;
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!stabilizer_)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no reference yet (waiting for the lock)");
    else
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "stabilising");
    stat.add("frames published", frames_published_);
    stat.add("frames with an invalid pose", frames_invalid_);
    stat.add("frames without a pose", frames_without_pose_);
    stat.add("frames dropped", framesDropped());
    stat.add("last drop", lastDropReason());
  }

  int max_pending_ = 10;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Publisher pub_image_;
  image_transport::Subscriber sub_image_;
  ros::Publisher pub_info_, pub_pose_;
  ros::Subscriber sub_info_, sub_points_, sub_pose_;
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;

  std::mutex mutex_;  // what follows
  ImageStabilizerParams params_;
  sensor_msgs::CameraInfoConstPtr info_;
  std::map<ros::Time, sensor_msgs::PointCloud2ConstPtr> clouds_;
  std::map<ros::Time, PoseDeltaConstPtr> poses_;
  ros::Time pending_lock_;  // a lock whose cloud or camera_info has not come yet (zero: none)
  std::deque<sensor_msgs::ImageConstPtr> images_;
  std::shared_ptr<const ImageStabilizer> stabilizer_;
  int64_t frames_published_ = 0, frames_invalid_ = 0, frames_without_pose_ = 0;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::ImageStabilizerNodelet, nodelet::Nodelet)
