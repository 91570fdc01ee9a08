// Triangulator nodelet: spots (CentroidArray) + camera/camera_info ->
// points (organised PointCloud2, one point per projector beam) and
// spots/assigned (the spots with their beam ids). All the work is done by
// the core Triangulator (triangulator.h); this file only wires it to ROS.
// camera_info: the latest one received serves (it rarely changes; a stale
// one is warned about once), or with ~exact_sync the one with the spots'
// stamp (message_filters ExactTime; spots without one are dropped).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>
#include <mutex>
#include <string>

#include <boost/thread/recursive_mutex.hpp>
#include <dynamic_reconfigure/server.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/Trigger.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/TriangulatorConfig.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"
#include "nodelets/common/resource_url.h"

namespace structured_light_stabilizer
{

namespace
{

using Config = structured_light_stabilizer::TriangulatorConfig;

// ---- The core interface: dynamic_reconfigure -> TriangulatorParams, and
// what decides whether the cached core object still fits.

// configCb() has made c.assignment valid.
TriangulatorParams paramsFromConfig(const Config& c)
{
  TriangulatorParams o;
  o.fromConfig(c);
  return o;
}

}  // namespace

class TriangulatorNodelet : public NodeletBase
{
public:
  TriangulatorNodelet() : NodeletBase("Triangulator") {}
  ~TriangulatorNodelet() override { stopCallbacks(); }

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readLazyParam();
    pnh.param("camera_info_stale_s", info_stale_s_, 1.0);
    pnh.param("exact_sync", exact_sync_, false);
    pnh.param<std::string>("projector_calibration", calibration_path_, "");
    loadCalibration();

    reconfigure_server_ = std::make_shared<dynamic_reconfigure::Server<Config>>(config_mutex_, pnh);
    reconfigure_server_->setCallback([this](Config& c, uint32_t level) { configCb(c, level); });

    setUpDiagnostics("structured_light_stabilizer/Triangulator");
    addFrequencyStatus();
    diagnostics_->add("triangulation", this, &TriangulatorNodelet::diagnose);
    startDiagnostics(1.0);

    srv_reload_ = pnh.advertiseService("reload_calibration", &TriangulatorNodelet::reloadCb, this);

    pub_points_ = advertise<sensor_msgs::PointCloud2>(nh, "points", 1);
    pub_assigned_ = advertise<CentroidArray>(nh, "spots/assigned", 1);
    startSubscriptions(
        "input (spots, camera/camera_info) is subscribed on demand, when points or spots/assigned "
        "has a subscriber (~lazy:=false to subscribe at start-up)");
  }

  void subscribe() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    if (exact_sync_)
    {
      sync_spots_.subscribe(nh, "spots", 5);
      sync_info_.subscribe(nh, "camera/camera_info", 5);
      sync_.reset(new message_filters::Synchronizer<ExactPolicy>(ExactPolicy(10), sync_spots_, sync_info_));
      sync_->registerCallback(&TriangulatorNodelet::syncedCb, this);
      sync_->getPolicy()->registerDropCallback(&TriangulatorNodelet::unmatchedCb, this);
      return;
    }
    sub_info_ = nh.subscribe("camera/camera_info", 1, &TriangulatorNodelet::infoCb, this);
    sub_spots_ = nh.subscribe("spots", 1, &TriangulatorNodelet::spotsCb, this);
  }

  void unsubscribe() override
  {
    sub_spots_.shutdown();
    sub_info_.shutdown();
    sync_spots_.unsubscribe();
    sync_info_.unsubscribe();
  }

  void loadCalibration()
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    triangulator_.reset();
    if (calibration_path_.empty())
    {
      calibration_error_ =
          "~projector_calibration is not set (the projector calibration YAML: a path, file:// or package:// URL)";
      NODELET_ERROR("Triangulator: %s; nothing will be published", calibration_error_.c_str());
      return;
    }
    ProjectorCalibration cal;
    std::string err, path;
    if (!resolveResourceUrl(calibration_path_, &path, &err) || !loadProjectorCalibration(path, &cal, &err))
    {
      calibration_error_ = "projector calibration refused: " + err;
      NODELET_ERROR("Triangulator: %s; nothing will be published", calibration_error_.c_str());
      return;
    }
    calibration_ = cal;
    calibration_error_.clear();
    NODELET_INFO("Triangulator: projector calibration %s: %d x %d beams", calibration_path_.c_str(), cal.rows,
                 cal.cols);
  }

  bool reloadCb(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res)
  {
    getPrivateNodeHandle().param<std::string>("projector_calibration", calibration_path_, calibration_path_);
    loadCalibration();
    std::lock_guard<std::mutex> lock(state_mutex_);
    res.success = calibration_error_.empty();
    res.message = res.success ? "loaded " + calibration_path_ : calibration_error_;
    return true;
  }

  void configCb(Config& c, uint32_t /*level*/)
  {
    // Validate here; the frame callback copies the accepted config.
    if (c.min_depth >= c.max_depth)
    {
      NODELET_WARN("Triangulator: min_depth %.3f >= max_depth %.3f; swapped", c.min_depth, c.max_depth);
      std::swap(c.min_depth, c.max_depth);
      if (c.min_depth == c.max_depth)
        c.max_depth = c.min_depth + 0.1;
    }
    if (c.assignment != "epipolar" && c.assignment != "sort")
    {
      // The last good value stays in force (epipolar before any).
      const std::string kept = config_.assignment == "sort" ? "sort" : "epipolar";
      NODELET_WARN("Triangulator: unknown assignment '%s' (epipolar | sort); keeping %s", c.assignment.c_str(),
                   kept.c_str());
      c.assignment = kept;
    }
    config_ = c;
  }

  void infoCb(const sensor_msgs::CameraInfoConstPtr& info)
  {
    CentroidArrayConstPtr waiting;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      info_ = info;
      waiting.swap(before_first_info_);
    }
    if (waiting)
      spotsCb(waiting);
  }

  void spotsCb(const CentroidArrayConstPtr& msg)
  {
    {
      // The first spots can beat the first camera_info (a replayed bag, a
      // slow link): the newest waits for it instead of being dropped.
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (!info_)
      {
        if (before_first_info_)
          dropFrame("no camera_info received on " + getNodeHandle().resolveName("camera/camera_info") +
                    " yet; nothing published");
        before_first_info_ = msg;
        return;
      }
    }
    guarded([&] { process(msg); });
  }

  // ~exact_sync: spots and the camera_info of their stamp.
  void syncedCb(const CentroidArrayConstPtr& msg, const sensor_msgs::CameraInfoConstPtr& info)
  {
    infoCb(info);
    spotsCb(msg);
  }

  void unmatchedCb(const CentroidArrayConstPtr& msg, const sensor_msgs::CameraInfoConstPtr& /*info*/)
  {
    if (msg)
      dropFrame("~exact_sync: no camera_info with the spots' stamp " + std::to_string(msg->header.stamp.toSec()) +
                "; frame dropped");
  }

  void process(const CentroidArrayConstPtr& msg)
  {
    const ros::WallTime start = ros::WallTime::now();
    Config config;
    {
      boost::recursive_mutex::scoped_lock lock(config_mutex_);
      config = config_;
    }
    if (!config.enabled)
      return;
    const std::shared_ptr<const Triangulator> tri = triangulatorFor(*msg, config);
    if (!tri)
      return;  // dropped, said why
    const Spots spots = spotsFromMsg(*msg);
    if (!allFinite(spots))
      return;
    const TriangulationResult result = track(tri, spots, msg->header.stamp, config);
    publish(msg, *tri, result);

    frequency_->tick();
    std::lock_guard<std::mutex> lock(stats_mutex_);
    last_ = result;
    last_spots_ = spots.size();
    last_beams_ = tri->projector().beamCount();
    last_ms_ = (ros::WallTime::now() - start).toSec() * 1e3;
    have_stats_ = true;
  }

  // The core object for this frame's camera_info and config (made again when
  // either changed); null, after dropping the frame, when there is none.
  // The core's BeamTracker decides when the previous result may serve as
  // the prior (tracking on, same core object, stamps close and increasing).
  TriangulationResult track(const std::shared_ptr<const Triangulator>& tri, const Spots& spots, const ros::Time& stamp,
                            const Config& config)
  {
    BeamTrackerParams tracking;
    tracking.fromConfig(config);
    std::lock_guard<std::mutex> lock(track_mutex_);
    tracker_.setParams(tracking);
    return tracker_.process(tri, spots, stamp.toSec());
  }

  std::shared_ptr<const Triangulator> triangulatorFor(const CentroidArray& msg, const Config& config)
  {
    sensor_msgs::CameraInfoConstPtr info;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (!calibration_error_.empty())
      {
        dropFrame(calibration_error_ + "; nothing published");
        return nullptr;
      }
      info = info_;
    }
    CameraModel model;
    if (!usableInfo(msg, info, &model))
      return nullptr;
    const TriangulatorParams params = paramsFromConfig(config);
    std::lock_guard<std::mutex> lock(state_mutex_);
    if (!triangulator_ || triangulator_->camera() != model || triangulator_->params() != params)
      triangulator_ = std::make_shared<const Triangulator>(model, calibration_, params);
    return triangulator_;
  }

  // The camera model of the latest camera_info, when it fits the spots'
  // image (style weak spots 2 and 3: refuse a mismatch, use the latest info
  // whatever its stamp and warn once when stale).
  bool usableInfo(const CentroidArray& msg, const sensor_msgs::CameraInfoConstPtr& info, CameraModel* model)
  {
    if (!info)
    {
      dropFrame("no camera_info received on " + getNodeHandle().resolveName("camera/camera_info") +
                " yet; nothing published");
      return false;
    }
    std::string err;
    if (!cameraModelFromInfo(*info, model, &err))
    {
      dropFrame(err + "; frame dropped");
      return false;
    }
    // The model is of the binned ROI the image is (cameraModelFromInfo).
    if (model->width != static_cast<int>(msg.image_width) || model->height != static_cast<int>(msg.image_height))
    {
      dropFrame(sizeMismatch(*info, *model, msg));
      return false;
    }
    const double age = std::abs((msg.header.stamp - info->header.stamp).toSec());
    if (info_stale_s_ > 0.0 && age > info_stale_s_ && !stale_warned_)
    {
      NODELET_WARN(
          "Triangulator: the latest camera_info is %.2f s away from the spots' stamp; using it anyway "
          "(warned once)",
          age);
      stale_warned_ = true;
    }
    return true;
  }

  // Why a camera_info does not fit the spots' image (binning and ROI named
  // when set: a different kind of problem for the drop log).
  static std::string sizeMismatch(const sensor_msgs::CameraInfo& info, const CameraModel& model,
                                  const CentroidArray& msg)
  {
    const auto size = [](uint32_t w, uint32_t h) { return std::to_string(w) + "x" + std::to_string(h); };
    const std::string spots = " but the spots come from a " + size(msg.image_width, msg.image_height) + " image";
    const SensorWindow w = sensorWindowFromInfo(info);
    const int sensor_w = static_cast<int>(info.width), sensor_h = static_cast<int>(info.height);
    if (w.isFullSensor(sensor_w, sensor_h))
      return "camera_info is " + size(info.width, info.height) + spots + "; frame dropped (wrong camera_info?)";
    const cv::Rect roi = w.roi(sensor_w, sensor_h);
    return "camera_info is " + size(info.width, info.height) + " with binning " + size(w.binning_x, w.binning_y) +
           " and ROI " + size(roi.width, roi.height) + "+" + std::to_string(roi.x) + "+" + std::to_string(roi.y) +
           ", i.e. " + size(model.width, model.height) + " images," + spots +
           "; frame dropped (wrong camera_info, or the window not applied to the image)";
  }

  // Non-finite centroids mean a broken upstream: drop the frame rather than
  // publish a map built from part of it.
  bool allFinite(const Spots& spots)
  {
    size_t bad = 0;
    for (const Spot& s : spots)
      bad += !std::isfinite(s.x) || !std::isfinite(s.y);
    if (bad == 0)
      return true;
    dropFrame(std::to_string(bad) + " of " + std::to_string(spots.size()) +
              " centroids are NaN or infinite; frame dropped");
    std::lock_guard<std::mutex> lock(stats_mutex_);
    nan_frames_ += 1;
    return false;
  }

  void publish(const CentroidArrayConstPtr& msg, const Triangulator& tri, const TriangulationResult& result)
  {
    const ProjectorCalibration& cal = tri.projector();
    pub_points_.publish(makeBeamCloud(msg->header, cal.rows, cal.cols, result.points, result.intensity));
    if (pub_assigned_.getNumSubscribers() > 0)
    {
      CentroidArrayPtr out(new CentroidArray(*msg));
      for (size_t j = 0; j < out->centroids.size(); ++j)
        out->centroids[j].beam = result.beam_of_spot[j];
      pub_assigned_.publish(out);
    }
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::string calib_error;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      calib_error = calibration_error_;
    }
    std::lock_guard<std::mutex> lock(stats_mutex_);
    if (!calib_error.empty())
    {
      stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, calib_error);
      return;
    }
    if (!have_stats_)
    {
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no spots processed yet");
      return;
    }
    const double fraction = last_beams_ > 0 ? static_cast<double>(last_.valid_points) / last_beams_ : 0.0;
    stat.summary(fraction > 0.5 ? diagnostic_msgs::DiagnosticStatus::OK : diagnostic_msgs::DiagnosticStatus::WARN,
                 std::to_string(last_.valid_points) + " of " + std::to_string(last_beams_) + " beams triangulated");
    stat.add("spots", last_spots_);
    stat.add("beams identified", last_.valid_points);
    stat.add("ambiguous pairs rejected", last_.ambiguous);
    stat.add("rejected by ray gap", last_.rejected_gap);
    stat.add("rejected by depth range", last_.rejected_depth);
    stat.add("spots unassigned", last_.unassigned_spots);
    stat.add("frames dropped for NaN centroids", nan_frames_);
    stat.add("mean ray gap (mm)", last_.mean_ray_gap * 1e3);
    stat.add("beams settled by the tracking prior",
             last_.tracked < 0 ? std::string("no prior") : std::to_string(last_.tracked));
    stat.add("processing time (ms)", last_ms_);
  }

  // Parameters fixed at start-up (the calibration path also on reload).
  double info_stale_s_ = 1.0;
  bool exact_sync_ = false;
  std::string calibration_path_;

  // dynamic_reconfigure: configCb() validates, the frame callback copies.
  boost::recursive_mutex config_mutex_;
  Config config_;
  std::shared_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;

  // Calibration, camera_info, cached core object.
  std::mutex state_mutex_;
  ProjectorCalibration calibration_;
  std::string calibration_error_;
  sensor_msgs::CameraInfoConstPtr info_;
  CentroidArrayConstPtr before_first_info_;  // the newest spots while no camera_info has come
  std::shared_ptr<const Triangulator> triangulator_;
  std::mutex track_mutex_;
  BeamTracker tracker_;  // the tracking prior carried from frame to frame
  std::atomic<bool> stale_warned_{false};

  ros::Subscriber sub_spots_, sub_info_;
  using ExactPolicy = message_filters::sync_policies::ExactTime<CentroidArray, sensor_msgs::CameraInfo>;
  message_filters::Subscriber<CentroidArray> sync_spots_;
  message_filters::Subscriber<sensor_msgs::CameraInfo> sync_info_;
  std::unique_ptr<message_filters::Synchronizer<ExactPolicy>> sync_;
  ros::Publisher pub_points_, pub_assigned_;
  ros::ServiceServer srv_reload_;

  // Statistics for diagnostics.
  std::mutex stats_mutex_;
  TriangulationResult last_;
  size_t last_spots_ = 0;
  int last_beams_ = 0;
  double last_ms_ = 0.0;
  bool have_stats_ = false;
  unsigned long nan_frames_ = 0;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::TriangulatorNodelet, nodelet::Nodelet)
