// The rock's own texture as constraints on the camera pose, ROS-free: the
// texture half of PoseDeltaEstimator (docs/pose_delta.md).
//
// Contract: when the reference is locked, features are chosen in its image
// away from the dots (texture_tracker.h; anywhere in an ambient frame without
// dots) and lifted to 3D in the reference camera frame (metres): onto the
// reference surface where a feature's ray meets it, otherwise onto the
// least-squares plane of the reference points with a loose depth prior that
// the registration refines. In each frame the
// features are predicted from a pose (p_cur = T * p_ref), tracked, and
// returned as TextureConstraints (undistorted normalised coordinates).
// Not thread-safe (one estimator's state); throws nothing.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/pose/beam_surface.h"
#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/pose/pose_delta_params.h"
#include "structured_light_stabilizer/pose/registration.h"
#include "structured_light_stabilizer/pose/texture_tracker.h"

namespace structured_light_stabilizer
{

// Pixels of the usable points of a beam map (NaN and points behind the
// camera skipped): where the dots are in the image.
std::vector<cv::Point2f> projectPoints(const CameraModel& camera, const std::vector<Eigen::Vector3d>& points);

// How an image relates to the beam map it comes with.
struct TextureExposure
{
  // p_image = offset * p_points: the ambient (projector-off) frame of a
  // strobed pair is exposed at another instant than the frame with the dots.
  Eigen::Isometry3d offset = Eigen::Isometry3d::Identity();
  bool dots_in_image = true;  // false for an ambient frame: no dot to mask
};

class TextureLandmarks
{
public:
  // Chooses and lifts the features of the reference `image` (8-bit; its
  // `channel` when it has three) whose beam map is `points` with `surface`
  // built on it; `camera` must match the image. Nothing to track when the
  // map has no dot in the image.
  void lock(const PoseDeltaParams& config, const CameraModel& camera, const cv::Mat& image, int channel,
            const std::vector<Eigen::Vector3d>& points, const BeamSurface& surface,
            const TextureExposure& exposure = TextureExposure());
  // No reference image any more.
  void clear();
  // Forgets the features (they were lifted with other intrinsics); the
  // reference still had an image.
  void dropFeatures();

  bool hasReferenceImage() const { return has_image_; }
  bool empty() const { return tracker_.empty(); }

  // Starts a frame: its image and beam map (the dots' windows are masked
  // when the dots are in the image). False when the image cannot be tracked
  // (see TextureTracker::setFrame).
  bool setFrame(const CameraModel& camera, const cv::Mat& image, int channel,
                const std::vector<Eigen::Vector3d>& points, bool dots_in_image = true);
  // Features predicted at T and tracked over the pyramid (a wide capture
  // range): about kCoarseFeatures of them spread over the list, or all.
  std::vector<TextureConstraint> trackCoarse(const Eigen::Isometry3d& T);
  std::vector<TextureConstraint> trackAll(const Eigen::Isometry3d& T);
  // Every feature refined with gain and offset from where T predicts it
  // (needs a prediction within about a pixel): the measurement.
  std::vector<TextureConstraint> refineAll(const Eigen::Isometry3d& T) const;

  // Two exposures bracketing the instant of the beam map (the ambient frames
  // before and after a strobed frame with dots; no dot in either): each
  // feature refined in both, from where T_first and T_second predict it,
  // and taken at `fraction` of the way from the first position to the
  // second (the instant's share of the gap). No velocity is needed: over a
  // 60 Hz field the rig's velocity barely changes, and the second exposure
  // is predicted from the first by a few features tracked over the pyramid.
  // Replaces setFrame().
  std::vector<TextureConstraint> refineBetween(const Eigen::Isometry3d& T_first, const Eigen::Isometry3d& T_second,
                                               const cv::Mat& first, const cv::Mat& second, int channel,
                                               double fraction);
  // After lock() on the first of two such exposures: each feature is lifted
  // again where it was at `fraction` of the way to the second (features
  // lost in the second are dropped). `points` and `surface` are the lock's.
  void centreBetween(const cv::Mat& second, int channel, double fraction, const CameraModel& camera,
                     const std::vector<Eigen::Vector3d>& points, const BeamSurface& surface,
                     const PoseDeltaParams& config);

  // The reference surface was refined (the same rock, the same reference
  // frame): each feature lifted on it again where its ray meets it (the
  // others keep their depth). Features of an image exposed away from the
  // points (a strobed ambient frame with a velocity offset) are kept.
  void relift(const BeamSurface& surface, const PoseDeltaParams& config);
  // Constraints of earlier frames take their features' current 3D points.
  void update(std::vector<TextureConstraint>* constraints) const;
  // The lock period's frames saw each feature from other poses (frame j at
  // poses[j], its image exposed at frames[j].offset * poses[j]): its depth
  // along its ray fitted to them and to its prior (the parallax of the
  // rig's motion), its 1-sigma becoming the fit's, the measured
  // covariances inflated by `inflation` (the features' errors are
  // correlated). Features of an image exposed away from the points are kept.
  void refineDepths(const std::vector<TextureObservations>& frames, const std::vector<Eigen::Isometry3d>& poses,
                    double inflation);

private:
  // How many features trackCoarse() tracks: enough to fix the in-plane axes
  // for a prediction, at a fraction of the cost of all.
  static constexpr size_t kCoarseFeatures = 48;

  // Pixels of the features at T and, with `warps`, the local linear map of
  // each feature's window (its patch of rock taken as the plane through its
  // point with its normal).
  std::vector<cv::Point2f> predict(const Eigen::Isometry3d& T, std::vector<cv::Matx22d>* warps = nullptr) const;
  // Every feature refined from where T predicts it, per feature.
  struct Refined
  {
    std::vector<cv::Point2f> tracked;
    std::vector<uint8_t> ok;
    std::vector<cv::Matx22d> covariance;
  };
  Refined refine(const Eigen::Isometry3d& T) const;
  Refined refineFrom(const Refined& first, const Eigen::Isometry3d& T);
  // The tracked features as constraints; with `covariance` (px^2, per
  // feature) each carries its measured covariance.
  std::vector<TextureConstraint> constraints(const std::vector<cv::Point2f>& tracked, const std::vector<uint8_t>& ok,
                                             const std::vector<cv::Matx22d>* covariance = nullptr) const;
  std::vector<TextureConstraint> trackPyramidal(const Eigen::Isometry3d& T, const std::vector<uint8_t>& which);

  // The image the tracker reads: `image` itself, or with
  // PoseDeltaParams::texture_flat_field its `*channel` over the lens's
  // natural vignetting (a 16-bit copy, brightest corner unchanged); then
  // *channel is 0.
  cv::Mat trackedImage(const cv::Mat& image, int* channel) const;

  TextureTracker tracker_;
  cv::Mat flat_field_gain_;               // CV_32F, per pixel; empty: no flat field
  std::vector<Eigen::Vector3d> points_;   // the features lifted to 3D, reference camera frame
  std::vector<Eigen::Vector3d> normals_;  // of the rock at each feature (reference surface or plane)
  std::vector<double> depth_sigma_;       // 1-sigma of each feature's depth (0 = fixed)
  // Where each feature was lifted and its 1-sigma then: refineDepths()'s prior.
  std::vector<Eigen::Vector3d> lifted_points_;
  std::vector<double> lifted_sigma_;
  bool lifted_at_points_ = true;          // the features were lifted at the instant of the points
  bool has_image_ = false;
  // The frame being tracked.
  CameraModel camera_;
  std::vector<cv::Point2f> dots_;
};

}  // namespace structured_light_stabilizer
