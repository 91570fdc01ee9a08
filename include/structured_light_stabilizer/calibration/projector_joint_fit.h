// Joint fit of the projector's beam rays and the board poses from
// chessboard views (docs/calibration.md), ROS-free.
//
// Contract: each view holds the board's corners (board frame, metres, z = 0;
// and their observed distorted pixels) and the dots on it (beam index,
// observed distorted pixel, the centre's own 1-sigma from the dot fit), with
// a starting pose (board -> camera optical frame). The fit minimises, over
// all views at once, the reprojection error of the corners (through the
// board pose) and of the dots (the beam ray meets the board plane, the hit
// point is projected), so corners and dots both constrain each board's pose
// while the dots of all views give the rays. Every distortion model of the
// CameraModel is honoured (residuals in distorted pixels).
//
// The projector's physics: kCentral: one centre of projection, every beam a
// ray from it (3 + 2 per beam parameters); kPerBeam: each beam its own line
// (4 per beam; a projector whose optics do not share one centre);
// kChosenByData fits both and keeps the per-beam model only when its
// improvement in chi-square is significant (an F test, `model_choice_z`
// standard deviations).
//
// Weights and outliers: each view has its own corner noise and its own
// scale on the dots' fitted sigmas, estimated robustly from its residuals
// (a blurred view gets larger ones and so counts less); an observation whose
// normalised residual exceeds `outlier_threshold` (chi-square of 2 degrees
// of freedom, 4.5 = p 4e-5) is rejected and reported, and re-admitted if it
// fits again. Reentrant; no shared state.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"

namespace structured_light_stabilizer
{

enum class ProjectorModel
{
  kCentral,
  kPerBeam,
  kChosenByData,
};

const char* projectorModelName(ProjectorModel model);

struct JointFitView
{
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // starting board -> camera
  std::vector<Eigen::Vector3d> corner_board;               // metres, board frame
  std::vector<cv::Point2d> corner_px;                      // observed, distorted
  std::vector<int> dot_beam;                               // row-major beam index
  std::vector<cv::Point2d> dot_px;                         // observed, distorted
  std::vector<double> dot_sigma_px;                        // the dot fit's 1-sigma (per axis); empty = all equal
};

struct JointFitParams
{
  ProjectorModel model = ProjectorModel::kChosenByData;
  double outlier_threshold = 4.5;  // normalised 2-D residual beyond which an observation is rejected
  // Floor of a view's corner noise, and the accuracy of the dot centroid's
  // model added in quadrature to every dot's own sigma (a bright dot fitted
  // to 0.005 px by its noise is not known to better than this; the issue's
  // bound for centroids on smooth albedo is 0.03 px).
  double min_sigma_px = 0.03;
  // Significance (standard deviations of the F statistic) the per-beam
  // model's improvement needs: 6, not 3, because the dots' errors have
  // heavier tails than a Gaussian (a bright, clipped dot is a few tenths of
  // a pixel off), which extra parameters absorb (measured: F 1.4 on four
  // simulated views of a central projector; optics with +-4 mm origins: F 8).
  double model_choice_z = 6.0;
  int max_iterations = 200;  // Levenberg-Marquardt iterations per round

  std::string validate() const;
};

struct JointFitViewReport
{
  double corner_sigma_px = 0.0;  // estimated corner noise (per axis)
  double dot_scale = 1.0;        // estimated factor on the dots' own sigmas
  double corner_rms_px = 0.0;    // RMS residual of the used corners
  double dot_rms_px = 0.0;       // RMS residual of the used dots
  int corners_used = 0, dots_used = 0;
  int corner_outliers = 0, dot_outliers = 0;
};

struct JointFitBeamReport
{
  int views = 0;                   // dots used
  double rms_px = 0.0;             // RMS residual of its dots
  double centre_distance_m = 0.0;  // distance of its per-beam line from the common centre (0 without that fit)
  double sigma_m = 0.0;            // predicted 1-sigma of the ray across itself at `reference_depth_m`
};

struct JointFitOutlier
{
  int view = 0;
  int beam = -1;  // -1: a corner
  int index = 0;  // corner or dot index in the view
  double residual_px = 0.0;
};

struct JointFitResult
{
  bool ok = false;
  std::string error;
  ProjectorCalibration calibration;                  // rows x cols rays in the camera frame
  ProjectorModel model = ProjectorModel::kCentral;   // the one kept
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // common centre of projection (least squares for per-beam)
  std::vector<Eigen::Isometry3d> poses;              // refined board -> camera, per view
  std::vector<JointFitViewReport> views;
  std::vector<JointFitBeamReport> beams;
  std::vector<JointFitOutlier> outliers;
  double reference_depth_m = 0.0;                  // mean board distance, where sigma_m is given
  double chi2_central = 0.0, chi2_per_beam = 0.0;  // with the final weights (0 when not fitted)
  int dof_central = 0, dof_per_beam = 0;
  double f_statistic = 0.0;  // of the per-beam model against the central one (0 when not compared)
};

// Fits the rays of a rows x cols projector. Fails (ok = false, error names
// it) when a beam has dots in fewer than two views, a view has fewer than 4
// corners, or the fit does not converge to finite values.
JointFitResult fitProjectorJoint(const CameraModel& camera, int rows, int cols, const std::vector<JointFitView>& views,
                                 const JointFitParams& params = JointFitParams());

}  // namespace structured_light_stabilizer
