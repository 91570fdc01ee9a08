// SpotDetector: the study's baseline chain and the fast detector. See the
// contract in spot_detector.h.
#include "structured_light_stabilizer/spot_detector.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>

#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>

namespace structured_light_stabilizer
{

namespace
{
using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point& t)
{
  const Clock::time_point now = Clock::now();
  const double ms = std::chrono::duration<double, std::milli>(now - t).count();
  t = now;
  return ms;
}

// Channel layout of a colour format: byte offsets of r, g, b and pixel size.
struct Layout
{
  int r, g, b, step;
};

Layout layoutOf(PixelFormat f)
{
  switch (f)
  {
    case PixelFormat::kBgr8:
      return {2, 1, 0, 3};
    case PixelFormat::kRgb8:
      return {0, 1, 2, 3};
    case PixelFormat::kBgra8:
      return {2, 1, 0, 4};
    case PixelFormat::kRgba8:
      return {0, 1, 2, 4};
    case PixelFormat::kMono8:
      return {0, 0, 0, 1};
  }
  return {0, 0, 0, 1};
}

std::string checkImage(const cv::Mat& image, PixelFormat format)
{
  if (image.empty() || image.rows <= 0 || image.cols <= 0)
    return "empty image";
  if (image.depth() != CV_8U)
    return "image depth is not 8-bit unsigned (type " + std::to_string(image.type()) + ")";
  if (image.channels() != channelCount(format))
    return "image has " + std::to_string(image.channels()) + " channels, the stated encoding needs " +
           std::to_string(channelCount(format));
  if (image.dims != 2)
    return "image is not two-dimensional";
  return std::string();
}

void clampInt(int* v, int lo, int hi, const char* name, std::vector<std::string>* changes)
{
  const int c = std::min(std::max(*v, lo), hi);
  if (c != *v)
  {
    std::ostringstream s;
    s << name << " " << *v << " out of [" << lo << ", " << hi << "], clamped to " << c;
    changes->push_back(s.str());
    *v = c;
  }
}

void clampDouble(double* v, double lo, double hi, const char* name, std::vector<std::string>* changes)
{
  const double c = std::isfinite(*v) ? std::min(std::max(*v, lo), hi) : lo;
  if (c != *v)
  {
    std::ostringstream s;
    s << name << " " << *v << " out of [" << lo << ", " << hi << "], clamped to " << c;
    changes->push_back(s.str());
    *v = c;
  }
}

template <typename T>
void orderPair(T* lo, T* hi, const char* lo_name, const char* hi_name, std::vector<std::string>* changes)
{
  if (*lo > *hi)
  {
    std::ostringstream s;
    s << lo_name << " " << *lo << " > " << hi_name << " " << *hi << ", swapped";
    changes->push_back(s.str());
    std::swap(*lo, *hi);
  }
}
}  // namespace

bool pixelFormatFromEncoding(const std::string& encoding, PixelFormat* format)
{
  if (encoding == "bgr8")
    *format = PixelFormat::kBgr8;
  else if (encoding == "rgb8")
    *format = PixelFormat::kRgb8;
  else if (encoding == "bgra8")
    *format = PixelFormat::kBgra8;
  else if (encoding == "rgba8")
    *format = PixelFormat::kRgba8;
  else if (encoding == "mono8" || encoding == "8UC1")
    *format = PixelFormat::kMono8;
  else
    return false;
  return true;
}

int channelCount(PixelFormat format)
{
  return layoutOf(format).step;
}

// ---------------------------------------------------------------------------
// Params

std::vector<std::string> SpotDetectorParams::sanitize()
{
  std::vector<std::string> changes;
  clampInt(&blur_kernel, 1, 31, "blur_kernel", &changes);
  if (blur_kernel % 2 == 0)
  {
    changes.push_back("blur_kernel " + std::to_string(blur_kernel) + " is even, using " +
                      std::to_string(blur_kernel + 1));
    ++blur_kernel;
  }
  clampInt(&h_min, 0, 179, "h_min", &changes);
  clampInt(&h_max, 0, 179, "h_max", &changes);
  clampInt(&s_min, 0, 255, "s_min", &changes);
  clampInt(&s_max, 0, 255, "s_max", &changes);
  clampInt(&v_min, 0, 255, "v_min", &changes);
  clampInt(&v_max, 0, 255, "v_max", &changes);
  orderPair(&h_min, &h_max, "h_min", "h_max", &changes);
  orderPair(&s_min, &s_max, "s_min", "s_max", &changes);
  orderPair(&v_min, &v_max, "v_min", "v_max", &changes);
  clampInt(&erosions, 0, 20, "erosions", &changes);
  clampInt(&dilations, 0, 20, "dilations", &changes);
  clampInt(&min_area, 0, 1000000, "min_area", &changes);
  clampInt(&max_area, 0, 1000000, "max_area", &changes);
  if (max_area > 0 && min_area > max_area)
    orderPair(&min_area, &max_area, "min_area", "max_area", &changes);
  clampInt(&projector_rows, 1, 1000, "projector_rows", &changes);
  clampInt(&projector_cols, 1, 1000, "projector_cols", &changes);
  clampInt(&detect_threshold, 1, 255, "detect_threshold", &changes);
  clampInt(&min_peak, 1, 255, "min_peak", &changes);
  clampInt(&mono_threshold, 1, 255, "mono_threshold", &changes);
  clampInt(&min_pixels, 1, 10000, "min_pixels", &changes);
  clampInt(&window_radius_px, 0, 24, "window_radius_px", &changes);
  clampDouble(&min_sigma_px, 0.0, 20.0, "min_sigma_px", &changes);
  clampDouble(&max_sigma_px, 0.3, 20.0, "max_sigma_px", &changes);
  orderPair(&min_sigma_px, &max_sigma_px, "min_sigma_px", "max_sigma_px", &changes);
  clampDouble(&max_red_deficit, 0.0, 100.0, "max_red_deficit", &changes);
  clampDouble(&max_chroma_ratio, 0.0, 100.0, "max_chroma_ratio", &changes);
  clampInt(&saturation_level, 1, 255, "saturation_level", &changes);
  return changes;
}

std::string SpotDetectorParams::validate() const
{
  SpotDetectorParams copy = *this;
  const std::vector<std::string> changes = copy.sanitize();
  return changes.empty() ? std::string() : changes.front();
}

// ---------------------------------------------------------------------------

SpotDetector::SpotDetector(const SpotDetectorParams& params)
{
  setParams(params);
}

std::vector<std::string> SpotDetector::setParams(const SpotDetectorParams& params)
{
  params_ = params;
  return params_.sanitize();
}

SpotDetectionResult SpotDetector::detect(const cv::Mat& image, PixelFormat format, SpotDetectorDebug* debug,
                                         SpotDetectorTimings* timings)
{
  if (debug)
    *debug = SpotDetectorDebug();
  if (timings)
    *timings = SpotDetectorTimings();
  SpotDetectionResult result;
  result.error = checkImage(image, format);
  if (!result.error.empty())
    return result;
  const Clock::time_point start = Clock::now();
  result = params_.method == SpotMethod::kBaseline ? detectBaseline(image, format, debug, timings)
                                                   : detectFast(image, format, debug, timings);
  if (timings)
    timings->total_ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  return result;
}

// ---------------------------------------------------------------------------
// Baseline: the study's chain, stage by stage, with OpenCV calls as it did.

SpotDetectionResult SpotDetector::detectBaseline(const cv::Mat& image, PixelFormat format, SpotDetectorDebug* debug,
                                                 SpotDetectorTimings* timings)
{
  SpotDetectionResult result;
  const SpotDetectorParams& p = params_;
  Clock::time_point t = Clock::now();
  SpotDetectorTimings tm;

  // Low-pass filter; kernel 1 "does nothing" (study §2.4.1).
  const cv::Mat* src = &image;
  if (p.blur_kernel > 1)
  {
    cv::blur(image, blurred_, cv::Size(p.blur_kernel, p.blur_kernel));
    src = &blurred_;
  }
  tm.blur_ms = msSince(t);

  const bool mono = format == PixelFormat::kMono8;
  int weight_channel = 0;
  if (mono)
  {
    // Intensity only: the mask is the V window, the weight is V.
    cv::inRange(*src, cv::Scalar(p.v_min), cv::Scalar(p.v_max), mask_);
    hsv_ = *src;
    tm.in_range_ms = msSince(t);
  }
  else
  {
    const bool rgb_order = format == PixelFormat::kRgb8 || format == PixelFormat::kRgba8;
    cv::cvtColor(*src, hsv_, rgb_order ? cv::COLOR_RGB2HSV : cv::COLOR_BGR2HSV);
    tm.hsv_ms = msSince(t);
    cv::inRange(hsv_, cv::Scalar(p.h_min, p.s_min, p.v_min), cv::Scalar(p.h_max, p.s_max, p.v_max), mask_);
    tm.in_range_ms = msSince(t);
    weight_channel = p.baseline_weight == BaselineWeight::kSaturation ? 1 : 2;
  }

  // N erosions then N dilations with a 3x3 rectangle.
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3));
  if (p.erosions > 0)
    cv::erode(mask_, mask_, kernel, cv::Point(-1, -1), p.erosions);
  if (p.dilations > 0)
    cv::dilate(mask_, mask_, kernel, cv::Point(-1, -1), p.dilations);
  tm.opening_ms = msSince(t);

  // The study's recursive flood fill visits left/right/up/down: 4-connectivity.
  const int n = cv::connectedComponentsWithStats(mask_, labels_, stats_, centroids_, 4, CV_32S);
  tm.labelling_ms = msSince(t);

  // Formulas 2.31-2.32 with I = S (or V), over each region's pixels.
  std::vector<double> sw(n, 0.0), sx(n, 0.0), sy(n, 0.0);
  const int channels = hsv_.channels();
  for (int y = 0; y < labels_.rows; ++y)
  {
    const int* lab = labels_.ptr<int>(y);
    const uint8_t* w = hsv_.ptr<uint8_t>(y);
    for (int x = 0; x < labels_.cols; ++x)
    {
      const int l = lab[x];
      if (l == 0)
        continue;
      const double v = w[x * channels + weight_channel];
      sw[l] += v;
      sx[l] += v * x;
      sy[l] += v * y;
    }
  }
  for (int l = 1; l < n; ++l)
  {
    const int area = stats_.at<int>(l, cv::CC_STAT_AREA);
    if (area < p.min_area || (p.max_area > 0 && area > p.max_area))
      continue;
    Spot s;
    if (sw[l] > 0.0)
    {
      s.x = sx[l] / sw[l];
      s.y = sy[l] / sw[l];
    }
    else
    {
      // All weights zero (e.g. s_min = 0 on grey pixels): the plain centroid
      // instead of a division by zero.
      s.x = centroids_.at<double>(l, 0);
      s.y = centroids_.at<double>(l, 1);
    }
    s.area = static_cast<float>(area);
    s.intensity = static_cast<float>(sw[l]);
    result.spots.push_back(s);
  }
  tm.centroids_ms = msSince(t);

  sortIntoRows(&result.spots, p.projector_cols, p.projector_rows, true);
  tm.sort_ms = msSince(t);

  if (debug)
  {
    debug->mask = mask_.clone();
    debug->candidates = n - 1;
  }
  if (timings)
    *timings = tm;
  result.ok = true;
  return result;
}

void sortIntoRows(Spots* spots, int cols, int rows, bool assign_beams)
{
  if (!spots || cols <= 0)
    return;
  Spots remaining = *spots;
  // Top first: the study takes "the ten centroids ... the most close to the top".
  std::stable_sort(remaining.begin(), remaining.end(), [](const Spot& a, const Spot& b) { return a.y < b.y; });
  Spots sorted;
  sorted.reserve(remaining.size());
  for (size_t i = 0; i < remaining.size(); i += cols)
  {
    const size_t end = std::min(remaining.size(), i + static_cast<size_t>(cols));
    std::stable_sort(remaining.begin() + i, remaining.begin() + end,
                     [](const Spot& a, const Spot& b) { return a.x < b.x; });
    sorted.insert(sorted.end(), remaining.begin() + i, remaining.begin() + end);
  }
  if (assign_beams)
  {
    const size_t beams = static_cast<size_t>(std::max(rows, 0)) * static_cast<size_t>(cols);
    for (size_t k = 0; k < sorted.size(); ++k)
      sorted[k].beam = k < beams ? static_cast<int>(k) : -1;
  }
  *spots = std::move(sorted);
}

// ---------------------------------------------------------------------------
// Fast detector.

namespace
{
// Greenness of one pixel: g - max(r, b), floored at 0. Reddish rock scores 0
// whatever its albedo; the dot's 520 nm light raises g alone. r and b sit at
// byte offsets 0 and 2 in every colour layout accepted, so one formula fits all.
inline int greenness(const uint8_t* px)
{
  return std::max(0, int(px[1]) - std::max(int(px[0]), int(px[2])));
}

template <int kChannels>
inline int score(const uint8_t* px)
{
  return kChannels == 1 ? int(px[0]) : greenness(px);
}

template <typename RunT>
inline void markPixel(std::vector<RunT>* runs, int y, int x)
{
  if (!runs->empty() && runs->back().y == y && runs->back().x1 == x - 1)
    runs->back().x1 = x;
  else
    runs->push_back({y, x, x});
}

// Candidate pixels (score >= threshold) of one row, appended as runs. One
// pass over the row, 16 pixels at a time when SIMD is available: a block
// without a candidate costs a deinterleaving load, a max, a saturating
// subtraction and one test, which keeps the whole frame at the memory
// bandwidth limit.
template <int kChannels, typename RunT>
void rowRuns(const uint8_t* row, int width, int y, int threshold, std::vector<RunT>* runs)
{
  int x = 0;
#if CV_SIMD128
  const cv::v_uint8x16 vthr = cv::v_setall_u8(static_cast<uint8_t>(threshold));
  alignas(16) uint8_t hit[16];
  for (; x + 16 <= width; x += 16)
  {
    cv::v_uint8x16 s;
    if (kChannels == 1)
    {
      s = cv::v_load(row + x);
    }
    else if (kChannels == 3)
    {
      cv::v_uint8x16 c0, c1, c2;
      cv::v_load_deinterleave(row + 3 * x, c0, c1, c2);
      s = c1 - cv::v_max(c0, c2);  // saturating
    }
    else
    {
      cv::v_uint8x16 c0, c1, c2, c3;
      cv::v_load_deinterleave(row + 4 * x, c0, c1, c2, c3);
      s = c1 - cv::v_max(c0, c2);
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
  for (; x < width; ++x)
    if (score<kChannels>(row + kChannels * x) >= threshold)
      markPixel(runs, y, x);
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
  int peak = 0;
  int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1;
};

struct Refined
{
  double x = 0, y = 0, sigma = 0, flux = 0;
  double red_ratio = 0, blue_ratio = 0;  // excess over background relative to green's
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
  double at(int dx, int dy) const { return a + bx * dx + by * dy; }
};

Plane borderPlane(const cv::Mat& img, int pixel_bytes, int ch, int cx, int cy, int H)
{
  struct Sample
  {
    int dx, dy;
    double v;
  };
  Sample samples[8 * 24];
  int n = 0;
  auto add = [&](int dx, int dy) {
    samples[n++] = {dx, dy, double(img.ptr<uint8_t>(cy + dy)[(cx + dx) * pixel_bytes + ch])};
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
  auto fit = [&](const double* keep_limit, const Plane& prev) {
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
    const cv::Matx33d A(s11, s1x, s1y, s1x, sxx, sxy, s1y, sxy, syy);
    cv::Vec3d x;
    Plane p = prev;
    if (s11 >= 6 && cv::solve(A, cv::Vec3d(b1, bx, by), x, cv::DECOMP_CHOLESKY))
    {
      p.a = x[0];
      p.bx = x[1];
      p.by = x[2];
    }
    return p;
  };
  Plane p = fit(nullptr, Plane());
  double res[8 * 24];
  for (int i = 0; i < n; ++i)
    res[i] = std::abs(samples[i].v - p.at(samples[i].dx, samples[i].dy));
  std::nth_element(res, res + n / 2, res + n);
  const double limit = std::max(2.0, 3.0 * 1.4826 * res[n / 2]);
  return fit(&limit, p);
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
bool refineSpot(const cv::Mat& img, int pixel_bytes, int ch, double x0, double y0, double sigma0, int fixed_radius,
                double max_sigma, Refined* out)
{
  double xc = x0, yc = y0, sw = sigma0;
  const int W = img.cols, Hgt = img.rows;
  constexpr int kMaxRadius = 24;
  float vals[(2 * kMaxRadius + 1) * (2 * kMaxRadius + 1)];
  double gx[2 * kMaxRadius + 1], gy[2 * kMaxRadius + 1];
  int cx = -1, cy = -1, H = -1;
  double flux = 0;
  bool converged = false;
  for (int it = 0; it < 12 && !converged; ++it)
  {
    const int ncx = static_cast<int>(std::lround(xc)), ncy = static_cast<int>(std::lround(yc));
    int nH = fixed_radius > 0 ? fixed_radius
                              : std::max(3, static_cast<int>(std::ceil(3.0 * std::min(sw, max_sigma))) + 1);
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
      const Plane bg = borderPlane(img, pixel_bytes, ch, cx, cy, H);
      float* v = vals;
      for (int dy = -H; dy <= H; ++dy)
      {
        const uint8_t* row = img.ptr<uint8_t>(cy + dy) + (cx - H) * pixel_bytes + ch;
        for (int dx = -H; dx <= H; ++dx)
          *v++ = static_cast<float>(row[(dx + H) * pixel_bytes] - bg.at(dx, dy));
      }
    }
    const double inv2s2 = 1.0 / (2.0 * sw * sw);
    for (int d = -H; d <= H; ++d)
    {
      const double ex = cx + d - xc, ey = cy + d - yc;
      gx[d + H] = std::exp(-ex * ex * inv2s2);
      gy[d + H] = std::exp(-ey * ey * inv2s2);
    }
    double Sw = 0, Sx = 0, Sy = 0, Sxx = 0, Syy = 0;
    const float* v = vals;
    for (int dy = -H; dy <= H; ++dy)
    {
      double rw = 0, rx = 0, rxx = 0;
      for (int dx = -H; dx <= H; ++dx)
      {
        const double d = *v++ * gx[dx + H];
        const double ex = cx + dx - xc;
        rw += d;
        rx += d * ex;
        rxx += d * ex * ex;
      }
      const double g = gy[dy + H], ey = cy + dy - yc;
      Sw += rw * g;
      Sx += rx * g;
      Sxx += rxx * g;
      Sy += rw * g * ey;
      Syy += rw * g * ey * ey;
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
    converged = step < 1e-3 && std::abs(s_new - sw) < 1e-2 * sw;
    sw = s_new;
    flux = Sw;
  }
  if (!std::isfinite(xc) || !std::isfinite(yc) || std::abs(xc - cx) > H || std::abs(yc - cy) > H)
    return false;
  out->x = xc;
  out->y = yc;
  out->sigma = sw;
  out->flux = flux;
  out->window = cv::Rect(cx - H, cy - H, 2 * H + 1, 2 * H + 1);
  return true;
}

// Red and blue excess of the spot over the local background, relative to the
// green excess, Gaussian-weighted, over unclipped pixels only.
void chroma(const cv::Mat& img, const Layout& L, int saturation, Refined* r)
{
  const int H = (r->window.width - 1) / 2;
  const int cx = r->window.x + H, cy = r->window.y + H;
  const Plane pr = borderPlane(img, L.step, L.r, cx, cy, H);
  const Plane pg = borderPlane(img, L.step, L.g, cx, cy, H);
  const Plane pb = borderPlane(img, L.step, L.b, cx, cy, H);
  const double inv2s2 = 1.0 / (2.0 * r->sigma * r->sigma);
  double gx[64], gy[64];
  for (int d = -H; d <= H && d + H < 64; ++d)
  {
    const double ex = cx + d - r->x, ey = cy + d - r->y;
    gx[d + H] = std::exp(-ex * ex * inv2s2);
    gy[d + H] = std::exp(-ey * ey * inv2s2);
  }
  double er = 0, eg = 0, eb = 0;
  for (int dy = -H; dy <= H; ++dy)
  {
    const uint8_t* row = img.ptr<uint8_t>(cy + dy);
    for (int dx = -H; dx <= H; ++dx)
    {
      const uint8_t* px = row + (cx + dx) * L.step;
      if (px[L.r] >= saturation || px[L.g] >= saturation || px[L.b] >= saturation)
        continue;
      const double w = gx[dx + H] * gy[dy + H];
      er += w * (px[L.r] - pr.at(dx, dy));
      eg += w * (px[L.g] - pg.at(dx, dy));
      eb += w * (px[L.b] - pb.at(dx, dy));
    }
  }
  if (eg > 1e-6)
  {
    r->red_ratio = er / eg;
    r->blue_ratio = eb / eg;
  }
  else
  {
    // Every pixel clipped, or no green excess at all: nothing to judge by here.
    r->red_ratio = r->blue_ratio = 0.0;
  }
}
}  // namespace

SpotDetectionResult SpotDetector::detectFast(const cv::Mat& image, PixelFormat format, SpotDetectorDebug* debug,
                                             SpotDetectorTimings* timings)
{
  SpotDetectionResult result;
  const SpotDetectorParams& p = params_;
  Clock::time_point t = Clock::now();
  SpotDetectorTimings tm;
  const Layout L = layoutOf(format);
  const bool mono = format == PixelFormat::kMono8;
  const int threshold = mono ? p.mono_threshold : p.detect_threshold;

  runs_.clear();
  for (int y = 0; y < image.rows; ++y)
  {
    const uint8_t* row = image.ptr<uint8_t>(y);
    switch (L.step)
    {
      case 1:
        rowRuns<1>(row, image.cols, y, threshold, &runs_);
        break;
      case 3:
        rowRuns<3>(row, image.cols, y, threshold, &runs_);
        break;
      default:
        rowRuns<4>(row, image.cols, y, threshold, &runs_);
        break;
    }
  }
  tm.threshold_ms = msSince(t);

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
  std::vector<Blob> blobs;
  for (int i = 0; i < n; ++i)
  {
    const int r = findRoot(parent_, i);
    if (blob_of[r] < 0)
    {
      blob_of[r] = static_cast<int>(blobs.size());
      blobs.emplace_back();
    }
    Blob& b = blobs[blob_of[r]];
    const Run& run = runs_[i];
    const uint8_t* row = image.ptr<uint8_t>(run.y);
    for (int x = run.x0; x <= run.x1; ++x)
    {
      const int s = mono ? row[x] : greenness(row + x * L.step);
      ++b.count;
      b.sum += s;
      b.sx += double(s) * x;
      b.sy += double(s) * run.y;
      b.peak = std::max(b.peak, s);
    }
    b.x0 = std::min(b.x0, run.x0);
    b.x1 = std::max(b.x1, run.x1);
    b.y0 = std::min(b.y0, run.y);
    b.y1 = std::max(b.y1, run.y);
  }
  tm.labelling_ms = msSince(t);

  // Refinement and rejection of each blob.
  std::vector<Refined> kept;
  auto reject = [&](double x, double y, const std::string& why) {
    if (debug)
      debug->rejected.push_back({x, y, why});
  };
  for (const Blob& b : blobs)
  {
    if (b.count < p.min_pixels || (!mono && b.peak < p.min_peak) || !(b.sum > 0))
      continue;  // noise: not worth a line in the debug output
    const double bx = b.sx / b.sum, by = b.sy / b.sum;
    // First guess of sigma from the candidate area: a Gaussian exceeds a
    // threshold within ~2 sigma of its centre for typical peak/threshold ratios.
    const double radius = 0.5 * std::max(b.x1 - b.x0 + 1, b.y1 - b.y0 + 1);
    const double sigma0 = std::min(std::max(0.5 * radius, 1.0), p.max_sigma_px);
    Refined r;
    if (!refineSpot(image, L.step, L.g, bx, by, sigma0, p.window_radius_px, p.max_sigma_px, &r))
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
    const uint8_t* core = image.ptr<uint8_t>(static_cast<int>(std::lround(r.y))) +
                          static_cast<int>(std::lround(r.x)) * L.step;
    const bool clipped = core[L.r] >= p.saturation_level || core[L.g] >= p.saturation_level ||
                         core[L.b] >= p.saturation_level;
    if (!mono && !clipped)
    {
      chroma(image, L, p.saturation_level, &r);
      if (r.red_ratio < -p.max_red_deficit || r.red_ratio > p.max_chroma_ratio ||
          std::abs(r.blue_ratio) > p.max_chroma_ratio)
      {
        reject(r.x, r.y, "colour: red/green " + std::to_string(r.red_ratio) + ", blue/green " +
                             std::to_string(r.blue_ratio));
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
  Spots spots;
  std::vector<Refined> refined;
  for (size_t i = 0; i < kept.size(); ++i)
  {
    if (drop[i])
      continue;
    spots.push_back(result.spots[i]);
    refined.push_back(kept[i]);
  }
  tm.refine_ms = msSince(t);

  // Row-major order for readability; beams are the Triangulator's business.
  sortIntoRows(&spots, p.projector_cols, p.projector_rows, false);
  if (debug)
  {
    // Per-spot debug data in the order of the sorted spots.
    debug->candidates = static_cast<int>(blobs.size());
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

// ---------------------------------------------------------------------------

cv::Mat toBgr(const cv::Mat& image, PixelFormat format)
{
  cv::Mat out;
  switch (format)
  {
    case PixelFormat::kBgr8:
      return image;
    case PixelFormat::kRgb8:
      cv::cvtColor(image, out, cv::COLOR_RGB2BGR);
      break;
    case PixelFormat::kBgra8:
      cv::cvtColor(image, out, cv::COLOR_BGRA2BGR);
      break;
    case PixelFormat::kRgba8:
      cv::cvtColor(image, out, cv::COLOR_RGBA2BGR);
      break;
    case PixelFormat::kMono8:
      cv::cvtColor(image, out, cv::COLOR_GRAY2BGR);
      break;
  }
  return out;
}

cv::Mat drawSpotDebugImage(const cv::Mat& image, PixelFormat format, const Spots& spots,
                           const SpotDetectorDebug& debug)
{
  cv::Mat out = toBgr(image, format).clone();
  if (out.empty())
    return out;
  if (!debug.mask.empty() && debug.mask.size() == out.size())
  {
    std::vector<std::vector<cv::Point>> contours;
    cv::findContours(debug.mask.clone(), contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
    cv::drawContours(out, contours, -1, cv::Scalar(255, 0, 255), 1);
  }
  for (const cv::Rect& r : debug.windows)
    cv::rectangle(out, r, cv::Scalar(255, 0, 255), 1);
  // Rejected candidates: a small orange circle (why is in the debug struct).
  for (const SpotDetectorDebug::Rejection& r : debug.rejected)
    cv::circle(out, cv::Point(static_cast<int>(std::lround(r.x)), static_cast<int>(std::lround(r.y))), 4,
               cv::Scalar(0, 128, 255), 1);
  // Crosses at 1/16 px precision so the drawing does not round the centroid.
  const int shift = 4;
  const double scale = 1 << shift;
  for (const Spot& s : spots)
  {
    const cv::Point c(static_cast<int>(std::lround(s.x * scale)), static_cast<int>(std::lround(s.y * scale)));
    const int arm = 5 << shift;
    cv::line(out, c - cv::Point(arm, 0), c + cv::Point(arm, 0), cv::Scalar(255, 255, 255), 1, cv::LINE_AA, shift);
    cv::line(out, c - cv::Point(0, arm), c + cv::Point(0, arm), cv::Scalar(255, 255, 255), 1, cv::LINE_AA, shift);
    if (s.beam >= 0)
      cv::putText(out, std::to_string(s.beam), cv::Point(static_cast<int>(s.x) + 6, static_cast<int>(s.y) - 6),
                  cv::FONT_HERSHEY_PLAIN, 0.8, cv::Scalar(0, 255, 255), 1);
  }
  return out;
}

}  // namespace structured_light_stabilizer
