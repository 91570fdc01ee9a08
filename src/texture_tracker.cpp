#include "structured_light_stabilizer/texture_tracker.h"

#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

namespace structured_light_stabilizer
{

bool TextureTracker::nearDot(const cv::Point2f& p, const std::vector<cv::Point2f>& dots) const
{
  const float r2 = static_cast<float>(config_.dot_clearance_px * config_.dot_clearance_px);
  for (const cv::Point2f& d : dots)
  {
    const float dx = p.x - d.x, dy = p.y - d.y;
    if (dx * dx + dy * dy < r2)
      return true;
  }
  return false;
}

cv::Mat TextureTracker::channelOf(const cv::Mat& image, int channel, const cv::Rect& roi)
{
  if (image.type() == CV_8UC1)
    return image(roi);
  if (image.type() != CV_8UC3 || channel < 0 || channel > 2)
    return cv::Mat();
  cv::Mat out;
  cv::extractChannel(image(roi), out, channel);
  return out;
}

cv::Mat TextureTracker::prepare(const cv::Mat& image, int channel, const cv::Rect& roi) const
{
  const cv::Mat one = channelOf(image, channel, roi);
  if (one.empty() || !(config_.smooth_sigma_px > 0.0))
    return one;
  // Sensor noise dominates the tracking error on a soft, defocused rock
  // texture; a light blur removes more noise than signal.
  cv::Mat smooth;
  cv::GaussianBlur(one, smooth, cv::Size(0, 0), config_.smooth_sigma_px);
  return smooth;
}

namespace
{
// The refinement sums run over rows padded to a multiple of this many lanes,
// with independent per-lane accumulators, so that the compiler vectorises
// them without reassociating float sums (the padding has zero weight).
constexpr int kLanes = 8;
int paddedWidth(int width)
{
  return (width + kLanes - 1) / kLanes * kLanes;
}
}  // namespace

// Zeroes the weight of the window samples within dot_clearance_px of a dot;
// `dots` relative to the window centre. False when no dot touches the window.
bool TextureTracker::maskDots(const std::vector<cv::Point2f>& dots, const cv::Point2f& centre,
                              std::vector<float>* mask) const
{
  const int h = config_.refinement_window_px / 2, stride = paddedWidth(2 * h + 1);
  const float reach = static_cast<float>(config_.dot_clearance_px);
  bool any = false;
  for (const cv::Point2f& d : dots)
  {
    const float cx = d.x - centre.x, cy = d.y - centre.y;
    if (std::abs(cx) > h + reach || std::abs(cy) > h + reach)
      continue;
    any = true;
    const int ylo = std::max(-h, static_cast<int>(std::floor(cy - reach))),
              yhi = std::min(h, static_cast<int>(std::ceil(cy + reach)));
    const int xlo = std::max(-h, static_cast<int>(std::floor(cx - reach))),
              xhi = std::min(h, static_cast<int>(std::ceil(cx + reach)));
    for (int dy = ylo; dy <= yhi; ++dy)
      for (int dx = xlo; dx <= xhi; ++dx)
        if ((dx - cx) * (dx - cx) + (dy - cy) * (dy - cy) < reach * reach)
          (*mask)[static_cast<size_t>(dy + h) * stride + (dx + h)] = 0.0f;
  }
  return any;
}

cv::Matx44d TextureTracker::normalOf(const Template& t, const std::vector<float>& mask) const
{
  cv::Matx44d normal = cv::Matx44d::zeros();
  for (size_t k = 0; k < mask.size(); ++k)
    if (mask[k] > 0.0f)
    {
      const cv::Vec4d j(t.gx[k], t.gy[k], -t.value[k], -1.0);
      normal += j * j.t();
    }
  return normal;
}

void TextureTracker::buildTemplates(const cv::Mat& roi_image, const std::vector<cv::Point2f>& dots)
{
  templates_.assign(features_.size(), Template());
  if (!config_.photometric_refinement)
    return;
  const int h = config_.refinement_window_px / 2;
  const int width = 2 * h + 1, stride = paddedWidth(width);
  for (size_t i = 0; i < features_.size(); ++i)
  {
    // Features sit on whole pixels (goodFeaturesToTrack), so the template is
    // read without interpolation.
    const int x0 = cvRound(features_[i].x) - roi_.x, y0 = cvRound(features_[i].y) - roi_.y;
    if (x0 - h - 1 < 0 || y0 - h - 1 < 0 || x0 + h + 1 >= roi_image.cols || y0 + h + 1 >= roi_image.rows)
      continue;
    Template& t = templates_[i];
    const size_t n = static_cast<size_t>(width) * stride;
    t.value.assign(n, 0.0f);
    t.gx.assign(n, 0.0f);
    t.gy.assign(n, 0.0f);
    t.mask.assign(n, 0.0f);
    for (int dy = -h; dy <= h; ++dy)
    {
      const uint8_t* row = roi_image.ptr<uint8_t>(y0 + dy);
      const uint8_t* up = roi_image.ptr<uint8_t>(y0 + dy - 1);
      const uint8_t* down = roi_image.ptr<uint8_t>(y0 + dy + 1);
      for (int dx = -h; dx <= h; ++dx)
      {
        const size_t k = static_cast<size_t>(dy + h) * stride + (dx + h);
        const int x = x0 + dx;
        t.value[k] = row[x];
        t.gx[k] = 0.5f * (static_cast<float>(row[x + 1]) - static_cast<float>(row[x - 1]));
        t.gy[k] = 0.5f * (static_cast<float>(down[x]) - static_cast<float>(up[x]));
        t.mask[k] = 1.0f;
      }
    }
    // The reference's own dots are not rock texture either.
    maskDots(dots, features_[i], &t.mask);
    const cv::Matx44d normal = normalOf(t, t.mask);
    bool invertible = false;
    t.inverse_normal = normal.inv(cv::DECOMP_CHOLESKY, &invertible);
    t.ok = invertible && cv::determinant(normal) > 0.0;
  }
}

bool TextureTracker::refine(size_t i, const cv::Mat& image, const std::vector<float>& mask,
                            const cv::Matx44d& inverse_normal, cv::Point2f* p) const
{
  const Template& t = templates_[i];
  const int h = config_.refinement_window_px / 2;
  const int width = 2 * h + 1, stride = paddedWidth(width);
  const cv::Point2f start = *p;
  double qx = p->x, qy = p->y;
  for (int it = 0; it < config_.refinement_iterations; ++it)
  {
    const int x0 = static_cast<int>(std::floor(qx)), y0 = static_cast<int>(std::floor(qy));
    if (x0 - h < 0 || y0 - h < 0 || x0 - h + stride + 1 >= image.cols || y0 + h + 1 >= image.rows)
      return false;
    // Integer window offsets: the bilinear weights are the same for every sample.
    const float fx = static_cast<float>(qx - x0), fy = static_cast<float>(qy - y0);
    const float w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
    // Residual r = I(q + xi) - T(xi). The model I = a T + b is linear in a
    // and b, so each pass solves for them afresh (from a = 1, b = 0)
    // together with the shift increment.
    float a0[kLanes] = {}, a1[kLanes] = {}, a2[kLanes] = {}, a3[kLanes] = {};
    for (int dy = 0; dy < width; ++dy)
    {
      const float* r0 = image.ptr<float>(y0 - h + dy) + (x0 - h);
      const float* r1 = image.ptr<float>(y0 - h + dy + 1) + (x0 - h);
      const float* T = &t.value[static_cast<size_t>(dy) * stride];
      const float* GX = &t.gx[static_cast<size_t>(dy) * stride];
      const float* GY = &t.gy[static_cast<size_t>(dy) * stride];
      const float* M = &mask[static_cast<size_t>(dy) * stride];
      for (int c = 0; c < stride; c += kLanes)
        for (int l = 0; l < kLanes; ++l)
        {
          const int x = c + l;
          const float v = w00 * r0[x] + w01 * r0[x + 1] + w10 * r1[x] + w11 * r1[x + 1];
          const float r = M[x] * (v - T[x]);
          a0[l] += GX[x] * r;
          a1[l] += GY[x] * r;
          a2[l] += T[x] * r;
          a3[l] += r;
        }
    }
    double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
    for (int l = 0; l < kLanes; ++l)
    {
      s0 += a0[l];
      s1 += a1[l];
      s2 += a2[l];
      s3 += a3[l];
    }
    const cv::Vec4d step = -(inverse_normal * cv::Vec4d(s0, s1, -s2, -s3));
    // The step is taken along the template's gradient; the image's is the
    // gain a = 1 + step[2] times that.
    const double gain = 1.0 + step[2];
    const double sx = step[0] / std::max(gain, 0.5), sy = step[1] / std::max(gain, 0.5);
    qx += sx;
    qy += sy;
    if (std::hypot(qx - start.x, qy - start.y) > config_.max_refinement_px)
      return false;
    if (sx * sx + sy * sy < 1e-4)  // 0.01 px: well below the noise of one feature
      break;
  }
  *p = cv::Point2f(static_cast<float>(qx), static_cast<float>(qy));
  return true;
}

void TextureTracker::clear()
{
  features_.clear();
  templates_.clear();
  frame_.release();
  frame_float_.release();
  frame_pyramid_.clear();
  reference_pyramid_.clear();
  roi_ = cv::Rect();
}

std::vector<cv::Point2f> TextureTracker::findCorners(const cv::Mat& image, const cv::Mat& mask) const
{
  std::vector<cv::Point2f> corners;
  if (!(config_.photometric_refinement && config_.min_distance_px >= 4.0))
  {
    cv::goodFeaturesToTrack(image, corners, config_.max_features, config_.quality, config_.min_distance_px, mask, 5);
    return corners;
  }
  // Corners for a large refinement window are found as well at half
  // resolution, at a quarter of the cost (the whole image is ~20 ms at full
  // resolution, and frame_to_frame mode selects on every frame).
  cv::Mat half, half_mask;
  cv::pyrDown(image, half);
  cv::resize(mask, half_mask, half.size(), 0, 0, cv::INTER_NEAREST);
  cv::goodFeaturesToTrack(half, corners, config_.max_features, config_.quality, 0.5 * config_.min_distance_px,
                          half_mask, 3);
  for (cv::Point2f& c : corners)
    c = cv::Point2f(static_cast<float>(std::min(2 * cvRound(c.x), image.cols - 1)),
                    static_cast<float>(std::min(2 * cvRound(c.y), image.rows - 1)));
  return corners;
}

int TextureTracker::setReference(const cv::Mat& image, int channel, const cv::Rect& region,
                                 const std::vector<cv::Point2f>& dots)
{
  clear();
  if (image.empty() || (image.type() != CV_8UC1 && image.type() != CV_8UC3))
    return 0;
  image_size_ = image.size();
  const cv::Rect full(0, 0, image.cols, image.rows);
  const int half = windowHalf();
  // Features need a whole window inside the image.
  const cv::Rect inner(half, half, std::max(0, image.cols - 2 * half), std::max(0, image.rows - 2 * half));
  const cv::Rect feature_region = region & inner;
  if (feature_region.area() <= 0)
    return 0;
  const int m = config_.roi_margin_px;
  roi_ = cv::Rect(feature_region.x - m, feature_region.y - m, feature_region.width + 2 * m,
                  feature_region.height + 2 * m) &
         full;

  // Mask out the dots so that no corner is a dot's edge.
  cv::Mat mask(feature_region.size(), CV_8UC1, cv::Scalar(255));
  for (const cv::Point2f& d : dots)
    cv::circle(mask, cv::Point(cvRound(d.x - feature_region.x), cvRound(d.y - feature_region.y)),
               static_cast<int>(std::ceil(config_.dot_clearance_px)), cv::Scalar(0), cv::FILLED);
  const cv::Mat roi_image = prepare(image, channel, roi_);
  if (roi_image.empty())
  {
    clear();
    return 0;
  }
  const cv::Rect in_roi(feature_region.x - roi_.x, feature_region.y - roi_.y, feature_region.width,
                        feature_region.height);
  for (const cv::Point2f& c : findCorners(roi_image(in_roi), mask))
  {
    const cv::Point2f p(c.x + feature_region.x, c.y + feature_region.y);
    if (!nearDot(p, dots))
      features_.push_back(p);
  }
  if (features_.empty())
  {
    clear();
    return 0;
  }
  const cv::Size win(config_.window_px, config_.window_px);
  // With the refinement to follow, pyramidal tracking only has to land
  // within a pixel: it runs at half resolution, a quarter of the cost.
  if (config_.photometric_refinement)
  {
    cv::Mat half;
    cv::pyrDown(roi_image, half);
    cv::buildOpticalFlowPyramid(half, reference_pyramid_, win, std::max(config_.pyramid_levels - 1, 0), true);
  }
  else
    cv::buildOpticalFlowPyramid(roi_image, reference_pyramid_, win, config_.pyramid_levels, true);
  buildTemplates(roi_image, dots);
  return static_cast<int>(features_.size());
}

void TextureTracker::retain(const std::vector<uint8_t>& keep)
{
  std::vector<cv::Point2f> kept;
  std::vector<Template> kept_templates;
  for (size_t i = 0; i < features_.size() && i < keep.size(); ++i)
    if (keep[i])
    {
      kept.push_back(features_[i]);
      if (i < templates_.size())
        kept_templates.push_back(std::move(templates_[i]));
    }
  features_.swap(kept);
  templates_.swap(kept_templates);
  if (features_.empty())
    clear();
}

bool TextureTracker::setFrame(const cv::Mat& image, int channel)
{
  frame_.release();
  frame_float_.release();
  frame_pyramid_.clear();
  if (features_.empty() || image.empty() || image.size() != image_size_)
    return false;
  frame_ = prepare(image, channel, roi_);
  if (!frame_.empty() && config_.photometric_refinement)
    frame_.convertTo(frame_float_, CV_32F);  // the refinement's sums vectorise on floats
  return !frame_.empty();
}

bool TextureTracker::accept(const cv::Point2f& p, const std::vector<cv::Point2f>& dots, cv::Point2f* full) const
{
  const float half = static_cast<float>(windowHalf());
  if (!(p.x >= half && p.y >= half && p.x <= roi_.width - 1 - half && p.y <= roi_.height - 1 - half))
    return false;
  *full = cv::Point2f(p.x + roi_.x, p.y + roi_.y);
  return !nearDot(*full, dots);
}

int TextureTracker::trackPyramidal(const std::vector<cv::Point2f>& predicted, const std::vector<uint8_t>& which,
                                   const std::vector<cv::Point2f>& dots, std::vector<cv::Point2f>* tracked,
                                   std::vector<uint8_t>* ok)
{
  const size_t n = features_.size();
  tracked->assign(n, cv::Point2f(NAN, NAN));
  ok->assign(n, 0);
  if (frame_.empty() || predicted.size() != n || (!which.empty() && which.size() != n))
    return 0;
  const cv::Point2f offset(static_cast<float>(roi_.x), static_cast<float>(roi_.y));
  // Pixel centres at integers: x_half = (x + 0.5) / 2 - 0.5.
  const bool half = config_.photometric_refinement;
  const float scale = half ? 0.5f : 1.0f, shift = half ? -0.25f : 0.0f;
  std::vector<size_t> index;
  std::vector<cv::Point2f> prev, next;
  for (size_t i = 0; i < n; ++i)
  {
    if (!which.empty() && !which[i])
      continue;
    index.push_back(i);
    const cv::Point2f& p = predicted[i];
    const cv::Point2f from = features_[i] - offset, to = std::isfinite(p.x) && std::isfinite(p.y) ? p - offset : from;
    prev.emplace_back(from.x * scale + shift, from.y * scale + shift);
    next.emplace_back(to.x * scale + shift, to.y * scale + shift);
  }
  if (index.empty())
    return 0;
  const cv::Size win(config_.window_px, config_.window_px);
  const int levels = half ? std::max(config_.pyramid_levels - 1, 0) : config_.pyramid_levels;
  if (frame_pyramid_.empty())
  {
    if (half)
    {
      cv::Mat down;
      cv::pyrDown(frame_, down);
      cv::buildOpticalFlowPyramid(down, frame_pyramid_, win, levels, false);
    }
    else
      cv::buildOpticalFlowPyramid(frame_, frame_pyramid_, win, levels, false);
  }
  std::vector<uchar> status;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(reference_pyramid_, frame_pyramid_, prev, next, status, err, win, levels,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 10, 0.01),
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  int good = 0;
  for (size_t k = 0; k < index.size(); ++k)
  {
    cv::Point2f full;
    const cv::Point2f at((next[k].x - shift) / scale, (next[k].y - shift) / scale);
    if (!status[k] || !(err[k] <= config_.max_error) || !accept(at, dots, &full))
      continue;
    (*tracked)[index[k]] = full;
    (*ok)[index[k]] = 1;
    ++good;
  }
  return good;
}

int TextureTracker::refineAll(const std::vector<cv::Point2f>& predicted, const std::vector<cv::Point2f>& dots,
                              std::vector<cv::Point2f>* tracked, std::vector<uint8_t>* ok) const
{
  const size_t n = features_.size();
  tracked->assign(n, cv::Point2f(NAN, NAN));
  ok->assign(n, 0);
  if (frame_.empty() || predicted.size() != n || templates_.size() != n)
    return 0;
  const cv::Point2f offset(static_cast<float>(roi_.x), static_cast<float>(roi_.y));
  std::vector<float> local_mask;
  int good = 0;
  for (size_t i = 0; i < n; ++i)
  {
    cv::Point2f p = predicted[i] - offset, full;
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !accept(p, dots, &full))
      continue;  // a feature centred on a dot has lost its own texture
    const Template& t = templates_[i];
    if (!t.ok)
      continue;
    // This frame's dots in the window get no weight either.
    local_mask = t.mask;
    const bool masked = maskDots(dots, predicted[i], &local_mask);
    cv::Matx44d inverse_normal = t.inverse_normal;
    if (masked)
    {
      bool invertible = false;
      inverse_normal = normalOf(t, local_mask).inv(cv::DECOMP_CHOLESKY, &invertible);
      if (!invertible)
        continue;
    }
    if (!refine(i, frame_float_, masked ? local_mask : t.mask, inverse_normal, &p) || !accept(p, dots, &full))
      continue;
    (*tracked)[i] = full;
    (*ok)[i] = 1;
    ++good;
  }
  return good;
}

}  // namespace structured_light_stabilizer
