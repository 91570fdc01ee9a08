// The rig as the Triangulator's beam identification sees it (not a public
// API: names may change without notice; see triangulator.h for the contract).
//
// Everything here is in the UNDISTORTED image (pixel = fx * x/z + cx,
// fy * y/z + cy of the camera optical frame) and in metres in the camera
// optical frame. Beams are row-major (beam = r * cols + c). Immutable after
// construction, so const use from several threads is safe.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"

namespace structured_light_stabilizer
{

// Image of each beam between two depths, in undistorted pixel coordinates
// (fx * x/z + cx, fy * y/z + cy).
struct EpipolarSegment
{
  Eigen::Vector2d near_px = Eigen::Vector2d::Zero();  // at min_depth
  Eigen::Vector2d far_px = Eigen::Vector2d::Zero();   // at max_depth
};

namespace detail
{

class BeamGeometry
{
public:
  // The camera and projector must be valid (validate() empty) and
  // 0 < min_depth < max_depth; the Triangulator checks them first.
  // `prediction_tolerance_px` sets the smoothness scale of a pattern
  // without neighbouring beams (twice the tolerance).
  BeamGeometry(const CameraModel& camera, const ProjectorCalibration& projector, double min_depth, double max_depth,
               double prediction_tolerance_px);

  const CameraModel& camera() const { return camera_; }
  const ProjectorCalibration& projector() const { return projector_; }
  int rows() const { return projector_.rows; }
  int cols() const { return projector_.cols; }
  int beamCount() const { return projector_.beamCount(); }
  const std::vector<EpipolarSegment>& segments() const { return segments_; }
  // Median image distance between the segment midpoints of neighbouring
  // beams (0 for a single beam).
  double beamPitchPx() const { return beam_pitch_px_; }

  // Squared distance (px^2) of an undistorted pixel to the epipolar segment of `beam`.
  double segmentDistance2(int beam, const Eigen::Vector2d& px) const;
  // Undistorted pixel of a camera-frame point (z > 0 expected).
  Eigen::Vector2d projectUndistorted(const Eigen::Vector3d& p) const;
  // Undistorted pixel of a distorted pixel (NaN in, NaN out).
  Eigen::Vector2d undistortPixel(double x, double y) const;
  // Camera ray through an undistorted pixel, as (x/z, y/z, 1).
  Eigen::Vector3d cameraRay(const Eigen::Vector2d& px) const;
  // Undistorted pixel where `beam` reaches the camera depth z.
  Eigen::Vector2d pixelAtDepth(int beam, double z) const;
  // Point of `beam` for an undistorted spot pixel; false when the rays are parallel.
  bool triangulatePixel(int beam, const Eigen::Vector2d& px, Eigen::Vector3d* p) const;

  // Smoothness cost (0..1) between the dot of `beam` at pixel `px` and a
  // grid neighbour's point `q` (8-neighbourhood): squared distance, in units
  // of half the beam pitch in the image, between px and where the beam would
  // be at q's depth, capped at 1 (a depth edge costs as much as a missing
  // dot; a dot read as its neighbour's, shifted by one pitch, costs the cap).
  double smoothnessCost(int beam, const Eigen::Vector2d& px, const Eigen::Vector3d& q) const;
  // The smoothness scale (px): half the beam pitch, see the constructor.
  double smoothnessScalePx() const { return smoothness_scale_px_; }

  // Undistorted pixel where `beam` meets the plane through the `support`
  // points (or the fronto-parallel plane at their mean depth when they span
  // no plane); false if none.
  bool predictPixel(int beam, const std::vector<Eigen::Vector3d>& support, Eigen::Vector2d* px) const;

  // The 8-neighbourhood of a beam in the grid, row by row (-1 outside).
  void neighbours(int beam, int out[8]) const;

private:
  CameraModel camera_;
  ProjectorCalibration projector_;
  std::vector<EpipolarSegment> segments_;
  double beam_pitch_px_ = 0.0;
  double smoothness_scale_px_ = 10.0;
};

}  // namespace detail
}  // namespace structured_light_stabilizer
