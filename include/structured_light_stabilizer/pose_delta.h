// Camera motion relative to a locked reference map of the rock, ROS-free.
//
// Contract: input per frame is the organised beam map (rows x cols points,
// camera optical frame, metres, NaN = no point; beam = r * cols + c) and,
// optionally, the camera image of the same instant (CV_8UC3 or CV_8UC1) with
// its CameraModel. Output is the PoseDelta convention of SPEC §2: the
// transform T with p_cur = T * p_ref for any rock point, a 6x6 covariance in
// the order (tx, ty, tz, rx, ry, rz) (metres, radians; a small rotation
// vector applied on the current-frame side), the RMS point-to-surface residual
// in metres, the points used, a validity flag and a status string naming
// any unobservable axis.
//
// The physics (SPEC §3): the dots are fixed to the projector, so beam i hits
// a different rock point in every frame. The estimator therefore never pairs
// points by beam index. It registers the current points against a smooth
// surface interpolated through the reference map (and the reference points
// against the current surface), point-to-plane with robust weights; the rock's
// own texture, tracked over the whole image away from the dots and lifted to
// 3D on the reference surface (or, off the dot map, on a plane through it,
// with the depth left free), adds reprojection constraints that pin the axes
// a smooth or flat rock leaves free (in-plane translation, roll about the
// view axis). Both go into one Gauss-Newton problem on se(3).
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/camera_model.h"

namespace structured_light_stabilizer
{

using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

// A smooth surface through an organised beam map: Catmull-Rom bicubic
// interpolation of the 3D points over the continuous beam-grid coordinates
// (u = row, v = column). Because the beams fan out smoothly, S(u, v) is a
// smooth parametrisation of the rock between the dots; the interpolant passes
// through every valid point and reproduces any quadratic surface exactly.
// A cell [r, r+1] x [c, c+1] exists when its four corners are valid and none
// of its edges jumps (occlusion); missing outer stencil points are linearly
// extrapolated.
class BeamSurface
{
public:
  // `points` has rows * cols entries (NaN = missing). `max_edge_ratio`: a cell
  // whose longest edge exceeds this multiple of the median edge is treated as
  // a depth discontinuity and dropped.
  void build(int rows, int cols, const std::vector<Eigen::Vector3d>& points, double max_edge_ratio = 3.0);

  int rows() const { return rows_; }
  int cols() const { return cols_; }
  int validCells() const { return valid_cells_; }
  bool empty() const { return valid_cells_ == 0; }
  // Median distance between neighbouring beam points (metres).
  double medianSpacing() const { return median_edge_; }

  // S(u, v) and its partial derivatives. False outside the valid cells.
  bool evaluate(double u, double v, Eigen::Vector3d* s, Eigen::Vector3d* s_u = nullptr,
                Eigen::Vector3d* s_v = nullptr) const;

  // Foot of the perpendicular from x onto the surface, by Gauss-Newton on
  // (u, v) starting at *uv. On success *uv, the foot point and the unit
  // normal (pointing towards the camera, -z side) are filled. Fails when the
  // foot leaves the valid cells or the iteration does not settle.
  bool closestPoint(const Eigen::Vector3d& x, Eigen::Vector2d* uv, Eigen::Vector3d* foot,
                    Eigen::Vector3d* normal) const;

  // Intersection of the camera ray through the origin along `direction` with
  // the surface. *uv is filled (the search starts at the nearest grid point
  // in the image when *uv is NaN).
  bool intersectRay(const Eigen::Vector3d& direction, Eigen::Vector2d* uv, Eigen::Vector3d* hit) const;

private:
  bool cellValid(int r, int c) const;

  int rows_ = 0;
  int cols_ = 0;
  int valid_cells_ = 0;
  double median_edge_ = 0.0;
  std::vector<Eigen::Vector3d> points_;
  // Per cell (rows-1) x (cols-1): the 4x4 Catmull-Rom control points, or
  // empty when the cell is invalid.
  std::vector<std::array<Eigen::Vector3d, 16>> control_;
  std::vector<uint8_t> cell_ok_;
};

enum class PoseDeltaMode
{
  kReference,    // every frame against the locked reference (no drift)
  kFrameToFrame  // against the previous valid frame, deltas chained
};

struct PoseDeltaParams
{
  PoseDeltaMode mode = PoseDeltaMode::kReference;
  bool use_texture = true;
  bool symmetric = true;  // also register the reference points against the current surface

  int min_points = 12;  // fewer usable points: not valid
  int max_iterations = 30;
  // Huber kernel threshold in robust standard deviations (MAD) of each kind of residual.
  double huber_k = 2.0;
  // Floors of the noise scales used to weight geometry against texture.
  double min_geometry_sigma_m = 0.05e-3;
  double min_texture_sigma_px = 0.05;
  // Weak prior that keeps unobservable directions at the initial guess (the
  // last estimate); its size is what an unobservable axis reports.
  double prior_sigma_translation_m = 0.05;
  double prior_sigma_rotation_rad = 0.05;
  // Validity: every axis' 1-sigma must be within these bounds (an axis beyond
  // them is named unobservable in `status`), and the RMS residual below max.
  double max_sigma_translation_m = 1.5e-3;
  double max_sigma_rotation_rad = 0.075 * 3.14159265358979323846 / 180.0;
  double max_rms_residual_m = 5e-3;
  // A direction of the solution whose 1-sigma exceeds freeze_factor times the
  // bounds is not updated (kept at the initial guess, the last estimate).
  double freeze_factor = 1.0;
  double max_edge_ratio = 3.0;

  // Texture tracking (pyramidal Lucas-Kanade on the red channel, dots masked).
  // Spread features (windows that barely overlap) carry more independent
  // information than dense ones, and cost less.
  int texture_max_features = 300;
  double texture_quality = 0.005;
  double texture_min_distance_px = 20.0;
  int texture_window_px = 13;
  int texture_pyramid_levels = 3;
  double texture_dot_clearance_px = 10.0;  // features closer than this to any dot are not used
  int texture_roi_margin_px = 48;          // how far features may move (after prediction)
  int texture_min_features = 20;
  // Final gain-and-offset sub-pixel refinement window (odd; 0 = off, plain
  // Lucas-Kanade): natural vignetting alone changes a point's brightness by
  // several per cent as it moves, which plain Lucas-Kanade reads as a shift.
  int texture_refinement_window_px = 23;
  // Features from the whole image (not only the box of the dots): their
  // perspective flow separates in-plane translation from tilt, which the
  // narrow box cannot. Outside the dot map a feature's depth is extrapolated
  // from a plane through the reference points and left free in the solve.
  bool texture_whole_image = true;
  // 1-sigma of a feature's depth taken from the surface between the dots
  // (interpolation error) and floor of it for extrapolated features.
  double texture_depth_sigma_m = 0.003;
  double texture_extrapolated_depth_sigma_m = 0.02;
  // The reported covariance takes the texture's noise this many times larger
  // than its scatter per feature says: the errors of different features are
  // correlated (rendering and photometry they share, depth priors from the
  // same surface), so n features are worth less than n independent ones. On
  // the simulator the in-plane errors are 2-2.5 times the independent sigma.
  double texture_error_inflation = 2.5;

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

// One frame for the estimator.
struct PoseDeltaInput
{
  int rows = 0;
  int cols = 0;
  std::vector<Eigen::Vector3d> points;  // rows * cols, camera frame, NaN = missing
  // Optional image of the same instant: CV_8UC1, or CV_8UC3 whose channel
  // `texture_channel` carries the rock texture with the least dot light (the
  // red channel for green dots: 2 in bgr8, 0 in rgb8).
  cv::Mat image;
  int texture_channel = 2;
};

struct PoseDeltaResult
{
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();  // p_cur = T * p_ref
  Matrix6d covariance = Matrix6d::Identity();                   // (tx, ty, tz, rx, ry, rz)
  double rms_residual_m = 0.0;
  int points_used = 0;
  int features_used = 0;  // texture constraints in the solution
  double sigma_geometry_m = 0.0;  // robust scale of the point-to-surface residuals
  double sigma_texture_px = 0.0;  // robust scale of the texture reprojection residuals
  int iterations = 0;
  bool valid = false;
  bool locked_now = false;             // this frame became the reference
  std::array<bool, 6> unobservable{};  // per axis, sigma beyond the validity bound
  std::string status;
};

class TextureTracker;

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
  std::string checkMap(const PoseDeltaInput& frame, int* valid_points) const;
  void lock(const PoseDeltaInput& frame);

  PoseDeltaParams config_;
  CameraModel camera_;
  bool has_camera_ = false;
  bool has_reference_ = false;
  bool lock_pending_ = true;

  std::unique_ptr<Frame> reference_;
  std::unique_ptr<TextureTracker> tracker_;
  Eigen::Isometry3d last_estimate_ = Eigen::Isometry3d::Identity();  // relative to reference_
  Eigen::Isometry3d chained_ = Eigen::Isometry3d::Identity();        // frame_to_frame: reference_ to the lock
  Matrix6d chained_covariance_ = Matrix6d::Zero();
};

// Lower-level solver, exposed for tests and the benchmark: registers `current`
// points (camera frame now) against `reference_surface` (reference frame)
// and, when `current_surface` is non-null, the `reference` points against it.
// Texture constraints: reference 3D points and their observed undistorted
// normalised coordinates in the current image (scaled by `focal_px`).
// A feature's depth along its reference ray is an unknown of the solve when
// depth_sigma_m > 0 (point_ref is then its prior, with this 1-sigma), fixed
// at point_ref otherwise. Free depths let features far from the dots, whose
// depth is only extrapolated, still separate rotation from translation.
struct TextureConstraint
{
  Eigen::Vector3d point_ref;
  Eigen::Vector2d observed_normalized;
  double depth_sigma_m = 0.0;
};

struct RegistrationOutput
{
  Eigen::Isometry3d transform = Eigen::Isometry3d::Identity();
  Matrix6d information = Matrix6d::Zero();  // J^T W J with noise-scaled weights (texture deflated), no prior
  Matrix6d covariance = Matrix6d::Identity();
  double rms_geometry_m = 0.0;
  double sigma_geometry_m = 0.0;
  double sigma_texture_px = 0.0;
  int points_used = 0;
  int features_used = 0;
  int iterations = 0;
};

RegistrationOutput registerToSurface(const BeamSurface& reference_surface,
                                     const std::vector<Eigen::Vector3d>& reference, const BeamSurface* current_surface,
                                     const std::vector<Eigen::Vector3d>& current,
                                     const std::vector<TextureConstraint>& texture, double focal_px,
                                     const Eigen::Isometry3d& initial, const PoseDeltaParams& config);

// Rotation vector <-> rotation, for tests and chaining.
Eigen::Matrix3d expSO3(const Eigen::Vector3d& w);
Eigen::Vector3d logSO3(const Eigen::Matrix3d& R);

}  // namespace structured_light_stabilizer
