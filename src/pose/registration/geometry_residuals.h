// The geometry residual builder of the registration (registration.h): point-to-plane
// distances against the beam surfaces. Private to the pose stage.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "pose/registration/normal_equations.h"

namespace structured_light_stabilizer
{
namespace registration
{

// Point-to-plane distances (metres): each current point to the reference
// surface and, with a current surface, each reference point to it. Both
// directions see the same two sets of measurements, so each is halved to
// count the information once. A foot is searched from where it was found
// at the previous linearisation.
class GeometryResiduals
{
public:
  GeometryResiduals(const BeamSurface& reference_surface, const std::vector<Eigen::Vector3d>& reference,
                    const BeamSurface* current_surface, const std::vector<Eigen::Vector3d>& current)
    : reference_surface_(reference_surface),
      reference_(reference),
      current_surface_(current_surface != nullptr && !current_surface->empty() ? current_surface : nullptr),
      current_(current),
      direction_weight_(current_surface_ ? 0.5 : 1.0),
      uv_forward_(current.size()),
      uv_reverse_(reference.size()),
      feet_forward_(current.size()),
      feet_reverse_(reference.size())
  {
    for (size_t i = 0; i < current.size(); ++i)
      uv_forward_[i] = gridPoint(reference_surface_, i, current.size());
    if (current_surface_)
      for (size_t j = 0; j < reference.size(); ++j)
        uv_reverse_[j] = gridPoint(*current_surface_, j, reference.size());
  }

  // Linearises at T and adds the Huber-weighted rows. Each direction has
  // its own robust scale: the current points against the (refined)
  // reference surface and the reference points against the current surface
  // interpolated from this frame's dots alone are not equally good.
  void addTo(const Eigen::Isometry3d& T, const PoseDeltaParams& config, NormalEquations* system)
  {
    linearize(T);
    std::vector<double> magnitudes[2];
    for (const Row& row : rows_)
      magnitudes[row.reverse ? 1 : 0].push_back(std::abs(row.r));
    double scale[2];
    for (int d = 0; d < 2; ++d)
      scale[d] = robustScale(magnitudes[d], config.min_geometry_sigma_m);
    sigma_floor_ = config.min_geometry_sigma_m;
    const Matrix6d before = system->H;
    sum_r2_ = 0.0;
    for (const Row& row : rows_)
    {
      const double sd = scale[row.reverse ? 1 : 0];
      const double ar = std::abs(row.r), kg = config.huber_k * sd;
      const double huber = ar <= kg ? 1.0 : kg / ar;
      const double w = row.w * huber / (sd * sd);
      system->H.noalias() += w * row.J.transpose() * row.J;
      system->g.noalias() += w * row.J.transpose() * row.r;
      sum_r2_ += row.r * row.r;
    }
    system->addInformation(before, 1.0);  // the points' errors are independent
  }

  bool empty() const { return rows_.empty(); }
  int pointsUsed() const { return forward_used_; }
  // Robust scale of all the residuals of the last linearisation (for the
  // report: computed once, at the solution).
  double sigma() const
  {
    std::vector<double> all;
    all.reserve(rows_.size());
    for (const Row& row : rows_)
      all.push_back(std::abs(row.r));
    return robustScale(std::move(all), sigma_floor_);
  }
  double rms() const { return rows_.empty() ? 0.0 : std::sqrt(sum_r2_ / static_cast<double>(rows_.size())); }

private:
  struct Row
  {
    Eigen::Matrix<double, 1, 6> J;
    double r;
    double w;
    bool reverse = false;  // a reference point against the current surface
  };

  // Where a point's perpendicular foot was last searched from, and what was found.
  struct Foot
  {
    Eigen::Vector3d from = Eigen::Vector3d::Constant(detail::kNaN);
    Eigen::Vector3d foot;
    Eigen::Vector3d normal;
  };

  // Where the foot search of beam `beam` of a map of `points` beams starts:
  // the beam's own grid point on a surface built on a beam map (the beam
  // hits the rock near where it hit it there), none (the nearest surface
  // point) on a surface built on another grid (a denser map of the rock).
  static Eigen::Vector2d gridPoint(const BeamSurface& surface, size_t beam, size_t points)
  {
    const size_t cols = static_cast<size_t>(std::max(surface.cols(), 1));
    if (static_cast<size_t>(surface.rows()) * cols != points)
      return Eigen::Vector2d::Constant(detail::kNaN);
    return Eigen::Vector2d(static_cast<double>(beam / cols), static_cast<double>(beam % cols));
  }

  // The foot of x on `surface` (point `index`), null when there is none. A
  // point that moved less than kFootReuseM since its last search keeps that
  // foot and normal: its residual is then the distance to the tangent plane
  // there, which differs from the distance to the surface by the curvature
  // times half the squared move (under a micrometre), and the search
  // (several patch evaluations) dominates the cost of a solve. A foot at the
  // border of the map is searched again every time: whether the point is
  // still on the mapped rock is the search's to say.
  const Foot* footOf(const BeamSurface& surface, const Eigen::Vector3d& x, size_t index, Eigen::Vector2d* uv,
                     Foot* cached) const
  {
    if ((x - cached->from).squaredNorm() < kFootReuseM * kFootReuseM)
      return cached;
    cached->from = x;
    if (surface.closestPoint(x, uv, &cached->foot, &cached->normal))
    {
      const double m = kFootBorderMargin;
      if (!(uv->x() > m && uv->y() > m && uv->x() < surface.rows() - 1 - m && uv->y() < surface.cols() - 1 - m))
        cached->from = Eigen::Vector3d::Constant(detail::kNaN);
      return cached;
    }
    *uv = gridPoint(surface, index, &surface == &reference_surface_ ? current_.size() : reference_.size());
    cached->from = Eigen::Vector3d::Constant(detail::kNaN);
    return nullptr;
  }

  void linearize(const Eigen::Isometry3d& T)
  {
    rows_.clear();
    forward_used_ = 0;
    const Eigen::Matrix3d R = T.linear();
    const Eigen::Isometry3d Tinv = T.inverse();
    for (size_t i = 0; i < current_.size(); ++i)
    {
      const Eigen::Vector3d& q = current_[i];
      if (!isUsablePoint(q))
        continue;
      const Eigen::Vector3d x = Tinv * q;
      const Foot* f = footOf(reference_surface_, x, i, &uv_forward_[i], &feet_forward_[i]);
      if (f == nullptr)
        continue;
      const Eigen::Vector3d& foot = f->foot;
      const Eigen::Vector3d& n = f->normal;
      const Eigen::Vector3d m = R * n;
      Row row;
      row.J << -m.transpose(), m.cross(q).transpose();
      row.r = n.dot(x - foot);
      row.w = direction_weight_;
      rows_.push_back(row);
      ++forward_used_;
    }
    if (current_surface_)
      linearizeReverse(T);
  }

  void linearizeReverse(const Eigen::Isometry3d& T)
  {
    for (size_t j = 0; j < reference_.size(); ++j)
    {
      if (!isUsablePoint(reference_[j]))
        continue;
      const Eigen::Vector3d y = T * reference_[j];
      const Foot* f = footOf(*current_surface_, y, j, &uv_reverse_[j], &feet_reverse_[j]);
      if (f == nullptr)
        continue;
      const Eigen::Vector3d& foot = f->foot;
      const Eigen::Vector3d& n = f->normal;
      Row row;
      row.J << n.transpose(), y.cross(n).transpose();
      row.r = n.dot(y - foot);
      row.w = direction_weight_;
      row.reverse = true;
      rows_.push_back(row);
    }
  }

  const BeamSurface& reference_surface_;
  const std::vector<Eigen::Vector3d>& reference_;
  const BeamSurface* current_surface_;  // null: one direction only
  const std::vector<Eigen::Vector3d>& current_;
  const double direction_weight_;
  std::vector<Eigen::Vector2d> uv_forward_, uv_reverse_;  // where each foot was found last
  std::vector<Foot> feet_forward_, feet_reverse_;
  std::vector<Row> rows_;
  int forward_used_ = 0;
  double sigma_floor_ = 0.0;
  double sum_r2_ = 0.0;
};

}  // namespace registration
}  // namespace structured_light_stabilizer
