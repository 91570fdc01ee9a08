// Shared by the registration's solver and its residual builders
// (src/pose/registration/): the normal equations every kind of residual adds
// into, and the robust scale of a set of residuals. Private to the pose stage.
#pragma once

#include <algorithm>
#include <vector>

#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/pose/registration.h"

namespace structured_light_stabilizer
{
namespace registration
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
inline double robustScale(std::vector<double> magnitudes, double floor)
{
  return std::max(floor, kMadToSigma * detail::medianInPlace(magnitudes.begin(), magnitudes.end()));
}

}  // namespace registration
}  // namespace structured_light_stabilizer
