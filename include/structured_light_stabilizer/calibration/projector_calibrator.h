// Projector calibration from views of a flat board ("adapted tools"), ROS-free.
//
// Contract: each view holds the distorted sub-pixel centroids of the dots on
// a flat board whose plane is known in the camera optical frame (metres):
// either the fronto-parallel plane z = distance_m, or a general plane
// n . p = offset. Spots carry their beam index (row-major) or -1; when every
// spot of a view is -1 and the view holds exactly rows * cols spots, the ids
// come from the study's row sort. Each dot is back-projected (camera model,
// undistorted) onto the board plane; each beam's ray is the least-squares 3D
// line through its board points (>= 2 views). The report gives, per beam, the
// RMS reprojection residual over the views (pixels; 0 with two views, where
// the line is exact), the distance of the beam from the projector's common
// centre (the least-squares point closest to all beams: a misidentified or
// badly detected dot shows up there even with two views), and a flag when
// either exceeds its threshold. The study's one-distance procedure
// (docs/study.md §3.3.1.1, §3.4 step 1: tan(alpha_i) = d/D - P_i Psize/f0)
// is calibrateFromOneBoard: the projector origin is known, one board view
// gives the directions.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/common/spot.h"

namespace structured_light_stabilizer
{

struct BoardView
{
  double distance_m = 0.0;                                 // used when plane_normal is zero: the plane z = distance_m
  Eigen::Vector3d plane_normal = Eigen::Vector3d::Zero();  // optional general plane n . p = plane_offset
  double plane_offset = 0.0;
  Spots spots;
};

struct BoardCalibrationParams
{
  int rows = 10;
  int cols = 10;
  double max_residual_px = 0.3;          // flag beams whose line misses their dots by more (RMS)
  double max_origin_distance_m = 0.005;  // flag beams passing farther from the common centre; <= 0 disables
};

struct BeamFit
{
  int views = 0;                   // board points used
  double residual_px = 0.0;        // RMS reprojection residual over the views
  double origin_distance_m = 0.0;  // distance from the common projector centre
  bool poor = false;
  std::string why;  // empty unless poor
};

struct BoardCalibrationResult
{
  bool ok = false;
  std::string error;  // why no calibration was produced
  ProjectorCalibration calibration;
  std::vector<BeamFit> beams;
  Eigen::Vector3d common_centre = Eigen::Vector3d::Zero();
  int poor_beams = 0;

  // Human-readable per-beam table and summary.
  std::string report() const;
};

// Fits every beam from >= 2 board views. Fails (ok = false) when a beam has
// fewer than two board points or a view is unusable; the error names it.
BoardCalibrationResult calibrateFromBoards(const CameraModel& camera, const std::vector<BoardView>& views,
                                           const BoardCalibrationParams& params);

// The study's one-distance procedure with a known projector origin.
BoardCalibrationResult calibrateFromOneBoard(const CameraModel& camera, const BoardView& view,
                                             const Eigen::Vector3d& projector_origin,
                                             const BoardCalibrationParams& params);

// Spot files of the calibration tool: YAML with `distance` (or `plane:
// [nx, ny, nz, offset]`) and `spots: [[x, y, beam], ...]` (beam -1 = unknown).
bool loadBoardView(const std::string& path, BoardView* view, std::string* error);
bool saveBoardView(const std::string& path, const BoardView& view, std::string* error);

// Camera intrinsics from a camera_info_manager YAML (image_width,
// image_height, camera_matrix.data, distortion_model, distortion_coefficients.data).
bool loadCameraModelYaml(const std::string& path, CameraModel* camera, std::string* error);

}  // namespace structured_light_stabilizer
