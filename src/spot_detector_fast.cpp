// SpotMethod::kFast: threshold pass, runs -> blobs, candidates, Gaussian-
// weighted refinement, colour test, de-duplication and frame checks. See the
// contract in spot_detector.h.
#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/core/hal/intrin.hpp>

#include "spot_detector_method.h"

namespace structured_light_stabilizer
{

namespace
{
// Greenness of one pixel: g - max(k r, b), floored at 0, k = red_weight in
// 1/256 units. Reddish rock (g/r about 0.55-0.65) scores 0 whatever its
// albedo or the sun; the projector's 520 nm light raises g far more than r or
// b; grey, white and bluish clutter scores 0 too.
inline int greenness(const uint8_t* px, const PixelLayout& L, int k256)
{
  return std::max(0, int(px[L.g]) - std::max((k256 * int(px[L.r])) >> 8, int(px[L.b])));
}

template <typename RunT>
inline void markPixel(std::vector<RunT>* runs, int y, int x)
{
  if (!runs->empty() && runs->back().y == y && runs->back().x1 == x - 1)
    runs->back().x1 = x;
  else
    runs->push_back({y, x, x});
}

#if CV_SIMD128
// k * r / 256 for 16 pixels, through 16-bit lanes.
inline cv::v_uint8x16 scaleRed(const cv::v_uint8x16& r, const cv::v_uint16x8& k)
{
  cv::v_uint16x8 lo, hi;
  cv::v_expand(r, lo, hi);
  return cv::v_pack(cv::v_shr<8>(cv::v_mul_wrap(lo, k)), cv::v_shr<8>(cv::v_mul_wrap(hi, k)));
}
#endif

// Candidate pixels (score >= threshold) of one row, appended as runs. One
// pass over the row, 16 pixels at a time when SIMD is available: a block
// without a candidate costs a deinterleaving load, a few multiply/max/
// saturating-subtract operations and one test, which keeps the whole frame
// near the memory bandwidth limit. kRedFirst: byte 0 is red (rgb8, rgba8).
// acc (may be null) accumulates every pixel's score, for the coarse pass.
template <int kChannels, bool kRedFirst, typename RunT>
void rowRuns(const uint8_t* row, int width, int y, int threshold, int k256, std::vector<RunT>* runs, uint16_t* acc)
{
  int x = 0;
#if CV_SIMD128
  const cv::v_uint8x16 vthr = cv::v_setall_u8(static_cast<uint8_t>(threshold));
  const cv::v_uint16x8 vk = cv::v_setall_u16(static_cast<uint16_t>(k256));
  alignas(16) uint8_t hit[16];
  for (; x + 16 <= width; x += 16)
  {
    cv::v_uint8x16 s;
    if (kChannels == 1)
    {
      s = cv::v_load(row + x);
    }
    else
    {
      cv::v_uint8x16 c0, c1, c2, c3;
      if (kChannels == 3)
        cv::v_load_deinterleave(row + 3 * x, c0, c1, c2);
      else
        cv::v_load_deinterleave(row + 4 * x, c0, c1, c2, c3);
      const cv::v_uint8x16& r = kRedFirst ? c0 : c2;
      const cv::v_uint8x16& b = kRedFirst ? c2 : c0;
      s = c1 - cv::v_max(scaleRed(r, vk), b);  // saturating
    }
    if (acc)
    {
      cv::v_uint16x8 lo, hi;
      cv::v_expand(s, lo, hi);
      cv::v_store(acc + x, cv::v_load(acc + x) + lo);
      cv::v_store(acc + x + 8, cv::v_load(acc + x + 8) + hi);
    }
    const cv::v_uint8x16 m = s >= vthr;
    if (!cv::v_check_any(m))
      continue;
    cv::v_store(hit, m);
    for (int i = 0; i < 16; ++i)
      if (hit[i])
        markPixel(runs, y, x + i);
  }
#endif
  const PixelLayout L = kRedFirst ? PixelLayout{0, 1, 2, kChannels} : PixelLayout{2, 1, 0, kChannels};
  for (; x < width; ++x)
  {
    const uint8_t* px = row + kChannels * x;
    const int score = kChannels == 1 ? int(px[0]) : greenness(px, L, k256);
    if (acc)
      acc[x] = static_cast<uint16_t>(acc[x] + score);
    if (score >= threshold)
      markPixel(runs, y, x);
  }
}

int findRoot(std::vector<int>& parent, int i)
{
  while (parent[i] != i)
  {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

struct Blob
{
  int count = 0;
  double sum = 0, sx = 0, sy = 0;
  int peak = 0, peak_x = 0, peak_y = 0;
  int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1;
};

struct Refined
{
  double x = 0, y = 0, sigma = 0, flux = 0;
  double sigma_major = 0;                // along the footprint's long axis (sigma: the mean of both axes)
  double red_ratio = 0, blue_ratio = 0;  // excess over background relative to green's
  double red_slack = 0;                  // how far texture alone could move the red ratio
  double background = 0;                 // local background level of the weight channel (DN)
  bool on_pedestal = false;              // found by the small-window retry
  bool clipped = false;                  // green core saturated: sigma inflated, flux short
  cv::Rect window;
};

// Background plane a + bx*dx + by*dy fitted to the one-pixel border ring of
// the (2H+1)^2 window centred on (cx, cy), channel at byte offset `ch`.
// Robust: a least-squares fit, then a refit without the border pixels far
// from it (a speck, a mineral edge or a neighbour's flank on the ring would
// otherwise tilt the plane and drag the centroid).
struct Plane
{
  double a = 0, bx = 0, by = 0;
  double spread = 0;  // robust RMS of the border about the plane (texture + noise)
  double at(int dx, int dy) const { return a + bx * dx + by * dy; }
};

// The value fitted is channel ch minus kappa times channel ch2 (ch2 < 0: ch alone).
Plane borderPlane(const cv::Mat& img, int pixel_bytes, int ch, int cx, int cy, int H, int ch2 = -1, double kappa = 0.0)
{
  struct Sample
  {
    int dx, dy;
    double v;
  };
  Sample samples[8 * 24];
  int n = 0;
  auto add = [&](int dx, int dy)
  {
    const uint8_t* px = img.ptr<uint8_t>(cy + dy) + (cx + dx) * pixel_bytes;
    samples[n++] = {dx, dy, double(px[ch]) - (ch2 >= 0 ? kappa * px[ch2] : 0.0)};
  };
  for (int dx = -H; dx <= H; ++dx)
  {
    add(dx, -H);
    add(dx, H);
  }
  for (int dy = -H + 1; dy <= H - 1; ++dy)
  {
    add(-H, dy);
    add(H, dy);
  }
  auto fit = [&](const double* keep_limit, const Plane& prev)
  {
    // Normal equations of (1, dx, dy); on the full ring they are diagonal.
    double s11 = 0, s1x = 0, s1y = 0, sxx = 0, sxy = 0, syy = 0, b1 = 0, bx = 0, by = 0;
    for (int i = 0; i < n; ++i)
    {
      const Sample& q = samples[i];
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
  };
  Plane p = fit(nullptr, Plane());
  double res[8 * 24];
  for (int i = 0; i < n; ++i)
    res[i] = std::abs(samples[i].v - p.at(samples[i].dx, samples[i].dy));
  std::nth_element(res, res + n / 2, res + n);
  const double mad = 1.4826 * res[n / 2];
  const double limit = std::max(2.0, 3.0 * mad);
  Plane robust = fit(&limit, p);
  robust.spread = mad;
  return robust;
}

// Iteratively Gaussian-weighted centroid with adaptive sigma (star-tracker
// IWC / adaptive moments): weights w = (v - background) * G(x - c_w; s_w).
// For a Gaussian dot of sigma s, the weighted variance m2 satisfies
// 1/m2 = 1/s^2 + 1/s_w^2, which gives s, and the weighted mean lies a
// fraction s^2 / (s^2 + s_w^2) of the way from c_w to the dot's centre, so
// one step scaled by the inverse fraction lands on it (a few iterations for
// real, pixel-integrated, clipped or noisy dots). The window is set by s, not
// by a threshold, so no pixel enters or leaves it because of noise, and a
// clipped (saturated) core stays symmetric, hence unbiased.
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

// Green-over-red ratio of the rock on the window's border (least squares
// through the origin); 0 when the border is too dark to tell (night).
double rockRatio(const cv::Mat& img, int pixel_bytes, int g_ch, int r_ch, int cx, int cy, int H)
{
  double gr = 0, rr = 0;
  int n = 0;
  auto add = [&](int dx, int dy)
  {
    const uint8_t* px = img.ptr<uint8_t>(cy + dy) + (cx + dx) * pixel_bytes;
    gr += double(px[g_ch]) * px[r_ch];
    rr += double(px[r_ch]) * px[r_ch];
    ++n;
  };
  for (int d = -H; d <= H; ++d)
  {
    add(d, -H);
    add(d, H);
  }
  for (int d = -H + 1; d <= H - 1; ++d)
  {
    add(-H, d);
    add(H, d);
  }
  if (rr < 9.0 * n)  // red below ~3 DN: no sunlit texture to follow
    return 0.0;
  return std::min(1.5, std::max(0.0, gr / rr));
}

// With red_ch >= 0 the weight channel is g - kappa r, kappa the rock's own
// green/red ratio around the dot: the sunlit rock texture under the dot then
// cancels pixel by pixel (it is in red as much as in green), and the dot,
// which barely reaches red, stays. A plane fitted to the window's border can
// only remove a gradient, not texture, which at full sun biases the centroid
// by a tenth of a pixel.
bool refineSpot(const cv::Mat& img, int pixel_bytes, int ch, int red_ch, double x0, double y0, double sigma0,
                int fixed_radius, double max_sigma, Refined* out)
{
  double xc = x0, yc = y0, sw = sigma0;
  const int W = img.cols, Hgt = img.rows;
  constexpr int kMaxRadius = 24;
  constexpr int kMaxStride = 52;  // 2 * kMaxRadius + 1 rounded up to 4 lanes
  // Window values, rows padded with zeros to a multiple of 4 floats.
  alignas(16) float vals[(2 * kMaxRadius + 1) * kMaxStride];
  alignas(16) float wx0[kMaxStride], wx1[kMaxStride], wx2[kMaxStride];
  double gy[2 * kMaxRadius + 1];
  int stride = 0;
  int cx = -1, cy = -1, H = -1;
  double flux = 0, background = 0, major = 0;
  bool converged = false;
  for (int it = 0; it < 12 && !converged; ++it)
  {
    const int ncx = static_cast<int>(std::lround(xc)), ncy = static_cast<int>(std::lround(yc));
    int nH =
        fixed_radius > 0 ? fixed_radius : std::max(3, static_cast<int>(std::ceil(3.0 * std::min(sw, max_sigma))) + 1);
    // Keep the window symmetric about the dot: clip it at the frame edge on
    // both sides rather than on one.
    nH = std::min({nH, kMaxRadius, ncx, ncy, W - 1 - ncx, Hgt - 1 - ncy});
    if (nH < 2)
      return false;
    if (ncx != cx || ncy != cy || nH != H)
    {
      cx = ncx;
      cy = ncy;
      H = nH;
      const double kappa = red_ch >= 0 ? rockRatio(img, pixel_bytes, ch, red_ch, cx, cy, H) : 0.0;
      const Plane bg = borderPlane(img, pixel_bytes, ch, cx, cy, H, red_ch, kappa);
      background = borderMean(img, pixel_bytes, ch, cx, cy, H);
      stride = (2 * H + 1 + 3) & ~3;
      for (int dy = -H; dy <= H; ++dy)
      {
        const uint8_t* row = img.ptr<uint8_t>(cy + dy) + (cx - H) * pixel_bytes;
        float* v = vals + (dy + H) * stride;
        for (int dx = -H; dx <= H; ++dx)
        {
          const uint8_t* px = row + (dx + H) * pixel_bytes;
          const double value = px[ch] - (kappa > 0.0 ? kappa * px[red_ch] : 0.0);
          v[dx + H] = static_cast<float>(value - bg.at(dx, dy));
        }
        for (int k = 2 * H + 1; k < stride; ++k)
          v[k] = 0.0f;
      }
    }
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
    double Sw = 0, Sx = 0, Sy = 0, Sxx = 0, Syy = 0, Sxy = 0;
    for (int dy = -H; dy <= H; ++dy)
    {
      const float* v = vals + (dy + H) * stride;
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
      Sw += rw * g;
      Sx += rx * g;
      Sxx += rxx * g;
      Sy += rw * g * ey;
      Syy += rw * g * ey * ey;
      Sxy += rx * g * ey;
    }
    if (!(Sw > 1e-6))
      return false;
    const double mx = Sx / Sw, my = Sy / Sw;
    const double m2 = 0.5 * ((Sxx / Sw - mx * mx) + (Syy / Sw - my * my));
    if (!(m2 > 0.0))
      return false;
    double s_new;
    if (m2 < 0.9 * sw * sw)
      s_new = std::sqrt(m2 * sw * sw / (sw * sw - m2));
    else
      s_new = 2.0 * sw;  // the weight is much narrower than the dot: widen it
    s_new = std::min(std::max(s_new, 0.3), 1.5 * max_sigma + 1.0);
    // Step to the dot's centre; the gain is bounded because real dots are
    // not exact Gaussians.
    const double gain = std::min(3.0, (s_new * s_new + sw * sw) / (s_new * s_new));
    const double step_x = gain * mx, step_y = gain * my;
    const double step = std::hypot(step_x, step_y), limit = std::max(1.0, sw);
    const double k = step > limit ? limit / step : 1.0;
    xc += k * step_x;
    yc += k * step_y;
    converged = step < 2e-3 && std::abs(s_new - sw) < 2e-2 * sw;
    {
      // Long axis of the dot (a dot on a slope is foreshortened across it):
      // the weighted covariance's larger eigenvalue l, deconvolved from the
      // weight as m2 is.
      const double cxx = Sxx / Sw - mx * mx, cyy = Syy / Sw - my * my, cxy = Sxy / Sw - mx * my;
      const double l = 0.5 * (cxx + cyy) + std::sqrt(0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy);
      major = l < 0.9 * sw * sw ? std::sqrt(l * sw * sw / (sw * sw - l)) : s_new;
      major = std::max(major, s_new);
    }
    sw = s_new;
    flux = Sw;
  }
  if (!std::isfinite(xc) || !std::isfinite(yc) || std::abs(xc - cx) > H || std::abs(yc - cy) > H)
    return false;
  out->x = xc;
  out->y = yc;
  out->sigma = sw;
  out->sigma_major = major;
  out->flux = flux;
  out->background = background;
  out->window = cv::Rect(cx - H, cy - H, 2 * H + 1, 2 * H + 1);
  return true;
}

// Colour of the spot's light. Red: excess over the local background plane
// relative to the green excess (texture-sensitive; slack says how much).
// Blue: measured on texture-free signals, green - kappa_g red and blue -
// kappa_b red (kappa = the rock's own ratios on the border), so sunlit rock
// texture cancels and what remains is the added light's blue/green ratio,
// (led_b - kappa_b led_r) / (1 - kappa_g led_r) for a dot. Gaussian-weighted,
// unclipped pixels only.
void chroma(const cv::Mat& img, const PixelLayout& L, int saturation, double led_red, double led_blue, Refined* r)
{
  const int H = (r->window.width - 1) / 2;
  const int cx = r->window.x + H, cy = r->window.y + H;
  // One pass over the border ring: least-squares planes of r, g, b (on the
  // full square ring 1, dx and dy are orthogonal, so each plane is three
  // sums; a plane of g - k r is the plane of g minus k times that of r) and
  // the rock's g/r and b/r ratios. Plain, not robust: the colour test only
  // needs ratios, and this runs for every candidate.
  double s[3] = {0, 0, 0}, sx[3] = {0, 0, 0}, sy[3] = {0, 0, 0}, sgr = 0, sbr = 0, srr = 0, srr_abs = 0;
  int n = 0;
  auto add = [&](int dx, int dy)
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
  };
  for (int d = -H; d <= H; ++d)
  {
    add(d, -H);
    add(d, H);
  }
  for (int d = -H + 1; d <= H - 1; ++d)
  {
    add(-H, d);
    add(H, d);
  }
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
  const bool sunlit = srr >= 9.0 * n;  // red above ~3 DN: a rock texture to follow
  const double kg = sunlit ? std::min(1.5, std::max(0.0, sgr / srr)) : 0.0;
  const double kb = sunlit ? std::min(1.5, std::max(0.0, sbr / srr)) : 0.0;
  // Spread of red about its plane: how much texture the red ratio carries.
  for (int d = -H; d <= H; ++d)
  {
    for (int e : {-H, H})
    {
      const double a = img.ptr<uint8_t>(cy + e)[(cx + d) * L.step + L.r] - planes[0].at(d, e);
      srr_abs += a * a;
      if (std::abs(d) < H)
      {
        const double b = img.ptr<uint8_t>(cy + d)[(cx + e) * L.step + L.r] - planes[0].at(e, d);
        srr_abs += b * b;
      }
    }
  }
  const Plane& pr = planes[0];
  const Plane& pg = planes[1];
  Plane pd = planes[1], pb = planes[2];
  pd.a -= kg * pr.a;
  pd.bx -= kg * pr.bx;
  pd.by -= kg * pr.by;
  pb.a -= kb * pr.a;
  pb.bx -= kb * pr.bx;
  pb.by -= kb * pr.by;
  const double red_spread = std::sqrt(srr_abs / n);
  const double inv2s2 = 1.0 / (2.0 * r->sigma * r->sigma);
  double gx[64], gy[64];
  for (int d = -H; d <= H && d + H < 64; ++d)
  {
    const double ex = cx + d - r->x, ey = cy + d - r->y;
    gx[d + H] = std::exp(-ex * ex * inv2s2);
    gy[d + H] = std::exp(-ey * ey * inv2s2);
  }
  double er = 0, eg = 0, ed = 0, eb = 0, sum_w = 0;
  for (int dy = -H; dy <= H; ++dy)
  {
    const uint8_t* row = img.ptr<uint8_t>(cy + dy);
    for (int dx = -H; dx <= H; ++dx)
    {
      const uint8_t* px = row + (cx + dx) * L.step;
      if (px[L.r] >= saturation || px[L.g] >= saturation || px[L.b] >= saturation)
        continue;
      const double w = gx[dx + H] * gy[dy + H];
      sum_w += w;
      er += w * (px[L.r] - pr.at(dx, dy));
      eg += w * (px[L.g] - pg.at(dx, dy));
      ed += w * (px[L.g] - kg * px[L.r] - pd.at(dx, dy));
      eb += w * (px[L.b] - kb * px[L.r] - pb.at(dx, dy));
    }
  }
  if (eg > 1e-6 && ed > 1e-6)
  {
    r->red_ratio = er / eg;
    // Rock texture is spatially correlated over the window, so its effect on
    // the weighted sums scales with the sum of the weights, not its root.
    r->red_slack = red_spread * sum_w / eg;
    // Mapped back to the LED's blue/green ratio for comparison.
    const double expected = (led_blue - kb * led_red) / std::max(0.1, 1.0 - kg * led_red);
    r->blue_ratio = eb / ed - expected + led_blue;
  }
  else
  {
    // No green excess over the rock: not light added by the projector.
    r->red_ratio = r->blue_ratio = std::numeric_limits<double>::quiet_NaN();
  }
}

class FastMethod : public SpotDetectionMethod
{
public:
  SpotDetectionResult detect(const cv::Mat& image, PixelFormat format, const SpotDetectorParams& params,
                             SpotDetectorDebug* debug, SpotDetectorTimings* timings) override;

private:
  // A horizontal run of candidate pixels [x0, x1] in row y.
  struct Run
  {
    int y, x0, x1;
  };

  // Scratch reused across frames (no per-frame allocation in the hot path).
  cv::Mat coarse_, coarse_mask_;
  std::vector<uint16_t> column_sums_;
  std::vector<Run> runs_;
  std::vector<int> parent_;
  // Blob splitting: blob of each run, runs grouped by blob, and the discs
  // already explained in each blob.
  std::vector<int> run_blob_, run_start_, run_list_;
  std::vector<std::vector<cv::Vec3d>> explained_;
};

SpotDetectionResult FastMethod::detect(const cv::Mat& image, PixelFormat format, const SpotDetectorParams& params,
                                       SpotDetectorDebug* debug, SpotDetectorTimings* timings)
{
  SpotDetectionResult result;
  const FastParams& p = params.fast;
  StageTimer timer;
  SpotDetectorTimings tm;
  const PixelLayout L = layoutOf(format);
  const bool mono = format == PixelFormat::kMono8;
  const int threshold = mono ? p.mono_threshold : p.detect_threshold;

  runs_.clear();
  const int k256 = static_cast<int>(std::lround(p.red_weight * 256.0));
  const bool red_first = format == PixelFormat::kRgb8 || format == PixelFormat::kRgba8;
  // Coarse pass: 4 x 4 block means of the greenness, accumulated in the same
  // pass (16-bit column sums over 4 rows, then 4 columns summed).
  constexpr int kBin = 4;
  const bool coarse = p.coarse_threshold > 0 && !mono && image.rows >= 2 * kBin && image.cols >= 2 * kBin;
  if (coarse)
  {
    coarse_.create(image.rows / kBin, image.cols / kBin, CV_8UC1);
    column_sums_.assign(static_cast<size_t>(image.cols) + 16, 0);
  }
  for (int y = 0; y < image.rows; ++y)
  {
    const uint8_t* row = image.ptr<uint8_t>(y);
    uint16_t* score_row = coarse && y / kBin < coarse_.rows ? column_sums_.data() : nullptr;
    if (L.step == 1)
      rowRuns<1, false>(row, image.cols, y, threshold, k256, &runs_, score_row);
    else if (L.step == 3)
      red_first ? rowRuns<3, true>(row, image.cols, y, threshold, k256, &runs_, score_row)
                : rowRuns<3, false>(row, image.cols, y, threshold, k256, &runs_, score_row);
    else
      red_first ? rowRuns<4, true>(row, image.cols, y, threshold, k256, &runs_, score_row)
                : rowRuns<4, false>(row, image.cols, y, threshold, k256, &runs_, score_row);
    if (score_row && y % kBin == kBin - 1)
    {
      uint8_t* out = coarse_.ptr<uint8_t>(y / kBin);
      uint16_t* a = column_sums_.data();
      for (int i = 0; i < coarse_.cols; ++i, a += kBin)
        out[i] = static_cast<uint8_t>((a[0] + a[1] + a[2] + a[3] + kBin * kBin / 2) / (kBin * kBin));
      std::fill(column_sums_.begin(), column_sums_.end(), 0);
    }
  }
  tm.threshold_ms = timer.lap();

  // Runs -> 8-connected blobs (union-find over runs of adjacent rows).
  const int n = static_cast<int>(runs_.size());
  parent_.resize(n);
  for (int i = 0; i < n; ++i)
    parent_[i] = i;
  int prev_begin = 0, prev_end = 0;
  for (int i = 0; i < n;)
  {
    const int y = runs_[i].y;
    int row_end = i;
    while (row_end < n && runs_[row_end].y == y)
      ++row_end;
    const bool prev_adjacent = prev_end > prev_begin && runs_[prev_begin].y == y - 1;
    int j = prev_begin;
    for (int k = i; k < row_end && prev_adjacent; ++k)
    {
      while (j < prev_end && runs_[j].x1 < runs_[k].x0 - 1)
        ++j;
      for (int m = j; m < prev_end && runs_[m].x0 <= runs_[k].x1 + 1; ++m)
      {
        const int a = findRoot(parent_, k), b = findRoot(parent_, m);
        if (a != b)
          parent_[std::max(a, b)] = std::min(a, b);
      }
    }
    prev_begin = i;
    prev_end = row_end;
    i = row_end;
  }
  std::vector<int> blob_of(n, -1);
  std::vector<int>& run_blob = run_blob_;
  run_blob.resize(n);
  std::vector<Blob> blobs;
  for (int i = 0; i < n; ++i)
  {
    const int r = findRoot(parent_, i);
    if (blob_of[r] < 0)
    {
      blob_of[r] = static_cast<int>(blobs.size());
      blobs.emplace_back();
    }
    run_blob[i] = blob_of[r];
    Blob& b = blobs[blob_of[r]];
    const Run& run = runs_[i];
    const uint8_t* row = image.ptr<uint8_t>(run.y);
    for (int x = run.x0; x <= run.x1; ++x)
    {
      const int s = mono ? row[x] : greenness(row + x * L.step, L, k256);
      ++b.count;
      b.sum += s;
      b.sx += double(s) * x;
      b.sy += double(s) * run.y;
      if (s > b.peak)
      {
        b.peak = s;
        b.peak_x = x;
        b.peak_y = run.y;
      }
    }
    b.x0 = std::min(b.x0, run.x0);
    b.x1 = std::max(b.x1, run.x1);
    b.y0 = std::min(b.y0, run.y);
    b.y1 = std::max(b.y1, run.y);
  }
  // Candidates: the full-resolution blobs worth refining, then the coarse
  // pass: wide dim dots (sigma 3-4 px on dark rock) whose every pixel stays
  // below detect_threshold still stand out in the 4 x 4 block means of the
  // greenness, where the noise is 4 times lower.
  struct Candidate
  {
    double x, y, sigma0;
    int count;
    int x0, y0, x1, y1;
    int peak_x = -1, peak_y = -1;  // strongest pixel (full-resolution blobs)
    int blob = -1;                 // index in blobs (full-resolution candidates)
    bool seed = false;             // a further local maximum of a blob (see nextSeed)
  };
  std::vector<Candidate> candidates;
  for (size_t k = 0; k < blobs.size(); ++k)
  {
    const Blob& b = blobs[k];
    if (b.count < p.min_pixels || (!mono && b.peak < p.min_peak) || !(b.sum > 0))
      continue;  // noise: not worth a line in the debug output
    // First guess of sigma from the candidate area: a Gaussian exceeds a
    // threshold within ~2 sigma of its centre for typical peak/threshold ratios.
    const double radius = 0.5 * std::max(b.x1 - b.x0 + 1, b.y1 - b.y0 + 1);
    candidates.push_back({b.sx / b.sum, b.sy / b.sum, std::min(std::max(0.5 * radius, 1.0), p.max_sigma_px), b.count,
                          b.x0, b.y0, b.x1, b.y1, b.peak_x, b.peak_y, static_cast<int>(k)});
  }
  if (coarse)
  {
    cv::compare(coarse_, cv::Scalar(p.coarse_threshold), coarse_mask_, cv::CMP_GE);
    // Cells already explained by a full-resolution candidate are skipped.
    for (const Candidate& c : candidates)
    {
      const cv::Rect cells(c.x0 / kBin - 1, c.y0 / kBin - 1, c.x1 / kBin - c.x0 / kBin + 3,
                           c.y1 / kBin - c.y0 / kBin + 3);
      coarse_mask_(cells & cv::Rect(0, 0, coarse_mask_.cols, coarse_mask_.rows)).setTo(0);
    }
    // 8-connected regions of the (nearly empty) coarse mask by flood fill:
    // cheaper than a labelling pass that writes a label per cell.
    const size_t full_res = candidates.size();
    std::vector<cv::Point> stack;
    for (int y = 0; y < coarse_mask_.rows; ++y)
    {
      uint8_t* row = coarse_mask_.ptr<uint8_t>(y);
      for (int x = 0; x < coarse_mask_.cols; ++x)
      {
        if (!row[x])
          continue;
        double sum = 0, sx = 0, sy = 0;
        int area = 0, x0 = x, x1 = x, y0 = y, y1 = y;
        stack.assign(1, cv::Point(x, y));
        row[x] = 0;
        while (!stack.empty())
        {
          const cv::Point q = stack.back();
          stack.pop_back();
          const double w = coarse_.at<uint8_t>(q.y, q.x);
          sum += w;
          sx += w * q.x;
          sy += w * q.y;
          ++area;
          x0 = std::min(x0, q.x);
          x1 = std::max(x1, q.x);
          y0 = std::min(y0, q.y);
          y1 = std::max(y1, q.y);
          for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx)
            {
              const int nx = q.x + dx, ny = q.y + dy;
              if (nx >= 0 && ny >= 0 && nx < coarse_mask_.cols && ny < coarse_mask_.rows &&
                  coarse_mask_.at<uint8_t>(ny, nx))
              {
                coarse_mask_.at<uint8_t>(ny, nx) = 0;
                stack.emplace_back(nx, ny);
              }
            }
        }
        const double cx = (sx / sum + 0.5) * kBin - 0.5, cy = (sy / sum + 0.5) * kBin - 0.5;
        const double extent = kBin * std::max(x1 - x0 + 1, y1 - y0 + 1);
        candidates.push_back({cx, cy, std::min(std::max(0.25 * extent, 1.5), p.max_sigma_px), area * kBin * kBin,
                              (x0 - 1) * kBin, (y0 - 1) * kBin, (x1 + 2) * kBin, (y1 + 2) * kBin, -1, -1, -1});
      }
    }
    if (debug)
      debug->coarse_candidates = static_cast<int>(candidates.size() - full_res);
  }
  tm.labelling_ms = timer.lap();

  // Refinement and rejection of each blob.
  std::vector<Refined> kept;
  auto reject = [&](double x, double y, const std::string& why)
  {
    if (debug)
      debug->rejected.push_back({x, y, why});
  };
  // A blob can hold several dots: sunlit rock whose green/red ratio is above
  // red_weight bridges neighbours (at full sun on bright rock the greenness
  // between two dots 35 px apart stays above detect_threshold). Each dot
  // refined in a blob explains a disc of 3 sigma; a blob larger than what it
  // explains is searched for the strongest local maximum of the greenness
  // outside the discs, which becomes a candidate of its own.
  // Runs of each blob (counting sort by blob) and the discs explained so
  // far, in scratch kept across frames.
  std::vector<int>& run_start = run_start_;
  std::vector<int>& run_list = run_list_;
  std::vector<std::vector<cv::Vec3d>>& explained = explained_;  // per blob: x, y, radius
  const bool split = !mono;
  if (split)
  {
    run_start.assign(blobs.size() + 2, 0);
    for (int i = 0; i < n; ++i)
      ++run_start[run_blob[i] + 2];
    for (size_t k = 1; k <= blobs.size(); ++k)
      run_start[k + 1] += run_start[k];
    run_list.resize(n);
    for (int i = 0; i < n; ++i)
      run_list[run_start[run_blob[i] + 1]++] = i;  // run_start[k] ends as blob k's first run
    if (explained.size() < blobs.size())
      explained.resize(blobs.size());
    for (size_t k = 0; k < blobs.size(); ++k)
      explained[k].clear();
  }
  auto greennessAt = [&](int x, int y)
  {
    return x < 0 || y < 0 || x >= image.cols || y >= image.rows
               ? -1
               : greenness(image.ptr<uint8_t>(y) + x * L.step, L, k256);
  };
  // The next seed of blob k (false when none), after a dot refined at (x, y)
  // with sigma s.
  auto nextSeed = [&](const Candidate& c, double x, double y, double s, Candidate* seed)
  {
    std::vector<cv::Vec3d>& disc = explained[c.blob];
    disc.emplace_back(x, y, std::max(3.0 * s, 4.0) + 1.0);
    const Blob& b = blobs[c.blob];
    // Small blobs are one dot (a cheap early out for nearly every blob).
    if (std::max(b.x1 - b.x0, b.y1 - b.y0) + 1 <= 2 * disc.back()[2] || disc.size() > 8)
      return false;
    // A dot stands out of the blob around it: the median greenness on a ring
    // of 2 sigma (the frame's dots share a size) is at most half its peak.
    // Noise maxima on a bright rock bridge and points on a dot's flank do not
    // (a flank has the dot on one side of its ring); each would cost a
    // refinement that leads nowhere or back to a dot already found.
    const int R = std::max(2, static_cast<int>(std::lround(2.0 * s)));
    const int Rd = static_cast<int>(std::lround(R * M_SQRT1_2));
    const int ring_dx[8] = {R, -R, 0, 0, Rd, Rd, -Rd, -Rd}, ring_dy[8] = {0, 0, R, -R, Rd, -Rd, Rd, -Rd};
    auto prominent = [&](int x, int y, int g)
    {
      int v[8];
      for (int k = 0; k < 8; ++k)
        v[k] = std::max(0, greennessAt(x + ring_dx[k], y + ring_dy[k]));
      std::sort(v, v + 8);
      return 2 * g - (v[3] + v[4]) >= 2 * std::max(p.min_peak, g / 2);
    };
    int best = p.min_peak - 1, bx = -1, by = -1;
    for (int ri = run_start[c.blob]; ri < run_start[c.blob + 1]; ++ri)
    {
      const Run& run = runs_[run_list[ri]];
      for (int px = run.x0; px <= run.x1; ++px)
      {
        bool inside = false;
        for (const cv::Vec3d& d : disc)
          inside = inside || (px - d[0]) * (px - d[0]) + (run.y - d[1]) * (run.y - d[1]) < d[2] * d[2];
        if (inside)
          continue;
        const int g = greennessAt(px, run.y);
        if (g <= best)
          continue;
        bool local_max = true;
        for (int dy = -1; dy <= 1 && local_max; ++dy)
          for (int dx = -1; dx <= 1 && local_max; ++dx)
            local_max = (dx == 0 && dy == 0) || greennessAt(px + dx, run.y + dy) <= g;
        if (local_max && prominent(px, run.y, g))
        {
          best = g;
          bx = px;
          by = run.y;
        }
      }
    }
    if (bx < 0)
      return false;
    *seed = c;
    seed->x = bx;
    seed->y = by;
    seed->sigma0 = std::min(std::max(s, 1.0), p.max_sigma_px);
    seed->peak_x = bx;
    seed->peak_y = by;
    seed->seed = true;
    return true;
  };
  for (size_t ci = 0; ci < candidates.size(); ++ci)
  {
    const Candidate b = candidates[ci];  // a copy: new seeds grow the vector
    const double bx = b.x, by = b.y, sigma0 = b.sigma0;
    Refined r;
    const int red_ch = mono || !p.subtract_rock_texture ? -1 : L.r;
    bool ok = refineSpot(image, L.step, L.g, red_ch, bx, by, sigma0, p.window_radius_px, p.max_sigma_px, &r);
    if ((!ok || r.sigma > p.max_sigma_px) && b.peak_x >= 0 && p.window_radius_px == 0)
    {
      // A dot on a green-ish pedestal (an olive mineral, a neighbour's
      // flank) grows the adaptive window over the pedestal: retry from the
      // strongest pixel in a small fixed window, whose border then lies on
      // the pedestal and subtracts it.
      Refined retry;
      // Only a real peak on the pedestal counts (amplitude of a Gaussian from
      // its self-weighted sum: A = sum / (pi sigma^2)).
      if (refineSpot(image, L.step, L.g, red_ch, b.peak_x, b.peak_y, 1.5, 5, p.max_sigma_px, &retry) &&
          retry.flux / (M_PI * retry.sigma * retry.sigma) >= p.min_peak)
      {
        r = retry;
        r.on_pedestal = true;
        ok = true;
      }
    }
    if (split && b.blob >= 0)
    {
      // A seed on a dot's pedestal (a mineral, a bright rock bridge) can
      // climb to a dot of its blob already refined: that one stands.
      bool again = false;
      for (const cv::Vec3d& d : explained[b.blob])
        again = again || (b.seed && ok && std::hypot(r.x - d[0], r.y - d[1]) < d[2]);
      // A fit out of the sigma range explains no more than its seed pixel.
      const bool fits = ok && !again && r.sigma >= p.min_sigma_px && r.sigma <= p.max_sigma_px;
      const int px = b.peak_x >= 0 ? b.peak_x : static_cast<int>(std::lround(bx));
      const int py = b.peak_y >= 0 ? b.peak_y : static_cast<int>(std::lround(by));
      Candidate seed;
      if (fits ? nextSeed(b, r.x, r.y, r.sigma, &seed) : nextSeed(b, px, py, 1.5, &seed))
        candidates.push_back(seed);
      if (again)
        continue;
    }
    if (!ok)
    {
      reject(bx, by, "refinement failed (no signal or at the border)");
      continue;
    }
    if (r.sigma < p.min_sigma_px || r.sigma > p.max_sigma_px)
    {
      reject(r.x, r.y, "sigma " + std::to_string(r.sigma) + " px out of range");
      continue;
    }
    // A clipped core carries no colour, and its unclipped flanks too little
    // excess to judge by: the green ring that made the blob vouches for it.
    const uint8_t* core =
        image.ptr<uint8_t>(static_cast<int>(std::lround(r.y))) + static_cast<int>(std::lround(r.x)) * L.step;
    const bool clipped =
        core[L.r] >= p.saturation_level || core[L.g] >= p.saturation_level || core[L.b] >= p.saturation_level;
    // The fit's weight channel clipped (red alone clips on bright sunlit rock
    // and leaves the dot's shape intact).
    r.clipped = core[L.g] >= p.saturation_level;
    if (!mono && !clipped)
    {
      chroma(image, L, p.saturation_level, p.colour_test.led_red_ratio, p.colour_test.led_blue_ratio, &r);
      // The red test sees the rock texture as much as the spot: off by default.
      // Red above the LED's: olive and yellow minerals (R = G) carry their own
      // red; the slack covers what rock texture alone can add.
      bool red_bad = p.colour_test.max_red_excess > 0 &&
                     r.red_ratio > p.colour_test.led_red_ratio + p.colour_test.max_red_excess + r.red_slack;
      red_bad = red_bad || (p.colour_test.max_red_deficit > 0 &&
                            r.red_ratio < p.colour_test.led_red_ratio - p.colour_test.max_red_deficit - r.red_slack);
      // A spot on a pedestal is suspect: the pedestal is often an olive or
      // yellow mineral, whose own red shows up as extra red excess.
      red_bad = red_bad ||
                (r.on_pedestal && std::abs(r.red_ratio - p.colour_test.led_red_ratio) > p.colour_test.max_chroma_error);
      if (!std::isfinite(r.blue_ratio) || red_bad ||
          std::abs(r.blue_ratio - p.colour_test.led_blue_ratio) > p.colour_test.max_chroma_error)
      {
        reject(r.x, r.y,
               "colour: red/green " + std::to_string(r.red_ratio) + ", blue/green " + std::to_string(r.blue_ratio));
        continue;
      }
    }
    // The centroid must stay on its blob: a refinement that wandered off to a
    // neighbour is not this blob's dot.
    if (r.x < b.x0 - 2 || r.x > b.x1 + 2 || r.y < b.y0 - 2 || r.y > b.y1 + 2)
    {
      reject(r.x, r.y, "refinement left its blob");
      continue;
    }
    kept.push_back(r);
    result.spots.push_back(Spot());
    Spot& s = result.spots.back();
    s.x = r.x;
    s.y = r.y;
    s.area = static_cast<float>(b.count);
    s.intensity = static_cast<float>(r.flux);
  }

  // A dot whose saturated core splits its candidate ring into pieces gives
  // several blobs that refine to the same centre: keep the strongest.
  std::vector<size_t> order(kept.size());
  for (size_t i = 0; i < order.size(); ++i)
    order[i] = i;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return kept[a].flux > kept[b].flux; });
  std::vector<char> drop(kept.size(), 0);
  for (size_t i = 0; i < order.size(); ++i)
  {
    if (drop[order[i]])
      continue;
    const Refined& a = kept[order[i]];
    for (size_t j = i + 1; j < order.size(); ++j)
    {
      const Refined& b = kept[order[j]];
      const double lim = std::max(2.0, 1.5 * std::max(a.sigma, b.sigma));
      if (std::hypot(a.x - b.x, a.y - b.y) < lim)
        drop[order[j]] = 1;
    }
  }
  // Frame-level consistency (see the params): outliers from the frame's
  // median size and energy are clutter. Amplitude of a Gaussian from its
  // self-weighted sum: sum = A pi sigma^2.
  std::vector<size_t> alive;
  for (size_t i = 0; i < kept.size(); ++i)
    if (!drop[i])
      alive.push_back(i);
  if (static_cast<int>(alive.size()) >= std::max(1, p.frame_checks.consistency_min_spots))
  {
    // The +4 DN keeps both finite at night (no background) without letting
    // noise in the background decide.
    auto contrast = [](const Refined& r)
    {
      const double amp = r.flux / (M_PI * r.sigma * r.sigma);
      return amp / (std::max(0.0, r.background) + 4.0);
    };
    auto energy = [](const Refined& r) { return r.flux / (std::max(0.0, r.background) + 4.0); };
    // A clipped core widens the fitted sigma and shortens the flux: the
    // medians come from unclipped spots when there are enough of them, and
    // clipped spots skip the size and energy tests.
    int unclipped = 0;
    for (size_t i : alive)
      unclipped += kept[i].clipped ? 0 : 1;
    const bool skip_clipped = unclipped >= 3;
    std::vector<double> sig, con, ene;
    for (size_t i : alive)
    {
      if (skip_clipped && kept[i].clipped)
        continue;
      sig.push_back(kept[i].sigma);
      con.push_back(contrast(kept[i]));
      ene.push_back(energy(kept[i]));
    }
    auto median = [](std::vector<double>& v)
    {
      std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
      return v[v.size() / 2];
    };
    const double sig_med = median(sig), con_med = median(con), ene_med = std::max(1e-9, median(ene));
    for (size_t i : alive)
    {
      const Refined& r = kept[i];
      const bool shape_known = !(skip_clipped && r.clipped);
      const double sr = r.sigma / sig_med, er = energy(r) / ene_med;
      // A dot on a slope is foreshortened across the slope only: below the
      // sigma floor, a spot whose long axis keeps the frame's size (at least
      // halfway from the floor to the median) is such a dot; a speck is
      // small both ways (measured: foreshortened dots 0.96-0.97, the
      // closest speck 0.92 of the median, with a mean sigma of 0.88-0.90).
      const bool foreshortened = r.sigma_major / sig_med >= 0.5 * (1.0 + p.frame_checks.min_sigma_fraction);
      const bool too_small =
          p.frame_checks.min_sigma_fraction > 0 && sr < p.frame_checks.min_sigma_fraction && !foreshortened;
      const bool off_size = (p.frame_checks.size_band_low > 0 && sr < p.frame_checks.size_band_low) ||
                            (p.frame_checks.size_band_high > 0 && sr > p.frame_checks.size_band_high);
      const bool off_energy = (p.frame_checks.energy_band_low > 0 && er < p.frame_checks.energy_band_low) ||
                              (p.frame_checks.energy_band_high > 0 && er > p.frame_checks.energy_band_high);
      std::string why;
      if (shape_known && (too_small || (p.frame_checks.max_sigma_factor > 0 && sr > p.frame_checks.max_sigma_factor)))
        why = "sigma " + std::to_string(r.sigma) + " px far from the frame's median " + std::to_string(sig_med);
      else if (p.frame_checks.max_contrast_factor > 0 && contrast(r) > p.frame_checks.max_contrast_factor * con_med)
        why = "contrast " + std::to_string(contrast(r)) + " above " +
              std::to_string(p.frame_checks.max_contrast_factor) + " x the frame's median " + std::to_string(con_med);
      else if (shape_known && p.frame_checks.min_energy_fraction > 0 && er < p.frame_checks.min_energy_fraction)
        why = "energy " + std::to_string(er) + " x the frame's median: not lit by the projector";
      else if (shape_known && off_size && off_energy)
        why = "both size (" + std::to_string(sr) + ") and energy (" + std::to_string(er) + ") off the frame's medians";
      if (!why.empty())
      {
        drop[i] = 1;
        reject(r.x, r.y, why);
      }
    }
  }
  Spots spots;
  std::vector<Refined> refined;
  for (size_t i = 0; i < kept.size(); ++i)
  {
    if (drop[i])
      continue;
    spots.push_back(result.spots[i]);
    refined.push_back(kept[i]);
  }
  tm.refine_ms = timer.lap();

  // Row-major order for readability; beams are the Triangulator's business.
  sortIntoRows(&spots, params.projector_cols, params.projector_rows, false);
  if (debug)
  {
    // Per-spot debug data in the order of the sorted spots.
    debug->candidates = static_cast<int>(candidates.size());
    for (const Spot& s : spots)
    {
      for (const Refined& r : refined)
      {
        if (r.x == s.x && r.y == s.y)
        {
          debug->windows.push_back(r.window);
          debug->sigmas_px.push_back(r.sigma);
          debug->chroma.emplace_back(r.red_ratio, r.blue_ratio);
          break;
        }
      }
    }
  }
  result.spots = std::move(spots);
  if (timings)
    *timings = tm;
  result.ok = true;
  return result;
}

}  // namespace

std::unique_ptr<SpotDetectionMethod> makeFastMethod()
{
  return std::make_unique<FastMethod>();
}

}  // namespace structured_light_stabilizer
