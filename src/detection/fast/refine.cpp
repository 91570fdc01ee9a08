// Stage 4 of the fast method: the measurement of one candidate in a window
// of the frame (see spot_detector_fast_stages.h): the dot's added light over
// the rock, normalised by the albedo under each pixel, and an iteratively
// Gaussian-weighted centroid of it (a Gaussian fit, spot_detector_fit.cpp,
// when the dot has clipped pixels).
//
// Why the normalisation (docs/spot_detector.md#texture-and-clipping): a
// pixel of a dot records the beam's irradiance at its surface point times
// the albedo there, so on textured rock the light centroid is pulled towards
// the brighter grains by sigma^2 times the albedo's log-gradient (0.4 px RMS
// for 1-3 cm texture of +-25 % at 1.5 m). The albedo is seen in the ambient
// light: A(p) = albedo(p) * E_sun, smooth E_sun. With an ambient frame A is
// measured; on a colour frame it is what the rock's other two channels
// predict of the signal (rockMix), after the dot's own small share of those
// channels is taken out. Dividing the added light by A / mean(A) leaves the
// beam's footprint, whose centre is the hit point.
#include <algorithm>
#include <cmath>

#include <opencv2/core/hal/intrin.hpp>

#include "structured_light_stabilizer/common/math.h"
#include "detection/fast/stages.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

namespace
{
constexpr int kMaxRadius = PlaneWindow::kMaxRadius;
constexpr int kMaxRing = 16 * kMaxRadius;
constexpr int kMaxStride = PlaneWindow::kStride;
// Largest ratio of the albedo under a pixel to its surroundings (a printed
// chessboard: 16).
constexpr double kAlphaMax = 20.0;
// F statistic the third channel's term must reach on a window's border for
// the rock's signal to be fitted to both other channels (rockMix): about the
// 5 % point of F(1, n - 2) for a border of 40-200 samples.
constexpr double kMinHueF = 4.0;

// Calls f(dx, dy) for every pixel of the border ring of the (2H+1)^2
// window, `thickness` pixels wide: top and bottom rows, then the left and
// right columns.
template <typename F>
void forRing(int H, int thickness, F f)
{
  for (int t = 0; t < thickness; ++t)
  {
    const int E = H - t;
    for (int d = -H; d <= H; ++d)
    {
      f(d, -E);
      f(d, E);
    }
    for (int d = -H + thickness; d <= H - thickness; ++d)
    {
      f(-E, d);
      f(E, d);
    }
  }
}

// Background plane a + bx*dx + by*dy of a window, in pixels from its centre.
struct Plane
{
  double a = 0, bx = 0, by = 0;
  double at(int dx, int dy) const { return a + bx * dx + by * dy; }
};

struct RingSample
{
  int dx, dy;
  double v;
};

// Least-squares plane through the samples; with keep_limit, only through
// those within it of prev. Keeps prev when the system is degenerate.
Plane fitPlane(const RingSample* samples, int n, const double* keep_limit, const Plane& prev)
{
  // Normal equations of (1, dx, dy); on the full ring they are diagonal.
  double s11 = 0, s1x = 0, s1y = 0, sxx = 0, sxy = 0, syy = 0, b1 = 0, bx = 0, by = 0;
  for (int i = 0; i < n; ++i)
  {
    const RingSample& q = samples[i];
    if (keep_limit && std::abs(q.v - prev.at(q.dx, q.dy)) > *keep_limit)
      continue;
    s11 += 1;
    s1x += q.dx;
    s1y += q.dy;
    sxx += double(q.dx) * q.dx;
    sxy += double(q.dx) * q.dy;
    syy += double(q.dy) * q.dy;
    b1 += q.v;
    bx += q.v * q.dx;
    by += q.v * q.dy;
  }
  Plane p = prev;
  const double S[6] = {s11, s1x, s1y, sxx, sxy, syy}, B[3] = {b1, bx, by};
  double x[3];
  if (s11 >= 6 && solveSymmetric3(S, B, 1e-9, x))
  {
    p.a = x[0];
    p.bx = x[1];
    p.by = x[2];
  }
  return p;
}

// Robust background plane of the ring samples: a least-squares fit, then a
// refit without the samples far from it (a speck, a mineral edge or a
// neighbour's flank on the ring would otherwise tilt the plane and drag the
// centroid). *spread: 1.4826 x the median absolute residual.
Plane robustPlane(const RingSample* samples, int n, double* spread)
{
  *spread = 0.0;
  if (n <= 0)
    return Plane();
  const Plane p = fitPlane(samples, n, nullptr, Plane());
  double res[kMaxRing];
  for (int i = 0; i < n; ++i)
    res[i] = std::abs(samples[i].v - p.at(samples[i].dx, samples[i].dy));
  *spread = 1.4826 * detail::medianInPlace(res, res + n);
  const double limit = std::max(2.0, 3.0 * *spread);
  return fitPlane(samples, n, &limit, p);
}

// ---------------------------------------------------------------------------
// The weight field.

// The rock's signal as a multiple of its other channels on the window's
// border: signal ~ a reference + b third (least squares through the origin
// over the signal's samples). A rock's reflectance spectrum is smooth, so the
// albedo at the signal's wavelength follows its neighbours' on both sides
// (green between red and blue); one channel alone leaves the texture's hue
// (red against blue) in the estimate. The border still gets some of the
// dot's light, which shows in the other channels too (led_reference,
// led_third); the fit is therefore made on the dot-free combinations
// r' = reference - led_reference signal and t' = third - led_third signal
// (signal ~ alpha r' + beta t', mapped back to a and b), or the dot's flank
// would be read as the rock's colour. b = 0 (the reference alone) where the
// third channel is dark, where its term explains no more of the border than
// its noise would (an F test: on grey texture or a uniform border the fit
// would only add the third channel's noise), or where the pair does not fit
// with non-negative weights, and on yuv422 frames (third_channel false:
// their chroma is shared by pixel pairs, so a pixel's colour there is half
// its neighbour's, dot light included). a = 0 when the reference is below
// ~3 DN: no sunlit texture to follow (night).
struct RockMix
{
  double a = 0, b = 0;
};

RockMix rockMix(const PlaneWindow& w, const ColourModel& model, bool third_channel)
{
  const double lr = model.led_reference, lt = model.led_third;
  double ss = 0, sr = 0, rr = 0, st = 0, tt = 0, rt = 0;
  int n = 0;
  forRing(w.H, w.ring,
          [&](int dx, int dy)
          {
            const int i = w.index(dx, dy);
            if ((w.flags[i] & (PlaneWindow::kSample | PlaneWindow::kClipped)) != PlaneWindow::kSample)
              return;
            const double s = w.signal[i], r = w.reference[i] - lr * s, t = w.third[i] - lt * s;
            ss += s * s;
            sr += s * r;
            rr += r * r;
            st += s * t;
            tt += t * t;
            rt += r * t;
            ++n;
          });
  RockMix m;
  if (n == 0 || rr < 9.0 * n)
    return m;
  // signal = alpha r' + beta t' for the rock is signal = a reference + b third
  // with (a, b) = (alpha, beta) / (1 + alpha led_reference + beta led_third).
  const double alpha = std::max(0.0, sr / rr);
  m.a = std::min(4.0, alpha / (1.0 + alpha * lr));
  const double det = rr * tt - rt * rt;
  if (!third_channel || n < 12 || tt < 9.0 * n || det <= 1e-12 * rr * tt)
    return m;
  const double al2 = (sr * tt - st * rt) / det, be2 = (st * rr - sr * rt) / det;
  if (al2 < 0.0 || be2 < 0.0 || al2 + be2 > 4.0)
    return m;
  // The third channel only where it explains what the reference leaves: the
  // drop in the residual sum of squares is kMinHueF times the residual
  // variance (an F test; on a grey or smooth border it is about 1).
  const double rss1 = std::max(0.0, ss - sr * sr / rr), rss2 = std::max(1e-12, ss - al2 * sr - be2 * st);
  if (rss1 - rss2 < kMinHueF * rss2 / (n - 2))
    return m;
  const double d = 1.0 + al2 * lr + be2 * lt;
  m.a = al2 / d;
  m.b = be2 / d;
  return m;
}

// What the window shows of the rock and the dot, per pixel.
struct Decomposition
{
  RockMix mix;         // the rock's signal from its reference and third channels (colour frames without ambient)
  bool rock = false;   // mix.a > 0: the rock's signal is rockAt() (computed where needed, not for the whole window)
  float a = 0, b = 0;  // mix.a, mix.b as floats
  double gain = 1;     // 1 / (1 - a led_reference - b led_third): the dot's share of those channels put back
  bool ambient_known = false;
};

// The rock's signal at pixel i, a reference + b third (in float, as WeightRow computes it).
inline float rockAt(const PlaneWindow& w, int i, const Decomposition& d)
{
  return d.a * w.reference[i] + d.b * w.third[i];
}

// The signal minus what the rock alone would give (before the plane).
inline double baseValue(const PlaneWindow& w, int i, const Decomposition& d)
{
  if (w.ambient)
    return double(w.signal[i]) - w.ambient_signal[i];
  // Without a colour model the reference plane is not filled (0 x garbage can be NaN).
  return d.rock ? double(w.signal[i]) - rockAt(w, i, d) : double(w.signal[i]);
}

// The ambient light in the signal channel at pixel i, given the added light P.
inline double ambientValue(const PlaneWindow& w, int i, double added)
{
  return w.ambient ? double(w.ambient_signal[i]) : double(w.signal[i]) - added;
}

// Marks as unusable for the Gaussian fit the clipped pixels and their four
// neighbours (blooming leaves the last, partly filled pixel next to a clipped
// one, and OpenCV-style demosaicing spreads clipping by one pixel). Only a
// window with a clipped pixel needs the neighbours looked at.
void markUsable(const PlaneWindow& pw, WeightWindow* win)
{
  const int H = pw.H, n = 2 * H + 1, stride = pw.stride;
  static_assert(PlaneWindow::kSample == 1, "usable is the sample bit");
  bool row_clipped[2 * PlaneWindow::kMaxRadius + 1];
  bool any = false;
  for (int r = 0; r < n; ++r)
  {
    const uint8_t* f = pw.flags + r * stride;
    uint8_t* u = win->usable + r * stride;
    uint8_t acc = 0;
    int k = 0;
#if CV_SIMD128
    // Chunks of sixteen, the last one ending at the row's end (it may
    // overlap the one before: the same bytes again).
    if (n >= 16)
    {
      cv::v_uint8x16 vacc = cv::v_setzero_u8();
      const cv::v_uint8x16 one = cv::v_setall_u8(1);
      for (int c = 0;; c += 16)
      {
        const int at = std::min(c, n - 16);
        const cv::v_uint8x16 v = cv::v_load(f + at);
        cv::v_store(u + at, v & one);
        vacc = vacc | v;
        if (at == n - 16)
          break;
      }
      acc = static_cast<uint8_t>(cv::v_reduce_max(vacc & cv::v_setall_u8(PlaneWindow::kClipped)));
      k = n;
    }
#endif
    for (; k < n; ++k)
    {
      u[k] = f[k] & PlaneWindow::kSample;
      acc |= f[k];
    }
    row_clipped[r] = (acc & PlaneWindow::kClipped) != 0;
    any = any || row_clipped[r];
  }
  win->any_clipped = any;
  if (!any)
    return;
  // A clipped pixel's row and the rows above and below it.
  for (int dy = -H; dy <= H; ++dy)
  {
    if (!row_clipped[dy + H])
      continue;
    for (int dx = -H; dx <= H; ++dx)
    {
      if (!(pw.flags[pw.index(dx, dy)] & PlaneWindow::kClipped))
        continue;
      win->usable[pw.index(dx, dy)] = 0;
      if (dx > -H)
        win->usable[pw.index(dx - 1, dy)] = 0;
      if (dx < H)
        win->usable[pw.index(dx + 1, dy)] = 0;
      if (dy > -H)
        win->usable[pw.index(dx, dy - 1)] = 0;
      if (dy < H)
        win->usable[pw.index(dx, dy + 1)] = 0;
    }
  }
}

// One row of the weight field (see buildWeights): v = P / alpha at the
// samples, 0 elsewhere and in the row's padding; the number of samples.
struct WeightRow
{
  const float* other;  // base = signal - c * other, or with mix signal - (c * other + b * third)
  const float* third;
  float c, b, gain, inv_mean, floor, lo, hi;
  bool mix, ambient, normalised;
  // With a plane of the ambient (albedo_plane): alpha from a0 + ax k + ay
  // (the row's part in a0) instead of each pixel's ambient.
  bool plane_alpha = false;
  float a0 = 0, ax = 0;
  int operator()(const PlaneWindow& pw, int row, float p0, float pbx, float* v) const;
};

int WeightRow::operator()(const PlaneWindow& pw, int row, float p0, float pbx, float* v) const
{
  const int n = 2 * pw.H + 1;
  int count = 0, k = 0;
#if CV_SIMD128
  // The scalar loop's operations in the same order: the same floats.
  const cv::v_float32x4 vc = cv::v_setall_f32(c), vb = cv::v_setall_f32(b), vg = cv::v_setall_f32(gain),
                        vp0 = cv::v_setall_f32(p0), vpbx = cv::v_setall_f32(pbx), vmean = cv::v_setall_f32(inv_mean),
                        vfl = cv::v_setall_f32(floor), vlo = cv::v_setall_f32(lo), vhi = cv::v_setall_f32(hi),
                        zero = cv::v_setzero_f32();
  const cv::v_uint32x4 sample_bit = cv::v_setall_u32(PlaneWindow::kSample), vn = cv::v_setall_u32(n);
  cv::v_uint32x4 lane(0, 1, 2, 3), counted = cv::v_setzero_u32();
  for (; k < pw.stride; k += 4, lane += cv::v_setall_u32(4))
  {
    const int i = row + k;
    const cv::v_float32x4 sig = cv::v_load_aligned(pw.signal + i);
    cv::v_float32x4 rock = vc * cv::v_load_aligned(other + i);
    if (mix)
      rock = rock + vb * cv::v_load_aligned(third + i);
    const cv::v_float32x4 added = (sig - rock - (vp0 + vpbx * cv::v_cvt_f32(cv::v_reinterpret_as_s32(lane)))) * vg;
    cv::v_float32x4 val = added;
    if (normalised && plane_alpha)
    {
      const cv::v_float32x4 amb = cv::v_setall_f32(a0) + cv::v_setall_f32(ax) * cv::v_cvt_f32(cv::v_reinterpret_as_s32(lane));
      val = added / cv::v_min(vhi, cv::v_max(vlo, (amb + vfl) * vmean));
    }
    else if (normalised)
    {
      const cv::v_float32x4 amb = ambient ? cv::v_load_aligned(pw.ambient_signal + i) : sig - added;
      val = added / cv::v_min(vhi, cv::v_max(vlo, (amb + vfl) * vmean));
    }
    const cv::v_uint32x4 is_sample = ((cv::v_load_expand_q(pw.flags + i) & sample_bit) == sample_bit) & (lane < vn);
    cv::v_store_aligned(v + k, cv::v_select(cv::v_reinterpret_as_f32(is_sample), val, zero));
    counted -= is_sample;  // all ones is -1
  }
  count = static_cast<int>(cv::v_reduce_sum(counted));
#endif
  for (; k < pw.stride; ++k)
  {
    const int i = row + k;
    if (k >= n || !(pw.flags[i] & PlaneWindow::kSample))
    {
      v[k] = 0.0f;
      continue;
    }
    ++count;
    const float rock = mix ? c * other[i] + b * third[i] : c * other[i];
    const float added = (pw.signal[i] - rock - (p0 + pbx * k)) * gain;
    float alpha = 1.0f;
    if (normalised)
    {
      const float amb = plane_alpha ? a0 + ax * k : (ambient ? pw.ambient_signal[i] : pw.signal[i] - added);
      alpha = std::min(hi, std::max(lo, (amb + floor) * inv_mean));
    }
    v[k] = added / alpha;
  }
  return count;
}

// The weight field of a filled PlaneWindow: P = (base - plane) * gain, the
// dot's added light (base = signal - the ambient frame's signal, or signal -
// a reference - b third, rockMix); divided by alpha = (A + floor) / (mean A + floor), the
// albedo relative to the border's, where the ambient A (the ambient frame's
// signal, or signal - P) is known and bright enough (mean A >= 2 floor: by
// night there is nothing to normalise by). One pass over the window.
void buildWeights(const PlaneWindow& pw, const ColourModel& model, bool third_channel, const RefineSettings& rs,
                  WeightWindow* win)
{
  const int H = pw.H;
  win->cx = pw.cx;
  win->cy = pw.cy;
  win->H = H;
  win->stride = pw.stride;
  Decomposition d;
  if (pw.colour && !pw.ambient && rs.subtract_texture)
  {
    d.mix = rockMix(pw, model, third_channel);
    d.rock = d.mix.a > 0.0;
    d.a = static_cast<float>(d.mix.a);
    d.b = static_cast<float>(d.mix.b);
    d.gain = 1.0 / std::max(0.5, 1.0 - d.mix.a * model.led_reference - d.mix.b * model.led_third);
  }
  d.ambient_known = pw.ambient || d.rock;
  RingSample samples[kMaxRing];
  int n = 0;
  double signal_sum = 0;
  forRing(H, pw.ring,
          [&](int dx, int dy)
          {
            // Clipped pixels are not background (a bloom streak can reach the border).
            const int i = pw.index(dx, dy);
            if ((pw.flags[i] & (PlaneWindow::kSample | PlaneWindow::kClipped)) != PlaneWindow::kSample)
              return;
            samples[n++] = {dx, dy, baseValue(pw, i, d)};
            signal_sum += pw.signal[i];
          });
  const Plane plane = robustPlane(samples, n, &win->noise);
  win->background = n ? signal_sum / n : 0.0;
  double ambient_sum = 0;
  for (int k = 0; k < n; ++k)
    ambient_sum += ambientValue(pw, pw.index(samples[k].dx, samples[k].dy),
                                (samples[k].v - plane.at(samples[k].dx, samples[k].dy)) * d.gain);
  // The floor regularises the ratio where the ambient is dark: at least the
  // noise of the border (which the ambient estimate shares).
  const double mean_ambient = n ? ambient_sum / n : 0.0, floor = std::max(rs.albedo_floor_dn, win->noise);
  win->normalised = rs.normalise_albedo && d.ambient_known && mean_ambient >= 2.0 * floor;
  // base = signal - c * other (- b * third: the rock's mix); the ambient = signal - P, or the ambient frame's.
  // (A mono window fills no reference plane: without a rock model it subtracts 0 x signal, never 0 x garbage.)
  WeightRow weigh;
  weigh.mix = !pw.ambient && d.rock;
  weigh.other = pw.ambient ? pw.ambient_signal : (d.rock ? pw.reference : pw.signal);
  weigh.third = pw.third;
  weigh.c = pw.ambient ? 1.0f : (d.rock ? d.a : 0.0f);
  weigh.b = d.b;
  weigh.gain = static_cast<float>(d.gain);
  weigh.inv_mean = static_cast<float>(1.0 / (mean_ambient + floor));
  weigh.floor = static_cast<float>(floor);
  weigh.lo = static_cast<float>(1.0 / kAlphaMax);
  weigh.hi = static_cast<float>(kAlphaMax);
  weigh.ambient = pw.ambient;
  weigh.normalised = win->normalised;
  // albedo_plane: the ambient's least-squares plane over the window's samples
  // (the grains' gradient across the dot, which pulls its centroid) rather
  // than each pixel's ambient, whose facet-to-facet shading by the sun the
  // projector's light does not share.
  Plane ambient_plane;
  if (win->normalised && rs.albedo_plane)
  {
    std::vector<RingSample> all;
    all.reserve(static_cast<size_t>((2 * H + 1) * (2 * H + 1)));
    for (int dy = -H; dy <= H; ++dy)
      for (int dx = -H; dx <= H; ++dx)
      {
        const int i = pw.index(dx, dy);
        if ((pw.flags[i] & (PlaneWindow::kSample | PlaneWindow::kClipped)) != PlaneWindow::kSample)
          continue;
        const double added = (baseValue(pw, i, d) - plane.at(dx, dy)) * d.gain;
        all.push_back({dx, dy, ambientValue(pw, i, added)});
      }
    ambient_plane = fitPlane(all.data(), static_cast<int>(all.size()), nullptr, Plane{mean_ambient, 0, 0});
    weigh.plane_alpha = true;
  }
  int samples_in = 0;
  for (int dy = -H; dy <= H; ++dy)
  {
    const int row = pw.index(-H, dy);
    weigh.a0 = static_cast<float>(ambient_plane.a + ambient_plane.by * dy - ambient_plane.bx * H);
    weigh.ax = static_cast<float>(ambient_plane.bx);
    samples_in += weigh(pw, row, static_cast<float>(plane.a + plane.by * dy - plane.bx * H),
                        static_cast<float>(plane.bx), win->vals + row);
  }
  win->density = samples_in / detail::square(2.0 * H + 1.0);
  markUsable(pw, win);
}

// ---------------------------------------------------------------------------
// Gaussian-weighted centroid.

// Moments of the window weighted by a Gaussian of sigma sw centred on
// (xc, yc), about that centre.
struct Moments
{
  double Sw = 0, Sx = 0, Sy = 0, Sxx = 0, Syy = 0, Sxy = 0;
};

Moments gaussianMoments(const WeightWindow& win, double xc, double yc, double sw)
{
  const int H = win.H, stride = win.stride, cx = win.cx, cy = win.cy;
  alignas(16) float wx0[kMaxStride], wx1[kMaxStride], wx2[kMaxStride];
  double gy[2 * kMaxRadius + 1];
  // Separable Gaussian weight; the x factors carry the moments' powers of x.
  const double k = -1.0 / (2.0 * sw * sw);
  double gx[2 * kMaxRadius + 1];
  gaussianRun(cx - H - xc, k, 2 * H + 1, gx);
  gaussianRun(cy - H - yc, k, 2 * H + 1, gy);
  for (int d = -H; d <= H; ++d)
  {
    const double ex = cx + d - xc, g = gx[d + H];
    wx0[d + H] = static_cast<float>(g);
    wx1[d + H] = static_cast<float>(g * ex);
    wx2[d + H] = static_cast<float>(g * ex * ex);
  }
  for (int k = 2 * H + 1; k < stride; ++k)
    wx0[k] = wx1[k] = wx2[k] = 0.0f;
  Moments m;
  for (int dy = -H; dy <= H; ++dy)
  {
    const float* v = win.vals + (dy + H) * stride;
    double rw = 0, rx = 0, rxx = 0;
#if CV_SIMD128
    cv::v_float32x4 a0 = cv::v_setzero_f32(), a1 = cv::v_setzero_f32(), a2 = cv::v_setzero_f32();
    for (int k = 0; k < stride; k += 4)
    {
      const cv::v_float32x4 x = cv::v_load_aligned(v + k);
      a0 = cv::v_fma(x, cv::v_load_aligned(wx0 + k), a0);
      a1 = cv::v_fma(x, cv::v_load_aligned(wx1 + k), a1);
      a2 = cv::v_fma(x, cv::v_load_aligned(wx2 + k), a2);
    }
    rw = cv::v_reduce_sum(a0);
    rx = cv::v_reduce_sum(a1);
    rxx = cv::v_reduce_sum(a2);
#else
    for (int k = 0; k < stride; ++k)
    {
      rw += v[k] * wx0[k];
      rx += v[k] * wx1[k];
      rxx += v[k] * wx2[k];
    }
#endif
    const double g = gy[dy + H], ey = cy + dy - yc;
    m.Sw += rw * g;
    m.Sx += rx * g;
    m.Sxx += rxx * g;
    m.Sy += rw * g * ey;
    m.Syy += rw * g * ey * ey;
    m.Sxy += rx * g * ey;
  }
  return m;
}

// For a Gaussian dot of sigma s weighted by a Gaussian of sigma sw, the
// weighted variance m satisfies 1/m = 1/s^2 + 1/sw^2. False when m is too
// close to sw^2 to tell (the weight is much narrower than the dot).
bool deconvolve(double m, double sw, double* s)
{
  if (!(m < 0.9 * sw * sw))
    return false;
  *s = std::sqrt(m * sw * sw / (sw * sw - m));
  return true;
}

// The dot's sigma from the weighted variance m2 (mean of both axes).
double nextSigma(double m2, double sw, double max_sigma)
{
  double s_new;
  if (!deconvolve(m2, sw, &s_new))
    s_new = 2.0 * sw;  // the weight is much narrower than the dot: widen it
  return std::min(std::max(s_new, 0.3), 1.5 * max_sigma + 1.0);
}

// Long axis of the dot (a dot on a slope is foreshortened across it): the
// weighted covariance's larger eigenvalue l, deconvolved from the weight as
// m2 is; at least the mean sigma s_new.
double majorSigma(const Moments& m, double mx, double my, double sw, double s_new)
{
  const double cxx = m.Sxx / m.Sw - mx * mx, cyy = m.Syy / m.Sw - my * my, cxy = m.Sxy / m.Sw - mx * my;
  const double l = 0.5 * (cxx + cyy) + std::sqrt(0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy);
  double major;
  if (!deconvolve(l, sw, &major))
    major = s_new;
  return std::max(major, s_new);
}

// Half size of the window around (cx, cy): fixed, or 3 sigma of the dot;
// kept symmetric about the dot by clipping it at the frame edge on both sides
// rather than on one.
int windowRadius(const FramePlanes& planes, int cx, int cy, int fixed_radius, double sw, double max_sigma)
{
  const int H =
      fixed_radius > 0 ? fixed_radius : std::max(3, static_cast<int>(std::ceil(3.0 * std::min(sw, max_sigma))) + 1);
  return std::min({H, kMaxRadius, cx, cy, planes.frameCols() - 1 - cx, planes.frameRows() - 1 - cy});
}

// Whether a clipped pixel lies within 2.5 sigma of (x, y).
bool clippedNear(const WeightWindow& w, double x, double y, double sigma)
{
  if (!w.any_clipped)
    return false;
  const double r2 = detail::square(2.5 * sigma + 1.0);
  for (int dy = -w.H; dy <= w.H; ++dy)
    for (int dx = -w.H; dx <= w.H; ++dx)
    {
      const int i = (dy + w.H) * w.stride + dx + w.H;
      if (!w.usable[i] && detail::square(w.cx + dx - x) + detail::square(w.cy + dy - y) <= r2 && (w.vals[i] != 0.0f))
        return true;
    }
  return false;
}
}  // namespace

double gaussianAmplitude(const SpotFit& fit)
{
  return fit.flux / (detail::kPi * fit.sigma * fit.sigma);
}

namespace
{
// The planes of the window centred on pixel (cx, cy), unless they are
// filled already. The weights are built from them when needed (withWeights):
// a dot found clipped from the planes' flags alone (clippedNearPlanes) is fitted
// in a wider window, and the weights of the first would be wasted.
void fillPlanes(const FramePlanes& planes, int cx, int cy, int H, RefineScratch* scratch)
{
  const PlaneWindow& pw = scratch->planes;
  if (cx == pw.cx && cy == pw.cy && H == pw.H)
    return;
  planes.fillWindow(cx, cy, H, &scratch->planes);
}

// The weights of the filled planes, unless they are built already.
void withWeights(const FramePlanes& planes, const RefineSettings& rs, RefineScratch* scratch)
{
  const PlaneWindow& pw = scratch->planes;
  WeightWindow& win = scratch->weights;
  if (pw.cx == win.cx && pw.cy == win.cy && pw.H == win.H)
    return;
  const bool shared_chroma = planes.format() == PixelFormat::kUyvy || planes.format() == PixelFormat::kYuyv;
  buildWeights(pw, planes.model(), !shared_chroma, rs, &win);
}

// For the iterated centroid: the planes of a window that covers half size H
// around pixel (cx, cy). The filled one is kept while it does and is not much
// larger (the centroid's steps are small after the first); else one is
// filled with a margin of 2 px, which spares most reloads.
void coverPlanes(const FramePlanes& planes, int cx, int cy, int H, RefineScratch* scratch)
{
  const PlaneWindow& pw = scratch->planes;
  const int off = std::max(std::abs(cx - pw.cx), std::abs(cy - pw.cy));
  if (pw.H >= 0 && H + off <= pw.H && pw.H <= H + 4)
    return;
  const int margin =
      std::min({2, kMaxRadius - H, cx - H, cy - H, planes.frameCols() - 1 - cx - H, planes.frameRows() - 1 - cy - H});
  fillPlanes(planes, cx, cy, H + std::max(0, margin), scratch);
}

// coverPlanes, and the weights of the window.
void coverWindow(const FramePlanes& planes, const RefineSettings& rs, int cx, int cy, int H, RefineScratch* scratch)
{
  coverPlanes(planes, cx, cy, H, scratch);
  withWeights(planes, rs, scratch);
}

// clippedNear from the planes alone: whether a sample within 2.5 sigma of
// (x, y) is clipped or next to a clipped pixel (what markUsable leaves out).
bool clippedNearPlanes(const PlaneWindow& pw, double x, double y, double sigma)
{
  const int H = pw.H, n = 2 * H + 1;
  int k = 0, end = n * pw.stride;
  bool any = false;
#if CV_SIMD128
  cv::v_uint8x16 acc = cv::v_setzero_u8();
  for (; k + 16 <= end; k += 16)
    acc = acc | cv::v_load(pw.flags + k);
  any = (cv::v_reduce_max(acc & cv::v_setall_u8(PlaneWindow::kClipped)) != 0);
#endif
  for (; k < end; ++k)
    any = any || (pw.flags[k] & PlaneWindow::kClipped);
  if (!any)
    return false;
  // The disk's bounding box in the window (a pixel within r of (x, y) lies in it).
  const double r = 2.5 * sigma + 1.0, r2 = r * r;
  const int dy0 = std::max(-H, static_cast<int>(std::floor(y - r)) - pw.cy);
  const int dy1 = std::min(H, static_cast<int>(std::ceil(y + r)) - pw.cy);
  const int dx0 = std::max(-H, static_cast<int>(std::floor(x - r)) - pw.cx);
  const int dx1 = std::min(H, static_cast<int>(std::ceil(x + r)) - pw.cx);
  auto clippedAt = [&](int dx, int dy)
  { return std::abs(dx) <= H && std::abs(dy) <= H && (pw.flags[pw.index(dx, dy)] & PlaneWindow::kClipped); };
  // Most often the answer is at the centre (a clipped dot's plateau) or
  // nowhere near it (a neighbour's plateau at the window's edge).
  const int sx = static_cast<int>(std::lround(x)) - pw.cx, sy = static_cast<int>(std::lround(y)) - pw.cy;
  if (clippedAt(sx, sy) && (pw.flags[pw.index(sx, sy)] & PlaneWindow::kSample) &&
      detail::square(pw.cx + sx - x) + detail::square(pw.cy + sy - y) <= r2)
    return true;
  bool near = false;
  for (int dy = std::max(-H, dy0 - 1); dy <= std::min(H, dy1 + 1) && !near; ++dy)
    for (int dx = std::max(-H, dx0 - 1); dx <= std::min(H, dx1 + 1); ++dx)
      near = near || (pw.flags[pw.index(dx, dy)] & PlaneWindow::kClipped);
  if (!near)
    return false;
  for (int dy = dy0; dy <= dy1; ++dy)
    for (int dx = dx0; dx <= dx1; ++dx)
    {
      if (!(pw.flags[pw.index(dx, dy)] & PlaneWindow::kSample) ||
          detail::square(pw.cx + dx - x) + detail::square(pw.cy + dy - y) > r2)
        continue;
      if (clippedAt(dx, dy) || clippedAt(dx - 1, dy) || clippedAt(dx + 1, dy) || clippedAt(dx, dy - 1) ||
          clippedAt(dx, dy + 1))
        return true;
    }
  return false;
}

// The fields of a fit that come from its window.
void describeWindow(const WeightWindow& win, SpotFit* out)
{
  out->background = win.background;
  out->noise = win.noise;
  out->normalised = win.normalised;
  out->window = cv::Rect(win.cx - win.H, win.cy - win.H, 2 * win.H + 1, 2 * win.H + 1);
}

// A dot with clipped pixels near the candidate: a clipped core carries no
// shape (and an iterated centroid can drift along a bloom streak), so a
// Gaussian fit to the flanks locates it, started from the plateau's centroid
// with sigmas that the plateau's width allows (a Gaussian of peak A clipped
// at L is clipped out to sigma sqrt(2 ln(A / L))), refitted once from the
// first fit where that moved the centre by a pixel or the disk's edge by one
// (a disk from a sigma guessed low leaves out flank samples the fit needs:
// 0.0616 -> 0.0587 px on benchmark_spot_detector's tracking frames). The window is the fit's disk (3 sigma + 2 px) and the
// background's ring just outside it, at 3.5 sigma or more, where the dot adds
// 2e-3 of its peak at most (sigma 6 px; 4e-5 at 2 px), and that evenly all
// round: the plane's offset, not its tilt. The ring nearest the dot is the
// best estimate of the background under it on a sloping or textured rock.
bool refineClipped(const FramePlanes& planes, const RefineSettings& rs, double x0, double y0, double sigma0,
                   int fixed_radius, RefineScratch* scratch, SpotFit* out)
{
  const WeightWindow& win = scratch->weights;
  cv::Point2d centre(x0, y0);
  double half_width = 0.0;
  if (!clippedPlateau(scratch->planes, x0, y0, &centre, &half_width))
    return false;
  SpotFit fit;
  fit.x = centre.x;
  fit.y = centre.y;
  fit.sigma = std::max(sigma0, std::min(rs.max_sigma, half_width / 1.5));
  for (int pass = 0; pass < 2; ++pass)
  {
    const int cx = static_cast<int>(std::lround(fit.x)), cy = static_cast<int>(std::lround(fit.y));
    const int reach = fixed_radius > 0 ? fixed_radius : static_cast<int>(std::ceil(3.0 * fit.sigma)) + 3;
    const int H = windowRadius(planes, cx, cy, reach, fit.sigma, rs.max_sigma);
    if (H < 2)
      return false;
    coverWindow(planes, rs, cx, cy, H, scratch);
    const double started = fit.sigma;
    if (!fitGaussian(win, rs.max_sigma, &fit))
      return false;
    // Again once, recentred, where the fit moved by a pixel or its sigma
    // moves the edge of the samples' disk (3 sigma + 2 px) by one.
    if (std::hypot(fit.x - cx, fit.y - cy) < 1.0 && std::abs(3.0 * (fit.sigma - started)) < 1.0)
      break;
  }
  *out = fit;
  describeWindow(win, out);
  out->clipped = true;
  return true;
}
}  // namespace

// Iteratively Gaussian-weighted centroid with adaptive sigma (star-tracker
// IWC / adaptive moments): weights w = (v - background) * G(x - c_w; s_w).
// The weighted variance gives the dot's sigma s (deconvolve), and the
// weighted mean lies a fraction s^2 / (s^2 + s_w^2) of the way from c_w to
// the dot's centre, so one step scaled by the inverse fraction lands on it (a
// few iterations for real, pixel-integrated or noisy dots). The window is
// set by s, not by a threshold, so no pixel enters or leaves it because of
// noise. A dot with clipped pixels near its centre is located by a Gaussian
// fit that leaves them out instead: a clipped plateau shaped by the albedo
// or by blooming along the columns is not symmetric about the hit point.
bool refineSpot(const FramePlanes& planes, const RefineSettings& rs, double x0, double y0, double sigma0,
                int fixed_radius, RefineScratch* scratch, SpotFit* out)
{
  const double max_sigma = rs.max_sigma;
  double xc = x0, yc = y0, sw = sigma0;
  WeightWindow& win = scratch->weights;
  win.cx = win.cy = win.H = -1;
  scratch->planes.cx = scratch->planes.cy = scratch->planes.H = -1;
  double flux = 0, major = 0;
  bool converged = false;
  for (int it = 0; it < 12 && !converged; ++it)
  {
    const int cx = static_cast<int>(std::lround(xc)), cy = static_cast<int>(std::lround(yc));
    const int H = windowRadius(planes, cx, cy, fixed_radius, sw, max_sigma);
    if (H < 2)
      return false;
    if (fixed_radius > 0)
      fillPlanes(planes, cx, cy, H, scratch);
    else
      coverPlanes(planes, cx, cy, H, scratch);
    if (it == 0 && clippedNearPlanes(scratch->planes, x0, y0, sigma0))
      return refineClipped(planes, rs, x0, y0, sigma0, fixed_radius, scratch, out);
    withWeights(planes, rs, scratch);
    const Moments m = gaussianMoments(win, xc, yc, sw);
    if (!(m.Sw > 1e-6))
      return false;
    const double mx = m.Sx / m.Sw, my = m.Sy / m.Sw;
    const double m2 = 0.5 * ((m.Sxx / m.Sw - mx * mx) + (m.Syy / m.Sw - my * my));
    if (!(m2 > 0.0))
      return false;
    const double s_new = nextSigma(m2, sw, max_sigma);
    // Step to the dot's centre; the gain is bounded because real dots are
    // not exact Gaussians.
    const double gain = std::min(3.0, (s_new * s_new + sw * sw) / (s_new * s_new));
    const double step_x = gain * mx, step_y = gain * my;
    const double step = std::hypot(step_x, step_y), limit = std::max(1.0, sw);
    const double k = step > limit ? limit / step : 1.0;
    xc += k * step_x;
    yc += k * step_y;
    converged = step < 2e-3 && std::abs(s_new - sw) < 2e-2 * sw;
    major = majorSigma(m, mx, my, sw, s_new);
    sw = s_new;
    flux = m.Sw;
  }
  if (!std::isfinite(xc) || !std::isfinite(yc) || std::abs(xc - win.cx) > win.H || std::abs(yc - win.cy) > win.H)
    return false;
  // The light's own centroid where the dot stands well out of what the
  // window's border shows of the rock: the plain first moment of the added
  // light in a disc of plain_radius sigmas. A Gaussian weight finds the
  // centre of a symmetric dot; the footprint of a beam on facets of the rock
  // is not symmetric, and its plain moment is the light's centroid (where the
  // rock's residual is small against the dot, its noise costs little).
  const double peak = flux / std::max(1e-3, win.density) / (2.0 * M_PI * sw * sw);
  if (rs.plain_radius > 0.0 && peak >= rs.plain_snr * std::max(win.noise, 0.5))
  {
    const double R = rs.plain_radius * sw;
    double s = 0, sx = 0, sy = 0;
    for (int dy = -win.H; dy <= win.H; ++dy)
    {
      const float* v = win.vals + (dy + win.H) * win.stride;
      const double ey = win.cy + dy - yc;
      for (int dx = -win.H; dx <= win.H; ++dx)
      {
        const double ex = win.cx + dx - xc;
        if (ex * ex + ey * ey > R * R)
          continue;
        s += v[dx + win.H];
        sx += v[dx + win.H] * ex;
        sy += v[dx + win.H] * ey;
      }
    }
    if (s > 1e-6 && std::abs(sx / s) < sw && std::abs(sy / s) < sw)
    {
      xc += sx / s;
      yc += sy / s;
    }
  }
  out->x = xc;
  out->y = yc;
  out->sigma = sw;
  out->sigma_major = major;
  // A mosaic's signal is sampled at a fraction of the pixels: the sums scale with it.
  out->flux = flux / std::max(1e-3, win.density);
  out->amplitude = gaussianAmplitude(*out);
  describeWindow(win, out);
  out->clipped = false;
  // Clipping found only where the centroid ended.
  if (clippedNear(win, xc, yc, sw))
    return refineClipped(planes, rs, xc, yc, sw, fixed_radius, scratch, out);
  return true;
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
