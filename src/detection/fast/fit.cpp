// Stage 4 of the fast method for dots with clipped pixels: the clipped
// plateau, and a Gaussian fitted to the unclipped flanks (see
// spot_detector_fast_stages.h). A clipped core is
// a plateau whose shape follows the albedo under it and the sensor's
// blooming, not the beam: the Gauss-weighted centroid of the plateau is
// pulled wherever the plateau is wider, the flanks are not.
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>

#include "structured_light_stabilizer/common/math.h"
#include "detection/fast/stages.h"

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

constexpr int kCols = 2 * PlaneWindow::kMaxRadius + 2;  // 2H + 1 rounded up to two lanes

// The window's usable pixels (always the same set, so that sums of squares
// of different models compare), as rows of the window: uv = v where a pixel
// is used and 0 elsewhere, each row's used columns in [c0, c1), and the row's
// runs of used columns (the clipped core splits a row in two).
struct Samples
{
  struct Run
  {
    int begin, end;  // columns [begin, end)
  };
  int cx = 0, cy = 0, H = 0, count = 0, rows = 0, stride = 0;
  double vv = 0;  // sum of v^2 over the used pixels
  std::vector<double> uv;
  std::vector<int> c0, c1;
  std::vector<Run> runs;       // all rows' runs, row by row
  std::vector<int> first_run;  // row r's runs are [first_run[r], first_run[r + 1])
  const double* uvRow(int r) const { return uv.data() + r * stride; }
};

// This thread's Samples, whose buffers are kept across fits. Out of line: a
// thread_local used directly in the loops below is looked up again at every
// access in a shared library (__tls_get_addr per pixel).
__attribute__((noinline)) Samples& threadSamples()
{
  thread_local Samples samples;
  return samples;
}

// Those within `radius` of (x, y) only: farther out a dot adds nothing but
// noise (and a neighbour's flank). Into *s, whose buffers are reused.
void usableSamples(const WeightWindow& w, double x, double y, double radius, Samples* s)
{
  s->cx = w.cx;
  s->cy = w.cy;
  s->H = w.H;
  s->rows = 2 * w.H + 1;
  s->stride = (s->rows + 1) & ~1;
  s->count = 0;
  s->uv.assign(s->rows * s->stride, 0.0);
  s->c0.assign(s->rows, 0);
  s->c1.assign(s->rows, 0);
  s->runs.clear();
  s->first_run.assign(s->rows + 1, 0);
  double vv = 0;
  int count = 0;
  const double r2 = radius * radius;
  for (int dy = -w.H; dy <= w.H; ++dy)
  {
    const int r = dy + w.H;
    s->first_run[r] = static_cast<int>(s->runs.size());
    // The disk's columns on this row, one more each side for the rounding
    // of the root (the exact test trims them).
    const double ey2 = detail::square(w.cy + dy - y), h2 = r2 - ey2;
    if (h2 < 0.0)
      continue;  // c0 = c1 = 0 from the assign above
    const double h = std::sqrt(h2), ox = x - w.cx;
    int from = std::max(-w.H, static_cast<int>(std::floor(ox - h)) - 1);
    int to = std::min(w.H, static_cast<int>(std::ceil(ox + h)) + 1);
    // The disk's columns are contiguous: the exact test at its ends only.
    auto inside = [&](int dx) { return detail::square(w.cx + dx - x) + ey2 <= r2; };
    while (from <= to && !inside(from))
      ++from;
    while (to >= from && !inside(to))
      --to;
    const uint8_t* usable = w.usable + r * w.stride + w.H;
    const float* vals = w.vals + r * w.stride + w.H;
    double* uv = s->uv.data() + r * s->stride + w.H;
    int first = s->stride, last = -1, run_begin = -1;
    for (int dx = from; dx <= to + 1; ++dx)
    {
      const bool used = dx <= to && usable[dx];
      if (used)
      {
        uv[dx] = vals[dx];
        vv += detail::square(double(vals[dx]));
        ++count;
        first = std::min(first, dx + w.H);
        last = dx + w.H;
        if (run_begin < 0)
          run_begin = dx + w.H;
      }
      else if (run_begin >= 0)
      {
        s->runs.push_back({run_begin, dx + w.H});
        run_begin = -1;
      }
    }
    // Whole lanes of two: the padding holds zeros.
    s->c0[r] = last < 0 ? 0 : first & ~1;
    s->c1[r] = last < 0 ? 0 : (last + 2) & ~1;
  }
  s->first_run[s->rows] = static_cast<int>(s->runs.size());
  s->vv = vv;
  s->count = count;
}

// The sums of a model over the used pixels, by the separability of its
// Gaussian g = gx(ex) gy(ey): for every row, A_k = sum u gx^2 ex^k (k = 0..4)
// and B_k = sum u v gx ex^k (k = 0..2), then weighted by gy, gy^2 and powers
// of the row's ey. Each term of J^T J, J^T r and the sum of squares is one
// of these (see normalEquations): a few multiply-adds per pixel instead of
// the residual's Jacobian evaluated at each. The A_k do not depend on the
// data, only on which pixels are used: a row's are differences of the
// columns' prefix sums over its runs.
struct ModelSums
{
  double P[5] = {0, 0, 0, 0, 0};  // sum gy^2 A_k
  double E[3] = {0, 0, 0};        // sum gy^2 ey A_k
  double F[3] = {0, 0, 0};        // sum gy^2 ey^2 A_k
  double G0 = 0, H0 = 0;          // sum gy^2 ey^3 A_0, sum gy^2 ey^4 A_0
  double R[3] = {0, 0, 0};        // sum gy B_k
  double Q0 = 0, Q2 = 0;          // sum gy ey B_0, sum gy ey^2 B_0
};

// kShape false: only P[0] and R[0] (what the best amplitude needs).
template <bool kShape>
ModelSums modelSums(const Samples& s, const Model& m)
{
  constexpr int kA = kShape ? 5 : 1;
  const double k = -0.5 / (m.s * m.s);
  alignas(16) double q[3][kCols];
  double cum[kA][kCols + 1];  // cum[p][c] = sum over columns < c of gx^2 ex^p
  double gx[kCols], gy[kCols];
  gaussianRun(s.cx - s.H - m.x, k, s.rows, gx);
  gaussianRun(s.cy - s.H - m.y, k, s.rows, gy);
  for (int p = 0; p < kA; ++p)
    cum[p][0] = 0.0;
  for (int c = 0; c < s.stride; ++c)
  {
    const double ex = s.cx + c - s.H - m.x;
    const double g = c < s.rows ? gx[c] : 0.0;
    q[0][c] = g;
    q[1][c] = kShape ? g * ex : 0.0;
    q[2][c] = kShape ? g * ex * ex : 0.0;
    double w = g * g;
    for (int p = 0; p < kA; ++p, w *= ex)
      cum[p][c + 1] = cum[p][c] + w;
  }
  ModelSums t;
  for (int r = 0; r < s.rows; ++r)
  {
    if (s.c1[r] <= s.c0[r])
      continue;
    const double* uv = s.uvRow(r);
    double A[5] = {0, 0, 0, 0, 0}, B[3] = {0, 0, 0};
    for (int j = s.first_run[r]; j < s.first_run[r + 1]; ++j)
    {
      const Samples::Run& run = s.runs[j];
      for (int p = 0; p < kA; ++p)
        A[p] += cum[p][run.end] - cum[p][run.begin];
    }
#if CV_SIMD128_64F
    cv::v_float64x2 b0 = cv::v_setzero_f64(), b1 = b0, b2 = b0;
    for (int c = s.c0[r]; c < s.c1[r]; c += 2)
    {
      const cv::v_float64x2 vuv = cv::v_load(uv + c);
      b0 = cv::v_fma(vuv, cv::v_load_aligned(q[0] + c), b0);
      if constexpr (kShape)
      {
        b1 = cv::v_fma(vuv, cv::v_load_aligned(q[1] + c), b1);
        b2 = cv::v_fma(vuv, cv::v_load_aligned(q[2] + c), b2);
      }
    }
    B[0] = cv::v_reduce_sum(b0);
    B[1] = cv::v_reduce_sum(b1);
    B[2] = cv::v_reduce_sum(b2);
#else
    for (int c = s.c0[r]; c < s.c1[r]; ++c)
      for (int p = 0; p < 3; ++p)
        B[p] += uv[c] * q[p][c];
#endif
    const double ey = s.cy + r - s.H - m.y;
    const double g = gy[r], g2 = g * g, ey2 = ey * ey;
    t.P[0] += g2 * A[0];
    t.R[0] += g * B[0];
    if constexpr (kShape)
    {
      for (int p = 1; p < 5; ++p)
        t.P[p] += g2 * A[p];
      for (int p = 0; p < 3; ++p)
      {
        t.E[p] += g2 * ey * A[p];
        t.F[p] += g2 * ey2 * A[p];
      }
      for (int p = 1; p < 3; ++p)
        t.R[p] += g * B[p];
      t.G0 += g2 * ey2 * ey * A[0];
      t.H0 += g2 * ey2 * ey2 * A[0];
      t.Q0 += g * ey * B[0];
      t.Q2 += g * ey2 * B[0];
    }
  }
  return t;
}

// Normal equations of the residuals v - a g, g = exp(-r^2 / 2 s^2), and
// their sum of squares. With c = 1 / s^2 the Jacobian's columns are g,
// a g ex c, a g ey c and a g r^2 c / s; each product summed over the pixels
// is a ModelSums term.
double normalEquations(const Samples& s, const Model& m, cv::Matx44d* JtJ, cv::Vec4d* Jtr)
{
  const ModelSums t = modelSums<true>(s, m);
  const double a = m.a, c = 1.0 / (m.s * m.s), ac = a * c, ac_s = ac / m.s;
  const double a0 = t.P[0], a1 = ac * t.P[1], a2 = ac * t.E[0], a3 = ac_s * (t.P[2] + t.F[0]);
  const double a4 = ac * ac * t.P[2], a5 = ac * ac * t.E[1], a6 = ac * ac_s * (t.P[3] + t.F[1]);
  const double a7 = ac * ac * t.F[0], a8 = ac * ac_s * (t.E[2] + t.G0);
  const double a9 = ac_s * ac_s * (t.P[4] + 2.0 * t.F[2] + t.H0);
  *JtJ = cv::Matx44d(a0, a1, a2, a3, a1, a4, a5, a6, a2, a5, a7, a8, a3, a6, a8, a9);
  *Jtr = cv::Vec4d(t.R[0] - a * t.P[0], ac * (t.R[1] - a * t.P[1]), ac * (t.Q0 - a * t.E[0]),
                   ac_s * (t.R[2] + t.Q2 - a * (t.P[2] + t.F[0])));
  return std::max(0.0, s.vv - 2.0 * a * t.R[0] + a * a * t.P[0]);
}

// The amplitude that fits best for the model's centre and sigma (linear),
// and the sum of squares it leaves.
double bestAmplitude(const Samples& s, Model* m)
{
  const ModelSums t = modelSums<false>(s, *m);
  const double vg = t.R[0], gg = t.P[0];
  m->a = gg > 0 ? vg / gg : 0.0;
  return gg > 0 ? s.vv - vg * vg / gg : detail::kInf;
}

// Solves A x = b for a symmetric positive definite 4 x 4 A by Cholesky
// (false, as cv::solve's DECOMP_CHOLESKY, when a pivot is below DBL_EPSILON):
// cv::solve's general entry costs twenty times the arithmetic here.
bool solve4(const cv::Matx44d& A, const cv::Vec4d& b, cv::Vec4d* x)
{
  double L[4][4] = {};
  for (int j = 0; j < 4; ++j)
  {
    double d = A(j, j);
    for (int k = 0; k < j; ++k)
      d -= L[j][k] * L[j][k];
    if (!(d >= std::numeric_limits<double>::epsilon()))
      return false;
    L[j][j] = std::sqrt(d);
    for (int i = j + 1; i < 4; ++i)
    {
      double v = A(i, j);
      for (int k = 0; k < j; ++k)
        v -= L[i][k] * L[j][k];
      L[i][j] = v / L[j][j];
    }
  }
  double y[4];
  for (int i = 0; i < 4; ++i)
  {
    double v = b[i];
    for (int k = 0; k < i; ++k)
      v -= L[i][k] * y[k];
    y[i] = v / L[i][i];
  }
  for (int i = 3; i >= 0; --i)
  {
    double v = y[i];
    for (int k = i + 1; k < 4; ++k)
      v -= L[k][i] * (*x)[k];
    (*x)[i] = v / L[i][i];
  }
  return true;
}

// Levenberg-Marquardt on (a, x, y, s) from m (whose amplitude is set); the
// sum of squares at the last model evaluated. Its steps shrink about
// twentyfold from one to the next near the minimum (0.3, 0.02, 0.001 px on
// the benchmark's clipped dots), so a step below kSmallStepPx is taken
// without evaluating the model there (which cost as much as the step) and
// ends the iterations. Against iterating down to 2e-4 px this moved the
// benchmark's clipped dots by at most 0.0012 px, and the spots of 45
// simulator frames of twelve input kinds by at most 0.006 px.
double levenbergMarquardt(const Samples& samples, Model* model)
{
  constexpr double kSmallStepPx = 2e-3, kSmallSigmaStepPx = 5e-3;
  // Only a Gauss-Newton step (damping at most the start's) is small because
  // the fit has converged; after a rejected step it can be small because the
  // damping grew.
  constexpr double kGaussNewtonLambda = 1e-3;
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
    if (!solve4(A, Jtr, &step))
      break;
    const Model trial{m.a + step[0], m.x + step[1], m.y + step[2], m.s + step[3]};
    const bool admissible = trial.s > 0.3 && trial.a > 0;
    if (admissible && lambda <= kGaussNewtonLambda && std::hypot(step[1], step[2]) < kSmallStepPx &&
        std::abs(step[3]) < kSmallSigmaStepPx)
    {
      m = trial;
      break;
    }
    cv::Matx44d JtJ2;
    cv::Vec4d Jtr2;
    const double ss2 = admissible ? normalEquations(samples, trial, &JtJ2, &Jtr2) : detail::kInf;
    if (ss2 <= ss)
    {
      m = trial;
      ss = ss2;
      JtJ = JtJ2;
      Jtr = Jtr2;
      lambda = std::max(1e-6, lambda * 0.3);
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
//
// The plateau is the clipped samples connected to the nearest one through
// steps of at most 2 px along each axis (a Bayer mosaic's samples of one
// colour are 2 px apart), found over the rows' runs of clipped samples rather
// than pixel by pixel: two runs connect when their rows and their columns
// are each at most 2 px apart.
bool clippedPlateau(const PlaneWindow& pw, double x, double y, cv::Point2d* centre, double* half_width)
{
  const int H = pw.H, rows = 2 * H + 1;
  constexpr uint8_t kClippedSample = PlaneWindow::kClipped | PlaneWindow::kSample;
  struct Run
  {
    int row, x0, x1;  // window coordinates, x0..x1 inclusive
  };
  // At most H + 1 runs per row (a gap between two); not initialised.
  Run runs[(2 * PlaneWindow::kMaxRadius + 1) * (PlaneWindow::kMaxRadius + 1)];
  int first[2 * PlaneWindow::kMaxRadius + 2];  // row r's runs are [first[r], first[r + 1])
  int n_runs = 0, seed = -1;
  double best = detail::kInf;
  const double ox = x - pw.cx;
  for (int r = 0; r < rows; ++r)
  {
    first[r] = n_runs;
    const uint8_t* f = pw.flags + r * pw.stride;
    const double ey2 = detail::square(pw.cy + r - H - y);
    for (int c = 0; c < rows; ++c)
    {
#if CV_SIMD128
      // Sixteen pixels without a clipped one at a time (most of the window).
      while (c + 16 <= rows && cv::v_reduce_max(cv::v_load(f + c) & cv::v_setall_u8(PlaneWindow::kClipped)) == 0)
        c += 16;
      if (c >= rows)
        break;
#endif
      if ((f[c] & kClippedSample) != kClippedSample)
        continue;
      const int c0 = c;
      while (c + 1 < rows && (f[c + 1] & kClippedSample) == kClippedSample)
        ++c;
      runs[n_runs] = Run{r, c0 - H, c - H};
      // The run's pixel nearest to x (the leftmost of two as near, as a
      // row-major scan keeping the first strict minimum would take).
      const int dx = std::min(std::max(static_cast<int>(std::ceil(ox - 0.5)), c0 - H), c - H);
      const double d2 = detail::square(pw.cx + dx - x) + ey2;
      if (d2 < best)
      {
        best = d2;
        seed = n_runs;
      }
      ++n_runs;
    }
  }
  first[rows] = n_runs;
  if (seed < 0)
    return false;
  // Breadth first over the runs from the seed's.
  bool in[sizeof(runs) / sizeof(runs[0])];
  std::fill(in, in + n_runs, false);
  int queue[sizeof(runs) / sizeof(runs[0])];
  int head = 0, tail = 0;
  queue[tail++] = seed;
  in[seed] = true;
  while (head < tail)
  {
    const Run& a = runs[queue[head++]];
    for (int k = first[std::max(0, a.row - 2)]; k < first[std::min(rows, a.row + 3)]; ++k)
      if (!in[k] && runs[k].x0 <= a.x1 + 2 && a.x0 <= runs[k].x1 + 2)
      {
        in[k] = true;
        queue[tail++] = k;
      }
  }
  long sx = 0, sy = 0, n = 0;
  int widest = 0;
  for (int r = 0; r < rows; ++r)
  {
    int lo = 1 << 20, hi = -(1 << 20);
    for (int k = first[r]; k < first[r + 1]; ++k)
    {
      if (!in[k])
        continue;
      const Run& q = runs[k];
      const long len = q.x1 - q.x0 + 1;
      sx += (q.x0 + q.x1) * len / 2;  // (x0 + x1) and len differ in parity: exact
      sy += (r - H) * len;
      n += len;
      lo = std::min(lo, q.x0);
      hi = std::max(hi, q.x1);
    }
    widest = std::max(widest, hi - lo + 1);
  }
  *centre = cv::Point2d(pw.cx + static_cast<double>(sx) / n, pw.cy + static_cast<double>(sy) / n);
  *half_width = 0.5 * widest;
  return true;
}

// From the centroid's estimate: of three starting sigmas (a clipped plateau
// inflates the centroid's) the one whose best amplitude fits best starts the
// iterations.
bool fitGaussian(const WeightWindow& w, double max_sigma, SpotFit* fit)
{
  Samples& samples = threadSamples();
  usableSamples(w, fit->x, fit->y, 3.0 * fit->sigma + 2.0, &samples);
  if (samples.count < 8)
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
