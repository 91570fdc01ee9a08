// Registration of a beam map against the reference rock surface, ROS-free:
// the Gauss-Newton solver behind PoseDeltaEstimator (docs/pose_delta.md),
// exposed for tests and tools.
//
// Contract: the unknown is T with p_cur = T * p_ref (metres, camera optical
// frames), found by increments on the current-frame side (se3.h). Two kinds
// of residual go into one set of normal equations:
//  - geometry: the point-to-plane distance (metres) of each `current` point
//    to `reference_surface` and, when `current_surface` is given, of each
//    `reference` point to it; Huber weights on the robust (MAD) scale;
//  - texture: the reprojection error (pixels, scaled by focal_px) of
//    reference texture points observed in the current image, whitened by
//    each feature's measured covariance (when it has one); Huber, then
//    Tukey's biweight once the pose settles, on the robust scale.
// A weak prior towards `initial` keeps unobservable directions put, and a
// direction whose 1-sigma exceeds freeze_factor times the validity bounds is
// not updated at all (it stays at `initial`). Points that are NaN or behind
// the camera are skipped. A pure function: thread-safe, throws nothing.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/pose/beam_surface.h"
#include "structured_light_stabilizer/pose/pose_delta_params.h"
#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

// One tracked texture feature: its reference 3D point and its observed
// undistorted normalised coordinates in the current image. Its depth along
// the reference ray is an unknown of the solve when depth_sigma_m > 0
// (point_ref is then its prior, with this 1-sigma), fixed at point_ref
// otherwise. Free depths let features far from the dots, whose depth is only
// extrapolated, still separate rotation from translation.
struct TextureConstraint
{
  Eigen::Vector3d point_ref;
  Eigen::Vector2d observed_normalized;
  double depth_sigma_m = 0.0;
  // Measured covariance of the observation (pixels^2, scaled by focal_px);
  // zero = unknown (the robust scale of all features alone weights it).
  Eigen::Matrix2d covariance_px = Eigen::Matrix2d::Zero();
  int landmark = -1;  // the reference feature it observes (TextureLandmarks' index), -1 = none
};

// A frame's texture constraints. The image they come from was exposed at the
// pose offset * T (T the pose of the points): the ambient frame of a strobed
// pair is exposed before or after the frame with the dots, and the rig moves
// in between (offset = identity for the same exposure).
struct TextureObservations
{
  std::vector<TextureConstraint> constraints;
  double focal_px = 1.0;  // pixels per unit of normalised coordinate
  Eigen::Isometry3d offset = Eigen::Isometry3d::Identity();
};

struct RegistrationOutput
{
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  Matrix6d information = Matrix6d::Zero();  // J^T W J with noise-scaled weights (texture deflated), no prior
  Matrix6d covariance = Matrix6d::Identity();
  double rms_geometry_m = 0.0;
  double sigma_geometry_m = 0.0;
  double sigma_texture_px = 0.0;
  int points_used = 0;  // current points with a foot on the reference surface
  int features_used = 0;
  int iterations = 0;
};

// Reads from `config`: max_iterations, huber_k, the noise floors, the prior
// sigmas, the validity sigmas with freeze_factor, and texture_error_inflation.
RegistrationOutput registerToSurface(const BeamSurface& reference_surface,
                                     const std::vector<Eigen::Vector3d>& reference, const BeamSurface* current_surface,
                                     const std::vector<Eigen::Vector3d>& current, const TextureObservations& texture,
                                     const Eigen::Isometry3d& initial, const PoseDeltaParams& config);

}  // namespace structured_light_stabilizer
