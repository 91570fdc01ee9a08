// Ambient image at the on-frame's time (ambient_compensation.h,
// docs/daylight.md#strobing): pick the frames, estimate the image motion
// between them from the rock's texture, warp each to the on-frame's time
// along a fraction of that motion, blend.
#include "structured_light_stabilizer/detection/ambient_compensation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include <Eigen/Core>
#include <unsupported/Eigen/MatrixFunctions>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

namespace structured_light_stabilizer
{

namespace
{

std::string fmt(const char* format, double a, double b = 0.0)
{
  char buf[160];
  std::snprintf(buf, sizeof(buf), format, a, b);
  return buf;
}

bool bayer(AmbientLayout layout)
{
  return layout != AmbientLayout::kInterleaved;
}

// Why the pair cannot be used; empty when it can.
std::string checkImages(const AmbientFrame& a, const AmbientFrame& b, const AmbientCompensationParams& p)
{
  for (const AmbientFrame* f : {&a, &b})
  {
    if (f->image.empty())
      continue;
    const int t = f->image.type();
    if (t != CV_8UC1 && t != CV_8UC3 && t != CV_8UC4 && t != CV_16UC1 && t != CV_16UC3)
      return "ambient images must be CV_8UC1/3/4 or CV_16UC1/3";
    if (bayer(p.layout) && (f->image.channels() != 1 || f->image.cols % 2 || f->image.rows % 2))
      return "a Bayer mosaic must be one channel of even width and height";
    if (!std::isfinite(f->stamp_s))
      return "an ambient stamp is not finite";
  }
  if (!a.image.empty() && !b.image.empty() && (a.image.size() != b.image.size() || a.image.type() != b.image.type()))
    return "the two ambient images differ in size or type";
  return "";
}

// 8-bit grey image for tracking: a Bayer mosaic binned 2 x 2 (its luma at
// half resolution, *scale = 0.5), colour converted (and binned 2 x 2 when
// `bin`), 16-bit scaled.
cv::Mat trackingImage(const cv::Mat& img, AmbientLayout layout, bool bin, double* scale)
{
  cv::Mat grey;
  *scale = 1.0;
  if (bayer(layout))
  {
    cv::Mat f;
    img.convertTo(f, CV_32F);
    cv::resize(f, grey, cv::Size(img.cols / 2, img.rows / 2), 0, 0, cv::INTER_AREA);
    *scale = 0.5;
  }
  else if (img.channels() == 3)
    cv::cvtColor(img, grey, cv::COLOR_BGR2GRAY);
  else if (img.channels() == 4)
    cv::cvtColor(img, grey, cv::COLOR_BGRA2GRAY);
  else
    grey = img;
  if (bin && !bayer(layout) && grey.cols >= 4 && grey.rows >= 4)
  {
    cv::Mat half;
    cv::resize(grey, half, cv::Size(grey.cols / 2, grey.rows / 2), 0, 0, cv::INTER_AREA);
    grey = half;
    *scale = 0.5;
  }
  if (grey.depth() == CV_8U)
    return grey;
  double hi = 0.0;
  cv::minMaxLoc(grey, nullptr, &hi);
  cv::Mat out;
  grey.convertTo(out, CV_8U, hi > 0.0 ? 255.0 / hi : 1.0);
  return out;
}

bool sameFrame(const AmbientTrackingCache::Entry& e, const AmbientFrame& f, const AmbientCompensationParams& p)
{
  return !e.pyramid.empty() && e.stamp_s == f.stamp_s && e.size == f.image.size() && e.type == f.image.type() &&
         e.layout == p.layout && e.half_resolution == p.half_resolution_tracking && e.window_px == p.window_px &&
         e.pyramid_levels == p.pyramid_levels;
}

// The tracking pyramid of a frame: the cache's when it has it.
AmbientTrackingCache::Entry trackingPyramid(const AmbientFrame& f, const AmbientCompensationParams& p,
                                            const AmbientTrackingCache* cache)
{
  if (cache)
    for (const AmbientTrackingCache::Entry& e : cache->entries)
      if (sameFrame(e, f, p))
        return e;
  AmbientTrackingCache::Entry e;
  e.stamp_s = f.stamp_s;
  e.size = f.image.size();
  e.type = f.image.type();
  e.layout = p.layout;
  e.half_resolution = p.half_resolution_tracking;
  e.window_px = p.window_px;
  e.pyramid_levels = p.pyramid_levels;
  const cv::Mat grey = trackingImage(f.image, p.layout, p.half_resolution_tracking, &e.scale);
  cv::buildOpticalFlowPyramid(grey, e.pyramid, cv::Size(p.window_px, p.window_px), p.pyramid_levels, true);
  return e;
}

// Homography a -> b in full-resolution pixels from the rock's texture.
bool estimateMotion(const AmbientFrame& a, const AmbientFrame& b, const AmbientCompensationParams& p,
                    AmbientTrackingCache* cache, AmbientEstimate* out)
{
  const AmbientTrackingCache::Entry ea = trackingPyramid(a, p, cache), eb = trackingPyramid(b, p, cache);
  if (cache)
  {
    cache->entries[0] = ea;
    cache->entries[1] = eb;
  }
  const double scale = ea.scale;
  const cv::Size size = ea.pyramid.front().size();
  std::vector<cv::Point2f> pa, pb;
  const int margin = p.window_px;
  for (int i = 0; i < p.grid; ++i)
    for (int j = 0; j < p.grid; ++j)
      pa.emplace_back(margin + (size.width - 2.0f * margin) * (j + 0.5f) / p.grid,
                      margin + (size.height - 2.0f * margin) * (i + 0.5f) / p.grid);
  std::vector<uchar> status;
  std::vector<float> err;
  // Each point stops once its step is below 0.01 px: their residuals about
  // the fitted homography are 0.06-0.07 px RMS.
  cv::calcOpticalFlowPyrLK(ea.pyramid, eb.pyramid, pa, pb, status, err, cv::Size(p.window_px, p.window_px),
                           p.pyramid_levels,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 1e-2), 0, 1e-3);
  std::vector<cv::Point2f> sa, sb;
  for (size_t k = 0; k < pa.size(); ++k)
    if (status[k])
    {
      sa.push_back(pa[k] / scale);
      sb.push_back(pb[k] / scale);
    }
  if (static_cast<int>(sa.size()) < p.min_points)
    return false;
  std::vector<uchar> inliers;
  const cv::Mat H = cv::findHomography(sa, sb, cv::RANSAC, p.ransac_threshold_px, inliers);
  if (H.empty())
    return false;
  out->motion_ab = cv::Matx33d(H);
  double sum2 = 0.0;
  out->points_used = 0;
  for (size_t k = 0; k < sa.size(); ++k)
    if (inliers[k])
    {
      const cv::Vec3d q = out->motion_ab * cv::Vec3d(sa[k].x, sa[k].y, 1.0);
      sum2 += std::pow(q[0] / q[2] - sb[k].x, 2) + std::pow(q[1] / q[2] - sb[k].y, 2);
      ++out->points_used;
    }
  out->residual_px = out->points_used > 0 ? std::sqrt(sum2 / out->points_used) : 0.0;
  return out->points_used >= p.min_points;
}

// A Bayer mosaic warped so that what was at x sits at H x (bilinear): each
// phase on its own sites, M_p = T_p^-1 H T_p with T_p the phase's
// half-resolution grid. (Interleaved layouts: warpRegion.)
cv::Mat warpBayer(const cv::Mat& img, const cv::Matx33d& H)
{
  cv::Mat out;
  out.create(img.size(), img.type());
  const cv::Size half(img.cols / 2, img.rows / 2);
  for (int oy = 0; oy < 2; ++oy)
    for (int ox = 0; ox < 2; ++ox)
    {
      cv::Mat plane(half, img.type()), warped;
      for (int r = 0; r < half.height; ++r)
        for (int c = 0; c < half.width; ++c)
        {
          if (img.depth() == CV_8U)
            plane.at<uchar>(r, c) = img.at<uchar>(2 * r + oy, 2 * c + ox);
          else
            plane.at<uint16_t>(r, c) = img.at<uint16_t>(2 * r + oy, 2 * c + ox);
        }
      const cv::Matx33d T(2, 0, ox, 0, 2, oy, 0, 0, 1);
      cv::warpPerspective(plane, warped, cv::Mat(T.inv() * H * T), half, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      for (int r = 0; r < half.height; ++r)
        for (int c = 0; c < half.width; ++c)
        {
          if (img.depth() == CV_8U)
            out.at<uchar>(2 * r + oy, 2 * c + ox) = warped.at<uchar>(r, c);
          else
            out.at<uint16_t>(2 * r + oy, 2 * c + ox) = warped.at<uint16_t>(r, c);
        }
    }
  return out;
}

// Where a region's pixels come from: the inverse of the region's homography
// M (region pixels -> source pixels), linearised about the region's centre,
// as the 2 x 3 matrix of warpAffine's inverse map, when the linearisation
// is within kAffineTolerancePx of the homography at the region's corners and
// edge midpoints (a perspective map deviates from its tangent quadratically
// away from the centre; near the identity, over a region of a hundred
// pixels, by far less). False: use the homography. OpenCV's bilinear warps
// resolve a sample's position to 1/32 px (INTER_TAB_SIZE): the tolerance is
// an eighth of that step.
constexpr double kAffineTolerancePx = 0.004;

bool affineInverse(const cv::Matx33d& M, const cv::Size& size, cv::Matx23d* A)
{
  const cv::Matx33d G = M.inv();
  const auto apply = [&G](double x, double y)
  {
    const cv::Vec3d q = G * cv::Vec3d(x, y, 1.0);
    return cv::Point2d(q[0] / q[2], q[1] / q[2]);
  };
  const double cx = 0.5 * (size.width - 1), cy = 0.5 * (size.height - 1);
  const cv::Vec3d c = G * cv::Vec3d(cx, cy, 1.0);
  if (!(std::fabs(c[2]) > 1e-12))
    return false;
  // Jacobian of the projective map at the centre.
  const double w = c[2], u = c[0] / w, v = c[1] / w;
  const double j00 = (G(0, 0) - u * G(2, 0)) / w, j01 = (G(0, 1) - u * G(2, 1)) / w;
  const double j10 = (G(1, 0) - v * G(2, 0)) / w, j11 = (G(1, 1) - v * G(2, 1)) / w;
  *A = cv::Matx23d(j00, j01, u - j00 * cx - j01 * cy, j10, j11, v - j10 * cx - j11 * cy);
  const double xs[3] = {0.0, cx, size.width - 1.0}, ys[3] = {0.0, cy, size.height - 1.0};
  for (double x : xs)
    for (double y : ys)
    {
      const cv::Point2d h = apply(x, y);
      const cv::Point2d a((*A)(0, 0) * x + (*A)(0, 1) * y + (*A)(0, 2), (*A)(1, 0) * x + (*A)(1, 1) * y + (*A)(1, 2));
      if (!(std::hypot(h.x - a.x, h.y - a.y) <= kAffineTolerancePx))
        return false;
    }
  return true;
}

// The smallest side a region is halved to before it is warped in
// perspective: the affine map's deviation falls with the square of the size.
constexpr int kMinAffineSide = 16;

// dst tiled for warping by the homographies M (region pixels from source
// pixels, one per frame): where every map is affine within
// kAffineTolerancePx over the tile (about half the cost of a perspective
// warp), affine_leaf(A, tile) with the tangent maps A; else the tile is halved
// along its longer side, each half with its own maps (the tile's shifted to
// its origin), down to kMinAffineSide, below which perspective_leaf(M, tile).
template <std::size_t N, typename AffineLeaf, typename PerspectiveLeaf>
void forEachWarpTile(const std::array<cv::Matx33d, N>& M, cv::Mat dst, const AffineLeaf& affine_leaf,
                     const PerspectiveLeaf& perspective_leaf)
{
  const cv::Size size = dst.size();
  std::array<cv::Matx23d, N> A;
  bool affine = true;
  for (std::size_t i = 0; i < N && affine; ++i)
    affine = affineInverse(M[i], size, &A[i]);
  if (affine)
  {
    affine_leaf(A, dst);
    return;
  }
  const bool split_x = size.width >= size.height;
  const int side = split_x ? size.width : size.height;
  if (side < 2 * kMinAffineSide)
  {
    perspective_leaf(M, dst);
    return;
  }
  const int half = side / 2;
  const cv::Rect first = split_x ? cv::Rect(0, 0, half, size.height) : cv::Rect(0, 0, size.width, half);
  const cv::Rect second =
      split_x ? cv::Rect(half, 0, size.width - half, size.height) : cv::Rect(0, half, size.width, size.height - half);
  forEachWarpTile(M, dst(first), affine_leaf, perspective_leaf);
  const cv::Matx33d shift(1, 0, -second.x, 0, 1, -second.y, 0, 0, 1);
  std::array<cv::Matx33d, N> shifted;
  for (std::size_t i = 0; i < N; ++i)
    shifted[i] = shift * M[i];
  forEachWarpTile(shifted, dst(second), affine_leaf, perspective_leaf);
}

// src warped by the homography M into dst (dst's size, allocated), tiled by
// forEachWarpTile.
void warpInto(const cv::Mat& src, const cv::Matx33d& M, cv::Mat dst)
{
  forEachWarpTile(
      std::array<cv::Matx33d, 1>{M}, dst,
      [&src](const std::array<cv::Matx23d, 1>& A, cv::Mat tile)
      {
        cv::warpAffine(src, tile, cv::Mat(A[0]), tile.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                       cv::BORDER_REPLICATE);
      },
      [&src](const std::array<cv::Matx33d, 1>& T, cv::Mat tile)
      { cv::warpPerspective(src, tile, cv::Mat(T[0]), tile.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE); });
}

void warpRegion(const cv::Mat& src, const cv::Matx33d& M, const cv::Size& size, cv::Mat* dst)
{
  dst->create(size, src.type());
  warpInto(src, M, *dst);
}

// The bilinear sample of an 8-bit frame at (sx, sy), its borders replicated
// (BORDER_REPLICATE), channel by channel into v.
void sampleReplicated(const cv::Mat& src, double sx, double sy, float* v)
{
  const int cn = src.channels();
  if (!(std::isfinite(sx) && std::isfinite(sy)))  // compensateAmbient passes finite maps only
  {
    std::fill(v, v + cn, 0.0f);
    return;
  }
  const double fx0 = std::floor(sx), fy0 = std::floor(sy);
  const float fx = static_cast<float>(sx - fx0), fy = static_cast<float>(sy - fy0);
  const auto clampTo = [](double q, int hi) { return static_cast<int>(std::min(std::max(q, 0.0), double(hi))); };
  const int x0 = clampTo(fx0, src.cols - 1), x1 = clampTo(fx0 + 1.0, src.cols - 1);
  const int y0 = clampTo(fy0, src.rows - 1), y1 = clampTo(fy0 + 1.0, src.rows - 1);
  const uchar *r0 = src.ptr<uchar>(y0), *r1 = src.ptr<uchar>(y1);
  for (int c = 0; c < cn; ++c)
  {
    const float top = r0[x0 * cn + c] + fx * (r0[x1 * cn + c] - r0[x0 * cn + c]);
    const float bottom = r1[x0 * cn + c] + fx * (r1[x1 * cn + c] - r1[x0 * cn + c]);
    v[c] = top + fy * (bottom - top);
  }
}

// How many pixels, from a fraction f in [0, 1) growing by df per pixel, keep
// f in [0, 1): along a run of them a pixel's taps are its left neighbour's
// shifted by one.
double stepsInCell(double f, double df)
{
  if (df > 0.0)
    return std::ceil((1.0 - f) / df);
  if (df < 0.0)
    return std::floor(f / -df) + 1.0;
  return 1e9;
}

// dst (CV_32FC(cn)) = or += weight x src (CV_8UC(cn)) sampled bilinearly in
// float at A (x, y, 1) for each pixel (x, y) of dst, borders replicated. A
// near-identity map keeps a pixel's four taps in the same two source rows,
// one column further than its left neighbour's, over runs of hundreds of
// pixels: along a run the weights are linear in the pixel's offset and every
// tap is a contiguous load, so the loop over the run's values vectorises.
// Unlike cv::warpAffine the weights are not rounded to 1/32 px and the
// result is not rounded to 8 bits.
void accumulateBilinear(const cv::Mat& src, const cv::Matx23d& A, float weight, bool first, cv::Mat dst)
{
  const int cn = src.channels(), width = dst.cols;
  // offset[e] = e / cn: the pixel of value e along a run (one table per channel count).
  static thread_local std::vector<float> offsets[5];
  std::vector<float>& offset = offsets[cn];
  if (offset.size() < static_cast<size_t>(width * cn))
  {
    offset.resize(static_cast<size_t>(width * cn));
    for (size_t e = 0; e < offset.size(); ++e)
      offset[e] = static_cast<float>(e / cn);
  }
  const float* pix = offset.data();
  const double du = A(0, 0) - 1.0, dv = A(1, 0);
  for (int y = 0; y < dst.rows; ++y)
  {
    float* out = dst.ptr<float>(y);
    const double sx0 = A(0, 1) * y + A(0, 2), sy0 = A(1, 1) * y + A(1, 2);
    int x = 0;
    while (x < width)
    {
      const double sx = sx0 + A(0, 0) * x, sy = sy0 + A(1, 0) * x;
      const double fx0 = std::floor(sx), fy0 = std::floor(sy);
      if (!(fx0 >= 0.0 && fx0 < src.cols - 1.0 && fy0 >= 0.0 && fy0 < src.rows - 1.0))
      {
        float v[4];
        sampleReplicated(src, sx, sy, v);
        for (int c = 0; c < cn; ++c)
          out[x * cn + c] = first ? weight * v[c] : out[x * cn + c] + weight * v[c];
        ++x;
        continue;
      }
      const int ix = static_cast<int>(fx0), iy = static_cast<int>(fy0);
      const double u = sx - fx0, v = sy - fy0;
      const double steps =
          std::min({stepsInCell(u, du), stepsInCell(v, dv), double(width - x), double(src.cols - 1 - ix)});
      const int n = std::max(1, static_cast<int>(steps));
      const uchar* r0 = src.ptr<uchar>(iy) + ix * cn;
      const uchar* r1 = src.ptr<uchar>(iy + 1) + ix * cn;
      const float fu = static_cast<float>(u), fdu = static_cast<float>(du);
      const float fv = static_cast<float>(v), fdv = static_cast<float>(dv);
      float* o = out + x * cn;
      const int values = n * cn;
      if (first)
        for (int e = 0; e < values; ++e)
        {
          const float fx = fu + fdu * pix[e], fy = fv + fdv * pix[e];
          const float top = r0[e] + fx * (r0[e + cn] - r0[e]);
          const float bottom = r1[e] + fx * (r1[e + cn] - r1[e]);
          o[e] = weight * (top + fy * (bottom - top));
        }
      else
        for (int e = 0; e < values; ++e)
        {
          const float fx = fu + fdu * pix[e], fy = fv + fdv * pix[e];
          const float top = r0[e] + fx * (r0[e + cn] - r0[e]);
          const float bottom = r1[e] + fx * (r1[e + cn] - r1[e]);
          o[e] += weight * (top + fy * (bottom - top));
        }
      x += n;
    }
  }
}

// The same through a homography M (region pixels from source pixels, as
// warpInto's): pixel by pixel, for the small tiles whose perspective an
// affine map does not follow.
void accumulateProjective(const cv::Mat& src, const cv::Matx33d& M, float weight, bool first, cv::Mat dst)
{
  const int cn = src.channels();
  const cv::Matx33d G = M.inv();
  float v[4];
  for (int y = 0; y < dst.rows; ++y)
  {
    float* out = dst.ptr<float>(y);
    for (int x = 0; x < dst.cols; ++x)
    {
      const cv::Vec3d q = G * cv::Vec3d(x, y, 1.0);
      sampleReplicated(src, q[0] / q[2], q[1] / q[2], v);
      for (int c = 0; c < cn; ++c)
        out[x * cn + c] = first ? weight * v[c] : out[x * cn + c] + weight * v[c];
    }
  }
}

// An 8-bit frame pair warped and blended in float into dst (CV_32FC(cn)):
// dst = wa a(Ma^-1 x) + wb b(Mb^-1 x), tiled by forEachWarpTile for both
// frames at once.
void warpBlendInto(const cv::Mat& a, const cv::Matx33d& Ma, float wa, const cv::Mat& b, const cv::Matx33d& Mb, float wb,
                   cv::Mat dst)
{
  forEachWarpTile(
      std::array<cv::Matx33d, 2>{Ma, Mb}, dst,
      [&](const std::array<cv::Matx23d, 2>& A, cv::Mat tile)
      {
        accumulateBilinear(a, A[0], wa, true, tile);
        accumulateBilinear(b, A[1], wb, false, tile);
      },
      [&](const std::array<cv::Matx33d, 2>& T, cv::Mat tile)
      {
        accumulateProjective(a, T[0], wa, true, tile);
        accumulateProjective(b, T[1], wb, false, tile);
      });
}

// The frames warped along their fractions of the motion (have_motion) and
// blended with weight wb on the second, into `out`: the whole frame, or only
// p.regions (interleaved layouts). A region's warp is the frame's, shifted to
// the region's origin: the same pixels as the whole frame's warp there, up
// to where the two tilings' tangent maps (each within kAffineTolerancePx of
// the homography) round a sample position to another 1/32 px. `warped`: two
// buffers for the warped frames (the cache's, kept from call to call).
void warpAndBlend(const cv::Mat& a, const cv::Mat& b, bool have_motion, const cv::Matx33d& Ha, const cv::Matx33d& Hb,
                  double wb, const AmbientCompensationParams& p, cv::Mat* warped, cv::Mat* out)
{
  // Unrounded: the blend in float. (When each warp was rounded to 8 bits
  // first, warping float copies measured 0.0948 px against 0.0968 px on the
  // strobed bag's scene.)
  const int depth = p.unrounded && a.depth() == CV_8U && !bayer(p.layout) ? CV_32F : a.depth();
  if (bayer(p.layout))
  {
    const cv::Mat ia = have_motion ? warpBayer(a, Ha) : a;
    const cv::Mat ib = have_motion ? warpBayer(b, Hb) : b;
    cv::addWeighted(ia, 1.0 - wb, ib, wb, 0.0, *out, depth);
    return;
  }
  out->create(a.size(), CV_MAKETYPE(depth, a.channels()));
  // 8-bit frames blended unrounded: warped and blended in one float pass
  // (warpBlendInto), without rounding each warp to 8 bits. Ha, Hb are the
  // identity when there is no motion.
  const bool fused = depth == CV_32F && a.depth() == CV_8U;
  const cv::Rect frame(0, 0, a.cols, a.rows);
  const std::vector<cv::Rect> whole{frame};
  for (const cv::Rect& region : p.regions.empty() ? whole : p.regions)
  {
    const cv::Rect r = region & frame;
    if (r.empty())
      continue;
    cv::Mat dst = (*out)(r);
    const cv::Matx33d shift(1, 0, -r.x, 0, 1, -r.y, 0, 0, 1);
    if (fused)
    {
      warpBlendInto(a, shift * Ha, static_cast<float>(1.0 - wb), b, shift * Hb, static_cast<float>(wb), dst);
      continue;
    }
    if (!have_motion)
    {
      cv::addWeighted(a(r), 1.0 - wb, b(r), wb, 0.0, dst, depth);
      continue;
    }
    warpRegion(a, shift * Ha, r.size(), &warped[0]);
    warpRegion(b, shift * Hb, r.size(), &warped[1]);
    cv::addWeighted(warped[0], 1.0 - wb, warped[1], wb, 0.0, dst, depth);
  }
}

// Orders the usable frames: *first is the earlier one. False when neither
// is usable; *only set when exactly one is.
bool usableFrames(double t, const AmbientFrame& a, const AmbientFrame& b, const AmbientCompensationParams& p,
                  const AmbientFrame** first, const AmbientFrame** second, std::string* why)
{
  auto usable = [&](const AmbientFrame& f) { return !f.image.empty() && std::fabs(f.stamp_s - t) <= p.max_gap_s; };
  const bool ua = usable(a), ub = usable(b);
  if (!ua && !ub)
  {
    *why = fmt("no ambient frame within %.3f s of the on-frame", p.max_gap_s);
    return false;
  }
  *first = ua ? &a : &b;
  *second = ua && ub ? &b : nullptr;
  if (*second && (*second)->stamp_s < (*first)->stamp_s)
    std::swap(*first, *second);
  if (*second && (*second)->stamp_s == (*first)->stamp_s)
    *second = nullptr;
  return true;
}

}  // namespace

cv::Matx33d homographyPower(const cv::Matx33d& H, double w)
{
  Eigen::Matrix3d M;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      M(r, c) = H(r, c);
  const double det = M.determinant();
  if (!(det > 0.0))  // singular or a reflection: no motion has it, and no real power
    return cv::Matx33d::all(std::numeric_limits<double>::quiet_NaN());
  M /= std::cbrt(det);
  const Eigen::Matrix3d P = (w * M.log()).exp();
  cv::Matx33d out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      out(r, c) = P(r, c);
  return out;
}

cv::Matx33d planeHomography(const cv::Matx33d& K, const cv::Matx33d& R, const cv::Vec3d& t, const cv::Vec3d& n,
                            double d)
{
  const cv::Matx33d tn(t[0] * n[0], t[0] * n[1], t[0] * n[2], t[1] * n[0], t[1] * n[1], t[1] * n[2], t[2] * n[0],
                       t[2] * n[1], t[2] * n[2]);
  return K * (R + tn * (1.0 / d)) * K.inv();
}

AmbientEstimate compensateAmbient(double t, const AmbientFrame& a, const AmbientFrame& b,
                                  const AmbientCompensationParams& p, const cv::Matx33d* hint,
                                  AmbientTrackingCache* cache)
{
  AmbientEstimate out;
  const AmbientFrame *first = nullptr, *second = nullptr;
  out.status = std::isfinite(t) ? checkImages(a, b, p) : "the on-frame's stamp is not finite";
  if (!out.status.empty() || !usableFrames(t, a, b, p, &first, &second, &out.status))
    return out;
  out.valid = true;
  if (!second || p.motion == AmbientMotion::kNearest)
  {
    const AmbientFrame* near =
        !second || std::fabs(first->stamp_s - t) <= std::fabs(second->stamp_s - t) ? first : second;
    out.image = near->image;
    out.fraction = near == first ? 0.0 : 1.0;
    out.status = fmt("nearest ambient frame, %.1f ms from the on-frame", 1e3 * std::fabs(near->stamp_s - t));
    return out;
  }
  double w = (t - first->stamp_s) / (second->stamp_s - first->stamp_s);
  w = std::min(std::max(w, -p.max_extrapolation), 1.0 + p.max_extrapolation);
  out.fraction = w;
  bool have_motion = false;
  if (p.motion == AmbientMotion::kHomography)
  {
    if (hint)
    {
      out.motion_ab = *hint;
      have_motion = true;
    }
    else
      have_motion = estimateMotion(*first, *second, p, cache, &out);
  }
  // Weights: a blend inside the interval; outside it the nearer frame alone.
  const double wb = std::min(std::max(w, 0.0), 1.0);
  cv::Matx33d Ha = have_motion ? homographyPower(out.motion_ab, w) : cv::Matx33d::eye();
  cv::Matx33d Hb = have_motion ? homographyPower(out.motion_ab, w - 1.0) : cv::Matx33d::eye();
  // A motion that is not finite (a hint with NaN, a power that failed: a
  // hint that is singular or mirrors) is no motion: the frames are blended by time.
  const bool bad_motion = have_motion && !(cv::checkRange(cv::Mat(out.motion_ab)) && cv::checkRange(cv::Mat(Ha)) &&
                                           cv::checkRange(cv::Mat(Hb)));
  if (bad_motion)
  {
    have_motion = false;
    Ha = Hb = cv::Matx33d::eye();
  }
  // An earlier call's buffer that only the cache holds (its pixels are all
  // written over where this estimate is defined).
  int slot = -1;
  for (int i = 0; cache && i < 2 && slot < 0; ++i)
    if (cache->images[i].u && cache->images[i].u->refcount == 1)
      slot = i;
  if (slot >= 0)
    out.image = cache->images[slot];
  cv::Mat warped[2];
  warpAndBlend(first->image, second->image, have_motion, Ha, Hb, wb, p, cache ? cache->warped : warped, &out.image);
  if (cache && (slot < 0 || out.image.data != cache->images[slot].data))
  {
    slot = slot >= 0 ? slot : cache->next_image;
    cache->next_image = 1 - slot;
    cache->images[slot] = out.image;
  }
  out.noise_variance_scale = (1.0 - wb) * (1.0 - wb) + wb * wb;
  if (have_motion && hint)
    out.status = fmt("warped along the given motion at fraction %.2f", w);
  else if (have_motion)
    out.status = fmt("warped along the motion between the ambient frames at fraction %.2f (%.0f points", w,
                     static_cast<double>(out.points_used)) +
                 fmt(", %.3f px RMS)", out.residual_px);
  else
    out.status = fmt("blended by time at fraction %.2f", w) +
                 (bad_motion                               ? " (the motion is not finite or not a motion)"
                  : p.motion == AmbientMotion::kHomography ? " (too little texture to track)"
                                                           : "");
  return out;
}

}  // namespace structured_light_stabilizer
