// The texture residual builder of the registration (registration.h): reprojection
// errors of the tracked rock texture, free depths eliminated per feature.
// Private to the pose stage.
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

// Reprojection errors (pixels) of the tracked texture features. A feature
// with a depth prior sits along its reference ray at a depth that is an
// unknown of the solve, eliminated per feature (Schur complement) so the pose
// system stays 6x6, and moved along with each pose step.
class TextureResiduals
{
public:
  // `floor_px`: least 1-sigma of a feature with a measured covariance.
  TextureResiduals(const TextureObservations& texture, double floor_px)
    : constraints_(texture.constraints),
      focal_px_(texture.focal_px),
      offset_(texture.offset),
      ray_(texture.constraints.size()),
      depth0_(texture.constraints.size()),
      whiten_(texture.constraints.size(), Eigen::Matrix2d::Identity())
  {
    for (size_t k = 0; k < constraints_.size(); ++k)
    {
      depth0_[k] = constraints_[k].point_ref.norm();
      ray_[k] = depth0_[k] > 0.0 ? Eigen::Vector3d(constraints_[k].point_ref / depth0_[k]) : Eigen::Vector3d::Zero();
      const Eigen::Matrix2d& C = constraints_[k].covariance_px;
      if (C.isZero() || !C.allFinite())
        continue;
      // W with W C W^T = I: the residual in units of its own 1-sigma.
      const Eigen::LLT<Eigen::Matrix2d> llt(C + floor_px * floor_px * Eigen::Matrix2d::Identity());
      if (llt.info() == Eigen::Success)
      {
        whiten_[k] = llt.matrixL().solve(Eigen::Matrix2d::Identity());
        whitened_ = true;
      }
    }
    depth_ = depth0_;
  }

  // Linearises at T and adds the robustly weighted rows; the features'
  // errors are correlated, so their information is deflated.
  void addTo(const Eigen::Isometry3d& T, const PoseDeltaParams& config, int iteration, NormalEquations* system)
  {
    linearize(T);
    std::vector<double> magnitudes;
    magnitudes.reserve(2 * rows_.size());
    for (const Row& row : rows_)
    {
      magnitudes.push_back(std::abs(row.r.x()));
      magnitudes.push_back(std::abs(row.r.y()));
    }
    // Whitened residuals are in units of their measured sigma: their scale
    // says how well those sigmas hold (no floor needed beyond degeneracy).
    scale_ = robustScale(std::move(magnitudes), whitened_ ? kMinWhitenedScale : config.min_texture_sigma_px);
    const Matrix6d before = system->H;
    eliminated_.clear();
    used_ = 0;
    for (const Row& row : rows_)
    {
      double robust = 0.0;
      if (!robustWeight(row.r.norm(), config.huber_k * scale_, iteration, &robust))
        continue;
      addRow(row, robust / (scale_ * scale_), system);
      ++used_;
    }
    system->addInformation(before, config.texture_error_inflation * config.texture_error_inflation);
  }

  // The features' depths follow the pose step `delta` taken.
  void applyStep(const Vector6d& delta)
  {
    for (const DepthElimination& e : eliminated_)
      depth_[e.k] -= (e.g + e.B.dot(delta)) / e.C;
  }

  // Back to the depth priors, for a new solve from the initial guess.
  void restart() { depth_ = depth0_; }

  int used() const { return used_; }
  // Robust scale of the last linearisation's residuals in pixels (for the
  // report: computed once, at the solution).
  double sigma() const
  {
    std::vector<double> pixels;
    pixels.reserve(2 * rows_.size());
    for (const Row& row : rows_)
    {
      pixels.push_back(std::abs(row.r_px.x()));
      pixels.push_back(std::abs(row.r_px.y()));
    }
    return robustScale(std::move(pixels), 0.0);
  }

private:
  struct Row
  {
    Eigen::Matrix<double, 2, 6> J;  // whitened, as Jd and r
    Eigen::Vector2d Jd;             // derivative of the residual by the feature's depth
    Eigen::Vector2d r;
    Eigen::Vector2d r_px;  // the residual in pixels
    size_t feature;
  };
  struct DepthElimination
  {
    size_t k;
    Vector6d B;
    double C;
    double g;
  };

  // The image was exposed at offset_ * T: the point y0 = T X seen as y = offset_ y0.
  void linearize(const Eigen::Isometry3d& T)
  {
    rows_.clear();
    const Eigen::Matrix3d R = T.linear(), Ro = offset_.linear();
    for (size_t k = 0; k < constraints_.size(); ++k)
    {
      const Eigen::Vector3d y0 = T * Eigen::Vector3d(depth_[k] * ray_[k]);
      const Eigen::Vector3d y = offset_ * y0;
      if (!(y.z() > 1e-6))
        continue;
      const double iz = 1.0 / y.z();
      Eigen::Matrix<double, 2, 3> dpi;
      dpi << iz, 0.0, -y.x() * iz * iz, 0.0, iz, -y.y() * iz * iz;
      dpi *= focal_px_;
      Eigen::Matrix<double, 3, 6> dy;
      dy << Eigen::Matrix3d::Identity(), -skew(y0);
      Row row;
      const Eigen::Matrix2d& W = whiten_[k];
      row.J = W * dpi * Ro * dy;
      row.Jd = W * dpi * (Ro * R * ray_[k]);
      row.r_px = focal_px_ * (Eigen::Vector2d(y.x() * iz, y.y() * iz) - constraints_[k].observed_normalized);
      row.r = W * row.r_px;
      row.feature = k;
      rows_.push_back(row);
    }
  }

  // Huber while the pose settles, then Tukey's biweight: a feature on
  // something that does not move with the rock (a shadow edge, the rim of
  // the view, a dot) gets no weight at all (false) instead of a pull that
  // many of them would add up.
  bool robustWeight(double ar, double kt, int iteration, double* robust) const
  {
    *robust = ar <= kt ? 1.0 : kt / ar;
    if (iteration >= kHuberIterations)
    {
      const double u = ar / (kTukeyC * scale_);
      if (u >= 1.0)
        return false;
      *robust = (1.0 - u * u) * (1.0 - u * u);
    }
    return true;
  }

  void addRow(const Row& row, double w, NormalEquations* system)
  {
    const size_t f = row.feature;
    const double sd = constraints_[f].depth_sigma_m;
    if (!(sd > 0.0))
    {
      system->H.noalias() += w * row.J.transpose() * row.J;
      system->g.noalias() += w * row.J.transpose() * row.r;
      return;
    }
    // Marginalise the depth: its prior and the feature's own parallax.
    DepthElimination e;
    e.k = f;
    e.B = w * row.J.transpose() * row.Jd;
    e.C = w * row.Jd.squaredNorm() + 1.0 / (sd * sd);
    e.g = w * row.Jd.dot(row.r) + (depth_[f] - depth0_[f]) / (sd * sd);
    system->H.noalias() += w * row.J.transpose() * row.J - e.B * e.B.transpose() / e.C;
    system->g.noalias() += w * row.J.transpose() * row.r - e.B * (e.g / e.C);
    eliminated_.push_back(e);
  }

  const std::vector<TextureConstraint>& constraints_;
  const double focal_px_;
  const Eigen::Isometry3d offset_;
  std::vector<Eigen::Vector3d> ray_;  // unit reference rays
  std::vector<double> depth0_;        // the priors (distances along the rays)
  std::vector<double> depth_;         // the current values
  std::vector<Row> rows_;
  std::vector<DepthElimination> eliminated_;  // of the last linearisation
  std::vector<Eigen::Matrix2d> whiten_;       // per feature (identity without a covariance)
  bool whitened_ = false;                     // some feature has a measured covariance
  int used_ = 0;
  double scale_ = 0.0;  // robust scale of the (whitened) residuals
};

}  // namespace registration
}  // namespace structured_light_stabilizer
