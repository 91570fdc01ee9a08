// Triangulator nodelet: spots (CentroidArray) + camera/camera_info ->
// points (organised PointCloud2, one point per projector beam) and
// spots/assigned (the spots with their beam ids). All the work is done by
// the core Triangulator (triangulator.h); this file only wires it to ROS.
#include <atomic>
#include <cmath>
#include <memory>
#include <mutex>
#include <string>

#include <boost/thread/recursive_mutex.hpp>
#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/update_functions.h>
#include <dynamic_reconfigure/server.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/Trigger.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/TriangulatorConfig.h"
#include "conversions.h"
#include "structured_light_stabilizer/projector_calibration.h"
#include "structured_light_stabilizer/triangulator.h"
#include "drop_log.h"

namespace structured_light_stabilizer
{

class TriangulatorNodelet : public nodelet::Nodelet
{
public:
  ~TriangulatorNodelet() override
  {
    if (diag_timer_.isValid())
      diag_timer_.stop();
  }

private:
  using Config = structured_light_stabilizer::TriangulatorConfig;

  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    pnh.param("lazy", lazy_, true);
    pnh.param("camera_info_stale_s", info_stale_s_, 1.0);
    pnh.param<std::string>("projector_calibration", calibration_path_, "");
    loadCalibration();

    reconfigure_server_ = std::make_shared<dynamic_reconfigure::Server<Config>>(config_mutex_, pnh);
    reconfigure_server_->setCallback(
        [this](Config& c, uint32_t level) { reconfigure(c, level); });

    diagnostics_ = std::make_unique<diagnostic_updater::Updater>(nh, pnh, getName());
    diagnostics_->setHardwareID("structured_light_stabilizer/Triangulator");
    freq_status_ = std::make_shared<diagnostic_updater::FrequencyStatus>(
        diagnostic_updater::FrequencyStatusParam(&min_freq_, &max_freq_, 0.1, 10));
    diagnostics_->add(*freq_status_);
    diagnostics_->add("triangulation", this, &TriangulatorNodelet::diagnose);
    diag_timer_ = nh.createTimer(ros::Duration(1.0), [this](const ros::TimerEvent&) { diagnostics_->update(); });

    reload_service_ = pnh.advertiseService("reload_calibration", &TriangulatorNodelet::reloadCallback, this);

    std::lock_guard<std::mutex> lock(connect_mutex_);
    const ros::SubscriberStatusCallback cb = [this](const ros::SingleSubscriberPublisher&) { connectCallback(); };
    points_pub_ = nh.advertise<sensor_msgs::PointCloud2>("points", 1, cb, cb);
    assigned_pub_ = nh.advertise<CentroidArray>("spots/assigned", 1, cb, cb);
    if (lazy_)
      NODELET_INFO("Triangulator: input (spots, camera/camera_info) is subscribed on demand, when points or "
                   "spots/assigned has a subscriber (~lazy:=false to subscribe at start-up)");
    else
      subscribe();
  }

  void loadCalibration()
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    triangulator_.reset();
    if (calibration_path_.empty())
    {
      calibration_error_ = "~projector_calibration is not set (path of the projector calibration YAML)";
      NODELET_ERROR("Triangulator: %s; nothing will be published", calibration_error_.c_str());
      return;
    }
    ProjectorCalibration cal;
    std::string err;
    if (!loadProjectorCalibration(calibration_path_, &cal, &err))
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

  bool reloadCallback(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res)
  {
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    pnh.param<std::string>("projector_calibration", calibration_path_, calibration_path_);
    loadCalibration();
    std::lock_guard<std::mutex> lock(state_mutex_);
    res.success = calibration_error_.empty();
    res.message = res.success ? "loaded " + calibration_path_ : calibration_error_;
    return true;
  }

  void reconfigure(Config& c, uint32_t /*level*/)
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

  void connectCallback()
  {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    const bool wanted = points_pub_.getNumSubscribers() > 0 || assigned_pub_.getNumSubscribers() > 0;
    if (wanted && !spots_sub_)
      subscribe();
    else if (!wanted && lazy_ && spots_sub_)
    {
      spots_sub_.shutdown();
      info_sub_.shutdown();
    }
  }

  void subscribe()
  {
    ros::NodeHandle& nh = getNodeHandle();
    info_sub_ = nh.subscribe("camera/camera_info", 1, &TriangulatorNodelet::infoCallback, this);
    spots_sub_ = nh.subscribe("spots", 1, &TriangulatorNodelet::spotsCallback, this);
  }

  void infoCallback(const sensor_msgs::CameraInfoConstPtr& info)
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    info_ = info;
  }

  static TriangulatorOptions optionsFrom(const Config& c)
  {
    TriangulatorOptions o;
    o.min_depth = c.min_depth;
    o.max_depth = c.max_depth;
    o.max_epipolar_distance_px = c.max_epipolar_distance_px;
    o.max_ray_gap = c.max_ray_gap;
    o.ambiguity_margin = c.ambiguity_margin;
    o.prediction_tolerance_px = c.prediction_tolerance_px;
    o.tracking_radius_px = c.tracking_radius_px;
    o.assignment = c.assignment == "sort" ? BeamAssignment::kSort : BeamAssignment::kEpipolar;
    return o;
  }

  static bool sameModel(const CameraModel& a, const CameraModel& b)
  {
    return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
           a.cy == b.cy && a.distortion == b.distortion && a.D == b.D;
  }

  static bool sameOptions(const TriangulatorOptions& a, const TriangulatorOptions& b)
  {
    return a.min_depth == b.min_depth && a.max_depth == b.max_depth &&
           a.max_epipolar_distance_px == b.max_epipolar_distance_px && a.max_ray_gap == b.max_ray_gap &&
           a.ambiguity_margin == b.ambiguity_margin && a.prediction_tolerance_px == b.prediction_tolerance_px &&
           a.tracking_radius_px == b.tracking_radius_px && a.assignment == b.assignment;
  }

  void spotsCallback(const CentroidArrayConstPtr& msg)
  {
    try
    {
      process(msg);
    }
    catch (const std::exception& e)
    {
      dropFrame(std::string("frame dropped: ") + e.what());
    }
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

    std::shared_ptr<const Triangulator> tri;
    sensor_msgs::CameraInfoConstPtr info;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (!calibration_error_.empty())
      {
        dropFrame(calibration_error_ + "; nothing published");
        return;
      }
      info = info_;
    }
    if (!info)
    {
      dropFrame("no camera_info received on " + getNodeHandle().resolveName("camera/camera_info") +
                " yet; nothing published");
      return;
    }
    if (info->width != msg->image_width || info->height != msg->image_height)
    {
      dropFrame("camera_info is " + std::to_string(info->width) + "x" + std::to_string(info->height) +
                " but the spots come from a " + std::to_string(msg->image_width) + "x" +
                std::to_string(msg->image_height) + " image; frame dropped (wrong camera_info, or binning/ROI upstream)");
      return;
    }
    const double age = std::abs((msg->header.stamp - info->header.stamp).toSec());
    if (info_stale_s_ > 0.0 && age > info_stale_s_ && !stale_warned_)
    {
      NODELET_WARN("Triangulator: the latest camera_info is %.2f s away from the spots' stamp; using it anyway "
                   "(warned once)",
                   age);
      stale_warned_ = true;
    }
    CameraModel model;
    std::string err;
    if (!cameraModelFromInfo(*info, &model, &err))
    {
      dropFrame(err + "; frame dropped");
      return;
    }

    const TriangulatorOptions options = optionsFrom(config);
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      if (!triangulator_ || !sameModel(triangulator_->camera(), model) ||
          !sameOptions(triangulator_->config(), options))
        triangulator_ = std::make_shared<const Triangulator>(model, calibration_, options);
      tri = triangulator_;
    }

    const Spots spots = spotsFromMsg(*msg);
    // Non-finite centroids mean a broken upstream: drop the frame rather
    // than publish a map built from part of it.
    size_t bad = 0;
    for (const Spot& s : spots)
      bad += !std::isfinite(s.x) || !std::isfinite(s.y);
    if (bad > 0)
    {
      dropFrame(std::to_string(bad) + " of " + std::to_string(spots.size()) +
                " centroids are NaN or infinite; frame dropped");
      std::lock_guard<std::mutex> lock(stats_mutex_);
      nan_frames_ += 1;
      return;
    }
    // Tracking prior: the previous result of this same core object (a new
    // calibration, camera_info or config makes a new one), unless the stamps
    // are too far apart or go backwards (a bag looping). When too few beams
    // persisted, the core itself falls back to the single-frame solution.
    std::shared_ptr<const TriangulationResult> prior;
    {
      std::lock_guard<std::mutex> lock(track_mutex_);
      const double gap = (msg->header.stamp - prior_stamp_).toSec();
      if (config.use_tracking && prior_ && prior_owner_ == tri && gap > 0.0 && gap <= config.tracking_reset_gap)
        prior = prior_;
    }
    const TriangulationResult result = tri->process(spots, prior.get());
    {
      std::lock_guard<std::mutex> lock(track_mutex_);
      if (config.use_tracking)
      {
        prior_ = std::make_shared<const TriangulationResult>(result);
        prior_owner_ = tri;
        prior_stamp_ = msg->header.stamp;
      }
      else
      {
        prior_.reset();
        prior_owner_.reset();
      }
    }

    const ProjectorCalibration& cal = tri->projector();
    points_pub_.publish(makeBeamCloud(msg->header, cal.rows, cal.cols, result.points, result.intensity));
    if (assigned_pub_.getNumSubscribers() > 0)
    {
      CentroidArrayPtr out(new CentroidArray(*msg));
      for (size_t j = 0; j < out->centroids.size(); ++j)
        out->centroids[j].beam = result.beam_of_spot[j];
      assigned_pub_.publish(out);
    }

    freq_status_->tick();
    std::lock_guard<std::mutex> lock(stats_mutex_);
    last_ = result;
    last_spots_ = spots.size();
    last_beams_ = cal.beamCount();
    last_ms_ = (ros::WallTime::now() - start).toSec() * 1e3;
    have_stats_ = true;
  }

  // Each kind of problem is logged at once, then at most every 5 s: a
  // throttle per call site would hide a second, different camera_info fault.
  void dropFrame(const std::string& why)
  {
    int suppressed = 0;
    if (!drop_log_.shouldLog(why, &suppressed))
      return;
    const std::string note = suppressed > 0 ? " (" + std::to_string(suppressed) + " more like it suppressed)" : "";
    NODELET_ERROR("Triangulator: %s%s", why.c_str(), note.c_str());
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
    stat.add("beams settled by the tracking prior", last_.tracked < 0 ? std::string("no prior") :
                                                                         std::to_string(last_.tracked));
    stat.add("processing time (ms)", last_ms_);
  }

  // Parameters.
  bool lazy_ = true;
  double info_stale_s_ = 1.0;
  std::string calibration_path_;

  // Reconfigure.
  boost::recursive_mutex config_mutex_;
  Config config_;
  std::shared_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;

  // Calibration, camera_info, cached core object.
  std::mutex state_mutex_;
  ProjectorCalibration calibration_;
  std::string calibration_error_;
  sensor_msgs::CameraInfoConstPtr info_;
  std::shared_ptr<const Triangulator> triangulator_;

  // Tracking prior: the last published result, the core object that made it, its stamp.
  std::mutex track_mutex_;
  std::shared_ptr<const TriangulationResult> prior_;
  std::shared_ptr<const Triangulator> prior_owner_;
  ros::Time prior_stamp_;
  std::atomic<bool> stale_warned_{false};

  // ROS I/O.
  std::mutex connect_mutex_;
  ros::Subscriber spots_sub_, info_sub_;
  ros::Publisher points_pub_, assigned_pub_;
  ros::ServiceServer reload_service_;

  // Diagnostics.
  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  double min_freq_ = 1.0, max_freq_ = 1000.0;
  std::shared_ptr<diagnostic_updater::FrequencyStatus> freq_status_;
  ros::Timer diag_timer_;
  std::mutex stats_mutex_;
  TriangulationResult last_;
  size_t last_spots_ = 0;
  int last_beams_ = 0;
  double last_ms_ = 0.0;
  bool have_stats_ = false;
  unsigned long nan_frames_ = 0;
  DropLog drop_log_;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::TriangulatorNodelet, nodelet::Nodelet)
