// ProjectorCalibrator nodelet (calibrate.launch): collects the spots of a
// flat board at user-signalled distances and fits the projector's beam rays
// with the core calibrateFromBoards (projector_calibrator.h).
//
// The operator puts the board at the next distance of ~distances and calls
// ~capture (std_srvs/Trigger); the next ~frames_per_view frames holding the
// whole pattern are averaged per beam. After the last distance the rays are
// fitted, the per-beam report is logged and published (latched) on ~report,
// and the YAML is written to ~output.
#include <array>
#include <cmath>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/projector_calibrator.h"
#include "structured_light_stabilizer/triangulator.h"
#include "conversions.h"
#include "nodelet_base.h"

namespace structured_light_stabilizer
{

class ProjectorCalibratorNodelet : public NodeletBase
{
public:
  ProjectorCalibratorNodelet() : NodeletBase("ProjectorCalibrator") {}

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    pnh.param("rows", params_.rows, 10);
    pnh.param("cols", params_.cols, 10);
    pnh.param("max_residual_px", params_.max_residual_px, params_.max_residual_px);
    pnh.param("max_origin_distance_m", params_.max_origin_distance_m, params_.max_origin_distance_m);
    pnh.param("frames_per_view", frames_per_view_, 5);
    pnh.param<std::string>("output", output_, "");
    pnh.param<std::string>("views_dir", views_dir_, "");
    pnh.getParam("distances", distances_);
    std::vector<double> origin;
    if (pnh.getParam("projector_origin", origin) && origin.size() == 3)
    {
      projector_origin_ = Eigen::Vector3d(origin[0], origin[1], origin[2]);
      have_origin_ = true;
    }
    const size_t needed = have_origin_ ? 1 : 2;
    if (distances_.size() < needed || output_.empty() || frames_per_view_ < 1)
    {
      NODELET_ERROR(
          "ProjectorCalibrator: needs ~distances (metres, >= 2, or >= 1 with ~projector_origin), ~output "
          "(YAML path) and ~frames_per_view >= 1; got %zu distance(s), output '%s'",
          distances_.size(), output_.c_str());
      return;
    }
    pub_report_ = pnh.advertise<std_msgs::String>("report", 1, true);
    srv_capture_ = pnh.advertiseService("capture", &ProjectorCalibratorNodelet::captureCb, this);
    sub_info_ = nh.subscribe("camera/camera_info", 1, &ProjectorCalibratorNodelet::infoCb, this);
    sub_spots_ = nh.subscribe("spots", 5, &ProjectorCalibratorNodelet::spotsCb, this);
    NODELET_INFO("ProjectorCalibrator: place the board at %.3f m and call %s", distances_[0],
                 srv_capture_.getService().c_str());
  }

  bool captureCb(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (views_.size() >= distances_.size())
    {
      res.success = false;
      res.message = "all distances are captured; restart to calibrate again";
      return true;
    }
    capturing_ = true;
    sums_.clear();
    frames_ = 0;
    res.success = true;
    res.message = "capturing the board at " + std::to_string(distances_[views_.size()]) + " m";
    NODELET_INFO("ProjectorCalibrator: %s", res.message.c_str());
    return true;
  }

  void infoCb(const sensor_msgs::CameraInfoConstPtr& info)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    info_ = info;
  }

  void spotsCb(const CentroidArrayConstPtr& msg)
  {
    guarded([&] { process(msg); });
  }

  void process(const CentroidArrayConstPtr& msg)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!capturing_)
      return;
    Spots spots = spotsFromMsg(*msg);
    if (!labelBeams(&spots))
      return;
    accumulate(spots);
    if (++frames_ < frames_per_view_)
      return;
    capturing_ = false;
    addView();
    if (views_.size() < distances_.size())
    {
      NODELET_INFO("ProjectorCalibrator: place the board at %.3f m and call capture", distances_[views_.size()]);
      return;
    }
    finish();
  }

  // Spots without beam ids (a plain detector upstream) are labelled by the
  // row sort when the board shows the whole pattern; false: wait for one.
  bool labelBeams(Spots* spots)
  {
    for (const Spot& s : *spots)
      if (s.beam >= 0)
        return true;
    const int n = params_.rows * params_.cols;
    if (static_cast<int>(spots->size()) != n)
    {
      NODELET_WARN_THROTTLE(2.0, "ProjectorCalibrator: %zu spots, the board must show all %d dots; waiting",
                            spots->size(), n);
      return false;
    }
    const std::vector<int> order = rowSortOrder(*spots, params_.cols);
    for (size_t k = 0; k < order.size(); ++k)
      (*spots)[order[k]].beam = static_cast<int>(k);
    return true;
  }

  void accumulate(const Spots& spots)
  {
    const int n = params_.rows * params_.cols;
    for (const Spot& s : spots)
    {
      if (s.beam < 0 || s.beam >= n || !std::isfinite(s.x) || !std::isfinite(s.y))
        continue;
      auto& acc = sums_[s.beam];
      acc[0] += s.x;
      acc[1] += s.y;
      acc[2] += 1.0;
    }
  }

  // The mean dot of each beam over the view's frames, at the view's distance.
  void addView()
  {
    BoardView view;
    view.distance_m = distances_[views_.size()];
    for (const auto& kv : sums_)
    {
      Spot s;
      s.x = kv.second[0] / kv.second[2];
      s.y = kv.second[1] / kv.second[2];
      s.beam = kv.first;
      view.spots.push_back(s);
    }
    if (!views_dir_.empty())
    {
      std::string err;
      const std::string path = views_dir_ + "/board_" + std::to_string(views_.size()) + ".yaml";
      if (!saveBoardView(path, view, &err))
        NODELET_WARN("ProjectorCalibrator: %s", err.c_str());
    }
    views_.push_back(view);
    NODELET_INFO("ProjectorCalibrator: board at %.3f m captured (%zu dots, %d frames)", view.distance_m,
                 view.spots.size(), frames_);
  }

  void finish()
  {
    CameraModel camera;
    std::string err;
    std_msgs::StringPtr report(new std_msgs::String);
    if (!info_ || !cameraModelFromInfo(*info_, &camera, &err))
    {
      report->data = "calibration failed: no usable camera_info (" + err + ")";
    }
    else
    {
      const BoardCalibrationResult res = have_origin_ && views_.size() == 1
                                             ? calibrateFromOneBoard(camera, views_[0], projector_origin_, params_)
                                             : calibrateFromBoards(camera, views_, params_);
      report->data = res.report();
      if (res.ok && !saveProjectorCalibration(output_, res.calibration, &err))
        report->data += "\nwriting failed: " + err;
      else if (res.ok)
        report->data += "\nwritten to " + output_;
    }
    NODELET_INFO("ProjectorCalibrator: %s", report->data.c_str());
    pub_report_.publish(report);
  }

  BoardCalibrationParams params_;
  int frames_per_view_ = 5;
  std::string output_, views_dir_;
  std::vector<double> distances_;
  Eigen::Vector3d projector_origin_ = Eigen::Vector3d::Zero();
  bool have_origin_ = false;

  std::mutex mutex_;  // the capture state below, and info_
  bool capturing_ = false;
  int frames_ = 0;
  std::map<int, std::array<double, 3>> sums_;  // per beam: sum of x, sum of y, count
  std::vector<BoardView> views_;
  sensor_msgs::CameraInfoConstPtr info_;

  ros::Subscriber sub_spots_, sub_info_;
  ros::Publisher pub_report_;
  ros::ServiceServer srv_capture_;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::ProjectorCalibratorNodelet, nodelet::Nodelet)
