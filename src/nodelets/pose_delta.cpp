// PoseDelta nodelet: the camera's motion relative to the locked rock.
//
// Wiring only: points (+ camera/image_raw, camera/camera_info for the texture
// part) -> PoseDeltaEstimator (core) -> pose_delta, pose_delta/pose, tf,
// diagnostics, and the service pose_delta/lock. Images are matched to clouds
// by header stamp (message_filters, cloud_image_matcher.h); a cloud whose
// image never comes is processed on geometry; the latest camera_info serves.
//
// Outputs (docs/interface.md, "tf" and "Frames"): pose_delta for every
// cloud; pose_delta/pose (the current camera's pose in the reference frame,
// PoseWithCovarianceStamped) and the tf <camera_frame> ->
// <camera_frame>_reference only for valid estimates, the tf never twice with
// one stamp. With ~publish_tf (default true) the tf is an output nobody
// subscribes to, so the inputs are always subscribed (no ~lazy).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include <boost/thread/recursive_mutex.hpp>
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/publisher.h>
#include <dynamic_reconfigure/server.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <image_transport/image_transport.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <sensor_msgs/image_encodings.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>

#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/PoseDeltaConfig.h"
#include "structured_light_stabilizer/pose/pose_delta.h"
#include "nodelets/common/ambient_pairing.h"
#include "nodelets/common/cloud_image_matcher.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"

namespace structured_light_stabilizer
{

namespace
{

namespace enc = sensor_msgs::image_encodings;
using Config = structured_light_stabilizer::PoseDeltaConfig;

// ---- The core interface: dynamic_reconfigure -> PoseDeltaParams, the
// fields of pose/pose_delta_params.def (config.mode must be valid).
PoseDeltaParams paramsFromConfig(const Config& config)
{
  PoseDeltaParams p;
  p.fromConfig(config);
  return p;
}

void fillFromResult(const PoseDeltaResult& r, PoseDelta* msg)
{
  msg->transform = transformFromIsometry(r.transform);
  for (int i = 0; i < 36; ++i)
    msg->covariance[i] = r.covariance(i / 6, i % 6);
  msg->rms_residual = r.rms_residual_m;
  msg->points_used = static_cast<uint32_t>(std::max(0, r.points_used));
  msg->valid = r.valid;
  msg->status = r.status;
}

void fillInvalid(PoseDelta* msg, const std::string& status)
{
  msg->transform.rotation.w = 1.0;
  msg->valid = false;
  msg->status = status;
  msg->points_used = 0;
}

}  // namespace

class PoseDeltaNodelet : public NodeletBase
{
public:
  PoseDeltaNodelet() : NodeletBase("PoseDelta") {}
  ~PoseDeltaNodelet() override { stopCallbacks(); }

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readLazyParam();
    pnh.param("publish_tf", publish_tf_, true);
    // The tf has no subscriber count: while it is wanted the inputs must be.
    lazy_ = lazy_ && !publish_tf_;
    pnh.param("auto_lock", auto_lock_, true);
    // Strobed operation: the texture from camera/image_ambient (ambient_pairing.h).
    pnh.param("strobe", strobe_, false);
    pnh.param("camera_frame", camera_frame_param_, std::string());
    pnh.param("image_queue_size", image_queue_size_, 5);
    image_queue_size_ = std::max(1, image_queue_size_);
    matcher_.setImageQueueSize(image_queue_size_);
    pnh.param("diagnostic_min_rate", min_frequency_, 1.0);
    pnh.param("diagnostic_max_rate", max_frequency_, 200.0);
    it_.reset(new image_transport::ImageTransport(nh));

    // dynamic_reconfigure: the server reads ~ params (mode, use_texture, ...)
    // and calls back at once with the initial config.
    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });
    {
      // The start-up mode must not count as a mode change (that re-locks,
      // which would defeat ~auto_lock:=false).
      std::lock_guard<std::mutex> lock(params_mutex_);
      estimator_.setParams(params_);
      params_changed_ = false;
    }
    estimator_.reset(auto_lock_);

    setUpDiagnostics("none");
    diagnostics_->add("pose delta", this, &PoseDeltaNodelet::diagnose);
    pose_diagnostic_.reset(new diagnostic_updater::TopicDiagnostic(
        "pose_delta", *diagnostics_,
        diagnostic_updater::FrequencyStatusParam(&min_frequency_, &max_frequency_, 0.1, 10),
        diagnostic_updater::TimeStampStatusParam(-1.0, 5.0)));
    startDiagnostics(0.5);

    srv_lock_ = nh.advertiseService("pose_delta/lock", &PoseDeltaNodelet::lockCb, this);
    pub_pose_ = advertise<PoseDelta>(nh, "pose_delta", 10);
    pub_pose_cov_ = advertise<geometry_msgs::PoseWithCovarianceStamped>(nh, "pose_delta/pose", 10);
    startSubscriptions(std::string("input (points") + (use_texture_ ? ", camera/image_raw, camera/camera_info" : "") +
                       ") is subscribed on demand, while pose_delta or pose_delta/pose has subscribers "
                       "(~lazy:=false, or ~publish_tf:=true, to always run)");
    if (publish_tf_)
      NODELET_INFO("PoseDelta: ~publish_tf: inputs subscribed at start-up; tf %s -> %s_reference for valid estimates",
                   camera_frame_param_.empty() ? "<camera frame>" : camera_frame_param_.c_str(),
                   camera_frame_param_.empty() ? "<camera frame>" : camera_frame_param_.c_str());
    NODELET_INFO("PoseDelta: %s; reference %s", auto_lock_ ? "auto_lock" : "no auto_lock",
                 auto_lock_ ? "= first valid map" : "locked by the pose_delta/lock service");
  }

  // ---- Inputs: points while wanted; the images too when the texture part is on.

  // The images first: a cloud that came before images_subscribed_ was set
  // went on alone, and a lock on it had no texture for as long as it held
  // (the first cloud can come while the image subscription is still being
  // made: a slow master, a loaded machine).
  void subscribe() override
  {
    syncImageSubscription(true);
    sub_points_ = getNodeHandle().subscribe("points", 5, &PoseDeltaNodelet::cloudCb, this);
    points_subscribed_ = true;
  }

  void unsubscribe() override
  {
    sub_points_.shutdown();
    points_subscribed_ = false;
    syncImageSubscription(false);
  }

  // Called with connect_mutex_ held.
  void syncImageSubscription(bool inputs_wanted)
  {
    bool texture;
    {
      std::lock_guard<std::mutex> lock(params_mutex_);
      texture = use_texture_;
    }
    const bool want_images = inputs_wanted && texture;
    if (want_images && !sub_image_)
    {
      image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
      sub_image_ = it_->subscribe("camera/image_raw", image_queue_size_, &PoseDeltaNodelet::imageCb, this, hints);
      sub_info_ = getNodeHandle().subscribe("camera/camera_info", image_queue_size_, &PoseDeltaNodelet::infoCb, this);
      if (strobe_)
        sub_ambient_ =
            it_->subscribe("camera/image_ambient", image_queue_size_, &PoseDeltaNodelet::ambientCb, this, hints);
      images_subscribed_ = true;
    }
    else if (!want_images && sub_image_)
    {
      images_subscribed_ = false;
      sub_image_.shutdown();
      sub_info_.shutdown();
      sub_ambient_.shutdown();
      std::lock_guard<std::mutex> lock(buffer_mutex_);
      matcher_.clearImages();
      ambient_pairing_.clear();
      before_first_info_.clear();
    }
  }

  // ---- Parameters

  void configCb(Config& config, uint32_t /*level*/)
  {
    sanitize(config);
    if (config.mode != "frame_to_frame" && config.mode != "reference")
    {
      // The last good value stays in force (reference before any).
      std::lock_guard<std::mutex> lock(params_mutex_);
      const char* kept = params_.mode == PoseDeltaMode::kFrameToFrame ? "frame_to_frame" : "reference";
      NODELET_WARN("PoseDelta: unknown mode '%s' (reference | frame_to_frame); keeping %s", config.mode.c_str(), kept);
      config.mode = kept;
    }
    const PoseDeltaParams params = paramsFromConfig(config);
    const std::string why = params.validate();
    if (!why.empty())
    {
      NODELET_ERROR("PoseDelta: rejected parameters (%s); keeping the previous ones", why.c_str());
      return;
    }
    bool texture_changed;
    {
      std::lock_guard<std::mutex> lock(params_mutex_);
      texture_changed = use_texture_ != config.use_texture;
      params_ = params;
      params_changed_ = true;
      use_texture_ = config.use_texture;
    }
    if (texture_changed && pub_pose_)
    {
      std::lock_guard<std::mutex> lock(connect_mutex_);
      syncImageSubscription(subscribed_);
    }
  }

  // Odd windows, min <= max: fixed in the config, with a warning.
  void sanitize(Config& config)
  {
    if (config.texture_window_px % 2 == 0)
    {
      NODELET_WARN("PoseDelta: texture_window_px must be odd; %d -> %d", config.texture_window_px,
                   config.texture_window_px + 1);
      config.texture_window_px += 1;
    }
    if (config.texture_refinement_window_px != 0 && config.texture_refinement_window_px % 2 == 0)
    {
      NODELET_WARN("PoseDelta: texture_refinement_window_px must be odd (or 0 = off); %d -> %d",
                   config.texture_refinement_window_px, config.texture_refinement_window_px + 1);
      config.texture_refinement_window_px += 1;
    }
    if (config.texture_refinement_window_px != 0 && config.texture_refinement_window_px < 5)
    {
      NODELET_WARN("PoseDelta: texture_refinement_window_px %d is below 5; using 5 (0 turns it off)",
                   config.texture_refinement_window_px);
      config.texture_refinement_window_px = 5;
    }
    if (config.texture_min_level > config.texture_max_level)
    {
      NODELET_WARN("PoseDelta: texture_min_level %d > texture_max_level %d; using %d", config.texture_min_level,
                   config.texture_max_level, config.texture_max_level);
      config.texture_min_level = config.texture_max_level;
    }
    if (config.texture_min_features > config.texture_max_features)
    {
      NODELET_WARN("PoseDelta: texture_min_features %d > texture_max_features %d; using %d",
                   config.texture_min_features, config.texture_max_features, config.texture_max_features);
      config.texture_min_features = config.texture_max_features;
    }
  }

  bool lockCb(std_srvs::Trigger::Request& /*req*/, std_srvs::Trigger::Response& res)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    if (!map_received_)
    {
      res.success = false;
      res.message = std::string("no map has arrived yet on ") + getNodeHandle().resolveName("points") +
                    (points_subscribed_ ? "" : " (not subscribed: nothing listens to pose_delta and ~lazy is true)");
      return true;
    }
    estimator_.requestLock();
    res.success = true;
    res.message = "the next valid map becomes the reference";
    NODELET_INFO("PoseDelta: lock requested; %s", res.message.c_str());
    return true;
  }

  // ---- Frames: clouds matched with their images by stamp.

  void infoCb(const sensor_msgs::CameraInfoConstPtr& info)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    latest_info_ = info;
    std::deque<FramePair> waiting;
    waiting.swap(before_first_info_);
    for (const FramePair& f : waiting)
      handleFrame(f.first, f.second);
  }

  void imageCb(const sensor_msgs::ImageConstPtr& image)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    const int lone = loneClouds();
    matcher_.addImage(image, handle_frame_);
    reportLone(lone);
  }

  void cloudCb(const sensor_msgs::PointCloud2ConstPtr& cloud)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    bool texture;
    {
      std::lock_guard<std::mutex> c(params_mutex_);
      texture = use_texture_;
    }
    const int lone = loneClouds();
    matcher_.addCloud(cloud, texture && images_subscribed_, handle_frame_);
    reportLone(lone);
  }

  // Clouds that went on without their image while images were wanted (under
  // buffer_mutex_). Reported once images have flowed: before the image
  // subscription connects, the first clouds go on alone by design.
  int loneClouds() const { return matcher_.lone().later_images + matcher_.lone().queue_full; }

  void reportLone(int before)
  {
    if (loneClouds() == before || matcher_.lone().matched == 0)
      return;
    const CloudImageMatcher::Lone& l = matcher_.lone();
    NODELET_WARN_THROTTLE(10.0,
                          "PoseDelta: the cloud at %.3f goes on without its image (newest image %.3f); %d so far: "
                          "%d whose image was lost (images of later stamps came), %d for a full queue "
                          "(~image_queue_size %d)",
                          l.last_stamp, l.newest_image, loneClouds(), l.later_images, l.queue_full, image_queue_size_);
  }

  void ambientCb(const sensor_msgs::ImageConstPtr& ambient)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    ambient_pairing_.addAmbient(ambient, release_strobed_);
  }

  // Called with buffer_mutex_ held: one frame at a time, in order. Strobed,
  // a frame waits for the ambient frame after it.
  void handleFrame(const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image)
  {
    // The texture needs the camera model. The first frames can beat the first
    // camera_info (a replayed bag, a slow link: the subscriptions connect one
    // by one); they wait for it, in order, instead of going on without their
    // texture (a reference locked so would differ from run to run). At most
    // ~image_queue_size wait; beyond that camera_info is taken as silent:
    // they all go on without texture, and later frames do not wait (no
    // standing delay in the loop).
    if (image && !latest_info_ && images_subscribed_ && !info_wait_over_)
    {
      before_first_info_.emplace_back(cloud, image);
      if (static_cast<int>(before_first_info_.size()) <= image_queue_size_)
        return;
      NODELET_WARN("PoseDelta: no camera_info on %s after %d frames; frames go on without their texture",
                   getNodeHandle().resolveName("camera/camera_info").c_str(), image_queue_size_);
      info_wait_over_ = true;
      std::deque<FramePair> waiting;
      waiting.swap(before_first_info_);
      for (const FramePair& f : waiting)
        processFrame(f.first, f.second);
      return;
    }
    processFrame(cloud, image);
  }

  void processFrame(const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image)
  {
    if (strobe_ && images_subscribed_)
      ambient_pairing_.addFrame(cloud, image, release_strobed_);
    else
      guarded([&] { process(cloud, image, nullptr, nullptr); });
  }

  void process(const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image,
               const sensor_msgs::ImageConstPtr& ambient_before, const sensor_msgs::ImageConstPtr& ambient_after)
  {
    const ros::WallTime start = ros::WallTime::now();
    PoseDeltaPtr msg(new PoseDelta);
    msg->header.stamp = cloud->header.stamp;
    msg->header.frame_id = !camera_frame_param_.empty()      ? camera_frame_param_
                           : !cloud->header.frame_id.empty() ? cloud->header.frame_id
                                                             : std::string("camera_optical_frame");
    {
      std::lock_guard<std::mutex> lock(params_mutex_);
      if (params_changed_)
      {
        estimator_.setParams(params_);
        params_changed_ = false;
      }
    }
    PoseDeltaInput input;
    std::string error;
    if (!readBeamCloud(*cloud, &input.rows, &input.cols, &input.points, nullptr, &error))
    {
      dropFrame("dropping a points cloud: " + error);
      fillInvalid(msg.get(), "bad points cloud: " + error);
      publish(msg, start, false);
      return;
    }
    map_received_ = map_received_ || std::any_of(input.points.begin(), input.points.end(),
                                                 [](const Eigen::Vector3d& p) { return p.allFinite(); });
    input.stamp_s = cloud->header.stamp.toSec();
    // A reference locked without its image has no texture for as long as it
    // stays locked (tx, ty, rz unobservable on smooth rock). The first cloud
    // often comes without one: its image went out before this nodelet's
    // image subscription connected, or before the first camera_info. The
    // lock waits for a frame that has both (lockMayWait), then locks on the
    // geometry alone.
    if (estimator_.lockPending() && estimator_.params().use_texture && images_subscribed_ &&
        (!image || !latest_info_) && lockMayWait(input.stamp_s))
    {
      ++lock_waits_;
      fillInvalid(msg.get(), std::string("reference lock waits for a frame with its ") +
                                 (image ? "camera_info" : "image") + " (texture on)");
      publish(msg, start, false);
      return;
    }
    if (image && estimator_.params().use_texture)
      prepareImage(image, &input, &swapped_[0]);
    if (estimator_.params().use_texture)
      prepareAmbient(ambient_before, ambient_after, &input);
    const PoseDeltaResult r = estimator_.process(input);
    if (r.locked_now)
    {
      if (lock_waits_ > 0)
        NODELET_INFO("PoseDelta: the lock waited %d frame(s) for %s", lock_waits_,
                     image && latest_info_ ? "a frame with its image and camera_info" : "images; none came");
      lock_waits_ = 0;
      NODELET_INFO("PoseDelta: reference locked at %.3f (%d points)", cloud->header.stamp.toSec(), r.points_used);
    }
    fillFromResult(r, msg.get());
    last_features_ = r.features_used;
    if (!r.valid)
      NODELET_WARN_THROTTLE(10.0, "PoseDelta: not valid: %s", r.status.c_str());
    else if (pub_pose_cov_.getNumSubscribers() > 0)
      publishPose(*msg, r);
    publish(msg, start, r.valid && estimator_.hasReference());
  }

  // The pending lock may pass over this frame for want of its image: for
  // kLockWaitFrames frames or kLockWaitSeconds of stamps, whichever is longer
  // (at 30 Hz and more, a subscription slow to connect on a loaded machine
  // takes more than ten frames), at most kLockWaitMaxFrames.
  bool lockMayWait(double stamp_s)
  {
    if (lock_waits_ == 0)
      lock_wait_since_s_ = stamp_s;
    if (lock_waits_ < kLockWaitFrames)
      return true;
    const double waited = stamp_s - lock_wait_since_s_;
    return lock_waits_ < kLockWaitMaxFrames && waited >= 0.0 && waited < kLockWaitSeconds;
  }

  // pose_delta/pose: the same estimate as a standard pose of the current
  // camera in the reference camera frame (conversions.h).
  void publishPose(const PoseDelta& msg, const PoseDeltaResult& r)
  {
    geometry_msgs::PoseWithCovarianceStampedPtr pose(new geometry_msgs::PoseWithCovarianceStamped);
    pose->header.stamp = msg.header.stamp;
    pose->header.frame_id = msg.header.frame_id + "_reference";
    pose->pose = currentPoseInReference(r.transform, r.covariance);
    pub_pose_cov_.publish(pose);
  }

  // Picks the image channel with the rock's texture and the least dot light.
  // bgr8, rgb8, mono8 and their 16-bit kinds are read as they are (a view of
  // the message, 16 bits at full depth; *swapped holds a big-endian 16-bit
  // image byte-swapped); other encodings are converted to bgr8.
  void prepareImage(const sensor_msgs::ImageConstPtr& image, PoseDeltaInput* input, cv::Mat* swapped)
  {
    try
    {
      const std::string& e = image->encoding;
      const bool rgb = e == enc::RGB8 || e == enc::RGB16, mono = e == enc::MONO8 || e == enc::MONO16;
      PixelFormat format = PixelFormat::kBgr8;
      if ((rgb || mono || e == enc::BGR8 || e == enc::BGR16) && pixelFormatFromEncoding(e, &format))
      {
        const std::string bad = imageInconsistency(*image, format);
        if (!bad.empty())
        {
          unusableImage(bad);
          input->image = cv::Mat();
          return;
        }
        input->image = imageView(*image, format, swapped);
        input->texture_channel = rgb ? 0 : 2;
        if (mono && !warned_mono_)
        {
          NODELET_WARN("PoseDelta: %s images: the texture is tracked without the colour that hides the dots",
                       e.c_str());
          warned_mono_ = true;
        }
      }
      else
      {
        if (!warned_encoding_)
        {
          NODELET_WARN("PoseDelta: image encoding %s is converted to bgr8 for the texture (a copy per frame)",
                       e.c_str());
          warned_encoding_ = true;
        }
        input->image = cv_bridge::toCvShare(image, enc::BGR8)->image;
        input->texture_channel = 2;
      }
      if (latest_info_)
        useCameraInfo(*latest_info_, input->image);
    }
    catch (const cv_bridge::Exception& ex)
    {
      unusableImage(ex.what());
      input->image = cv::Mat();
    }
  }

  // An image the texture cannot read (the frame goes on with the geometry):
  // each kind of problem logged at once, then at most every 5 s (drop_log.h).
  void unusableImage(const std::string& why)
  {
    int suppressed = 0;
    if (!image_log_.shouldLog(why, &suppressed))
      return;
    if (suppressed > 0)
      NODELET_ERROR("PoseDelta: image not usable for the texture (%s; %d more of this kind since the last message)",
                    why.c_str(), suppressed);
    else
      NODELET_ERROR("PoseDelta: image not usable for the texture (%s)", why.c_str());
  }

  // The ambient frames around a strobed frame, as the texture images (the
  // same conversion as the frame's own image).
  void prepareAmbient(const sensor_msgs::ImageConstPtr& before, const sensor_msgs::ImageConstPtr& after,
                      PoseDeltaInput* input)
  {
    const sensor_msgs::ImageConstPtr first = before ? before : after;
    const sensor_msgs::ImageConstPtr second = before ? after : nullptr;
    PoseDeltaInput ambient;
    if (first)
    {
      prepareImage(first, &ambient, &swapped_[1]);
      input->ambient_image = ambient.image;
      input->ambient_stamp_s = first->header.stamp.toSec();
    }
    if (second)
    {
      prepareImage(second, &ambient, &swapped_[2]);
      input->ambient_after_image = ambient.image;
      input->ambient_after_stamp_s = second->header.stamp.toSec();
    }
  }

  void useCameraInfo(const sensor_msgs::CameraInfo& info, const cv::Mat& image)
  {
    CameraModel model;
    std::string error;
    if (!cameraModelFromInfo(info, &model, &error))
    {
      NODELET_WARN_THROTTLE(10.0, "PoseDelta: camera_info unusable for the texture: %s", error.c_str());
      return;
    }
    if (model.width != image.cols || model.height != image.rows)
      NODELET_WARN_THROTTLE(10.0, "PoseDelta: camera_info is %dx%d but the image %dx%d; texture unused", model.width,
                            model.height, image.cols, image.rows);
    estimator_.setCamera(model);
  }

  void publish(const PoseDeltaPtr& msg, const ros::WallTime& start, bool broadcast_tf)
  {
    last_status_ = msg->status;
    last_valid_ = msg->valid;
    last_residual_ = msg->rms_residual;
    last_points_ = msg->points_used;
    last_ms_ = (ros::WallTime::now() - start).toSec() * 1e3;
    ++frames_;
    valid_frames_ += msg->valid ? 1 : 0;
    // tf: parent = current camera frame, child = the reference camera pose;
    // p_cur = T p_ref is exactly the child-to-parent transform. Only valid
    // estimates; never the same stamp twice (TF_REPEATED_DATA).
    if (publish_tf_ && broadcast_tf && msg->header.stamp != last_tf_stamp_)
    {
      geometry_msgs::TransformStamped tf;
      tf.header = msg->header;
      tf.child_frame_id = msg->header.frame_id + "_reference";
      tf.transform = msg->transform;
      tf_broadcaster_.sendTransform(tf);
      last_tf_stamp_ = msg->header.stamp;
    }
    pose_diagnostic_->tick(msg->header.stamp);
    pub_pose_.publish(msg);
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    if (frames_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no points received yet");
    else if (!estimator_.hasReference())
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no reference: " + last_status_);
    else if (!last_valid_)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, last_status_);
    else
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, last_status_);
    stat.add("valid", last_valid_);
    stat.add("status", last_status_);
    stat.add("rms residual (mm)", last_residual_ * 1e3);
    stat.add("points used", last_points_);
    stat.add("texture features used", last_features_);
    stat.add("processing time (ms)", last_ms_);
    stat.add("frames", frames_);
    stat.add("valid frames", valid_frames_);
    stat.add("reference locked", estimator_.hasReference());
    stat.add("clouds without their image", loneClouds());
  }

  // Parameters fixed at start-up.
  bool auto_lock_ = true;
  bool publish_tf_ = true;
  bool strobe_ = false;
  std::string camera_frame_param_;
  int image_queue_size_ = 5;

  // dynamic_reconfigure: the server holds config_mutex_ while calling
  // configCb(); the accepted parameters are handed to the frame callbacks
  // under params_mutex_ (not config_mutex_: configCb() takes connect_mutex_
  // and buffer_mutex_, which the frame callbacks hold).
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  std::mutex params_mutex_;
  PoseDeltaParams params_;
  bool params_changed_ = false;
  bool use_texture_ = true;

  ros::Publisher pub_pose_;
  ros::Publisher pub_pose_cov_;
  ros::Subscriber sub_points_;
  ros::Subscriber sub_info_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber sub_image_;
  image_transport::Subscriber sub_ambient_;
  std::atomic<bool> images_subscribed_{false};
  std::atomic<bool> points_subscribed_{false};
  ros::ServiceServer srv_lock_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;

  // Frame state, guarded by buffer_mutex_.
  std::mutex buffer_mutex_;
  CloudImageMatcher matcher_;
  const CloudImageMatcher::Emit handle_frame_ =
      [this](const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image)
  { handleFrame(cloud, image); };
  sensor_msgs::CameraInfoConstPtr latest_info_;
  using FramePair = std::pair<sensor_msgs::PointCloud2ConstPtr, sensor_msgs::ImageConstPtr>;
  std::deque<FramePair> before_first_info_;  // frames with an image, before any camera_info
  bool info_wait_over_ = false;              // camera_info silent for ~image_queue_size frames
  static constexpr int kLockWaitFrames = 10;
  static constexpr double kLockWaitSeconds = 2.0;
  static constexpr int kLockWaitMaxFrames = 500;
  int lock_waits_ = 0;            // frames the pending lock has passed over for want of an image
  double lock_wait_since_s_ = 0;  // the first such frame's stamp
  AmbientPairing ambient_pairing_;
  const AmbientPairing::Release release_strobed_ =
      [this](const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image,
             const sensor_msgs::ImageConstPtr& before, const sensor_msgs::ImageConstPtr& after)
  { guarded([&] { process(cloud, image, before, after); }); };
  PoseDeltaEstimator estimator_;
  bool map_received_ = false;
  ros::Time last_tf_stamp_;
  bool warned_mono_ = false;
  bool warned_encoding_ = false;
  DropLog image_log_;   // images the texture cannot read
  cv::Mat swapped_[3];  // big-endian 16-bit frame, ambient before, after: byte-swapped copies

  // Diagnostics (under buffer_mutex_).
  std::unique_ptr<diagnostic_updater::TopicDiagnostic> pose_diagnostic_;
  std::string last_status_ = "no frame yet";
  bool last_valid_ = false;
  double last_residual_ = 0.0;
  int last_points_ = 0;
  int last_features_ = 0;
  double last_ms_ = 0.0;
  int frames_ = 0;
  int valid_frames_ = 0;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::PoseDeltaNodelet, nodelet::Nodelet)
