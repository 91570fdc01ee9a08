// Settings of the PoseDelta estimator and of its registration solver, ROS-free.
// Units are in the names (_m metres, _rad radians, _px pixels); the ROS
// parameter and dynamic_reconfigure names (cfg/PoseDelta.cfg) are the same
// without the struct. validate() says what is unusable; nothing here throws.
#pragma once

#include <string>

namespace structured_light_stabilizer
{

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
  double max_edge_ratio = 3.0;  // a surface cell with an edge longer than this times the median is a depth jump

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
  // Pyramid levels of the refinement windows (texture_tracker.h): a weak,
  // low-frequency texture (features of 10 cm and more) carries its
  // information on a coarse level, where a window spans more rock; the
  // finest is half resolution (0 = full resolution too).
  int texture_min_level = 1;
  int texture_max_level = 2;
  // A window is a feature only when its texture's gradient energy exceeds
  // the image noise's this many times (a flat, textureless board has none),
  // and when its predicted shift 1-sigma is at most texture_max_sigma_px.
  double texture_min_snr = 1.0;
  double texture_max_sigma_px = 0.5;
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

  // Optional constant-velocity filter over the estimates (pose_filter.h):
  // the result's transform and covariance are then the filter's, the raw
  // estimate stays in PoseDeltaResult::raw_*. Needs PoseDeltaInput::stamp_s.
  bool filter = false;
  double filter_acceleration_noise = 0.1;           // m/s^2/sqrt(Hz), per axis (pose_filter.h)
  double filter_angular_acceleration_noise = 0.15;  // rad/s^2/sqrt(Hz), per axis

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

}  // namespace structured_light_stabilizer
