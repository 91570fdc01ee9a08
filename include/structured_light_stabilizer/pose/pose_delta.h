// Camera motion relative to a locked reference map of the rock, ROS-free.
//
// Contract: input per frame is the organised beam map (rows x cols points,
// camera optical frame, metres, NaN = no point; beam = r * cols + c) and,
// optionally, the camera image of the same instant (CV_8UC3 or CV_8UC1) with
// its CameraModel, its time stamp, and in strobed operation the projector-off
// frames around it. Output is the PoseDelta convention of docs/interface.md:
// the transform T with p_cur = T * p_ref for any rock point, a 6x6 covariance
// in the order (tx, ty, tz, rx, ry, rz) (metres, radians; a small rotation
// vector applied on the current-frame side, se3.h), the RMS point-to-surface
// residual in metres, the points used, a validity flag and a status string
// naming any unobservable axis. One estimator is not thread-safe; setParams()
// throws std::invalid_argument, nothing else throws on bad input (the result
// says why it is not valid).
//
// The physics (docs/pose_delta.md): the dots are fixed to the projector, so
// beam i hits a different rock point in every frame. The estimator therefore
// never pairs points by beam index. It registers the current points against
// a smooth surface interpolated through the reference map (beam_surface.h;
// and the reference points against the current surface), point-to-plane with
// robust weights; the rock's own texture, tracked over the whole image away
// from the dots and lifted to 3D on the reference surface (or, off the dot
// map, on a plane through it, with the depth left free; texture_landmarks.h),
// adds reprojection constraints that pin the axes a smooth or flat rock
// leaves free (in-plane translation, roll about the view axis), each weighted
// by its measured covariance (texture_tracker.h). Both go into one
// Gauss-Newton problem on se(3) (registration.h). A constant-velocity filter
// follows the motion (pose_filter.h); its pose is the output only when asked.
#pragma once

#include <array>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/pose/beam_surface.h"
#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/pose/pose_delta_params.h"
#include "structured_light_stabilizer/pose/pose_filter.h"
#include "structured_light_stabilizer/pose/registration.h"
#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

// One frame for the estimator.
struct PoseDeltaInput
{
  int rows = 0;
  int cols = 0;
  std::vector<Eigen::Vector3d> points;  // rows * cols, camera frame, NaN = missing
  // Optional image of the same instant: CV_8UC1 or CV_16UC1, or CV_8UC3 or
  // CV_16UC3 whose channel `texture_channel` carries the rock texture with the
  // least dot light (the red channel for green dots: 2 in bgr8/bgr16, 0 in
  // rgb8/rgb16). 16-bit pixels are MSB-aligned (ROS's 16-bit encodings).
  cv::Mat image;
  int texture_channel = 2;
  // Time of the frame (seconds, one clock for the stream); NaN = unknown
  // (the filter then restarts at every frame).
  double stamp_s = std::numeric_limits<double>::quiet_NaN();
  // Optional projector-off (ambient) frames of strobed operation, same
  // camera and channel convention as `image`: the rock's texture without the
  // dots. When the reference is locked with one, the texture is tracked on
  // the ambient frames (nothing to mask). Best with both neighbours, one
  // exposed before and one after the points (ambient_stamp_s <= stamp_s <=
  // ambient_after_stamp_s): each feature is taken between its two positions,
  // which needs no velocity. With one, the rig's motion over the gap is its
  // velocity (from the last estimates) times the gap, which lags behind the
  // arm's jitter (about 0.05 deg on the simulator against 0.01 deg with both).
  cv::Mat ambient_image;
  double ambient_stamp_s = std::numeric_limits<double>::quiet_NaN();
  cv::Mat ambient_after_image;
  double ambient_after_stamp_s = std::numeric_limits<double>::quiet_NaN();
  // Read only when this frame becomes the reference (each optional):
  //  - lock_image: a projector-off exposure of the same instant (same
  //    conventions as `image`), without strobing: the reference texture is
  //    chosen in it (nothing masked, features on the dots too, where the
  //    surface is the triangulated depth); later frames are tracked in
  //    `image` as usual;
  //  - surface_points: a denser organised map of the same rock at the same
  //    instant (surface_rows x surface_cols, camera frame, NaN = missing,
  //    e.g. the true rock of a simulation) on which the reference surface is
  //    built instead of the beam map (the registration and the texture's
  //    depths use it; the beam map stays the reference points).
  cv::Mat lock_image;
  int surface_rows = 0;
  int surface_cols = 0;
  std::vector<Eigen::Vector3d> surface_points;
};

struct PoseDeltaResult
{
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();  // p_cur = T * p_ref
  Matrix6d covariance = Matrix6d::Identity();                   // (tx, ty, tz, rx, ry, rz)
  // The estimate of this frame alone; equal to transform and covariance
  // unless PoseDeltaParams::filter is on.
  Eigen::Isometry3d raw_transform = Eigen::Isometry3d::Identity();
  Matrix6d raw_covariance = Matrix6d::Identity();
  bool filtered = false;  // transform and covariance come from the filter
  double rms_residual_m = 0.0;
  int points_used = 0;
  int features_used = 0;          // texture constraints in the solution
  double sigma_geometry_m = 0.0;  // robust scale of the point-to-surface residuals
  double sigma_texture_px = 0.0;  // robust scale of the texture reprojection residuals
  int iterations = 0;
  bool valid = false;
  bool locked_now = false;             // this frame became the reference
  bool texture_from_motion = false;    // the texture was refined from the motion filter's prediction
  std::array<bool, 6> unobservable{};  // per axis, sigma beyond the validity bound
  std::string status;
};

class TextureLandmarks;

class PoseDeltaEstimator
{
public:
  explicit PoseDeltaEstimator(const PoseDeltaParams& config = PoseDeltaParams());
  ~PoseDeltaEstimator();

  // Throws std::invalid_argument with the reason when the config is unusable.
  void setParams(const PoseDeltaParams& config);
  const PoseDeltaParams& params() const { return config_; }

  // Needed for the texture part; without it the estimator uses geometry only.
  void setCamera(const CameraModel& camera);

  // The next frame with a usable map becomes the reference.
  void requestLock();
  // Forgets the reference; with lock_on_next_frame false nothing is locked
  // (and every frame reports so) until requestLock().
  void reset(bool lock_on_next_frame);
  bool hasReference() const { return has_reference_; }
  bool lockPending() const { return lock_pending_; }

  PoseDeltaResult process(const PoseDeltaInput& frame);

private:
  struct Frame;
  struct TextureMeasurement;

  // The steps of process(), in order. The first two return why the frame
  // cannot be used ("" when it can); referenceFor() locks a pending reference.
  std::string checkMap(const PoseDeltaInput& frame, int* valid_points) const;
  std::string referenceFor(const PoseDeltaInput& frame, PoseDeltaResult* result);
  // Image -> texture constraints; *initial becomes the best prediction of the pose.
  TextureMeasurement measureTexture(const PoseDeltaInput& frame, Eigen::Isometry3d* initial);
  // The refinement from the motion filter's prediction, when it is sure
  // enough (texture_motion_prediction_max_px) and keeps the features.
  bool refineFromMotion(const PoseDeltaInput& frame, const Eigen::Isometry3d& offset, Eigen::Isometry3d* initial,
                        std::vector<TextureConstraint>* tracked) const;
  RegistrationOutput registerFrame(const PoseDeltaInput& frame, const TextureMeasurement& texture,
                                   const Eigen::Isometry3d& initial) const;
  // Covariance (chained in frame_to_frame), per-axis observability, validity and status.
  void report(const RegistrationOutput& reg, const TextureMeasurement& texture, int valid_points,
              PoseDeltaResult* result) const;
  std::string describe(const PoseDeltaResult& result, int valid_points, bool enough, bool residual_ok,
                       const std::string& unobservable, const std::string& texture_note) const;
  // A valid result becomes the next frame's starting point (or reference, frame_to_frame).
  void advance(const PoseDeltaInput& frame, const PoseDeltaResult& result, const RegistrationOutput& reg);
  // Follows the motion with the filter (a valid result updates it); with
  // PoseDeltaParams::filter the result's transform and covariance become the filter's.
  void track(const PoseDeltaInput& frame, PoseDeltaResult* result);
  // Where the texture image of `frame` was exposed relative to its points
  // (the rig's velocity times the gap for a strobed ambient frame).
  Eigen::Isometry3d exposureOffset(const PoseDeltaInput& frame) const;
  const cv::Mat& textureImage(const PoseDeltaInput& frame) const;
  // Where the points' instant lies between the two ambient frames (0-1), or
  // -1 when the frame has not two around it.
  double bracketFraction(const PoseDeltaInput& frame) const;

  // Why the texture cannot be tracked in this frame, or "".
  std::string textureUnavailable(const PoseDeltaInput& frame) const;
  // A quick one-way registration from *pose, for a prediction: *pose becomes
  // the fit when it is usable (true).
  bool refit(const PoseDeltaInput& frame, const TextureObservations& texture, const PoseDeltaParams& params,
             Eigen::Isometry3d* pose) const;
  void lock(const PoseDeltaInput& frame);
  // The lock period (reference_fusion_frames): a valid frame's points, pose
  // and texture kept; with enough of them the reference surface is fitted
  // to all their points and their poses solved again, in turn.
  void collectForFusion(const PoseDeltaInput& frame, const TextureMeasurement& texture, const RegistrationOutput& reg,
                        const PoseDeltaResult& result);
  void fuseReference(bool last);

  PoseDeltaParams config_;
  CameraModel camera_;
  bool has_camera_ = false;
  bool has_reference_ = false;
  bool lock_pending_ = true;

  std::unique_ptr<Frame> reference_;
  std::unique_ptr<TextureLandmarks> texture_;
  Eigen::Isometry3d last_estimate_ = Eigen::Isometry3d::Identity();  // relative to reference_
  Eigen::Isometry3d chained_ = Eigen::Isometry3d::Identity();        // frame_to_frame: reference_ to the lock
  Matrix6d chained_covariance_ = Matrix6d::Zero();
  PoseFilter motion_;                          // the rig's motion (and, with config_.filter, the output)
  bool reference_ambient_ = false;             // the reference texture comes from an ambient frame
  Vector6d lock_velocity_ = Vector6d::Zero();  // the rig's velocity at the lock
  bool lock_velocity_known_ = false;
  struct FusionFrame;
  std::vector<FusionFrame> fusion_;  // the lock period's frames so far
  bool fused_ = false;               // the reference surface was refined since the lock
  size_t last_tracked_ = 0;          // texture features refined on the last frame with texture
};

}  // namespace structured_light_stabilizer
