// Stage 4 of the fast method for dots with clipped pixels: a Gaussian fitted
// to the unclipped flanks (see spot_detector_fast_stages.h). A clipped core is
// a plateau whose shape follows the albedo under it and the sensor's
// blooming, not the beam: the Gauss-weighted centroid of the plateau is
// pulled wherever the plateau is wider, the flanks are not.
#include <cmath>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/detail/math.h"
#include "spot_detector_fast_stages.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

namespace
{
struct Model
{
  double a, x, y, s;  // amplitude, centre (pixels of the frame), sigma
};

// Normal equations of the residuals v - a exp(-r^2 / 2 s^2) over the
// window's usable pixels (always the same set, so that sums of squares of
// different models compare), and their sum of squares.
double normalEquations(const WeightWindow& w, const Model& m, cv::Matx44d* JtJ, cv::Vec4d* Jtr, int* used)
{
  *JtJ = cv::Matx44d::zeros();
  *Jtr = cv::Vec4d::all(0.0);
  *used = 0;
  double ss = 0;
  const double inv_s2 = 1.0 / (m.s * m.s);
  for (int dy = -w.H; dy <= w.H; ++dy)
    for (int dx = -w.H; dx <= w.H; ++dx)
    {
      const int i = (dy + w.H) * w.stride + dx + w.H;
      const double ex = w.cx + dx - m.x, ey = w.cy + dy - m.y, r2 = ex * ex + ey * ey;
      if (!w.usable[i])
        continue;
      const double g = std::exp(-0.5 * r2 * inv_s2);
      const double res = w.vals[i] - m.a * g;
      const cv::Vec4d J(g, m.a * g * ex * inv_s2, m.a * g * ey * inv_s2, m.a * g * r2 * inv_s2 / m.s);
      *JtJ += J * J.t();
      *Jtr += J * res;
      ss += res * res;
      ++*used;
    }
  return ss;
}

// The amplitude that fits best for a given centre and sigma (linear).
double bestAmplitude(const WeightWindow& w, const Model& m)
{
  double vg = 0, gg = 0;
  const double inv_s2 = 1.0 / (m.s * m.s);
  for (int dy = -w.H; dy <= w.H; ++dy)
    for (int dx = -w.H; dx <= w.H; ++dx)
    {
      const int i = (dy + w.H) * w.stride + dx + w.H;
      if (!w.usable[i])
        continue;
      const double g = std::exp(-0.5 * (detail::square(w.cx + dx - m.x) + detail::square(w.cy + dy - m.y)) * inv_s2);
      vg += w.vals[i] * g;
      gg += g * g;
    }
  return gg > 0 ? vg / gg : 0.0;
}

// Levenberg-Marquardt on (a, x, y, s) from m; false when it cannot start.
bool levenbergMarquardt(const WeightWindow& w, Model* model, double* sum_sq)
{
  Model& m = *model;
  m.a = bestAmplitude(w, m);
  if (!(m.a > 0))
    return false;
  double lambda = 1e-3;
  cv::Matx44d JtJ;
  cv::Vec4d Jtr;
  int used = 0;
  double ss = normalEquations(w, m, &JtJ, &Jtr, &used);
  bool converged = false;
  for (int it = 0; it < 30 && !converged; ++it)
  {
    if (used < 8)
      return false;
    cv::Matx44d A = JtJ;
    for (int k = 0; k < 4; ++k)
      A(k, k) *= 1.0 + lambda;
    cv::Vec4d step;
    if (!cv::solve(A, Jtr, step, cv::DECOMP_CHOLESKY))
      return false;
    const Model trial{m.a + step[0], m.x + step[1], m.y + step[2], m.s + step[3]};
    cv::Matx44d JtJ2;
    cv::Vec4d Jtr2;
    int used2 = 0;
    const double ss2 = trial.s > 0.3 && trial.a > 0 ? normalEquations(w, trial, &JtJ2, &Jtr2, &used2) : detail::kInf;
    if (ss2 <= ss && used2 >= 8)
    {
      converged = std::hypot(step[1], step[2]) < 1e-4 && std::abs(step[3]) < 1e-4;
      m = trial;
      ss = ss2;
      JtJ = JtJ2;
      Jtr = Jtr2;
      used = used2;
      lambda = std::max(1e-6, lambda * 0.3);
    }
    else
    {
      lambda *= 10.0;
      converged = lambda > 1e6;
    }
  }
  *sum_sq = ss;
  return true;
}
}  // namespace

// From the centroid's estimate, with three starting sigmas (a clipped
// plateau inflates the centroid's): the best fit wins.
bool fitGaussian(const WeightWindow& w, double max_sigma, SpotFit* fit)
{
  Model best{0, 0, 0, 0};
  double best_ss = detail::kInf;
  for (double f : {1.0, 0.7, 1.4})
  {
    Model m{0, fit->x, fit->y, std::max(0.8, f * fit->sigma)};
    double ss;
    if (levenbergMarquardt(w, &m, &ss) && ss < best_ss)
    {
      best = m;
      best_ss = ss;
    }
  }
  if (!std::isfinite(best_ss))
    return false;
  const Model& m = best;
  // The fit must stay in its window (a bloom streak can pull the centroid
  // along the column by several pixels, so not necessarily near it) and keep
  // a dot's size.
  if (!std::isfinite(m.x) || std::abs(m.x - w.cx) > w.H - 1 || std::abs(m.y - w.cy) > w.H - 1 ||
      m.s > 1.5 * max_sigma + 1.0)
    return false;
  fit->x = m.x;
  fit->y = m.y;
  fit->sigma = fit->sigma_major = m.s;
  fit->amplitude = m.a;
  fit->flux = m.a * detail::kPi * m.s * m.s;
  return true;
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
