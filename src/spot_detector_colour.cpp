// Stage 4b of the fast method: the colour of the light a spot adds to the rock
// (see spot_detector_fast_stages.h and ColourTestParams). Channels are named
// by the model: signal (the projector's colour), reference, third.
#include <algorithm>
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
  cv::Matx33d A = cv::Matx33d::zeros();
  cv::Vec3d b[3];
  double sr = 0, tr = 0, rr = 0;
  int n = 0;
  forBorderSamples(w,
                   [&](int dx, int dy, int i)
                   {
                     const cv::Vec3d u(1.0, dx, dy);
                     A += u * u.t();
                     const double c[3] = {w.signal[i], w.reference[i], w.third[i]};
                     for (int k = 0; k < 3; ++k)
                       b[k] += u * c[k];
                     sr += c[kSig] * c[kRef];
                     tr += c[kThird] * c[kRef];
                     rr += c[kRef] * c[kRef];
                     ++n;
                   });
  RingColour ring;
  for (int k = 0; k < 3; ++k)
    if (!cv::solve(A, b[k], ring.plane[k], cv::DECOMP_CHOLESKY))
      ring.plane[k] = cv::Vec3d(n ? b[k][0] / n : 0.0, 0, 0);
  // Ratios only where the reference is above ~3 DN (sunlit rock).
  if (n > 0 && rr >= 9.0 * n)
  {
    ring.k_sig = std::min(4.0, std::max(0.0, sr / rr));
    ring.k_third = std::min(4.0, std::max(0.0, tr / rr));
  }
  double spread = 0;
  forBorderSamples(w, [&](int dx, int dy, int i) { spread += detail::square(w.reference[i] - ring.at(kRef, dx, dy)); });
  ring.ref_spread = n ? std::sqrt(spread / n) : 0.0;
  return ring;
}

// Gaussian-weighted excess of the spot's unclipped samples over the rock:
// reference, signal, and texture-free signal and third (minus the rock's own
// multiple of the reference), or with an ambient frame frame - ambient.
struct Excess
{
  double ref = 0, sig = 0, free_sig = 0, free_third = 0, sum_w = 0;
};

Excess weightedExcess(const PlaneWindow& w, const SpotFit& fit, const RingColour& ring)
{
  const double inv2s2 = 1.0 / (2.0 * fit.sigma * fit.sigma);
  double gx[2 * PlaneWindow::kMaxRadius + 1], gy[2 * PlaneWindow::kMaxRadius + 1];
  for (int d = -w.H; d <= w.H; ++d)
  {
    gx[d + w.H] = std::exp(-detail::square(w.cx + d - fit.x) * inv2s2);
    gy[d + w.H] = std::exp(-detail::square(w.cy + d - fit.y) * inv2s2);
  }
  Excess e;
  for (int dy = -w.H; dy <= w.H; ++dy)
    for (int dx = -w.H; dx <= w.H; ++dx)
    {
      const int i = w.index(dx, dy);
      if ((w.flags[i] & (PlaneWindow::kSample | PlaneWindow::kClipped)) != PlaneWindow::kSample)
        continue;
      const double weight = gx[dx + w.H] * gy[dy + w.H];
      double s, r, t;
      if (w.ambient)
      {
        s = w.signal[i] - w.ambient_signal[i];
        r = w.reference[i] - w.ambient_reference[i];
        t = w.third[i] - w.ambient_third[i];
        e.free_sig += weight * s;
        e.free_third += weight * t;
      }
      else
      {
        s = w.signal[i] - ring.at(kSig, dx, dy);
        r = w.reference[i] - ring.at(kRef, dx, dy);
        t = w.third[i] - ring.at(kThird, dx, dy);
        e.free_sig += weight * (s - ring.k_sig * r);
        e.free_third += weight * (t - ring.k_third * r);
      }
      e.sum_w += weight;
      e.ref += weight * r;
      e.sig += weight * s;
    }
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
void measureColour(const PlaneWindow& w, const ColourModel& model, SpotFit* fit)
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
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
