// ProjectorCalibrator nodelet (calibrate.launch; docs/calibration.md), two
// modes, each calling the core:
//  - chessboard (~board "COLSxROWS" and ~square set): each ~capture
//    (std_srvs/Trigger) analyses the latest camera/image_raw with its
//    camera/camera_info (chessboard_calibration.h); the response says what
//    the view gave (board, dots) or why it is refused; after ~views usable
//    views every view is fitted at once, the report logged and latched on
//    ~report, the YAML written to ~output and the PNG report next to it.
//  - distances (the study's procedure, ~distances): the operator puts a
//    board facing the camera at the next distance and calls ~capture; the
//    next ~frames_per_view frames of `spots` holding the whole pattern are
//    averaged per beam; after the last distance calibrateFromBoards
//    (projector_calibrator.h).
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include <cv_bridge/cv_bridge.h>
#include <image_transport/image_transport.h>
#include <opencv2/imgcodecs.hpp>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/calibration/chessboard_calibration.h"
#include "structured_light_stabilizer/calibration/projector_calibrator.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"

namespace structured_light_stabilizer
{

class ProjectorCalibratorNodelet : public NodeletBase
{
public:
  ProjectorCalibratorNodelet() : NodeletBase("ProjectorCalibrator") {}

private:
  void onInit() override
  {
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    if (pnh.hasParam("board"))
      initChessboard();
    else
      initDistances();
  }

  void initDistances()
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

  // ---- Chessboard mode.

  void initChessboard()
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const std::string board = pnh.param<std::string>("board", "");
    const std::string colour = pnh.param<std::string>("projector_color", "green");
    const std::string model = pnh.param<std::string>("model", "auto");
    ChessboardCalibrationParams& p = board_params_;
    p.board.square_m = pnh.param("square", 0.0);
    p.board.margin_m = pnh.param("margin", 0.0);
    p.rows = pnh.param("rows", 10);
    p.cols = pnh.param("cols", 10);
    pnh.param("views", views_wanted_, 6);
    pnh.param<std::string>("output", output_, "");
    pnh.param<std::string>("views_dir", views_dir_, "");
    std::string why;
    if (!parseBoardSize(board, &p.board.cols, &p.board.rows))
      why = "~board must be COLSxROWS inner corners (e.g. 10x8), got '" + board + "'";
    else if (!channelsForProjectorColor(colour, &p.dot_channel, &p.board_channel))
      why = "unknown ~projector_color '" + colour + "'";
    else if (model != "auto" && model != "central" && model != "per-beam")
      why = "~model must be auto, central or per-beam";
    else if (output_.empty() || views_wanted_ < 2)
      why = "~output (YAML path) and ~views >= 2 are needed";
    else
      why = p.validate();
    p.fit.model = model == "central" ? ProjectorModel::kCentral
                                     : (model == "per-beam" ? ProjectorModel::kPerBeam : ProjectorModel::kChosenByData);
    if (!why.empty())
    {
      NODELET_ERROR("ProjectorCalibrator: %s; not calibrating", why.c_str());
      return;
    }
    pub_report_ = pnh.advertise<std_msgs::String>("report", 1, true);
    srv_capture_ = pnh.advertiseService("capture", &ProjectorCalibratorNodelet::captureBoardCb, this);
    it_.reset(new image_transport::ImageTransport(nh));
    sub_image_ = it_->subscribe("camera/image_raw", 1, &ProjectorCalibratorNodelet::imageCb, this,
                                image_transport::TransportHints("raw", ros::TransportHints(), pnh));
    sub_info_ = nh.subscribe("camera/camera_info", 1, &ProjectorCalibratorNodelet::infoCb, this);
    NODELET_INFO(
        "ProjectorCalibrator: chessboard %s of %.4f m squares; show it to the camera at 1.2-1.6 m, tilted "
        "up to 20 deg, with every dot on the print in at least two views, and call %s for each of %d views",
        board.c_str(), p.board.square_m, srv_capture_.getService().c_str(), views_wanted_);
  }

  void imageCb(const sensor_msgs::ImageConstPtr& msg)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    image_ = msg;
  }

  // The latest image as the core wants it: mono8/mono16 as they are, any
  // colour or Bayer encoding as bgr8; false with the reason.
  static bool toCore(const sensor_msgs::ImageConstPtr& msg, cv::Mat* out, std::string* why)
  {
    try
    {
      const std::string& e = msg->encoding;
      if (e == "mono8" || e == "mono16" || e == "8UC1" || e == "16UC1")
        *out = cv_bridge::toCvShare(msg)->image.clone();
      else
        *out = cv_bridge::toCvCopy(msg, "bgr8")->image;
      return true;
    }
    catch (const std::exception& ex)
    {
      *why = "cannot convert the image (" + msg->encoding + "): " + ex.what();
      return false;
    }
  }

  bool captureBoardCb(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res)
  {
    std::lock_guard<std::mutex> serial(capture_mutex_);  // one capture at a time
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CameraInfoConstPtr info;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      image = image_;
      info = info_;
    }
    res.success = false;
    CameraModel camera;
    cv::Mat mat;
    std::string why;
    if (board_views_.size() >= static_cast<size_t>(views_wanted_) && done_)
      res.message = "all views are captured; restart to calibrate again";
    else if (!image || !info)
      res.message = "no image and camera_info received yet on camera/image_raw, camera/camera_info";
    else if (last_stamp_ == image->header.stamp)
      res.message = "no new image since the last capture";
    else if (!cameraModelFromInfo(*info, &camera, &why))
      res.message = "unusable camera_info: " + why;
    else if (!toCore(image, &mat, &why))
      res.message = why;
    if (!res.message.empty())
      return true;
    last_stamp_ = image->header.stamp;
    guarded([&] { addBoardView(camera, mat, &res); });
    return true;
  }

  void addBoardView(const CameraModel& camera, const cv::Mat& image, std_srvs::Trigger::Response* res)
  {
    const std::string name = "capture " + std::to_string(captures_++);
    if (!views_dir_.empty())
      cv::imwrite(views_dir_ + "/view_" + std::to_string(captures_ - 1) + ".png", image);
    ChessboardView view = analyseChessboardView(image, name, camera, board_params_);
    std::ostringstream msg;
    if (!view.usable)
    {
      msg << name << " refused: " << view.why;
      res->message = msg.str();
      NODELET_WARN("ProjectorCalibrator: %s", res->message.c_str());
      return;
    }
    msg << name << ": board found, " << view.grid.count << " of " << board_params_.rows * board_params_.cols
        << " dots on the print" << (view.offset_known ? "" : " (not the whole pattern: numbered from the others)");
    board_views_.push_back(std::move(view));
    msg << "; " << board_views_.size() << " of " << views_wanted_ << " views";
    res->success = true;
    res->message = msg.str();
    NODELET_INFO("ProjectorCalibrator: %s", res->message.c_str());
    if (board_views_.size() >= static_cast<size_t>(views_wanted_))
      finishBoards(camera);
  }

  void finishBoards(const CameraModel& camera)
  {
    const ChessboardCalibrationResult cal = calibrateFromChessboardViews(camera, board_views_, board_params_);
    std_msgs::StringPtr report(new std_msgs::String);
    report->data = cal.report();
    std::string err;
    const std::string png = output_.substr(0, output_.rfind('.')) + ".png";
    if (!cv::imwrite(png, drawCalibrationReport(cal, board_params_.board)))
      report->data += "cannot write the PNG report " + png + "\n";
    if (cal.ok && !saveProjectorCalibration(output_, cal.fit.calibration, &err))
      report->data += "writing failed: " + err + "\n";
    else if (cal.ok)
      report->data += "written to " + output_ + " and " + png + "\n";
    done_ = cal.ok;
    if (!cal.ok)
    {
      // Keep the usable views: the operator may add more.
      views_wanted_ = static_cast<int>(board_views_.size()) + 1;
      report->data += "capture another view to try again\n";
    }
    NODELET_INFO("ProjectorCalibrator:\n%s", report->data.c_str());
    pub_report_.publish(report);
  }

  // ---- Distances mode.

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

  // Chessboard mode: captureBoardCb runs the analysis under capture_mutex_
  // (captures one at a time), outside mutex_ (the image callback's).
  std::mutex capture_mutex_;
  ChessboardCalibrationParams board_params_;
  int views_wanted_ = 6;
  int captures_ = 0;
  bool done_ = false;
  std::vector<ChessboardView> board_views_;
  ros::Time last_stamp_;
  sensor_msgs::ImageConstPtr image_;  // latest, under mutex_
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Subscriber sub_image_;

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
