#include "structured_light_stabilizer/calibration/board_dots.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "calibration/board_dot_fit.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

// Blurs a map that is NaN beyond the print; pixels whose blur reaches past
// the print become NaN.
cv::Mat blurWithinPrint(const cv::Mat& map, double sigma)
{
  if (sigma <= 0.0)
    return map.clone();
  cv::Mat valid = (map == map);  // false at NaN
  cv::Mat filled = map.clone();
  filled.setTo(0.0f, ~valid);
  cv::Mat validf;
  valid.convertTo(validf, CV_32F, 1.0 / 255.0);
  cv::GaussianBlur(filled, filled, cv::Size(0, 0), sigma);
  cv::GaussianBlur(validf, validf, cv::Size(0, 0), sigma);
  filled.setTo(std::numeric_limits<float>::quiet_NaN(), validf < 0.999f);
  return filled;
}

// Ambient light on white at every pixel: the median of image / albedo over
// 16 x 16 blocks (a dot covers a small part of a block), smoothed over 3 x 3
// blocks, interpolated. NaN where the block lies beyond the print.
cv::Mat ambientOnWhite(const cv::Mat& img, const cv::Mat& albedo)
{
  const int B = 16;
  const int bw = (img.cols + B - 1) / B, bh = (img.rows + B - 1) / B;
  cv::Mat blocks(bh, bw, CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  std::vector<float> ratios;
  for (int by = 0; by < bh; ++by)
    for (int bx = 0; bx < bw; ++bx)
    {
      ratios.clear();
      for (int v = by * B; v < std::min(img.rows, (by + 1) * B); ++v)
        for (int u = bx * B; u < std::min(img.cols, (bx + 1) * B); ++u)
        {
          const float a = albedo.at<float>(v, u);
          if (a > 0.0f)
            ratios.push_back(img.at<float>(v, u) / a);
        }
      if (ratios.size() > B * B / 4)
        blocks.at<float>(by, bx) = detail::medianInPlace(ratios.begin(), ratios.end());
    }
  // Smooth over 3 x 3 blocks (median of the valid ones), then fill the
  // blocks beyond the print from their valid neighbours for interpolation.
  cv::Mat smooth = blocks.clone();
  for (int by = 0; by < bh; ++by)
    for (int bx = 0; bx < bw; ++bx)
    {
      ratios.clear();
      for (int y = std::max(0, by - 1); y <= std::min(bh - 1, by + 1); ++y)
        for (int x = std::max(0, bx - 1); x <= std::min(bw - 1, bx + 1); ++x)
          if (std::isfinite(blocks.at<float>(y, x)))
            ratios.push_back(blocks.at<float>(y, x));
      if (!ratios.empty())
        smooth.at<float>(by, bx) = detail::medianInPlace(ratios.begin(), ratios.end());
    }
  smooth.setTo(0.0f, smooth != smooth);
  cv::Mat out;
  cv::resize(smooth, out, img.size(), 0, 0, cv::INTER_LINEAR);
  return out;
}

// Robust (MAD) standard deviation of the finite values of m where `mask`
// is set (every other pixel, for speed); 1 when there are too few.
double robustSigma(const cv::Mat& m, const cv::Mat& mask = cv::Mat())
{
  std::vector<float> v;
  v.reserve(m.total() / 4);
  for (int y = 0; y < m.rows; y += 2)
    for (int x = 0; x < m.cols; x += 2)
    {
      const float f = m.at<float>(y, x);
      if (std::isfinite(f) && (mask.empty() || mask.at<uint8_t>(y, x)))
        v.push_back(f);
    }
  if (v.size() < 16)
    return 1.0;
  const float med = detail::medianInPlace(v.begin(), v.end());
  for (float& f : v)
    f = std::abs(f - med);
  return std::max(1e-3, 1.4826 * detail::medianInPlace(v.begin(), v.end()));
}

// Sub-pixels per pixel of the albedo windows of the blur measurement.
constexpr int kPsfSub = 4;

// Sum of squared residuals of I = b + L * box(blur_sigma(albedo)) over
// windows straddling square edges, with b and L free per window. The blur
// is applied at sub-pixel resolution before the pixel box, as in the dot
// model (board_dot_fit.h).
double edgeMisfit(const std::vector<cv::Mat>& img_windows, const std::vector<cv::Mat>& alb_windows, double sigma,
                  int pad)
{
  double sse = 0.0;
  for (size_t k = 0; k < img_windows.size(); ++k)
  {
    cv::Mat blurred, a;
    if (sigma > 0.0)
      cv::GaussianBlur(alb_windows[k], blurred, cv::Size(0, 0), sigma * kPsfSub);
    else
      blurred = alb_windows[k];
    const cv::Size inner(img_windows[k].cols * kPsfSub, img_windows[k].rows * kPsfSub);
    cv::resize(blurred(cv::Rect(pad * kPsfSub, pad * kPsfSub, inner.width, inner.height)), a, img_windows[k].size(), 0,
               0, cv::INTER_AREA);
    Eigen::Matrix2d N = Eigen::Matrix2d::Zero();
    Eigen::Vector2d r = Eigen::Vector2d::Zero();
    double yy = 0.0;
    for (int v = 0; v < a.rows; ++v)
      for (int u = 0; u < a.cols; ++u)
      {
        const Eigen::Vector2d x(1.0, a.at<float>(v, u));
        const double y = img_windows[k].at<float>(v, u);
        N += x * x.transpose();
        r += x * y;
        yy += y * y;
      }
    const Eigen::Vector2d beta = N.ldlt().solve(r);
    sse += yy - beta.dot(r);
  }
  return sse;
}

// Lens blur (px) from the board's own square edges: windows on the edges
// between neighbouring inner corners, away from dot candidates; the sigma
// whose blurred albedo matches them best (golden section over [0, 4] px).
double measurePsf(const cv::Mat& img, const cv::Mat& albedo, const CameraModel& camera, const BoardParams& board,
                  const ChessboardDetection& det, double black_ratio, const std::vector<cv::Point2d>& avoid)
{
  const int half = 6, pad = 6;
  std::vector<cv::Mat> imgs, albs;
  for (int k = 0; k < board.cornerCount(); ++k)
    for (int step : {1, board.cols})
    {
      const int k2 = k + step;
      if (k2 >= board.cornerCount() || (step == 1 && (k % board.cols) == board.cols - 1))
        continue;
      const Eigen::Vector3d mid = 0.5 * (board.corner(k) + board.corner(k2));
      const cv::Point2d p = camera.project(det.pose * mid);
      const cv::Rect outer(static_cast<int>(std::lround(p.x)) - half - pad,
                           static_cast<int>(std::lround(p.y)) - half - pad, 2 * (half + pad) + 1, 2 * (half + pad) + 1);
      if ((outer & cv::Rect(0, 0, albedo.cols, albedo.rows)) != outer ||
          cv::countNonZero(albedo(outer) != albedo(outer)))
        continue;
      bool near_dot = false;
      for (const cv::Point2d& q : avoid)
        near_dot |= std::abs(q.x - p.x) < half + 12 && std::abs(q.y - p.y) < half + 12;
      if (near_dot)
        continue;
      albs.push_back(
          renderBoardAlbedoWindow(camera, board, det.pose, det.square00_white, black_ratio, outer, kPsfSub, 8));
      imgs.push_back(img(cv::Rect(outer.x + pad, outer.y + pad, 2 * half + 1, 2 * half + 1)).clone());
    }
  if (imgs.size() < 4)
    return 0.7;  // too few clean edges: a typical sharp lens
  // 24 edges spread over the board measure the blur to well below 0.01 px
  // and keep the cost at a tenth of a second.
  if (imgs.size() > 24)
  {
    std::vector<cv::Mat> ki, ka;
    for (size_t k = 0; k < 24; ++k)
    {
      ki.push_back(imgs[k * imgs.size() / 24]);
      ka.push_back(albs[k * albs.size() / 24]);
    }
    imgs.swap(ki);
    albs.swap(ka);
  }
  double lo = 0.0, hi = 4.0;
  const double g = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
  double f1 = edgeMisfit(imgs, albs, x1, pad), f2 = edgeMisfit(imgs, albs, x2, pad);
  for (int it = 0; it < 20; ++it)  // 4 px * 0.618^20 = 3e-4 px
  {
    if (f1 < f2)
    {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - g * (hi - lo);
      f1 = edgeMisfit(imgs, albs, x1, pad);
    }
    else
    {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + g * (hi - lo);
      f2 = edgeMisfit(imgs, albs, x2, pad);
    }
  }
  return 0.5 * (lo + hi);
}

struct Candidate
{
  cv::Point2d p;
  double snr = 0.0;
  double peak = 0.0;  // smoothed dot light, DN
};

// Blob-shaped local maxima of the smoothed dot light, over the noise of
// the squares they lie on (shot noise makes white squares noisier than
// black ones). A ridge along a square edge (a slightly wrong blur) is
// refused by the shape test on the Hessian.
std::vector<Candidate> findCandidates(const cv::Mat& dot_light, const cv::Mat& albedo, double min_snr,
                                      double* noise_white, double* noise_black)
{
  cv::Mat s;
  cv::GaussianBlur(dot_light, s, cv::Size(0, 0), 1.5);
  const cv::Mat white = albedo >= 0.5f;
  *noise_white = robustSigma(s, white);
  *noise_black = robustSigma(s, albedo < 0.5f);
  cv::Mat clean = s.clone();
  clean.setTo(-1e9f, clean != clean);
  cv::Mat dil;
  cv::dilate(clean, dil, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(7, 7)));
  std::vector<Candidate> out;
  for (int v = 2; v < s.rows - 2; ++v)
    for (int u = 2; u < s.cols - 2; ++u)
    {
      const float c = clean.at<float>(v, u);
      const double noise = white.at<uint8_t>(v, u) ? *noise_white : *noise_black;
      if (c < min_snr * noise || c < dil.at<float>(v, u))
        continue;
      const double dxx = clean.at<float>(v, u + 2) + clean.at<float>(v, u - 2) - 2 * c;
      const double dyy = clean.at<float>(v + 2, u) + clean.at<float>(v - 2, u) - 2 * c;
      const double dxy = 0.25 * (clean.at<float>(v + 2, u + 2) + clean.at<float>(v - 2, u - 2) -
                                 clean.at<float>(v + 2, u - 2) - clean.at<float>(v - 2, u + 2));
      const double tr = dxx + dyy, det = dxx * dyy - dxy * dxy;
      const double disc = std::sqrt(std::max(0.0, 0.25 * tr * tr - det));
      const double l1 = 0.5 * tr - disc, l2 = 0.5 * tr + disc;  // l1 <= l2 < 0 for a blob
      if (!(l2 < 0.0) || l2 / l1 < 0.05)
        continue;
      // Sub-pixel start: parabola through the neighbours.
      const double ox = 0.5 * (s.at<float>(v, u - 1) - s.at<float>(v, u + 1)) /
                        std::min(-1e-6, static_cast<double>(s.at<float>(v, u - 1) + s.at<float>(v, u + 1) - 2 * c));
      const double oy = 0.5 * (s.at<float>(v - 1, u) - s.at<float>(v + 1, u)) /
                        std::min(-1e-6, static_cast<double>(s.at<float>(v - 1, u) + s.at<float>(v + 1, u) - 2 * c));
      out.push_back(
          {cv::Point2d(u - std::max(-0.5, std::min(0.5, ox)), v - std::max(-0.5, std::min(0.5, oy))), c / noise, c});
    }
  std::sort(out.begin(), out.end(), [](const Candidate& a, const Candidate& b) { return a.snr > b.snr; });
  return out;
}

}  // namespace

std::string BoardDotParams::validate() const
{
  std::ostringstream why;
  if (black_ratio < 0.0 || black_ratio >= 1.0 || !(default_black_ratio > 0.0 && default_black_ratio < 1.0))
    why << "black_ratio must be in [0, 1) and default_black_ratio in (0, 1); ";
  if (!(min_snr > 0.0))
    why << "min_snr must be positive; ";
  if (!(clip_fraction > 0.0 && clip_fraction <= 1.0))
    why << "clip_fraction must be in (0, 1]; ";
  if (!(min_sigma_px > 0.0 && max_sigma_px > min_sigma_px))
    why << "need 0 < min_sigma_px < max_sigma_px; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

namespace
{

// The fitted dot, or false when the window's fit does not describe a dot.
bool fitDot(const cv::Mat& img, double ambient_dn, const detail::BoardAlbedoSource& src, const Candidate& c, double psf,
            double clip, double noise, const BoardDotParams& params, BoardDot* dot)
{
  const int R = params.window_radius_px > 0 ? params.window_radius_px : 10;
  const int cx = static_cast<int>(std::lround(c.p.x)), cy = static_cast<int>(std::lround(c.p.y));
  const detail::DotWindow w(img, cv::Rect(cx - R, cy - R, 2 * R + 1, 2 * R + 1), psf, clip, src);
  if (!w.valid() || w.usable() < detail::kDotParams * 4)
    return false;  // beyond the print (or the image), or clipped all over
  detail::DotVector th;
  const double a0 = std::max(1e-3, w.ambientAlbedo(R, R));
  th << 0.0, ambient_dn, 0.0, 0.0, std::max(1.0, c.peak / a0), c.p.x, c.p.y, std::log(0.25), 0.0, std::log(0.25);
  detail::DotMatrix cov;
  double rms = 0.0;
  if (!detail::fitDotWindow(w, noise, &th, &cov, &rms))
    return false;
  double p = 0.0, q = 0.0, r = 0.0;
  detail::footprintInverse(th, &p, &q, &r);
  const Eigen::Matrix2d S = (Eigen::Matrix2d() << p, q, q, r).finished().inverse();
  const double size = std::sqrt(0.5 * S.trace());
  const int X = detail::kDotX, Y = detail::kDotY;
  if (!(th(4) > 0.0) || size < params.min_sigma_px || size > params.max_sigma_px ||
      std::hypot(th(X) - c.p.x, th(Y) - c.p.y) > 0.5 * R)
    return false;
  dot->x = th(X);
  dot->y = th(Y);
  dot->sigma_xy_px = std::sqrt(0.5 * (cov(X, X) + cov(Y, Y)));
  dot->sigma_px = size;
  dot->amplitude = th(4);
  dot->ambient_dn = th(1);
  dot->snr = c.snr;
  dot->fit_rms = rms;
  dot->clipped = w.clipped();
  dot->black_fraction = w.blackFraction(th);
  return true;
}

// Fits every candidate (duplicates within 3 px skipped); the dots on the
// print whose fit describes a dot.
std::vector<BoardDot> fitCandidates(const cv::Mat& img, double full_scale, const CameraModel& camera,
                                    const BoardParams& board, const ChessboardDetection& det,
                                    const BoardDotParams& params,
                                    const std::vector<std::pair<Candidate, double>>& starts, BoardDotReport* rep)
{
  detail::BoardAlbedoSource src;
  src.camera = &camera;
  src.board = &board;
  src.pose = det.pose;
  src.square00_white = det.square00_white;
  src.black_ratio = rep->black_ratio;
  std::vector<BoardDot> out;
  for (const auto& start : starts)
  {
    const Candidate& c = start.first;
    BoardDot d;
    bool dup = false;
    for (const BoardDot& o : out)
      dup |= std::hypot(o.x - c.p.x, o.y - c.p.y) < 3.0;
    if (dup ||
        !fitDot(img, start.second, src, c, rep->psf_sigma_px, params.clip_fraction * full_scale, rep->pixel_noise_dn,
                params, &d) ||
        !pixelToBoard(camera, det.pose, cv::Point2d(d.x, d.y), &d.board_xy))
    {
      ++rep->rejected;
      continue;
    }
    out.push_back(d);
  }
  return out;
}

}  // namespace

std::vector<BoardDot> refitBoardDots(const cv::Mat& dots_in, double full_scale, const CameraModel& camera,
                                     const BoardParams& board, const ChessboardDetection& det,
                                     const BoardDotParams& params, const std::vector<BoardDot>& previous,
                                     BoardDotReport* report)
{
  cv::Mat img;
  dots_in.convertTo(img, CV_32F);
  std::vector<std::pair<Candidate, double>> starts;
  for (const BoardDot& d : previous)
    starts.push_back({Candidate{cv::Point2d(d.x, d.y), d.snr, d.amplitude}, d.ambient_dn});
  report->rejected = 0;
  return fitCandidates(img, full_scale, camera, board, det, params, starts, report);
}

std::vector<BoardDot> findBoardDots(const cv::Mat& dots_in, double full_scale, const CameraModel& camera,
                                    const BoardParams& board, const ChessboardDetection& det,
                                    const BoardDotParams& params, BoardDotReport* report)
{
  BoardDotReport rep;
  std::vector<BoardDot> out;
  cv::Mat img;
  dots_in.convertTo(img, CV_32F);
  const bool measured = params.black_ratio <= 0.0 && det.white_level >= params.min_ambient_dn;
  rep.black_ratio = params.black_ratio > 0.0
                        ? params.black_ratio
                        : (measured ? std::max(1e-3, det.black_level) / det.white_level : params.default_black_ratio);
  rep.black_ratio_measured = measured;
  const cv::Mat alb = renderBoardAlbedo(camera, board, det.pose, det.square00_white, rep.black_ratio, img.size());
  // First pass: candidates with the unblurred albedo; they are kept away from
  // the edge windows that measure the blur.
  cv::Mat ambient = ambientOnWhite(img, alb);
  double noise = 1.0, noise_black = 1.0;
  std::vector<Candidate> cands = findCandidates(img - ambient.mul(alb), alb, params.min_snr, &noise, &noise_black);
  rep.psf_sigma_px = params.psf_sigma_px;
  if (params.psf_sigma_px < 0.0)
  {
    std::vector<cv::Point2d> avoid;
    for (const Candidate& c : cands)
      avoid.push_back(c.p);
    rep.psf_sigma_px = measurePsf(img, alb, camera, board, det, rep.black_ratio, avoid);
  }
  const cv::Mat alb_blur = blurWithinPrint(alb, rep.psf_sigma_px);
  ambient = ambientOnWhite(img, alb_blur);
  cands = findCandidates(img - ambient.mul(alb_blur), alb_blur, params.min_snr, &noise, &noise_black);
  rep.noise_dn = noise;
  rep.noise_black_dn = noise_black;
  rep.candidates = static_cast<int>(cands.size());
  rep.pixel_noise_dn = std::max(0.3, robustSigma(img - ambient.mul(alb_blur)));
  std::vector<std::pair<Candidate, double>> starts;  // (candidate, ambient on white there)
  for (const Candidate& c : cands)
    starts.push_back(
        {c, ambient.at<float>(static_cast<int>(std::lround(c.p.y)), static_cast<int>(std::lround(c.p.x)))});
  out = fitCandidates(img, full_scale, camera, board, det, params, starts, &rep);
  if (report)
    *report = rep;
  return out;
}

}  // namespace structured_light_stabilizer
