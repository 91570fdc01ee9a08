// Stage 4b of the fast method: the colour of the light a spot adds to the rock
// (see spot_detector_fast_stages.h and ColourTestParams). Channels are named
// by the model: signal (the projector's colour), reference, third.
#include <algorithm>
#include <cmath>

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
enum Plane3
{
  kSig = 0,
  kRef = 1,
  kThird = 2,
};

// Least-squares planes a + bx dx + by dy of the three channels over the
// window's border samples, the rock's signal/reference and third/reference
// ratios there, and the spread of the reference about its plane (how much
// texture the reference ratio carries). Plain, not robust: the colour test
// only needs ratios.
struct RingColour
{
  cv::Vec3d plane[3];  // (a, bx, by) per channel
  double k_sig = 0, k_third = 0;
  double ref_spread = 0;
  // Spread of the texture-free signal and third (channel - k reference)
  // about their planes: what the rock's own colour texture, and the shading
  // of its facets in another hue, leave in the texture-free ratio.
  double free_sig_spread = 0, free_third_spread = 0;
  double at(int c, int dx, int dy) const { return plane[c][0] + plane[c][1] * dx + plane[c][2] * dy; }
};

template <typename F>
void forBorderSamples(const PlaneWindow& w, F f)
{
  const int H = w.H, inner = H - w.ring;
  for (int dy = -H; dy <= H; ++dy)
  {
    // Row by row as the whole window would be read, the interior skipped.
    const bool interior_row = std::abs(dy) <= inner;
    for (int dx = -H; dx <= H; ++dx)
    {
      if (interior_row && dx == -inner)
        dx = inner + 1;  // <= H: the ring is at least one pixel wide
      const int i = w.index(dx, dy);
      if (w.flags[i] & PlaneWindow::kSample)
        f(dx, dy, i);
    }
  }
}

RingColour ringColour(const PlaneWindow& w)
{
  // Normal equations of (1, dx, dy): their upper triangle, and one right-hand side per channel.
  double A[6] = {0, 0, 0, 0, 0, 0}, b[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  double sr = 0, tr = 0, rr = 0;
  int n = 0;
  forBorderSamples(w,
                   [&](int dx, int dy, int i)
                   {
                     A[1] += dx;
                     A[2] += dy;
                     A[3] += double(dx) * dx;
                     A[4] += double(dx) * dy;
                     A[5] += double(dy) * dy;
                     const double c[3] = {w.signal[i], w.reference[i], w.third[i]};
                     for (int k = 0; k < 3; ++k)
                     {
                       b[k][0] += c[k];
                       b[k][1] += dx * c[k];
                       b[k][2] += dy * c[k];
                     }
                     sr += c[kSig] * c[kRef];
                     tr += c[kThird] * c[kRef];
                     rr += c[kRef] * c[kRef];
                     ++n;
                   });
  A[0] = n;
  RingColour ring;
  for (int k = 0; k < 3; ++k)
  {
    double x[3];
    if (solveSymmetric3(A, b[k], 1e-9, x))
      ring.plane[k] = cv::Vec3d(x[0], x[1], x[2]);
    else
      ring.plane[k] = cv::Vec3d(n ? b[k][0] / n : 0.0, 0, 0);
  }
  // Ratios only where the reference is above ~3 DN (sunlit rock).
  if (n > 0 && rr >= 9.0 * n)
  {
    ring.k_sig = std::min(4.0, std::max(0.0, sr / rr));
    ring.k_third = std::min(4.0, std::max(0.0, tr / rr));
  }
  // The texture-free spreads robustly (1.4826 x the median absolute
  // residual): a bloom streak or a neighbour's flank crossing a part of the
  // border is not the rock's texture.
  double spread = 0;
  float fs[8 * (2 * PlaneWindow::kMaxRadius + 1)], ft[8 * (2 * PlaneWindow::kMaxRadius + 1)];
  int m = 0;
  forBorderSamples(w,
                   [&](int dx, int dy, int i)
                   {
                     const double r = w.reference[i] - ring.at(kRef, dx, dy);
                     spread += detail::square(r);
                     if (m < static_cast<int>(sizeof(fs) / sizeof(fs[0])))
                     {
                       fs[m] = static_cast<float>(std::abs(w.signal[i] - ring.at(kSig, dx, dy) - ring.k_sig * r));
                       ft[m] = static_cast<float>(std::abs(w.third[i] - ring.at(kThird, dx, dy) - ring.k_third * r));
                       ++m;
                     }
                   });
  ring.ref_spread = n ? std::sqrt(spread / n) : 0.0;
  if (m > 0)
  {
    std::nth_element(fs, fs + m / 2, fs + m);
    std::nth_element(ft, ft + m / 2, ft + m);
    ring.free_sig_spread = 1.4826 * fs[m / 2];
    ring.free_third_spread = 1.4826 * ft[m / 2];
  }
  return ring;
}

// Gaussian-weighted excess of the spot's unclipped samples over the rock:
// reference, signal, and texture-free signal and third (minus the rock's own
// multiple of the reference), or with an ambient frame frame - ambient.
struct Excess
{
  double ref = 0, sig = 0, free_sig = 0, free_third = 0, sum_w = 0;
};

// The window's weighted sums, about whose samples the excess is linear: the
// weights (and their moments in dx, dy, for the planes) and the weighted
// signal, reference and third (minus the ambient frame's, with kAmbient).
struct WeightedSums
{
  double w = 0, wx = 0, wy = 0, sig = 0, ref = 0, third = 0;
};

template <bool kAmbient>
WeightedSums weightedSums(const PlaneWindow& w, const double* gx, const double* gy)
{
  const int H = w.H, n = 2 * H + 1;
  WeightedSums t;
#if CV_SIMD128_64F
  alignas(16) double ex[2 * PlaneWindow::kMaxRadius + 4];  // k - H
  for (int k = 0; k < n; ++k)
    ex[k] = k - H;
#endif
  for (int dy = -H; dy <= H; ++dy)
  {
    const int row = w.index(-H, dy);
    const auto weight = [&](int k) {
      return (w.flags[row + k] & (PlaneWindow::kSample | PlaneWindow::kClipped)) == PlaneWindow::kSample ? gx[k] : 0.0;
    };
    const auto channel = [&](const float* plane, const float* ambient, int i)
    { return kAmbient ? plane[i] - ambient[i] : plane[i]; };
    double rw = 0, rwx = 0, rs = 0, rr = 0, rt = 0;
    int k = 0;
#if CV_SIMD128_64F
    // Four pixels at a time, two lanes of doubles (the channels' differences in float, as below).
    cv::v_float64x2 aw = cv::v_setzero_f64(), awx = aw, as = aw, ar = aw, at = aw;
    const auto add =
        [](const cv::v_float32x4& v, const cv::v_float64x2& g0, const cv::v_float64x2& g1, cv::v_float64x2* acc)
    { *acc = cv::v_fma(g1, cv::v_cvt_f64_high(v), cv::v_fma(g0, cv::v_cvt_f64(v), *acc)); };
    for (; k + 4 <= n; k += 4)
    {
      const int i = row + k;
      alignas(16) const double g[4] = {weight(k), weight(k + 1), weight(k + 2), weight(k + 3)};
      const cv::v_float64x2 g0 = cv::v_load_aligned(g), g1 = cv::v_load_aligned(g + 2);
      aw = aw + g0 + g1;
      awx = cv::v_fma(g1, cv::v_load_aligned(ex + k + 2), cv::v_fma(g0, cv::v_load_aligned(ex + k), awx));
      const auto load = [&](const float* plane, const float* ambient)
      { return kAmbient ? cv::v_load(plane + i) - cv::v_load(ambient + i) : cv::v_load(plane + i); };
      add(load(w.signal, w.ambient_signal), g0, g1, &as);
      add(load(w.reference, w.ambient_reference), g0, g1, &ar);
      add(load(w.third, w.ambient_third), g0, g1, &at);
    }
    rw = cv::v_reduce_sum(aw);
    rwx = cv::v_reduce_sum(awx);
    rs = cv::v_reduce_sum(as);
    rr = cv::v_reduce_sum(ar);
    rt = cv::v_reduce_sum(at);
#endif
    for (; k < n; ++k)
    {
      const int i = row + k;
      const double g = weight(k);
      rw += g;
      rwx += g * (k - H);
      rs += g * channel(w.signal, w.ambient_signal, i);
      rr += g * channel(w.reference, w.ambient_reference, i);
      rt += g * channel(w.third, w.ambient_third, i);
    }
    const double g = gy[dy + H];
    t.w += g * rw;
    t.wx += g * rwx;
    t.wy += g * rw * dy;
    t.sig += g * rs;
    t.ref += g * rr;
    t.third += g * rt;
  }
  return t;
}

Excess weightedExcess(const PlaneWindow& w, const SpotFit& fit, const RingColour& ring)
{
  const double k = -1.0 / (2.0 * fit.sigma * fit.sigma);
  double gx[2 * PlaneWindow::kMaxRadius + 1], gy[2 * PlaneWindow::kMaxRadius + 1];
  gaussianRun(w.cx - w.H - fit.x, k, 2 * w.H + 1, gx);
  gaussianRun(w.cy - w.H - fit.y, k, 2 * w.H + 1, gy);
  Excess e;
  if (w.ambient)
  {
    const WeightedSums t = weightedSums<true>(w, gx, gy);
    e.sum_w = t.w;
    e.sig = e.free_sig = t.sig;
    e.ref = t.ref;
    e.free_third = t.third;
    return e;
  }
  // Each channel's excess over its border plane: the weighted sum of the
  // channel minus the plane's, a W + bx Wx + by Wy (W, Wx, Wy: the weights' sum and moments).
  const WeightedSums t = weightedSums<false>(w, gx, gy);
  const auto planeSum = [&](int c)
  { return ring.plane[c][0] * t.w + ring.plane[c][1] * t.wx + ring.plane[c][2] * t.wy; };
  const double s = t.sig - planeSum(kSig), r = t.ref - planeSum(kRef), th = t.third - planeSum(kThird);
  e.sum_w = t.w;
  e.sig = s;
  e.ref = r;
  e.free_sig = s - ring.k_sig * r;
  e.free_third = th - ring.k_third * r;
  return e;
}
}  // namespace

// Reference: excess over the local background plane relative to the signal
// excess (texture-sensitive; slack says how much). Third: measured on
// texture-free signals, signal - k_sig reference and third - k_third
// reference (k = the rock's own ratios on the border), so sunlit rock texture
// cancels and what remains is the added light's third/signal ratio,
// (led_third - k_third led_ref) / (1 - k_sig led_ref) for a dot, mapped back
// to led_third for the comparison. With an ambient frame both are plain
// ratios of frame - ambient. Gaussian-weighted, unclipped samples only.
void measureColour(const PlaneWindow& w, const ColourModel& model, double max_slack, SpotFit* fit)
{
  const RingColour ring = w.ambient ? RingColour() : ringColour(w);
  const Excess e = weightedExcess(w, *fit, ring);
  if (!(e.sig > 1e-6 && e.free_sig > 1e-6))
  {
    // No excess over the rock: not light added by the projector.
    fit->red_ratio = fit->blue_ratio = detail::kNaN;
    return;
  }
  fit->red_ratio = e.ref / e.sig;
  // Rock texture is spatially correlated over the window, so its effect on
  // the weighted sums scales with the sum of the weights, not its root.
  fit->red_slack = ring.ref_spread * e.sum_w / e.sig;
  const double expected =
      (model.led_third - ring.k_third * model.led_reference) / std::max(0.1, 1.0 - ring.k_sig * model.led_reference);
  fit->blue_ratio = e.free_third / e.free_sig - expected + model.led_third;
  // The same reasoning for the texture-free ratio: what the border's
  // texture-free spread can move it by (first order in both sums).
  fit->blue_slack =
      e.sum_w * (ring.free_third_spread + std::abs(fit->blue_ratio) * ring.free_sig_spread) / e.free_sig;
  fit->blue_slack = std::min(fit->blue_slack, max_slack);
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
