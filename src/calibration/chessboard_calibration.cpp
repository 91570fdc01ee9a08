#include "structured_light_stabilizer/calibration/chessboard_calibration.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "calibration/calibration_geometry.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

// One channel of the image (or its grey level), and the clipping level.
cv::Mat channelOf(const cv::Mat& image, int channel)
{
  if (image.channels() == 1)
    return image;
  if (channel < 0 || channel >= image.channels())
  {
    cv::Mat grey;
    cv::cvtColor(image, grey, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
    return grey;
  }
  cv::Mat out;
  cv::extractChannel(image, out, channel);
  return out;
}

double fullScale(const cv::Mat& image)
{
  return image.depth() == CV_16U ? 65535.0 : 255.0;
}

std::string checkImage(const cv::Mat& image, const CameraModel& camera)
{
  if (image.empty())
    return "the image is empty or unreadable";
  if (image.depth() != CV_8U && image.depth() != CV_16U)
    return "the image must be 8- or 16-bit";
  if (image.channels() != 1 && image.channels() != 3 && image.channels() != 4)
    return "the image must have 1, 3 or 4 channels";
  if (image.cols != camera.width || image.rows != camera.height)
    return "the image is " + std::to_string(image.cols) + "x" + std::to_string(image.rows) + ", the camera_info " +
           std::to_string(camera.width) + "x" + std::to_string(camera.height);
  return "";
}

// Corners whose refinement window a dot's light reaches are not used (a
// bright spot inside the window pulls the corner).
int dropCornersNearDots(const std::vector<BoardDot>& dots, ChessboardDetection* det)
{
  int dropped = 0;
  for (size_t k = 0; k < det->corners.size(); ++k)
  {
    const double reach = det->corner_window_px + 1.0;
    for (const BoardDot& d : dots)
    {
      const double r = reach + 3.0 * d.sigma_px;
      if (std::abs(d.x - det->corners[k].x) < r && std::abs(d.y - det->corners[k].y) < r)
      {
        dropped += det->corner_used[k] ? 1 : 0;
        det->corner_used[k] = 0;
        break;
      }
    }
  }
  return dropped;
}

// Undistorted pixels of the dots, where the pattern is a projective image
// of the grid.
std::vector<Eigen::Vector2d> undistortedDots(const CameraModel& camera, const std::vector<BoardDot>& dots)
{
  std::vector<Eigen::Vector2d> out;
  for (const BoardDot& d : dots)
  {
    const Eigen::Vector2d n = camera.normalize(cv::Point2d(d.x, d.y));
    out.emplace_back(camera.fx * n.x() + camera.cx, camera.fy * n.y() + camera.cy);
  }
  return out;
}

void labelView(const CameraModel& camera, const ChessboardCalibrationParams& params, ChessboardView* view)
{
  view->grid = labelDotGrid(undistortedDots(camera, view->dots), params.grid);
  const DotGrid& g = view->grid;
  std::ostringstream why;
  if (g.rowSpan() > params.rows || g.colSpan() > params.cols)
    why << "its dots form a " << g.rowSpan() << " x " << g.colSpan() << " grid, larger than the pattern's "
        << params.rows << " x " << params.cols << " (--rows/--cols?)";
  else if (g.count < params.min_dots)
    why << "only " << g.count << " dots on the board form the pattern's grid (" << params.min_dots << " needed)";
  view->why = why.str();
  view->usable = view->why.empty();
  view->offset_known = view->usable && g.rowSpan() == params.rows && g.colSpan() == params.cols;
  if (view->offset_known)
  {
    view->row_offset = -g.min_row;
    view->col_offset = -g.min_col;
  }
}

}  // namespace

std::string ChessboardCalibrationParams::validate() const
{
  std::string why = board.validate();
  if (why.empty())
    why = dots.validate();
  if (why.empty())
    why = fit.validate();
  if (why.empty() && (rows < 2 || cols < 2))
    why = "the pattern needs at least 2 x 2 beams (--rows, --cols)";
  if (why.empty() && !(offset_margin > 1.0))
    why = "offset_margin must be > 1";
  return why;
}

bool channelsForProjectorColor(const std::string& color, int* dot_channel, int* board_channel)
{
  static const std::map<std::string, std::pair<int, int>> table = {
      {"green", {1, 2}}, {"red", {2, 0}}, {"blue", {0, 2}}, {"nir", {-1, -1}}, {"white", {-1, -1}}};
  const auto it = table.find(color);
  if (it == table.end())
    return false;
  *dot_channel = it->second.first;
  *board_channel = it->second.second;
  return true;
}

ChessboardView analyseChessboardView(const cv::Mat& image, const std::string& name, const CameraModel& camera,
                                     const ChessboardCalibrationParams& params)
{
  ChessboardView view;
  view.name = name;
  view.why = checkImage(image, camera);
  if (!view.why.empty())
    return view;
  cv::Mat board8 = channelOf(image, params.board_channel);
  if (board8.depth() == CV_16U)
    board8.convertTo(board8, CV_8U, 255.0 / 65535.0);
  view.board = detectChessboard(board8, camera, params.board);
  if (!view.board.found)
  {
    view.why = view.board.why;
    return view;
  }
  const cv::Mat dot_img = channelOf(image, params.dot_channel);
  // Scale the board's levels to the dot channel's full scale (16-bit images).
  ChessboardDetection det = view.board;
  det.white_level *= fullScale(image) / 255.0;
  det.black_level *= fullScale(image) / 255.0;
  view.dots = findBoardDots(dot_img, fullScale(image), camera, params.board, det, params.dots, &view.dot_report);
  // Without the corners a dot may have pulled, the pose moves a little; the
  // dots are fitted again on the moved albedo when it moved by more than a
  // hundredth of a pixel.
  view.corners_near_dots = dropCornersNearDots(view.dots, &view.board);
  Eigen::Isometry3d pose = view.board.pose;
  double rms = 0.0;
  if (view.corners_near_dots > 0 &&
      refineBoardPose(camera, params.board, view.board.corners, view.board.corner_used, &pose, &rms))
  {
    double moved = 0.0;
    for (int k = 0; k < params.board.cornerCount(); ++k)
      moved = std::max(moved, cv::norm(camera.project(pose * params.board.corner(k)) -
                                       camera.project(view.board.pose * params.board.corner(k))));
    view.board.pose = pose;
    view.board.corner_rms_px = rms;
    det.pose = pose;
    if (moved > 0.01)
      view.dots = refitBoardDots(dot_img, fullScale(image), camera, params.board, det, params.dots, view.dots,
                                 &view.dot_report);
  }
  labelView(camera, params, &view);
  return view;
}

}  // namespace structured_light_stabilizer
