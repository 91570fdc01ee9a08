// Projector calibration from chessboard views at any tilt (
// docs/calibration.md), ROS-free: the procedure behind the
// calibrate_projector tool and calibrate.launch's chessboard mode.
//
// Per view (analyseChessboardView): the board's corners and pose in the
// channel with the least projector light (chessboard.h), the dots on the
// print fitted with the albedo under them (board_dots.h), corners near a
// dot dropped (a dot's light biases a corner) and the pose refined without
// them, the dots labelled by the pattern's neighbourhood graph (dot_grid.h).
// A view whose labelled dots span the whole pattern fixes its beam numbers;
// the others get the offset whose rays meet best with the views already
// numbered (and are skipped, with the reason, when no offset is clearly
// best). Then every view at once (projector_joint_fit.h).
//
// Images: 8- or 16-bit, 1 channel (a monochrome camera) or 3 / 4 channels in
// BGR(A) order, of the camera's size; distorted (the CameraModel of the
// camera's calibration, any of its distortion models). Reentrant.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/board_dots.h"
#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/chessboard.h"
#include "structured_light_stabilizer/calibration/dot_grid.h"
#include "structured_light_stabilizer/calibration/projector_joint_fit.h"

namespace structured_light_stabilizer
{

struct ChessboardCalibrationParams
{
  BoardParams board;
  int rows = 10;  // the projector's pattern
  int cols = 10;
  // Channels of a colour image (BGR order): where the dots are, and where
  // the board is read with the least dot light. -1: the grey image.
  int dot_channel = 1;
  int board_channel = 2;
  BoardDotParams dots;
  DotGridParams grid;
  JointFitParams fit;
  int min_dots = 8;  // a view with fewer labelled dots is not used
  // A view's pattern offset is taken when the next best offset's rays meet
  // this many times worse.
  double offset_margin = 3.0;

  std::string validate() const;
};

// The channels for a projector colour ("green", "red", "blue", "nir",
// "white"); false for an unknown name.
bool channelsForProjectorColor(const std::string& color, int* dot_channel, int* board_channel);

struct ChessboardView
{
  std::string name;
  bool usable = false;
  std::string why;  // why not usable, or why skipped in the calibration
  ChessboardDetection board;
  BoardDotReport dot_report;
  std::vector<BoardDot> dots;          // on the print
  DotGrid grid;                        // their labels (relative)
  int corners_near_dots = 0;           // corners not used: a dot within reach of their window
  bool offset_known = false;           // the beam numbers are fixed
  int row_offset = 0, col_offset = 0;  // beam = (row + row_offset) * cols + col + col_offset
  bool used = false;                   // in the joint fit

  // Beam of dot k (-1: unlabelled or the offset is not known).
  int beamOf(size_t k, int cols) const
  {
    return offset_known && grid.labelled[k] ? (grid.row[k] + row_offset) * cols + grid.col[k] + col_offset : -1;
  }
};

ChessboardView analyseChessboardView(const cv::Mat& image, const std::string& name, const CameraModel& camera,
                                     const ChessboardCalibrationParams& params);

enum class CalibrationFailure
{
  kNone,
  kBadInput,     // params or camera unusable
  kTooFewViews,  // fewer than two views with a board and dots
  kNoFullView,   // no view shows the whole pattern, so no beam numbers
  kBeamNotSeen,  // a beam in fewer than two views
  kFitFailed,
};

struct ChessboardCalibrationResult
{
  bool ok = false;
  CalibrationFailure failure = CalibrationFailure::kNone;
  std::string error;
  std::vector<ChessboardView> views;  // every view, with its status
  JointFitResult fit;                 // indices of fit.views follow the used views in order
  std::vector<int> fit_views;         // view index of each fitted view

  // The per-view and per-beam tables and the summary.
  std::string report() const;
};

ChessboardCalibrationResult calibrateFromChessboardViews(const CameraModel& camera, std::vector<ChessboardView> views,
                                                         const ChessboardCalibrationParams& params);

// The report as a picture (bgr8, 1240 x 620): the RMS residual of every
// beam at its place in the pattern, and the fitted rays with the boards
// seen from above; a failed calibration gives its error.
cv::Mat drawCalibrationReport(const ChessboardCalibrationResult& result, const BoardParams& board);

}  // namespace structured_light_stabilizer
