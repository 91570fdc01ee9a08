#include "calibration/joint_fit_problem.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace detail
{

Eigen::Vector2d cornerResidual(const CameraModel& cam, const Eigen::Isometry3d& pose, const Eigen::Vector3d& b,
                               const cv::Point2d& obs)
{
  return toVec(cam.project(pose * b)) - toVec(obs);
}

Eigen::Vector2d dotResidual(const CameraModel& cam, const Eigen::Isometry3d& pose, const BeamRay& ray,
                            const cv::Point2d& obs)
{
  Eigen::Vector3d hit;
  // A per-beam line's origin lies at the boards' mean depth: either side counts.
  if (!linePlaneHit(pose, ray.origin, ray.direction, &hit, false))
    return Eigen::Vector2d::Constant(kNaN);
  return toVec(cam.project(hit)) - toVec(obs);
}

double JointProblem::cost(const State& st, const Weights& w) const
{
  double c = 0.0;
  for (size_t v = 0; v < views_.size(); ++v)
  {
    const int vi = static_cast<int>(v);
    const JointFitView& view = views_[v];
    for (size_t k = 0; k < view.corner_px.size(); ++k)
      if (w.corner_in[v][k])
        c += cornerResidual(cam_, st.poses[v], view.corner_board[k], view.corner_px[k]).squaredNorm() *
             cornerWeight(vi, static_cast<int>(k), w);
    for (size_t j = 0; j < view.dot_px.size(); ++j)
      if (w.dot_in[v][j])
        c += dotResidual(cam_, st.poses[v], st.ray(view.dot_beam[j]), view.dot_px[j]).squaredNorm() *
             dotWeight(vi, static_cast<int>(j), w);
  }
  return std::isfinite(c) ? c : kInf;
}

int JointProblem::dotJacobian(const State& st, int v, int j, Eigen::Matrix<double, 2, 11>* J, int idx[11],
                              Eigen::Vector2d* r0) const
{
  const JointFitView& view = views_[v];
  const int beam = view.dot_beam[j];
  const int nb = st.central ? 5 : 4;
  const auto residual = [&](const Eigen::Isometry3d& pose, const BeamRay& ray)
  { return dotResidual(cam_, pose, ray, view.dot_px[j]); };
  *r0 = residual(st.poses[v], st.ray(beam));
  for (int p = 0; p < 6; ++p)
  {
    Vector6d inc = Vector6d::Zero();
    inc(p) = 1e-6;
    J->col(p) = (residual(applyPoseIncrement(st.poses[v], inc), st.ray(beam)) -
                 residual(applyPoseIncrement(st.poses[v], -inc), st.ray(beam))) /
                2e-6;
    idx[p] = st.poseIndex(v) + p;
  }
  for (int p = 0; p < nb; ++p)
  {
    BeamRay plus = st.ray(beam), minus = plus;
    const double h = 1e-6;
    if (st.central && p < 3)
    {
      plus.origin(p) += h;
      minus.origin(p) -= h;
      idx[6 + p] = st.centreIndex() + p;
    }
    else
    {
      const int q = st.central ? p - 3 : p;  // index within the beam's parameters
      Eigen::Vector3d& a = (!st.central && q < 2) ? plus.origin : plus.direction;
      Eigen::Vector3d& b = (!st.central && q < 2) ? minus.origin : minus.direction;
      a(q % 2) += h;
      b(q % 2) -= h;
      idx[6 + p] = st.beamIndex(beam) + q;
    }
    J->col(6 + p) = (residual(st.poses[v], plus) - residual(st.poses[v], minus)) / (2 * h);
  }
  return 6 + nb;
}

void JointProblem::cornerJacobian(const State& st, int v, int k, Eigen::Matrix<double, 2, 6>* J,
                                  Eigen::Vector2d* r0) const
{
  const Eigen::Vector3d& b = views_[v].corner_board[k];
  const cv::Point2d& obs = views_[v].corner_px[k];
  *r0 = cornerResidual(cam_, st.poses[v], b, obs);
  for (int p = 0; p < 6; ++p)
  {
    Vector6d inc = Vector6d::Zero();
    inc(p) = 1e-6;
    J->col(p) = (cornerResidual(cam_, applyPoseIncrement(st.poses[v], inc), b, obs) -
                 cornerResidual(cam_, applyPoseIncrement(st.poses[v], -inc), b, obs)) /
                2e-6;
  }
}

void JointProblem::normalEquations(const State& st, const Weights& w, Eigen::MatrixXd* H, Eigen::VectorXd* g) const
{
  H->setZero(st.size(), st.size());
  g->setZero(st.size());
  Eigen::Matrix<double, 2, 6> Jc;
  Eigen::Matrix<double, 2, 11> Jd;
  Eigen::Vector2d r0;
  int idx[11];
  for (size_t v = 0; v < views_.size(); ++v)
  {
    const int vi = static_cast<int>(v), base = st.poseIndex(vi);
    for (size_t k = 0; k < views_[v].corner_px.size(); ++k)
    {
      if (!w.corner_in[v][k])
        continue;
      const double wc = cornerWeight(vi, static_cast<int>(k), w);
      cornerJacobian(st, vi, static_cast<int>(k), &Jc, &r0);
      H->block<6, 6>(base, base) += wc * Jc.transpose() * Jc;
      g->segment<6>(base) += wc * Jc.transpose() * r0;
    }
    for (size_t j = 0; j < views_[v].dot_px.size(); ++j)
    {
      if (!w.dot_in[v][j])
        continue;
      const int n = dotJacobian(st, vi, static_cast<int>(j), &Jd, idx, &r0);
      const double wd = dotWeight(vi, static_cast<int>(j), w);
      for (int a = 0; a < n; ++a)
      {
        (*g)(idx[a]) += wd * Jd.col(a).dot(r0);
        for (int b = 0; b < n; ++b)
          (*H)(idx[a], idx[b]) += wd * Jd.col(a).dot(Jd.col(b));
      }
    }
  }
}

bool JointProblem::solve(State* st, const Weights& w) const
{
  double c = cost(*st, w), lambda = 1e-4;
  if (!std::isfinite(c))
    return false;
  Eigen::MatrixXd H;
  Eigen::VectorXd g;
  for (int it = 0; it < params_.max_iterations; ++it)
  {
    normalEquations(*st, w, &H, &g);
    State candidate;
    bool converged = false;
    const bool accepted = levenbergMarquardtIteration(
        &c, &lambda,
        [&](double l)
        {
          Eigen::MatrixXd A = H;
          A.diagonal() = A.diagonal() * (1.0 + l) + Eigen::VectorXd::Constant(A.rows(), 1e-12);
          return Eigen::VectorXd(-A.ldlt().solve(g));
        },
        [&](const Eigen::VectorXd& step, double* cc)
        {
          candidate = st->plus(step);
          *cc = cost(candidate, w);
          return true;
        },
        [&] { *st = candidate; }, &converged);
    if (!accepted || converged)
      break;
  }
  return std::isfinite(c);
}

// sigma of one axis of 2-D Gaussian residuals from the median of |r|^2
// (the median of chi-square with 2 dof is 2 ln 2).
namespace
{
double sigmaFromSquares(std::vector<double> r2)
{
  return std::sqrt(median(std::move(r2)) / (2.0 * std::log(2.0)));
}
}  // namespace

// Leverage of an observation (the mean diagonal of its 2 x 2 block of the
// hat matrix): how much of its own residual the fit absorbs. A dot of a
// beam seen in two views is fitted exactly by a per-beam line (leverage
// 1): its residual says nothing about the noise and it cannot be tested.
double JointProblem::leverage(const Eigen::MatrixXd& cov, const double* J, const int* idx, int n, double weight) const
{
  double h = 0.0;
  for (int row = 0; row < 2; ++row)
    for (int a = 0; a < n; ++a)
      for (int b = 0; b < n; ++b)
        h += J[2 * a + row] * cov(idx[a], idx[b]) * J[2 * b + row];
  return std::min(1.0, 0.5 * h * weight);
}

void JointProblem::normalisedSquares(const State& st, const Weights& w, std::vector<std::vector<double>>* corners,
                                     std::vector<std::vector<double>>* dots) const
{
  Eigen::MatrixXd H;
  Eigen::VectorXd g;
  normalEquations(st, w, &H, &g);
  const Eigen::MatrixXd cov = H.ldlt().solve(Eigen::MatrixXd::Identity(H.rows(), H.cols()));
  Eigen::Matrix<double, 2, 6> Jc;
  Eigen::Matrix<double, 2, 11> Jd;
  Eigen::Vector2d r;
  int idx[11];
  corners->assign(views_.size(), {});
  dots->assign(views_.size(), {});
  for (size_t v = 0; v < views_.size(); ++v)
  {
    const int vi = static_cast<int>(v);
    for (int p = 0; p < 6; ++p)
      idx[p] = st.poseIndex(vi) + p;
    for (size_t k = 0; k < views_[v].corner_px.size(); ++k)
    {
      cornerJacobian(st, vi, static_cast<int>(k), &Jc, &r);
      const double h = leverage(cov, Jc.data(), idx, 6, cornerWeight(vi, static_cast<int>(k), w));
      const double r2 = r.squaredNorm() / square(w.corner_sigma[v]);
      (*corners)[v].push_back(h < 0.99 ? r2 / (1.0 - h) : kNaN);
    }
    for (size_t j = 0; j < views_[v].dot_px.size(); ++j)
    {
      const int n = dotJacobian(st, vi, static_cast<int>(j), &Jd, idx, &r);
      const double h = leverage(cov, Jd.data(), idx, n, dotWeight(vi, static_cast<int>(j), w));
      const double r2 = r.allFinite() ? r.squaredNorm() / square(dotSigma(vi, static_cast<int>(j), w)) : kInf;
      (*dots)[v].push_back(h < 0.99 ? r2 / (1.0 - h) : kNaN);
    }
  }
}

bool JointProblem::reweigh(const State& st, Weights* w, bool robust) const
{
  // Squared residuals over the current sigmas, corrected for leverage.
  std::vector<std::vector<double>> corner_r2, dot_r2;
  normalisedSquares(st, *w, &corner_r2, &dot_r2);
  bool changed = false;
  const double t2 = square(params_.outlier_threshold);
  const auto flag = [&](double r2, char* in, double* rw)
  {
    // Untestable (leverage 1): kept with full weight.
    const char now = robust || std::isnan(r2) || r2 <= t2;
    *rw = robust && std::isfinite(r2) ? 1.0 / (1.0 + r2 / 9.0) : 1.0;
    changed |= now != *in;
    *in = now;
  };
  for (size_t v = 0; v < views_.size(); ++v)
  {
    // New scales: the current ones times the robust spread of the
    // normalised residuals of the observations in use (all, when robust:
    // the median ignores the outliers).
    std::vector<double> rc, rd;
    for (size_t k = 0; k < corner_r2[v].size(); ++k)
      if ((robust || w->corner_in[v][k]) && std::isfinite(corner_r2[v][k]))
        rc.push_back(corner_r2[v][k]);
    for (size_t j = 0; j < dot_r2[v].size(); ++j)
      if ((robust || w->dot_in[v][j]) && std::isfinite(dot_r2[v][j]))
        rd.push_back(dot_r2[v][j]);
    const double fc = rc.size() >= 6 ? sigmaFromSquares(rc) : 1.0;
    const double fd = rd.size() >= 6 ? sigmaFromSquares(rd) : 1.0;
    w->corner_sigma[v] = std::max(params_.min_sigma_px, w->corner_sigma[v] * fc);
    w->dot_scale[v] = std::max(0.1, w->dot_scale[v] * fd);
    for (size_t k = 0; k < corner_r2[v].size(); ++k)
      flag(corner_r2[v][k] / (fc * fc), &w->corner_in[v][k], &w->corner_rw[v][k]);
    for (size_t j = 0; j < dot_r2[v].size(); ++j)
      flag(dot_r2[v][j] / (fd * fd), &w->dot_in[v][j], &w->dot_rw[v][j]);
  }
  return changed;
}

bool fitRounds(const JointProblem& prob, State* st, Weights* w)
{
  // Robust rounds: a dot many pixels off (a reflection) would otherwise
  // drag its beam's ray so far that the beam's good dots look like the
  // outliers.
  for (int round = 0; round < 6; ++round)
  {
    if (!prob.solve(st, *w))
      return false;
    prob.reweigh(*st, w, true);
  }
  for (int round = 0; round < 8; ++round)
  {
    if (!prob.solve(st, *w))
      return false;
    const std::vector<double> before_c = w->corner_sigma, before_d = w->dot_scale;
    const bool flags = prob.reweigh(*st, w, false);
    double change = 0.0;
    for (size_t v = 0; v < before_c.size(); ++v)
      change = std::max(
          {change, std::abs(w->corner_sigma[v] / before_c[v] - 1.0), std::abs(w->dot_scale[v] / before_d[v] - 1.0)});
    if (!flags && change < 0.02)
      break;
  }
  return prob.solve(st, *w);
}

}  // namespace detail
}  // namespace structured_light_stabilizer
