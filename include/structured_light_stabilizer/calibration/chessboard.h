// A printed chessboard: its corners in an image, its pose, and the albedo it
// puts under every pixel. ROS-free.
//
// Contract: the board follows OpenCV's inner-corner convention: `cols` x
// `rows` inner corners (cv::Size(cols, rows)), squares of `square_m` metres,
// so (cols + 1) x (rows + 1) squares, plus a printed white margin of
// `margin_m` around them. Board frame: origin at the first inner corner of
// OpenCV's corner order, x along a corner row, y to the next row, z = x cross
// y (into the board, away from the camera), metres. Corner k sits at
// ((k % cols) * square_m, (k / cols) * square_m, 0). Pixels follow the
// CameraModel (distorted, OpenCV convention); the pose maps board points into
// the camera optical frame: p_camera = pose * p_board. Every distortion model
// of CameraModel is honoured (the pose is refined on distorted pixels
// through CameraModel::project).
//
// A board with an odd number of squares both ways (e.g. 10 x 8 inner
// corners) looks the same turned by 180 degrees, so OpenCV may number its
// corners from either end; the plane and the albedo are the same either way,
// and that is all the projector calibration needs. The colour of square
// (0, 0) (between corners 0, 1, cols, cols + 1) is measured from the image.
// Functions are reentrant (no shared state).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"

namespace structured_light_stabilizer
{

struct BoardParams
{
  int cols = 10;           // inner corners along a row (OpenCV patternSize.width)
  int rows = 8;            // inner corners along a column (patternSize.height)
  double square_m = 0.08;  // side of a square, metres
  // Printed white margin around the outer squares that dots may use
  // (metres); beyond it the albedo is unknown and dots there are not used.
  double margin_m = 0.0;

  // Empty when usable, otherwise why not.
  std::string validate() const;
  // Board coordinates (metres) of inner corner k.
  Eigen::Vector3d corner(int k) const { return Eigen::Vector3d((k % cols) * square_m, (k / cols) * square_m, 0.0); }
  int cornerCount() const { return cols * rows; }
};

// Parses "COLSxROWS" (e.g. "10x8"); false when malformed.
bool parseBoardSize(const std::string& text, int* cols, int* rows);

struct ChessboardDetection
{
  bool found = false;
  std::string why;                   // why not found (empty when found)
  std::vector<cv::Point2d> corners;  // distorted px, OpenCV order (row-major)
  std::vector<char> corner_used;     // per corner: used by the pose (0 = dropped, e.g. a dot next to it)
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // board -> camera optical frame
  double corner_rms_px = 0.0;                              // RMS reprojection residual of the used corners
  bool square00_white = true;                              // colour of square (0, 0), measured
  double white_level = 0.0;  // median of the white squares' centres in the board image (DN)
  double black_level = 0.0;  // same for the black squares
  int corner_window_px = 0;  // half-size of the sub-pixel refinement window
};

// Finds the chessboard in an 8-bit one-channel image (the channel with the
// least projector light: red for green dots), refines the corners to
// sub-pixel, estimates the pose and measures the square colours. found =
// false with `why` when there is no board, when it is cut by the image edge
// or when the pose is degenerate.
ChessboardDetection detectChessboard(const cv::Mat& board_image, const CameraModel& camera, const BoardParams& params);

// Pose of the board from its corners (distorted px) by Levenberg-Marquardt
// on the reprojection error, starting from *pose (identity: from a planar
// PnP on the undistorted corners). Corners with used[k] == 0 are ignored.
// Returns false when fewer than 4 corners are usable or the fit diverges.
bool refineBoardPose(const CameraModel& camera, const BoardParams& params, const std::vector<cv::Point2d>& corners,
                     const std::vector<char>& used, Eigen::Isometry3d* pose, double* rms_px);

// Reflectance of the board at board coordinates (x, y) metres: 1 on white,
// `black_ratio` on black, 1 on the margin, NaN beyond it.
double boardAlbedo(const BoardParams& params, bool square00_white, double black_ratio, double x, double y);

// The board's albedo under every pixel of the image (CV_32F, `size`): the
// mean of boardAlbedo over the pixel's footprint (pixels crossed by a square
// edge are sampled `edge_samples` x `edge_samples` times), NaN where any
// part of the pixel lies beyond the board (margin included). This is what a
// flat-lit board would show before the lens blur, white = 1.
cv::Mat renderBoardAlbedo(const CameraModel& camera, const BoardParams& params, const Eigen::Isometry3d& pose,
                          bool square00_white, double black_ratio, const cv::Size& size, int edge_samples = 16);

// The same over the pixels of `rect` divided `subsample` times per pixel:
// CV_32F of rect.size() * subsample, cell (i, j) covering pixel coordinates
// [rect.x - 0.5 + i / subsample, ... + 1 / subsample) likewise in y.
cv::Mat renderBoardAlbedoWindow(const CameraModel& camera, const BoardParams& params, const Eigen::Isometry3d& pose,
                                bool square00_white, double black_ratio, const cv::Rect& rect, int subsample,
                                int edge_samples = 16);

// Where the camera ray through a distorted pixel meets the board plane, in
// board coordinates (x, y); false when it misses (parallel or behind).
bool pixelToBoard(const CameraModel& camera, const Eigen::Isometry3d& pose, const cv::Point2d& pixel,
                  Eigen::Vector2d* board_xy);

}  // namespace structured_light_stabilizer
