#include "structured_light_stabilizer/pose/registration.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SVD>

#include "structured_light_stabilizer/common/math.h"
#include "pose/registration/geometry_residuals.h"
#include "pose/registration/normal_equations.h"
#include "pose/registration/texture_residuals.h"

namespace structured_light_stabilizer
{

namespace
{

using registration::GeometryResiduals;
using registration::kHuberIterations;
using registration::NormalEquations;
using registration::Subspace;
using registration::TextureResiduals;

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

// 10 um, 5 urad (7.5 um at the rock): a tenth of the noise (0.1 mm), a fifth
// of the return-to-reference bound (0.05 mm); the robust weights of marginal
// features flipping keep smaller steps going without changing the answer.
// From 2 um / 1 urad: 7.7 -> 6.0 iterations and 3.61 -> 3.15 ms per frame
// (benchmark_pose_delta 60 6 0.0333), every pose test's figure the same to
// within 0.005 mm (scripts/test --stage pose).
bool negligible(const Vector6d& delta)
{
  return delta.head<3>().norm() < 1e-5 && delta.tail<3>().norm() < 5e-6;
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
        config.freeze_factor * std::max(config.max_sigma_translation_m, config.maxSigmaRotationRad() * depth);
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
