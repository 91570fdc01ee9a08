#include "structured_light_stabilizer/calibration/projector_joint_fit.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Dense>

#include "calibration/joint_fit_problem.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

using detail::JointProblem;
using detail::State;
using detail::Weights;

using detail::distanceToLine;

bool commonCentreOf(const std::vector<BeamRay>& rays, Eigen::Vector3d* centre)
{
  return detail::closestPointToLines(rays, centre);
}

// Starting rays: each dot back-projected onto its board, a line through
// each beam's board points, their common centre; the central state's
// directions point from it to each beam's mean board point.
bool initialState(const CameraModel& cam, const std::vector<JointFitView>& views, int n_beams, State* st,
                  std::string* error)
{
  std::vector<std::vector<Eigen::Vector3d>> pts(n_beams);
  std::vector<std::vector<int>> seen(n_beams);
  st->poses.clear();
  double z_sum = 0.0;
  for (size_t v = 0; v < views.size(); ++v)
  {
    st->poses.push_back(views[v].pose);
    z_sum += views[v].pose.translation().z();
    for (size_t j = 0; j < views[v].dot_px.size(); ++j)
    {
      const int b = views[v].dot_beam[j];
      const Eigen::Vector2d n = cam.normalize(views[v].dot_px[j]);
      Eigen::Vector3d hit;
      if (b < 0 || b >= n_beams ||
          !detail::linePlaneHit(views[v].pose, Eigen::Vector3d::Zero(), Eigen::Vector3d(n.x(), n.y(), 1.0), &hit))
        continue;
      pts[b].push_back(hit);
      if (seen[b].empty() || seen[b].back() != static_cast<int>(v))
        seen[b].push_back(static_cast<int>(v));
    }
  }
  st->z_ref = z_sum / std::max<size_t>(1, views.size());
  std::vector<BeamRay> lines(n_beams);
  for (int b = 0; b < n_beams; ++b)
  {
    if (seen[b].size() < 2)
    {
      *error = "beam " + std::to_string(b) + " was seen in " + std::to_string(seen[b].size()) +
               " view(s); every beam needs two or more";
      return false;
    }
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : pts[b])
      mean += p / static_cast<double>(pts[b].size());
    Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
    for (const auto& p : pts[b])
      S += (p - mean) * (p - mean).transpose();
    Eigen::Vector3d d = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(S).eigenvectors().col(2);
    lines[b].origin = mean;
    lines[b].direction = d.z() < 0.0 ? Eigen::Vector3d(-d) : d;
  }
  if (!commonCentreOf(lines, &st->centre))
    st->centre = Eigen::Vector3d::Zero();
  st->central = true;
  st->beam.assign(n_beams, Eigen::Vector4d::Zero());
  for (int b = 0; b < n_beams; ++b)
  {
    const Eigen::Vector3d d = lines[b].origin - st->centre;
    if (!(d.z() > 1e-6))
    {
      *error = "beam " + std::to_string(b) + " does not point away from the projector's centre";
      return false;
    }
    st->beam[b] << d.x() / d.z(), d.y() / d.z(), 0.0, 0.0;
  }
  return true;
}

State perBeamFrom(const State& central)
{
  State s = central;
  s.central = false;
  for (size_t i = 0; i < s.beam.size(); ++i)
  {
    const BeamRay r = central.ray(static_cast<int>(i));
    const Eigen::Vector3d p = r.origin + (s.z_ref - r.origin.z()) * r.direction;
    s.beam[i] << p.x(), p.y(), r.direction.x(), r.direction.y();
  }
  return s;
}

Weights startWeights(const std::vector<JointFitView>& views)
{
  Weights w;
  for (const JointFitView& v : views)
  {
    w.corner_sigma.push_back(0.05);
    w.dot_scale.push_back(1.0);
    w.corner_in.emplace_back(v.corner_px.size(), 1);
    w.dot_in.emplace_back(v.dot_px.size(), 1);
    w.corner_rw.emplace_back(v.corner_px.size(), 1.0);
    w.dot_rw.emplace_back(v.dot_px.size(), 1.0);
  }
  return w;
}

int usedObservations(const Weights& w)
{
  int n = 0;
  for (size_t v = 0; v < w.corner_in.size(); ++v)
    n += 2 * static_cast<int>(std::count(w.corner_in[v].begin(), w.corner_in[v].end(), 1) +
                              std::count(w.dot_in[v].begin(), w.dot_in[v].end(), 1));
  return n;
}

std::string checkInput(int rows, int cols, const std::vector<JointFitView>& views, const JointFitParams& params)
{
  std::string why = params.validate();
  if (!why.empty())
    return why;
  if (rows <= 0 || cols <= 0)
    return "rows and cols must be positive";
  if (views.size() < 2)
    return "need two or more views, got " + std::to_string(views.size());
  for (size_t v = 0; v < views.size(); ++v)
  {
    const JointFitView& view = views[v];
    if (view.corner_board.size() != view.corner_px.size() || view.corner_px.size() < 4)
      return "view " + std::to_string(v) + " needs 4 or more corners with their board points";
    if (view.dot_beam.size() != view.dot_px.size() ||
        (!view.dot_sigma_px.empty() && view.dot_sigma_px.size() != view.dot_px.size()))
      return "view " + std::to_string(v) + ": dot beams, pixels and sigmas differ in number";
    for (size_t j = 0; j < view.dot_px.size(); ++j)
      if (!std::isfinite(view.dot_px[j].x) || !std::isfinite(view.dot_px[j].y) || view.dot_beam[j] < 0 ||
          view.dot_beam[j] >= rows * cols)
        return "view " + std::to_string(v) + ": dot " + std::to_string(j) + " has no valid beam or pixel";
  }
  return "";
}

// Per-view and per-beam residual figures, the outliers, and the rays'
// predicted uncertainty at the reference depth.
void fillReport(const JointProblem& prob, const State& st, const Weights& w, JointFitResult* res)
{
  const auto& views = prob.views();
  const CameraModel& cam = prob.camera();
  const int n_beams = static_cast<int>(st.beam.size());
  res->views.assign(views.size(), JointFitViewReport());
  res->beams.assign(n_beams, JointFitBeamReport());
  std::vector<double> beam_sum2(n_beams, 0.0);
  for (size_t v = 0; v < views.size(); ++v)
  {
    JointFitViewReport& vr = res->views[v];
    vr.corner_sigma_px = w.corner_sigma[v];
    vr.dot_scale = w.dot_scale[v];
    double c2 = 0.0, d2 = 0.0;
    for (size_t k = 0; k < views[v].corner_px.size(); ++k)
    {
      const double r = detail::cornerResidual(cam, st.poses[v], views[v].corner_board[k], views[v].corner_px[k]).norm();
      if (w.corner_in[v][k])
      {
        c2 += r * r;
        ++vr.corners_used;
      }
      else
      {
        ++vr.corner_outliers;
        res->outliers.push_back({static_cast<int>(v), -1, static_cast<int>(k), r});
      }
    }
    for (size_t j = 0; j < views[v].dot_px.size(); ++j)
    {
      const int b = views[v].dot_beam[j];
      const double r = detail::dotResidual(cam, st.poses[v], st.ray(b), views[v].dot_px[j]).norm();
      if (w.dot_in[v][j])
      {
        d2 += r * r;
        ++vr.dots_used;
        beam_sum2[b] += r * r;
        ++res->beams[b].views;
      }
      else
      {
        ++vr.dot_outliers;
        res->outliers.push_back({static_cast<int>(v), b, static_cast<int>(j), r});
      }
    }
    vr.corner_rms_px = std::sqrt(c2 / std::max(1, vr.corners_used));
    vr.dot_rms_px = std::sqrt(d2 / std::max(1, vr.dots_used));
  }
  Eigen::MatrixXd H;
  Eigen::VectorXd g;
  prob.normalEquations(st, w, &H, &g);
  const Eigen::MatrixXd cov = H.ldlt().solve(Eigen::MatrixXd::Identity(H.rows(), H.cols()));
  for (int b = 0; b < n_beams; ++b)
  {
    res->beams[b].rms_px = std::sqrt(beam_sum2[b] / std::max(1, res->beams[b].views));
    // d(point of the ray at z_ref, x and y) / d(its parameters).
    Eigen::MatrixXd J = Eigen::MatrixXd::Zero(2, st.size());
    if (st.central)
    {
      const double dz = st.z_ref - st.centre.z();
      J(0, st.centreIndex()) = 1.0;
      J(1, st.centreIndex() + 1) = 1.0;
      J(0, st.centreIndex() + 2) = -st.beam[b](0);
      J(1, st.centreIndex() + 2) = -st.beam[b](1);
      J(0, st.beamIndex(b)) = dz;
      J(1, st.beamIndex(b) + 1) = dz;
    }
    else
    {
      J(0, st.beamIndex(b)) = 1.0;
      J(1, st.beamIndex(b) + 1) = 1.0;
    }
    res->beams[b].sigma_m = std::sqrt(std::max(0.0, 0.5 * (J * cov * J.transpose()).trace()));
  }
}

ProjectorCalibration calibrationOf(const State& st, int rows, int cols, Eigen::Vector3d* centre)
{
  ProjectorCalibration cal;
  cal.rows = rows;
  cal.cols = cols;
  for (int b = 0; b < rows * cols; ++b)
  {
    BeamRay r = st.ray(b);
    r.direction.normalize();
    cal.beams.push_back(r);
  }
  if (st.central)
  {
    *centre = st.centre;
  }
  else if (commonCentreOf(cal.beams, centre))
  {
    // Each origin: the point of its beam nearest the common centre (a
    // readable file; the ray itself is unchanged).
    for (BeamRay& r : cal.beams)
      r.origin = r.pointAt((*centre - r.origin).dot(r.direction));
  }
  return cal;
}

}  // namespace

const char* projectorModelName(ProjectorModel model)
{
  switch (model)
  {
    case ProjectorModel::kCentral:
      return "central";
    case ProjectorModel::kPerBeam:
      return "per-beam";
    default:
      return "chosen by the data";
  }
}

std::string JointFitParams::validate() const
{
  std::ostringstream why;
  if (!(outlier_threshold > 1.0))
    why << "outlier_threshold must be > 1; ";
  if (!(min_sigma_px > 0.0))
    why << "min_sigma_px must be positive; ";
  if (max_iterations < 1)
    why << "max_iterations must be >= 1; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

JointFitResult fitProjectorJoint(const CameraModel& camera, int rows, int cols, const std::vector<JointFitView>& views,
                                 const JointFitParams& params)
{
  JointFitResult res;
  res.error = checkInput(rows, cols, views, params);
  if (res.error.empty())
    res.error = camera.validate();
  State central;
  if (!res.error.empty() || !initialState(camera, views, rows * cols, &central, &res.error))
    return res;
  const JointProblem prob(camera, views, params);
  Weights w_central = startWeights(views);
  if (!detail::fitRounds(prob, &central, &w_central))
  {
    res.error = "the joint fit did not converge (central model)";
    return res;
  }
  const int n_central = central.size();
  res.dof_central = usedObservations(w_central) - n_central;
  res.chi2_central = prob.cost(central, w_central);
  State chosen = central;
  Weights w = w_central;
  res.model = ProjectorModel::kCentral;
  std::vector<double> distances(rows * cols, 0.0);
  if (params.model != ProjectorModel::kCentral)
  {
    // The per-beam model with the central fit's weights and observations:
    // under one centre of projection those describe the noise, and the
    // extra parameters lower chi-square by about their number (F ~ 1);
    // optics without one centre leave the central model's misfit in its
    // weights, which the per-beam lines then undercut (F >> 1).
    State per_beam = perBeamFrom(central);
    if (!prob.solve(&per_beam, w_central))
    {
      res.error = "the joint fit did not converge (per-beam model)";
      return res;
    }
    res.dof_per_beam = usedObservations(w_central) - per_beam.size();
    res.chi2_per_beam = prob.cost(per_beam, w_central);
    const int extra = per_beam.size() - n_central;
    res.f_statistic =
        ((res.chi2_central - res.chi2_per_beam) / extra) / (res.chi2_per_beam / std::max(1, res.dof_per_beam));
    const double critical = 1.0 + params.model_choice_z * std::sqrt(2.0 / extra + 2.0 / std::max(1, res.dof_per_beam));
    Weights w_pb = w_central;
    if (params.model == ProjectorModel::kPerBeam || res.f_statistic > critical)
    {
      // Kept: its own noise estimates and outliers.
      if (!detail::fitRounds(prob, &per_beam, &w_pb))
      {
        res.error = "the joint fit did not converge (per-beam model)";
        return res;
      }
      chosen = per_beam;
      w = w_pb;
      res.model = ProjectorModel::kPerBeam;
    }
    // The per-beam lines' distances from their common centre: how far the
    // optics are from one centre of projection, beam by beam.
    Eigen::Vector3d c;
    std::vector<BeamRay> lines;
    for (int b = 0; b < rows * cols; ++b)
      lines.push_back(per_beam.ray(b));
    if (commonCentreOf(lines, &c))
      for (int b = 0; b < rows * cols; ++b)
        distances[b] = distanceToLine(c, lines[b]);
  }
  fillReport(prob, chosen, w, &res);
  for (int b = 0; b < rows * cols; ++b)
    res.beams[b].centre_distance_m = distances[b];
  res.calibration = calibrationOf(chosen, rows, cols, &res.centre);
  res.poses = chosen.poses;
  res.reference_depth_m = chosen.z_ref;
  res.ok = res.calibration.validate().empty();
  if (!res.ok)
    res.error = "the fitted rays are not valid: " + res.calibration.validate();
  return res;
}

}  // namespace structured_light_stabilizer
