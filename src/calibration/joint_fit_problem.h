// The joint fit's unknowns, weights and Levenberg-Marquardt problem
// (projector_joint_fit.h gives the model). Not a public API.
#pragma once

#include <cmath>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "calibration/calibration_geometry.h"
#include "structured_light_stabilizer/calibration/projector_joint_fit.h"

namespace structured_light_stabilizer
{
namespace detail
{

using Vector6d = Eigen::Matrix<double, 6, 1>;

// The unknowns: every view's pose, and the rays. Central: the centre c and
// per beam (a, b): ray c + s (a, b, 1). Per beam: (x, y, a, b): the line
// through (x, y, z_ref) along (a, b, 1); z_ref is the mean board distance,
// so that position and direction are nearly uncorrelated.
struct State
{
  bool central = true;
  double z_ref = 1.5;
  std::vector<Eigen::Isometry3d> poses;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector4d> beam;

  int poseIndex(int v) const { return 6 * v; }
  int centreIndex() const { return 6 * static_cast<int>(poses.size()); }
  int beamIndex(int i) const { return central ? centreIndex() + 3 + 2 * i : centreIndex() + 4 * i; }
  int beamParams() const { return central ? 2 : 4; }
  int size() const { return beamIndex(static_cast<int>(beam.size())); }

  BeamRay ray(int i) const
  {
    BeamRay r;
    const Eigen::Vector4d& b = beam[i];
    if (central)
    {
      r.origin = centre;
      r.direction = Eigen::Vector3d(b(0), b(1), 1.0);
    }
    else
    {
      r.origin = Eigen::Vector3d(b(0), b(1), z_ref);
      r.direction = Eigen::Vector3d(b(2), b(3), 1.0);
    }
    return r;
  }

  State plus(const Eigen::VectorXd& d) const
  {
    State s = *this;
    for (size_t v = 0; v < poses.size(); ++v)
      s.poses[v] = applyPoseIncrement(poses[v], d.segment<6>(poseIndex(static_cast<int>(v))));
    if (central)
      s.centre += d.segment<3>(centreIndex());
    for (size_t i = 0; i < beam.size(); ++i)
      s.beam[i].head(beamParams()) += d.segment(beamIndex(static_cast<int>(i)), beamParams());
    return s;
  }
};

// Per view: its noise estimates and which observations are in use.
struct Weights
{
  std::vector<double> corner_sigma, dot_scale;
  std::vector<std::vector<char>> corner_in, dot_in;
  // Robust multipliers of the observations' weights (iteratively
  // reweighted least squares; 1 in the final, hard-flagged rounds).
  std::vector<std::vector<double>> corner_rw, dot_rw;
};

Eigen::Vector2d cornerResidual(const CameraModel& cam, const Eigen::Isometry3d& pose, const Eigen::Vector3d& b,
                               const cv::Point2d& obs);
Eigen::Vector2d dotResidual(const CameraModel& cam, const Eigen::Isometry3d& pose, const BeamRay& ray,
                            const cv::Point2d& obs);

class JointProblem
{
public:
  JointProblem(const CameraModel& cam, const std::vector<JointFitView>& views, const JointFitParams& params)
    : cam_(cam), views_(views), params_(params)
  {
  }

  // A dot's sigma: its own (from the dot fit) and in quadrature the floor
  // (the centroid model's accuracy, which a bright dot's small statistical
  // sigma does not include), times the view's scale.
  double dotSigma(int v, int j, const Weights& w) const
  {
    const auto& s = views_[v].dot_sigma_px;
    const double own = s.empty() ? 0.05 : s[j];
    return w.dot_scale[v] * std::sqrt(own * own + params_.min_sigma_px * params_.min_sigma_px);
  }

  // Sum of squared normalised residuals of the observations in use.
  double cost(const State& st, const Weights& w) const;
  // Gauss-Newton normal equations (numeric Jacobian of each observation
  // over its own parameters only).
  void normalEquations(const State& st, const Weights& w, Eigen::MatrixXd* H, Eigen::VectorXd* g) const;
  // Levenberg-Marquardt from *st; false when nothing finite comes out.
  bool solve(State* st, const Weights& w) const;
  // New noise estimates from the residuals. Robust: every observation in
  // use, with a Cauchy multiplier 1 / (1 + r^2 / 9) of its weight (r in
  // sigmas); else hard flags at the outlier threshold (multipliers 1).
  // True when the flags changed.
  bool reweigh(const State& st, Weights* w, bool robust) const;
  // Weight (1 / sigma^2 times the robust multiplier; 0 when not in use).
  double cornerWeight(int v, int k, const Weights& w) const
  {
    return w.corner_in[v][k] ? w.corner_rw[v][k] / (w.corner_sigma[v] * w.corner_sigma[v]) : 0.0;
  }
  double dotWeight(int v, int j, const Weights& w) const
  {
    const double s = dotSigma(v, j, w);
    return w.dot_in[v][j] ? w.dot_rw[v][j] / (s * s) : 0.0;
  }

  const std::vector<JointFitView>& views() const { return views_; }
  const CameraModel& camera() const { return cam_; }

private:
  // Residual and Jacobian of dot j of view v over its own parameters (the
  // view's pose, then the ray's); returns their number, fills idx with
  // their indices in the state.
  int dotJacobian(const State& st, int v, int j, Eigen::Matrix<double, 2, 11>* J, int idx[11],
                  Eigen::Vector2d* r0) const;
  void cornerJacobian(const State& st, int v, int k, Eigen::Matrix<double, 2, 6>* J, Eigen::Vector2d* r0) const;
  double leverage(const Eigen::MatrixXd& cov, const double* J, const int* idx, int n, double weight) const;
  // Per observation: squared residual over its current sigma, divided by
  // (1 - leverage); NaN when the leverage is ~1 (the fit passes through it).
  void normalisedSquares(const State& st, const Weights& w, std::vector<std::vector<double>>* corners,
                         std::vector<std::vector<double>>* dots) const;

  const CameraModel& cam_;
  const std::vector<JointFitView>& views_;
  JointFitParams params_;
};

// Robust rounds (iteratively reweighted, Cauchy), then hard rounds: solve,
// re-estimate the noise, re-flag the outliers, until nothing changes.
bool fitRounds(const JointProblem& prob, State* st, Weights* w);

}  // namespace detail
}  // namespace structured_light_stabilizer
