// PoseDelta nodelet: the camera's motion relative to the locked rock.
//
// Wiring only: points (+ camera/image_raw, camera/camera_info for the texture
// part) -> PoseDeltaEstimator (core) -> pose_delta, tf, diagnostics, and the
// service pose_delta/lock. Images are matched to clouds by header stamp from a
// short buffer; a cloud whose image never comes is processed on geometry.
#include <atomic>
#include <cmath>
#include <deque>
#include <memory>
#include <mutex>
#include <string>

#include <boost/thread/recursive_mutex.hpp>
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/publisher.h>
#include <dynamic_reconfigure/server.h>
#include <geometry_msgs/TransformStamped.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
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
#include "conversions.h"
#include "structured_light_stabilizer/pose_delta.h"

namespace structured_light_stabilizer
{

namespace enc = sensor_msgs::image_encodings;

class PoseDeltaNodelet : public nodelet::Nodelet
{
public:
  ~PoseDeltaNodelet() override
  {
    diagnostics_timer_.stop();
    std::lock_guard<std::mutex> lock(connect_mutex_);
    points_sub_.shutdown();
    image_sub_.shutdown();
    info_sub_.shutdown();
  }

private:
  using ReconfigureServer = dynamic_reconfigure::Server<PoseDeltaConfig>;

  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    pnh.param("lazy", lazy_, true);
    pnh.param("auto_lock", auto_lock_, true);
    pnh.param("camera_frame", camera_frame_param_, std::string());
    pnh.param("image_queue_size", image_queue_size_, 5);
    image_queue_size_ = std::max(1, image_queue_size_);
    double min_rate = 1.0, max_rate = 200.0;
    pnh.param("diagnostic_min_rate", min_rate, min_rate);
    pnh.param("diagnostic_max_rate", max_rate, max_rate);
    min_rate_ = min_rate;
    max_rate_ = max_rate;

    it_.reset(new image_transport::ImageTransport(nh));

    // dynamic_reconfigure: the server reads ~ params (mode, use_texture, ...)
    // and calls back at once with the initial config.
    reconfigure_server_.reset(new ReconfigureServer(reconfigure_mutex_, pnh));
    reconfigure_server_->setCallback(
        [this](PoseDeltaConfig& config, uint32_t level) { onReconfigure(config, level); });
    {
      // The start-up mode must not count as a mode change (that re-locks,
      // which would defeat ~auto_lock:=false).
      std::lock_guard<std::mutex> lock(config_mutex_);
      estimator_.setParams(config_);
      config_changed_ = false;
    }
    estimator_.reset(auto_lock_);

    updater_.reset(new diagnostic_updater::Updater(nh, pnh, getName()));
    updater_->setHardwareID("none");
    updater_->add("pose delta", this, &PoseDeltaNodelet::diagnose);
    pose_diag_.reset(new diagnostic_updater::TopicDiagnostic(
        "pose_delta", *updater_, diagnostic_updater::FrequencyStatusParam(&min_rate_, &max_rate_, 0.1, 10),
        diagnostic_updater::TimeStampStatusParam(-1.0, 5.0)));
    diagnostics_timer_ = nh.createTimer(ros::Duration(0.5), [this](const ros::TimerEvent&) { updater_->update(); });

    lock_service_ = nh.advertiseService("pose_delta/lock", &PoseDeltaNodelet::onLock, this);
    {
      std::lock_guard<std::mutex> lock(connect_mutex_);
      ros::SubscriberStatusCallback cb = [this](const ros::SingleSubscriberPublisher&) { connectCb(); };
      pose_pub_ = nh.advertise<PoseDelta>("pose_delta", 10, cb, cb);
    }
    if (lazy_)
      NODELET_INFO("PoseDelta: input (points%s) is subscribed on demand, while pose_delta has subscribers "
                   "(~lazy:=false to always run, e.g. for tf only)",
                   use_texture_ ? ", camera/image_raw, camera/camera_info" : "");
    connectCb();
    NODELET_INFO("PoseDelta: %s; reference %s", auto_lock_ ? "auto_lock" : "no auto_lock",
                 auto_lock_ ? "= first valid map" : "locked by the pose_delta/lock service");
  }

  // Subscribes the inputs while someone listens (or always without ~lazy);
  // the image inputs only when the texture part is on.
  void connectCb()
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    ros::NodeHandle& nh = getNodeHandle();
    const bool wanted = !lazy_ || pose_pub_.getNumSubscribers() > 0;
    bool texture;
    {
      std::lock_guard<std::mutex> c(config_mutex_);
      texture = use_texture_;
    }
    if (wanted && !points_sub_)
      points_sub_ = nh.subscribe("points", 5, &PoseDeltaNodelet::onCloud, this);
    else if (!wanted && points_sub_)
      points_sub_.shutdown();
    points_subscribed_ = wanted;
    const bool want_images = wanted && texture;
    if (want_images && !image_sub_)
    {
      image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
      image_sub_ = it_->subscribe("camera/image_raw", 5, &PoseDeltaNodelet::onImage, this, hints);
      info_sub_ = nh.subscribe("camera/camera_info", 5, &PoseDeltaNodelet::onInfo, this);
      images_subscribed_ = true;
    }
    else if (!want_images && image_sub_)
    {
      images_subscribed_ = false;
      image_sub_.shutdown();
      info_sub_.shutdown();
      std::lock_guard<std::mutex> b(buffer_mutex_);
      images_.clear();
    }
  }

  void onReconfigure(PoseDeltaConfig& config, uint32_t /*level*/)
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
    if (config.texture_min_features > config.texture_max_features)
    {
      NODELET_WARN("PoseDelta: texture_min_features %d > texture_max_features %d; using %d",
                   config.texture_min_features, config.texture_max_features, config.texture_max_features);
      config.texture_min_features = config.texture_max_features;
    }
    PoseDeltaParams core;
    if (config.mode != "frame_to_frame" && config.mode != "reference")
    {
      // The last good value stays in force (reference before any).
      std::lock_guard<std::mutex> lock(config_mutex_);
      const char* kept = config_.mode == PoseDeltaMode::kFrameToFrame ? "frame_to_frame" : "reference";
      NODELET_WARN("PoseDelta: unknown mode '%s' (reference | frame_to_frame); keeping %s", config.mode.c_str(), kept);
      config.mode = kept;
    }
    core.mode = config.mode == "frame_to_frame" ? PoseDeltaMode::kFrameToFrame : PoseDeltaMode::kReference;
    core.use_texture = config.use_texture;
    core.symmetric = config.symmetric;
    core.min_points = config.min_points;
    core.max_iterations = config.max_iterations;
    core.huber_k = config.huber_k;
    core.min_geometry_sigma_m = config.min_geometry_sigma_m;
    core.min_texture_sigma_px = config.min_texture_sigma_px;
    core.freeze_factor = config.freeze_factor;
    core.max_edge_ratio = config.max_edge_ratio;
    core.max_sigma_translation_m = config.max_sigma_translation_m;
    core.max_sigma_rotation_rad = config.max_sigma_rotation_deg * M_PI / 180.0;
    core.max_rms_residual_m = config.max_rms_residual_m;
    core.texture_max_features = config.texture_max_features;
    core.texture_min_features = config.texture_min_features;
    core.texture_min_distance_px = config.texture_min_distance_px;
    core.texture_whole_image = config.texture_whole_image;
    core.texture_window_px = config.texture_window_px;
    core.texture_refinement_window_px = config.texture_refinement_window_px;
    core.texture_depth_sigma_m = config.texture_depth_sigma_m;
    core.texture_extrapolated_depth_sigma_m = config.texture_extrapolated_depth_sigma_m;
    core.texture_error_inflation = config.texture_error_inflation;
    core.texture_pyramid_levels = config.texture_pyramid_levels;
    core.texture_dot_clearance_px = config.texture_dot_clearance_px;
    core.texture_roi_margin_px = config.texture_roi_margin_px;
    const std::string why = core.validate();
    if (!why.empty())
    {
      NODELET_ERROR("PoseDelta: rejected parameters (%s); keeping the previous ones", why.c_str());
      return;
    }
    bool texture_changed;
    {
      std::lock_guard<std::mutex> lock(config_mutex_);
      texture_changed = use_texture_ != config.use_texture;
      config_ = core;
      config_changed_ = true;
      use_texture_ = config.use_texture;
    }
    if (texture_changed && pose_pub_)
      connectCb();
  }

  bool onLock(std_srvs::Trigger::Request& /*req*/, std_srvs::Trigger::Response& res)
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

  void onInfo(const sensor_msgs::CameraInfoConstPtr& info)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    latest_info_ = info;
  }

  void onImage(const sensor_msgs::ImageConstPtr& image)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    images_.push_back(image);
    while (static_cast<int>(images_.size()) > image_queue_size_)
      images_.pop_front();
    // Clouds waiting for this image, or for an image that will never come
    // (per-topic delivery is in order, so an older unmatched stamp is lost).
    while (!pending_.empty())
    {
      const sensor_msgs::PointCloud2ConstPtr cloud = pending_.front();
      if (cloud->header.stamp > image->header.stamp)
        break;
      pending_.pop_front();
      process(cloud, cloud->header.stamp == image->header.stamp ? image : nullptr);
    }
  }

  void onCloud(const sensor_msgs::PointCloud2ConstPtr& cloud)
  {
    std::lock_guard<std::mutex> lock(buffer_mutex_);
    bool texture;
    {
      std::lock_guard<std::mutex> c(config_mutex_);
      texture = use_texture_;
    }
    // Images stopped (or never came): do not hold clouds back for long.
    while (!pending_.empty() && (cloud->header.stamp - pending_.front()->header.stamp).toSec() > 0.5)
    {
      process(pending_.front(), nullptr);
      pending_.pop_front();
    }
    if (!texture || !images_subscribed_)
    {
      process(cloud, nullptr);
      return;
    }
    for (auto it = images_.rbegin(); it != images_.rend(); ++it)
    {
      if ((*it)->header.stamp == cloud->header.stamp)
      {
        process(cloud, *it);
        return;
      }
    }
    if (!images_.empty() && images_.back()->header.stamp > cloud->header.stamp)
    {
      process(cloud, nullptr);  // its image was dropped upstream
      return;
    }
    pending_.push_back(cloud);
    while (pending_.size() > 3)
    {
      process(pending_.front(), nullptr);
      pending_.pop_front();
    }
  }

  // Called with buffer_mutex_ held: one frame at a time, in order.
  void process(const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image)
  {
    const ros::WallTime start = ros::WallTime::now();
    const std::string frame_id = !camera_frame_param_.empty() ? camera_frame_param_ :
                                 !cloud->header.frame_id.empty() ? cloud->header.frame_id :
                                                                   std::string("camera_optical_frame");
    PoseDeltaPtr msg(new PoseDelta);
    msg->header.stamp = cloud->header.stamp;
    msg->header.frame_id = frame_id;
    try
    {
      {
        std::lock_guard<std::mutex> c(config_mutex_);
        if (config_changed_)
        {
          estimator_.setParams(config_);
          config_changed_ = false;
        }
      }
      PoseDeltaInput input;
      std::string error;
      if (!readBeamCloud(*cloud, &input.rows, &input.cols, &input.points, nullptr, &error))
      {
        NODELET_ERROR_THROTTLE(5.0, "PoseDelta: dropping a points cloud: %s", error.c_str());
        fillInvalid(msg.get(), "bad points cloud: " + error);
        publish(msg, start, false);
        return;
      }
      for (const Eigen::Vector3d& p : input.points)
      {
        if (p.allFinite())
        {
          map_received_ = true;
          break;
        }
      }
      if (image && estimator_.params().use_texture)
        prepareImage(image, &input);
      const PoseDeltaResult r = estimator_.process(input);
      if (r.locked_now)
        NODELET_INFO("PoseDelta: reference locked at %.3f (%d points)", cloud->header.stamp.toSec(), r.points_used);
      msg->transform = transformFromIsometry(r.transform);
      for (int i = 0; i < 36; ++i)
        msg->covariance[i] = r.covariance(i / 6, i % 6);
      msg->rms_residual = r.rms_residual_m;
      msg->points_used = static_cast<uint32_t>(std::max(0, r.points_used));
      msg->valid = r.valid;
      msg->status = r.status;
      last_features_ = r.features_used;
      if (!r.valid)
        NODELET_WARN_THROTTLE(10.0, "PoseDelta: not valid: %s", r.status.c_str());
      publish(msg, start, estimator_.hasReference());
    }
    catch (const std::exception& e)
    {
      NODELET_ERROR_THROTTLE(5.0, "PoseDelta: frame dropped: %s", e.what());
    }
  }

  // Picks the image channel with the rock's texture and the least dot light.
  void prepareImage(const sensor_msgs::ImageConstPtr& image, PoseDeltaInput* input)
  {
    try
    {
      const std::string& e = image->encoding;
      if (e == enc::BGR8 || e == enc::RGB8 || e == enc::MONO8)
      {
        input->image = cv_bridge::toCvShare(image)->image;
        input->texture_channel = e == enc::RGB8 ? 0 : 2;
        if (e == enc::MONO8 && !warned_mono_)
        {
          NODELET_WARN("PoseDelta: mono8 images: the texture is tracked without the colour that hides the dots");
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
      {
        CameraModel model;
        std::string error;
        if (cameraModelFromInfo(*latest_info_, &model, &error))
        {
          if (model.width != input->image.cols || model.height != input->image.rows)
            NODELET_WARN_THROTTLE(10.0, "PoseDelta: camera_info is %dx%d but the image %dx%d; texture unused",
                                  model.width, model.height, input->image.cols, input->image.rows);
          estimator_.setCamera(model);
        }
        else
          NODELET_WARN_THROTTLE(10.0, "PoseDelta: camera_info unusable for the texture: %s", error.c_str());
      }
    }
    catch (const cv_bridge::Exception& ex)
    {
      NODELET_ERROR_THROTTLE(5.0, "PoseDelta: image not usable for the texture (%s)", ex.what());
      input->image = cv::Mat();
    }
  }

  void fillInvalid(PoseDelta* msg, const std::string& status)
  {
    msg->transform.rotation.w = 1.0;
    msg->valid = false;
    msg->status = status;
    msg->points_used = 0;
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
    // p_cur = T p_ref is exactly the child-to-parent transform. Never the
    // same stamp twice (TF_REPEATED_DATA).
    if (broadcast_tf && msg->header.stamp != last_tf_stamp_)
    {
      geometry_msgs::TransformStamped tf;
      tf.header = msg->header;
      tf.child_frame_id = msg->header.frame_id + "_reference";
      tf.transform = msg->transform;
      tf_broadcaster_.sendTransform(tf);
      last_tf_stamp_ = msg->header.stamp;
    }
    pose_diag_->tick(msg->header.stamp);
    pose_pub_.publish(msg);
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
  }

  // Parameters fixed at start-up.
  bool lazy_ = true;
  bool auto_lock_ = true;
  std::string camera_frame_param_;
  int image_queue_size_ = 5;
  double min_rate_ = 1.0, max_rate_ = 200.0;

  // Live parameters (dynamic_reconfigure), copied under config_mutex_.
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<ReconfigureServer> reconfigure_server_;
  std::mutex config_mutex_;
  PoseDeltaParams config_;
  bool config_changed_ = false;
  bool use_texture_ = true;

  std::mutex connect_mutex_;
  ros::Publisher pose_pub_;
  ros::Subscriber points_sub_;
  ros::Subscriber info_sub_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber image_sub_;
  std::atomic<bool> images_subscribed_{false};
  std::atomic<bool> points_subscribed_{false};
  ros::ServiceServer lock_service_;
  tf2_ros::TransformBroadcaster tf_broadcaster_;

  // Frame state, guarded by buffer_mutex_.
  std::mutex buffer_mutex_;
  std::deque<sensor_msgs::ImageConstPtr> images_;
  std::deque<sensor_msgs::PointCloud2ConstPtr> pending_;
  sensor_msgs::CameraInfoConstPtr latest_info_;
  PoseDeltaEstimator estimator_;
  bool map_received_ = false;
  ros::Time last_tf_stamp_;
  bool warned_mono_ = false;
  bool warned_encoding_ = false;

  // Diagnostics.
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  std::unique_ptr<diagnostic_updater::TopicDiagnostic> pose_diag_;
  ros::Timer diagnostics_timer_;
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
