#include "structured_light_stabilizer/registration.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SVD>

#include "structured_light_stabilizer/detail/math.h"

namespace structured_light_stabilizer
{

namespace
{

// MAD of Gaussian noise -> its standard deviation.
constexpr double kMadToSigma = 1.4826;
// Tukey's biweight constant (95 % efficiency on Gaussian noise), in robust sigmas.
constexpr double kTukeyC = 4.685;
// Texture weights turn from Huber to Tukey after this many iterations.
constexpr int kHuberIterations = 3;
// Least robust scale of whitened texture residuals: only against degeneracy
// (all residuals zero), far below any real scatter.
constexpr double kMinWhitenedScale = 1e-3;
// A point moved less than this (metres) since its foot on a surface was
// searched keeps that foot within a solve (GeometryResiduals::footOf).
constexpr double kFootReuseM = 2e-4;
// Feet within this (grid cells) of the border of the map are not reused.
constexpr double kFootBorderMargin = 0.05;

// Directions of the update in scaled coordinates (rotations times the scene
// depth), one per column.
using Subspace = Eigen::Matrix<double, 6, Eigen::Dynamic>;

// Normal equations of the pose increment delta (se3.h): H delta = -g. Every
// kind of residual adds into the same running sums, in a fixed order.
struct NormalEquations
{
  Matrix6d H = Matrix6d::Zero();  // J^T W J, each residual weighted as independent: this sets the step
  Vector6d g = Vector6d::Zero();  // J^T W r
  // H with each kind's share divided by the square of its error inflation:
  // what the solution is worth (covariance, frozen directions).
  Matrix6d information = Matrix6d::Zero();

  // Books what H gained since `before` into the information.
  void addInformation(const Matrix6d& before, double inflation2) { information += (H - before) / inflation2; }
};

// Robust scale (MAD) of residual magnitudes, floored by the expected noise.
double robustScale(std::vector<double> magnitudes, double floor)
{
  return std::max(floor, kMadToSigma * detail::medianInPlace(magnitudes.begin(), magnitudes.end()));
}

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
      cols_(std::max(reference_surface.cols(), 1)),
      direction_weight_(current_surface_ ? 0.5 : 1.0),
      uv_forward_(current.size()),
      uv_reverse_(reference.size()),
      feet_forward_(current.size()),
      feet_reverse_(reference.size())
  {
    for (size_t i = 0; i < current.size(); ++i)
      uv_forward_[i] = gridPoint(i);
    for (size_t j = 0; j < reference.size(); ++j)
      uv_reverse_[j] = gridPoint(j);
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

  Eigen::Vector2d gridPoint(size_t beam) const
  {
    return Eigen::Vector2d(static_cast<double>(beam / cols_), static_cast<double>(beam % cols_));
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
    *uv = gridPoint(index);
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
  const size_t cols_;
  const double direction_weight_;
  std::vector<Eigen::Vector2d> uv_forward_, uv_reverse_;  // where each foot was found last
  std::vector<Foot> feet_forward_, feet_reverse_;
  std::vector<Row> rows_;
  int forward_used_ = 0;
  double sigma_floor_ = 0.0;
  double sum_r2_ = 0.0;
};

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

// The weak prior (information) that keeps unobservable directions at the initial guess.
Matrix6d priorInformation(const PoseDeltaParams& config)
{
  Matrix6d prior = Matrix6d::Zero();
  for (int a = 0; a < 3; ++a)
  {
    prior(a, a) = 1.0 / (config.prior_sigma_translation_m * config.prior_sigma_translation_m);
    prior(a + 3, a + 3) = 1.0 / (config.prior_sigma_rotation_rad * config.prior_sigma_rotation_rad);
  }
  return prior;
}

// How far T is from the initial guess, in the increments' coordinates.
Vector6d priorResidual(const Eigen::Isometry3d& T, const Eigen::Isometry3d& initial)
{
  Vector6d r;
  const Eigen::Isometry3d D = T * initial.inverse();
  r << D.translation(), logSO3(D.linear());
  return r;
}

// The Gauss-Newton step with the prior, restricted to the directions V.
// Scaling the rotations by the scene depth makes both halves metres.
Vector6d solveStep(const NormalEquations& system, const Matrix6d& prior, const Vector6d& prior_r, const Subspace& V,
                   const Vector6d& scale)
{
  const Matrix6d A = system.H + prior;
  const Vector6d b = system.g + prior * prior_r;
  const Matrix6d As = scale.cwiseInverse().asDiagonal() * A * scale.cwiseInverse().asDiagonal();
  const Vector6d bs = scale.cwiseInverse().asDiagonal() * b;
  const Eigen::MatrixXd Ar = V.transpose() * As * V;
  const Eigen::VectorXd step_r = -Ar.ldlt().solve(V.transpose() * bs);
  return scale.cwiseInverse().asDiagonal() * (V * step_r);
}

// The directions (scaled coordinates) in which the information fixes the
// pose to within freeze_sigma metres.
Subspace observableDirections(const Matrix6d& information, const Vector6d& scale, double freeze_sigma)
{
  const Matrix6d Hs = scale.cwiseInverse().asDiagonal() * information * scale.cwiseInverse().asDiagonal();
  // Hs is symmetric positive semi-definite, so its SVD is its eigen
  // decomposition (and Jacobi SVD avoids a GCC false positive that the
  // tridiagonalising eigen solver triggers with -Wall).
  const Eigen::JacobiSVD<Matrix6d> eig(Hs, Eigen::ComputeFullU);
  const double min_info = 1.0 / (freeze_sigma * freeze_sigma);
  Subspace kept(6, 0);
  for (int k = 0; k < 6; ++k)
  {
    if (eig.singularValues()[k] >= min_info)
    {
      kept.conservativeResize(Eigen::NoChange, kept.cols() + 1);
      kept.col(kept.cols() - 1) = eig.matrixU().col(k);
    }
  }
  return kept;
}

// Median distance of the current points: converts rotations into metres of motion at the rock.
double sceneDepth(const std::vector<Eigen::Vector3d>& points)
{
  std::vector<double> range;
  for (const Eigen::Vector3d& q : points)
    if (isUsablePoint(q))
      range.push_back(q.norm());
  return range.empty() ? 1.0 : detail::medianInPlace(range.begin(), range.end());
}

// 2 um, 1 urad (1.5 um at the rock): far below the noise (0.1 mm) and the
// return-to-reference bound (0.05 mm); the robust weights of marginal
// features flipping keep smaller steps going without changing the answer.
bool negligible(const Vector6d& delta)
{
  return delta.head<3>().norm() < 2e-6 && delta.tail<3>().norm() < 1e-6;
}

class SurfaceRegistration
{
public:
  SurfaceRegistration(const BeamSurface& reference_surface, const std::vector<Eigen::Vector3d>& reference,
                      const BeamSurface* current_surface, const std::vector<Eigen::Vector3d>& current,
                      const TextureObservations& texture, const PoseDeltaParams& config)
    : config_(config),
      geometry_(reference_surface, reference, current_surface, current),
      texture_(texture, config.min_texture_sigma_px),
      prior_(priorInformation(config))
  {
    const double depth = sceneDepth(current);
    scale_ << 1.0, 1.0, 1.0, depth, depth, depth;
    freeze_sigma_ =
        config.freeze_factor * std::max(config.max_sigma_translation_m, config.max_sigma_rotation_rad * depth);
  }

  RegistrationOutput run(const Eigen::Isometry3d& initial)
  {
    Solution s = gaussNewton(initial, Matrix6d::Identity());
    // Directions the data cannot fix to within the validity bounds must not
    // move at all: the estimate is the next frame's initial guess, and noise
    // would make them random-walk from frame to frame. Decided at the
    // solution (where the residual scales are the noise, not the initial
    // misalignment), then solved again from the initial guess with those
    // directions frozen.
    const Subspace observable = observableDirections(s.system.information, scale_, freeze_sigma_);
    if (observable.cols() < 6)
    {
      texture_.restart();
      s = gaussNewton(initial, observable);
    }
    return output(s);
  }

private:
  struct Solution
  {
    Eigen::Isometry3d T;
    NormalEquations system;  // at T
    int iterations = 0;
  };

  // The residuals of the registration at T. A new kind of residual is one
  // more builder and one more line here.
  NormalEquations linearize(const Eigen::Isometry3d& T, int iteration)
  {
    NormalEquations system;
    geometry_.addTo(T, config_, &system);
    texture_.addTo(T, config_, iteration, &system);
    return system;
  }

  Solution gaussNewton(const Eigen::Isometry3d& initial, const Subspace& directions)
  {
    Solution s;
    s.T = initial;
    bool converged = false;
    for (int it = 0; it <= config_.max_iterations; ++it)
    {
      s.system = linearize(s.T, it);
      s.iterations = it;
      // Once settled, this last pass has evaluated residuals and information at the solution.
      if (it == config_.max_iterations || geometry_.empty() || converged || directions.cols() == 0)
        break;
      const Vector6d delta = solveStep(s.system, prior_, priorResidual(s.T, initial), directions, scale_);
      if (!delta.allFinite())
        break;
      s.T = applyIncrement(delta, s.T);
      texture_.applyStep(delta);
      // Not before the texture's weights have turned to Tukey's.
      converged = negligible(delta) && it >= kHuberIterations;
    }
    return s;
  }

  RegistrationOutput output(const Solution& s) const
  {
    RegistrationOutput out;
    out.transform = s.T;
    out.information = s.system.information;
    out.covariance = (s.system.information + prior_).inverse();
    out.rms_geometry_m = geometry_.rms();
    out.sigma_geometry_m = geometry_.sigma();
    out.sigma_texture_px = texture_.sigma();
    out.points_used = geometry_.pointsUsed();
    out.features_used = texture_.used();
    out.iterations = s.iterations;
    return out;
  }

  const PoseDeltaParams& config_;
  GeometryResiduals geometry_;
  TextureResiduals texture_;
  const Matrix6d prior_;
  Vector6d scale_;  // (1, 1, 1, d, d, d), d the scene depth: rotations as metres at the rock
  double freeze_sigma_ = 0.0;
};

}  // namespace

RegistrationOutput registerToSurface(const BeamSurface& reference_surface,
                                     const std::vector<Eigen::Vector3d>& reference, const BeamSurface* current_surface,
                                     const std::vector<Eigen::Vector3d>& current, const TextureObservations& texture,
                                     const Eigen::Isometry3d& initial, const PoseDeltaParams& config)
{
  return SurfaceRegistration(reference_surface, reference, current_surface, current, texture, config).run(initial);
}

}  // namespace structured_light_stabilizer
