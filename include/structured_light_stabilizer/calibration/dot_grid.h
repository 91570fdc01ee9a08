// Beam identification on a flat board from the pattern's neighbourhood
// graph (not the study's row sort), ROS-free.
//
// The projector's beams form a grid; on a flat board (one plane) their dots
// form the image of that grid under a smooth map, locally affine. Starting
// from a dot whose four neighbours are where a grid predicts, the labelling
// grows from labelled dots to their grid neighbours (one or two sites away,
// so a missing dot does not stop it), each site predicted by a local affine
// fit of the labelled dots around it and taken by the nearest dot within a
// tolerance. Spots that fit no site (a reflection, a speck) stay unlabelled;
// a labelled dot that its neighbours' fit contradicts is unlabelled again.
// Dots missing anywhere or beyond the board are simply absent sites.
//
// The labels are relative: (row, col) up to a common offset. +col runs
// along the image's +x and +row along +y, so the projector's grid must not
// be rolled by more than 45 degrees in the image (beam = row * cols + col as
// in projector_calibration.h). When the labelled extent equals the
// pattern's size the offset is known; otherwise the calibration resolves it
// from the other views (chessboard_calibration.h).
//
// Input positions are in any image where the pattern is locally affine
// (the undistorted image is best). Reentrant.
#pragma once

#include <vector>

#include <Eigen/Core>

namespace structured_light_stabilizer
{

struct DotGridParams
{
  // A dot may lie this fraction of the local grid step away from its
  // predicted site (the rest of a step is left for the neighbours).
  double tolerance = 0.3;
  // Once the labelled dots' spread about their neighbours' fit is known,
  // the tolerance becomes 6 times that spread (never below this, px).
  double min_tolerance_px = 1.5;
};

struct DotGrid
{
  std::vector<char> labelled;  // per input point
  std::vector<int> row, col;   // per input point, relative labels (valid where labelled)
  int min_row = 0, max_row = -1, min_col = 0, max_col = -1;
  int count = 0;          // labelled points
  double pitch_px = 0.0;  // median step between neighbouring labelled dots

  int rowSpan() const { return count > 0 ? max_row - min_row + 1 : 0; }
  int colSpan() const { return count > 0 ? max_col - min_col + 1 : 0; }
};

DotGrid labelDotGrid(const std::vector<Eigen::Vector2d>& points, const DotGridParams& params = DotGridParams());

}  // namespace structured_light_stabilizer
