// Stage 4 of the fast method: the measurement of one candidate in a window
// of the frame (see spot_detector_fast_stages.h): an iteratively
// Gaussian-weighted centroid over a background plane, and the colour of the
// light the spot adds to the rock.
#include <algorithm>
#include <cmath>

#include <opencv2/core/hal/intrin.hpp>

#include "structured_light_stabilizer/detail/math.h"
#include "spot_detector_fast_stages.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

namespace
{
constexpr int kMaxRadius = 24;  // largest window half size
constexpr int kMaxRing = 8 * kMaxRadius;
constexpr int kMaxStride = 52;  // 2 * kMaxRadius + 1 rounded up to 4 lanes

// Calls f(dx, dy) for every pixel of the one-pixel border ring of the
// (2H+1)^2 window: top and bottom rows, then the left and right columns.
template <typename F>
void forRing(int H, F f)
{
  for (int d = -H; d <= H; ++d)
  {
    f(d, -H);
    f(d, H);
  }
  for (int d = -H + 1; d <= H - 1; ++d)
  {
    f(-H, d);
    f(H, d);
  }
}

// The rock's ratio of a channel to red, from sums over n ring pixels (least
// squares through the origin); 0 when red is below ~3 DN: no sunlit texture
// to follow (night).
double ratioToRed(double sum_cr, double sum_rr, int n)
{
  if (sum_rr < 9.0 * n)
    return 0.0;
  return std::min(1.5, std::max(0.0, sum_cr / sum_rr));
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
  // 3 x 3 symmetric system by Cramer's rule (hot path: no cv::solve overhead).
  Plane p = prev;
  const double c00 = sxx * syy - sxy * sxy, c01 = s1y * sxy - s1x * syy, c02 = s1x * sxy - s1y * sxx;
  const double det = s11 * c00 + s1x * c01 + s1y * c02;
  if (s11 >= 6 && std::abs(det) > 1e-9)
  {
    const double c11 = s11 * syy - s1y * s1y, c12 = s1x * s1y - s11 * sxy, c22 = s11 * sxx - s1x * s1x;
    p.a = (c00 * b1 + c01 * bx + c02 * by) / det;
    p.bx = (c01 * b1 + c11 * bx + c12 * by) / det;
    p.by = (c02 * b1 + c12 * bx + c22 * by) / det;
  }
  return p;
}

// Background plane of channel ch minus kappa times channel ch2 (ch2 < 0: ch
// alone) on the border ring of the (2H+1)^2 window centred on (cx, cy).
// Robust: a least-squares fit, then a refit without the border pixels far
// from it (a speck, a mineral edge or a neighbour's flank on the ring would
// otherwise tilt the plane and drag the centroid).
Plane borderPlane(const cv::Mat& img, int pixel_bytes, int ch, int cx, int cy, int H, int ch2, double kappa)
{
  RingSample samples[kMaxRing];
  int n = 0;
  forRing(H,
          [&](int dx, int dy)
          {
            const uint8_t* px = img.ptr<uint8_t>(cy + dy) + (cx + dx) * pixel_bytes;
            samples[n++] = {dx, dy, double(px[ch]) - (ch2 >= 0 ? kappa * px[ch2] : 0.0)};
          });
  const Plane p = fitPlane(samples, n, nullptr, Plane());
  double res[kMaxRing];
  for (int i = 0; i < n; ++i)
    res[i] = std::abs(samples[i].v - p.at(samples[i].dx, samples[i].dy));
  const double mad = 1.4826 * detail::medianInPlace(res, res + n);
  const double limit = std::max(2.0, 3.0 * mad);
  return fitPlane(samples, n, &limit, p);
}

// Mean of channel ch on the window's border.
double borderMean(const cv::Mat& img, int pixel_bytes, int ch, int cx, int cy, int H)
{
  double sum = 0;
  const uint8_t* top = img.ptr<uint8_t>(cy - H) + (cx - H) * pixel_bytes + ch;
  const uint8_t* bottom = img.ptr<uint8_t>(cy + H) + (cx - H) * pixel_bytes + ch;
  for (int d = 0; d <= 2 * H; ++d)
    sum += top[d * pixel_bytes] + bottom[d * pixel_bytes];
  for (int dy = -H + 1; dy <= H - 1; ++dy)
  {
    const uint8_t* row = img.ptr<uint8_t>(cy + dy) + ch;
    sum += row[(cx - H) * pixel_bytes] + row[(cx + H) * pixel_bytes];
  }
  return sum / (8.0 * H);
}

// Green-over-red ratio of the rock on the window's border.
double rockRatio(const cv::Mat& img, int pixel_bytes, int g_ch, int r_ch, int cx, int cy, int H)
{
  double gr = 0, rr = 0;
  int n = 0;
  forRing(H,
          [&](int dx, int dy)
          {
            const uint8_t* px = img.ptr<uint8_t>(cy + dy) + (cx + dx) * pixel_bytes;
            gr += double(px[g_ch]) * px[r_ch];
            rr += double(px[r_ch]) * px[r_ch];
            ++n;
          });
  return ratioToRed(gr, rr, n);
}

// ---------------------------------------------------------------------------
// Gaussian-weighted centroid.

// The refinement window: the weight channel minus its background plane, rows
// padded with zeros to a multiple of 4 floats (SIMD lanes).
struct Window
{
  int cx = -1, cy = -1, H = -1, stride = 0;
  double background = 0;  // mean of the weight channel on the border (DN)
  alignas(16) float vals[(2 * kMaxRadius + 1) * kMaxStride];
};

// With red_ch >= 0 the weight channel is g - kappa r, kappa the rock's own
// green/red ratio around the dot: the sunlit rock texture under the dot then
// cancels pixel by pixel (it is in red as much as in green), and the dot,
// which barely reaches red, stays. A plane fitted to the window's border can
// only remove a gradient, not texture, which at full sun biases the centroid
// by a tenth of a pixel.
void loadWindow(const cv::Mat& img, int pixel_bytes, int ch, int red_ch, int cx, int cy, int H, Window* win)
{
  win->cx = cx;
  win->cy = cy;
  win->H = H;
  const double kappa = red_ch >= 0 ? rockRatio(img, pixel_bytes, ch, red_ch, cx, cy, H) : 0.0;
  const Plane bg = borderPlane(img, pixel_bytes, ch, cx, cy, H, red_ch, kappa);
  win->background = borderMean(img, pixel_bytes, ch, cx, cy, H);
  win->stride = (2 * H + 1 + 3) & ~3;
  for (int dy = -H; dy <= H; ++dy)
  {
    const uint8_t* row = img.ptr<uint8_t>(cy + dy) + (cx - H) * pixel_bytes;
    float* v = win->vals + (dy + H) * win->stride;
    for (int dx = -H; dx <= H; ++dx)
    {
      const uint8_t* px = row + (dx + H) * pixel_bytes;
      const double value = px[ch] - (kappa > 0.0 ? kappa * px[red_ch] : 0.0);
      v[dx + H] = static_cast<float>(value - bg.at(dx, dy));
    }
    for (int k = 2 * H + 1; k < win->stride; ++k)
      v[k] = 0.0f;
  }
}

// Moments of the window weighted by a Gaussian of sigma sw centred on
// (xc, yc), about that centre.
struct Moments
{
  double Sw = 0, Sx = 0, Sy = 0, Sxx = 0, Syy = 0, Sxy = 0;
};

Moments gaussianMoments(const Window& win, double xc, double yc, double sw)
{
  const int H = win.H, stride = win.stride, cx = win.cx, cy = win.cy;
  alignas(16) float wx0[kMaxStride], wx1[kMaxStride], wx2[kMaxStride];
  double gy[2 * kMaxRadius + 1];
  // Separable Gaussian weight; the x factors carry the moments' powers of x.
  const double inv2s2 = 1.0 / (2.0 * sw * sw);
  for (int d = -H; d <= H; ++d)
  {
    const double ex = cx + d - xc, ey = cy + d - yc;
    const double g = std::exp(-ex * ex * inv2s2);
    wx0[d + H] = static_cast<float>(g);
    wx1[d + H] = static_cast<float>(g * ex);
    wx2[d + H] = static_cast<float>(g * ex * ex);
    gy[d + H] = std::exp(-ey * ey * inv2s2);
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
int windowRadius(const cv::Mat& img, int cx, int cy, int fixed_radius, double sw, double max_sigma)
{
  const int H =
      fixed_radius > 0 ? fixed_radius : std::max(3, static_cast<int>(std::ceil(3.0 * std::min(sw, max_sigma))) + 1);
  return std::min({H, kMaxRadius, cx, cy, img.cols - 1 - cx, img.rows - 1 - cy});
}
}  // namespace

double gaussianAmplitude(const SpotFit& fit)
{
  return fit.flux / (detail::kPi * fit.sigma * fit.sigma);
}

// Iteratively Gaussian-weighted centroid with adaptive sigma (star-tracker
// IWC / adaptive moments): weights w = (v - background) * G(x - c_w; s_w).
// The weighted variance gives the dot's sigma s (deconvolve), and the
// weighted mean lies a fraction s^2 / (s^2 + s_w^2) of the way from c_w to
// the dot's centre, so one step scaled by the inverse fraction lands on it (a
// few iterations for real, pixel-integrated, clipped or noisy dots). The
// window is set by s, not by a threshold, so no pixel enters or leaves it
// because of noise, and a clipped (saturated) core stays symmetric, hence
// unbiased.
bool refineSpot(const cv::Mat& img, int pixel_bytes, int ch, int red_ch, double x0, double y0, double sigma0,
                int fixed_radius, double max_sigma, SpotFit* out)
{
  double xc = x0, yc = y0, sw = sigma0;
  Window win;
  double flux = 0, major = 0;
  bool converged = false;
  for (int it = 0; it < 12 && !converged; ++it)
  {
    const int cx = static_cast<int>(std::lround(xc)), cy = static_cast<int>(std::lround(yc));
    const int H = windowRadius(img, cx, cy, fixed_radius, sw, max_sigma);
    if (H < 2)
      return false;
    if (cx != win.cx || cy != win.cy || H != win.H)
      loadWindow(img, pixel_bytes, ch, red_ch, cx, cy, H, &win);
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
  out->x = xc;
  out->y = yc;
  out->sigma = sw;
  out->sigma_major = major;
  out->flux = flux;
  out->background = win.background;
  out->window = cv::Rect(win.cx - win.H, win.cy - win.H, 2 * win.H + 1, 2 * win.H + 1);
  return true;
}

// ---------------------------------------------------------------------------
// Colour of the added light.

namespace
{
// The rock around a spot, from the border ring of its window: least-squares
// planes of r, g, b (on the full square ring 1, dx and dy are orthogonal, so
// each plane is three sums; a plane of g - k r is the plane of g minus k
// times that of r), the rock's g/r and b/r ratios, and the spread of red
// about its plane (how much texture the red ratio carries). Plain, not
// robust: the colour test only needs ratios, and this runs for every
// candidate.
struct RingColour
{
  Plane red, green, blue;
  double kg = 0, kb = 0;  // the rock's green/red and blue/red
  double red_spread = 0;  // RMS of red about its plane (DN)
};

// RMS of red about its plane over the n pixels of the border ring.
double redSpread(const cv::Mat& img, const PixelLayout& L, int cx, int cy, int H, const Plane& red, int n)
{
  double sum = 0;
  for (int d = -H; d <= H; ++d)
  {
    for (int e : {-H, H})
    {
      const double a = img.ptr<uint8_t>(cy + e)[(cx + d) * L.step + L.r] - red.at(d, e);
      sum += a * a;
      if (std::abs(d) < H)
      {
        const double b = img.ptr<uint8_t>(cy + d)[(cx + e) * L.step + L.r] - red.at(e, d);
        sum += b * b;
      }
    }
  }
  return std::sqrt(sum / n);
}

RingColour ringColour(const cv::Mat& img, const PixelLayout& L, int cx, int cy, int H)
{
  double s[3] = {0, 0, 0}, sx[3] = {0, 0, 0}, sy[3] = {0, 0, 0}, sgr = 0, sbr = 0, srr = 0;
  int n = 0;
  forRing(H,
          [&](int dx, int dy)
          {
            const uint8_t* px = img.ptr<uint8_t>(cy + dy) + (cx + dx) * L.step;
            const double c[3] = {double(px[L.r]), double(px[L.g]), double(px[L.b])};
            for (int k = 0; k < 3; ++k)
            {
              s[k] += c[k];
              sx[k] += c[k] * dx;
              sy[k] += c[k] * dy;
            }
            sgr += c[1] * c[0];
            sbr += c[2] * c[0];
            srr += c[0] * c[0];
            ++n;
          });
  // Sum of dx^2 over the ring (the same for dy).
  double sdd = 0;
  for (int d = -H; d <= H; ++d)
    sdd += 2.0 * d * d + (std::abs(d) < H ? 2.0 * H * H : 0.0);
  Plane planes[3];
  for (int k = 0; k < 3; ++k)
  {
    planes[k].a = s[k] / n;
    planes[k].bx = sx[k] / sdd;
    planes[k].by = sy[k] / sdd;
  }
  RingColour ring;
  ring.red = planes[0];
  ring.green = planes[1];
  ring.blue = planes[2];
  ring.kg = ratioToRed(sgr, srr, n);
  ring.kb = ratioToRed(sbr, srr, n);
  ring.red_spread = redSpread(img, L, cx, cy, H, ring.red, n);
  return ring;
}

// plane - k * other, coefficient by coefficient.
Plane minusScaled(Plane plane, double k, const Plane& other)
{
  plane.a -= k * other.a;
  plane.bx -= k * other.bx;
  plane.by -= k * other.by;
  return plane;
}

// Gaussian-weighted excess of the spot's unclipped pixels over the rock:
// red, green, green - kg red (texture-free) and blue - kb red (texture-free).
struct Excess
{
  double red = 0, green = 0, texture_free_green = 0, texture_free_blue = 0, sum_w = 0;
};

Excess weightedExcess(const cv::Mat& img, const PixelLayout& L, int saturation, const SpotFit& fit,
                      const RingColour& ring)
{
  const int H = (fit.window.width - 1) / 2;
  const int cx = fit.window.x + H, cy = fit.window.y + H;
  const Plane pd = minusScaled(ring.green, ring.kg, ring.red), pb = minusScaled(ring.blue, ring.kb, ring.red);
  const double inv2s2 = 1.0 / (2.0 * fit.sigma * fit.sigma);
  double gx[64], gy[64];
  for (int d = -H; d <= H && d + H < 64; ++d)
  {
    const double ex = cx + d - fit.x, ey = cy + d - fit.y;
    gx[d + H] = std::exp(-ex * ex * inv2s2);
    gy[d + H] = std::exp(-ey * ey * inv2s2);
  }
  Excess e;
  for (int dy = -H; dy <= H; ++dy)
  {
    const uint8_t* row = img.ptr<uint8_t>(cy + dy);
    for (int dx = -H; dx <= H; ++dx)
    {
      const uint8_t* px = row + (cx + dx) * L.step;
      if (px[L.r] >= saturation || px[L.g] >= saturation || px[L.b] >= saturation)
        continue;
      const double w = gx[dx + H] * gy[dy + H];
      e.sum_w += w;
      e.red += w * (px[L.r] - ring.red.at(dx, dy));
      e.green += w * (px[L.g] - ring.green.at(dx, dy));
      e.texture_free_green += w * (px[L.g] - ring.kg * px[L.r] - pd.at(dx, dy));
      e.texture_free_blue += w * (px[L.b] - ring.kb * px[L.r] - pb.at(dx, dy));
    }
  }
  return e;
}
}  // namespace

// Red: excess over the local background plane relative to the green excess
// (texture-sensitive; slack says how much). Blue: measured on texture-free
// signals, green - kappa_g red and blue - kappa_b red (kappa = the rock's own
// ratios on the border), so sunlit rock texture cancels and what remains is
// the added light's blue/green ratio, (led_b - kappa_b led_r) / (1 - kappa_g
// led_r) for a dot. Gaussian-weighted, unclipped pixels only.
void measureColour(const cv::Mat& img, const PixelLayout& L, int saturation, double led_red, double led_blue,
                   SpotFit* fit)
{
  const int H = (fit->window.width - 1) / 2;
  const RingColour ring = ringColour(img, L, fit->window.x + H, fit->window.y + H, H);
  const Excess e = weightedExcess(img, L, saturation, *fit, ring);
  if (e.green > 1e-6 && e.texture_free_green > 1e-6)
  {
    fit->red_ratio = e.red / e.green;
    // Rock texture is spatially correlated over the window, so its effect on
    // the weighted sums scales with the sum of the weights, not its root.
    fit->red_slack = ring.red_spread * e.sum_w / e.green;
    // Mapped back to the LED's blue/green ratio for comparison.
    const double expected = (led_blue - ring.kb * led_red) / std::max(0.1, 1.0 - ring.kg * led_red);
    fit->blue_ratio = e.texture_free_blue / e.texture_free_green - expected + led_blue;
  }
  else
  {
    // No green excess over the rock: not light added by the projector.
    fit->red_ratio = fit->blue_ratio = detail::kNaN;
  }
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
