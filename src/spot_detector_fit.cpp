// Stage 4 of the fast method for dots with clipped pixels: the clipped
// plateau, and a Gaussian fitted to the unclipped flanks (see
// spot_detector_fast_stages.h). A clipped core is
// a plateau whose shape follows the albedo under it and the sensor's
// blooming, not the beam: the Gauss-weighted centroid of the plateau is
// pulled wherever the plateau is wider, the flanks are not.
#include <algorithm>
#include <cmath>
#include <vector>

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

// The window's usable pixels (always the same set, so that sums of squares
// of different models compare), by offset from the window's centre.
struct Samples
{
  int cx = 0, cy = 0, H = 0;
  std::vector<int> dx, dy;
  std::vector<double> v;
};

// Those within `radius` of (x, y) only: farther out a dot adds nothing but
// noise (and a neighbour's flank). Into *s, whose buffers are reused.
void usableSamples(const WeightWindow& w, double x, double y, double radius, Samples* s)
{
  s->cx = w.cx;
  s->cy = w.cy;
  s->H = w.H;
  s->dx.clear();
  s->dy.clear();
  s->v.clear();
  const double r2 = radius * radius;
  for (int dy = -w.H; dy <= w.H; ++dy)
    for (int dx = -w.H; dx <= w.H; ++dx)
    {
      const int i = (dy + w.H) * w.stride + dx + w.H;
      if (!w.usable[i] || detail::square(w.cx + dx - x) + detail::square(w.cy + dy - y) > r2)
        continue;
      s->dx.push_back(dx);
      s->dy.push_back(dy);
      s->v.push_back(w.vals[i]);
    }
}

// The separable Gaussian of a model over the window: g(dx, dy) = gx[dx + H] gy[dy + H].
struct Profile
{
  double gx[2 * PlaneWindow::kMaxRadius + 1], gy[2 * PlaneWindow::kMaxRadius + 1];
  Profile(const Samples& s, const Model& m)
  {
    const double k = -0.5 / (m.s * m.s);
    for (int d = -s.H; d <= s.H; ++d)
    {
      gx[d + s.H] = std::exp(k * detail::square(s.cx + d - m.x));
      gy[d + s.H] = std::exp(k * detail::square(s.cy + d - m.y));
    }
  }
  double at(const Samples& s, size_t i) const { return gx[s.dx[i] + s.H] * gy[s.dy[i] + s.H]; }
};

// Normal equations of the residuals v - a exp(-r^2 / 2 s^2) and their sum
// of squares (the ten distinct terms of J^T J accumulated by hand: this runs
// a few times per iteration for every clipped dot).
double normalEquations(const Samples& s, const Model& m, cv::Matx44d* JtJ, cv::Vec4d* Jtr)
{
  const Profile p(s, m);
  const double inv_s2 = 1.0 / (m.s * m.s);
  double a[10] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0}, b[4] = {0, 0, 0, 0}, ss = 0;
  for (size_t i = 0; i < s.v.size(); ++i)
  {
    const double ex = s.cx + s.dx[i] - m.x, ey = s.cy + s.dy[i] - m.y;
    const double g = p.at(s, i), ag = m.a * g;
    const double res = s.v[i] - ag;
    const double j0 = g, j1 = ag * ex * inv_s2, j2 = ag * ey * inv_s2, j3 = ag * (ex * ex + ey * ey) * inv_s2 / m.s;
    a[0] += j0 * j0;
    a[1] += j0 * j1;
    a[2] += j0 * j2;
    a[3] += j0 * j3;
    a[4] += j1 * j1;
    a[5] += j1 * j2;
    a[6] += j1 * j3;
    a[7] += j2 * j2;
    a[8] += j2 * j3;
    a[9] += j3 * j3;
    b[0] += j0 * res;
    b[1] += j1 * res;
    b[2] += j2 * res;
    b[3] += j3 * res;
    ss += res * res;
  }
  *JtJ = cv::Matx44d(a[0], a[1], a[2], a[3], a[1], a[4], a[5], a[6], a[2], a[5], a[7], a[8], a[3], a[6], a[8], a[9]);
  *Jtr = cv::Vec4d(b[0], b[1], b[2], b[3]);
  return ss;
}

// The amplitude that fits best for the model's centre and sigma (linear),
// and the sum of squares it leaves.
double bestAmplitude(const Samples& s, Model* m)
{
  const Profile p(s, *m);
  double vg = 0, gg = 0, vv = 0;
  for (size_t i = 0; i < s.v.size(); ++i)
  {
    const double g = p.at(s, i);
    vg += s.v[i] * g;
    gg += g * g;
    vv += s.v[i] * s.v[i];
  }
  m->a = gg > 0 ? vg / gg : 0.0;
  return gg > 0 ? vv - vg * vg / gg : detail::kInf;
}

// Levenberg-Marquardt on (a, x, y, s) from m (whose amplitude is set).
double levenbergMarquardt(const Samples& samples, Model* model)
{
  Model& m = *model;
  double lambda = 1e-3;
  cv::Matx44d JtJ;
  cv::Vec4d Jtr;
  double ss = normalEquations(samples, m, &JtJ, &Jtr);
  for (int it = 0; it < 30; ++it)
  {
    cv::Matx44d A = JtJ;
    for (int k = 0; k < 4; ++k)
      A(k, k) *= 1.0 + lambda;
    cv::Vec4d step;
    if (!cv::solve(A, Jtr, step, cv::DECOMP_CHOLESKY))
      break;
    const Model trial{m.a + step[0], m.x + step[1], m.y + step[2], m.s + step[3]};
    cv::Matx44d JtJ2;
    cv::Vec4d Jtr2;
    const double ss2 = trial.s > 0.3 && trial.a > 0 ? normalEquations(samples, trial, &JtJ2, &Jtr2) : detail::kInf;
    if (ss2 <= ss)
    {
      m = trial;
      ss = ss2;
      JtJ = JtJ2;
      Jtr = Jtr2;
      lambda = std::max(1e-6, lambda * 0.3);
      // Far below the noise of a centroid (a few thousandths of a pixel).
      if (std::hypot(step[1], step[2]) < 2e-4 && std::abs(step[3]) < 1e-3)
        break;
    }
    else if ((lambda *= 10.0) > 1e6)
    {
      break;
    }
  }
  return ss;
}
}  // namespace

// The clipped plateau nearest to (x, y) in the window: its centroid and its
// half width across the columns (blooming runs along them, so the width is
// the clipping's own). False when the window has no clipped sample.
bool clippedPlateau(const PlaneWindow& pw, double x, double y, cv::Point2d* centre, double* half_width)
{
  const int H = pw.H;
  auto clipped = [&](int dx, int dy)
  {
    return std::abs(dx) <= H && std::abs(dy) <= H &&
           (pw.flags[pw.index(dx, dy)] & (PlaneWindow::kClipped | PlaneWindow::kSample)) ==
               (PlaneWindow::kClipped | PlaneWindow::kSample);
  };
  int sx = 0, sy = 0;
  double best = detail::kInf;
  for (int dy = -H; dy <= H; ++dy)
    for (int dx = -H; dx <= H; ++dx)
      if (clipped(dx, dy) && detail::square(pw.cx + dx - x) + detail::square(pw.cy + dy - y) < best)
      {
        best = detail::square(pw.cx + dx - x) + detail::square(pw.cy + dy - y);
        sx = dx;
        sy = dy;
      }
  if (!std::isfinite(best))
    return false;
  // Flood fill within 2 px (a Bayer mosaic's samples of one colour are 2 px apart).
  uint8_t seen[PlaneWindow::kSize] = {};
  cv::Point stack[PlaneWindow::kSize];
  int top = 0;
  stack[top++] = cv::Point(sx, sy);
  seen[pw.index(sx, sy)] = 1;
  double mx = 0, my = 0;
  int n = 0, widest = 0;
  cv::Vec2i row_span[2 * PlaneWindow::kMaxRadius + 1];
  std::fill(row_span, row_span + 2 * H + 1, cv::Vec2i(1 << 20, -(1 << 20)));
  while (top > 0)
  {
    const cv::Point q = stack[--top];
    mx += q.x;
    my += q.y;
    ++n;
    cv::Vec2i& span = row_span[q.y + H];
    span = cv::Vec2i(std::min(span[0], q.x), std::max(span[1], q.x));
    widest = std::max(widest, span[1] - span[0] + 1);
    for (int ey = -2; ey <= 2; ++ey)
      for (int ex = -2; ex <= 2; ++ex)
        if (clipped(q.x + ex, q.y + ey) && !seen[pw.index(q.x + ex, q.y + ey)])
        {
          seen[pw.index(q.x + ex, q.y + ey)] = 1;
          stack[top++] = cv::Point(q.x + ex, q.y + ey);  // each pixel once: fits
        }
  }
  *centre = cv::Point2d(pw.cx + mx / n, pw.cy + my / n);
  *half_width = 0.5 * widest;
  return true;
}

// From the centroid's estimate: of three starting sigmas (a clipped plateau
// inflates the centroid's) the one whose best amplitude fits best starts the
// iterations.
bool fitGaussian(const WeightWindow& w, double max_sigma, SpotFit* fit)
{
  thread_local Samples samples;  // buffers kept across calls
  usableSamples(w, fit->x, fit->y, 3.0 * fit->sigma + 2.0, &samples);
  if (samples.v.size() < 8)
    return false;
  Model best{0, 0, 0, 0};
  double best_ss = detail::kInf;
  for (double f : {1.0, 0.7, 1.4})
  {
    Model m{0, fit->x, fit->y, std::max(0.8, f * fit->sigma)};
    const double ss = bestAmplitude(samples, &m);
    if (m.a > 0 && ss < best_ss)
    {
      best = m;
      best_ss = ss;
    }
  }
  if (!std::isfinite(best_ss))
    return false;
  Model m = best;
  levenbergMarquardt(samples, &m);
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
