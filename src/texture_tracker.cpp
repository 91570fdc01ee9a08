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

void TextureTracker::clear()
{
  features_.clear();
  reference_pyramid_.clear();
  roi_ = cv::Rect();
}

int TextureTracker::setReference(const cv::Mat& image, int channel, const cv::Rect& region,
                                 const std::vector<cv::Point2f>& dots)
{
  clear();
  if (image.empty() || (image.type() != CV_8UC1 && image.type() != CV_8UC3))
    return 0;
  image_size_ = image.size();
  const cv::Rect full(0, 0, image.cols, image.rows);
  const int half = config_.window_px / 2 + 1;
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
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(roi_image(in_roi), corners, config_.max_features, config_.quality, config_.min_distance_px,
                          mask, 5);
  for (const cv::Point2f& c : corners)
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
  cv::buildOpticalFlowPyramid(roi_image, reference_pyramid_, win, config_.pyramid_levels, true);
  return static_cast<int>(features_.size());
}

void TextureTracker::retain(const std::vector<uint8_t>& keep)
{
  std::vector<cv::Point2f> kept;
  for (size_t i = 0; i < features_.size() && i < keep.size(); ++i)
    if (keep[i])
      kept.push_back(features_[i]);
  features_.swap(kept);
  if (features_.empty())
    clear();
}

int TextureTracker::track(const cv::Mat& image, int channel, const std::vector<cv::Point2f>& predicted,
                          const std::vector<cv::Point2f>& dots, std::vector<cv::Point2f>* tracked,
                          std::vector<uint8_t>* ok) const
{
  const size_t n = features_.size();
  tracked->assign(n, cv::Point2f(NAN, NAN));
  ok->assign(n, 0);
  if (n == 0 || image.empty() || image.size() != image_size_ || predicted.size() != n)
    return 0;
  const cv::Mat roi_image = prepare(image, channel, roi_);
  if (roi_image.empty())
    return 0;

  std::vector<cv::Point2f> prev(n), next(n);
  for (size_t i = 0; i < n; ++i)
  {
    prev[i] = features_[i] - cv::Point2f(static_cast<float>(roi_.x), static_cast<float>(roi_.y));
    const cv::Point2f& p = predicted[i];
    next[i] = std::isfinite(p.x) && std::isfinite(p.y)
                  ? p - cv::Point2f(static_cast<float>(roi_.x), static_cast<float>(roi_.y))
                  : prev[i];
  }
  const cv::Size win(config_.window_px, config_.window_px);
  std::vector<cv::Mat> pyramid;
  cv::buildOpticalFlowPyramid(roi_image, pyramid, win, config_.pyramid_levels, false);
  std::vector<uchar> status;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(reference_pyramid_, pyramid, prev, next, status, err, win, config_.pyramid_levels,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 10, 0.01),
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  const float half = static_cast<float>(config_.window_px / 2 + 1);
  int good = 0;
  for (size_t i = 0; i < n; ++i)
  {
    if (!status[i] || !(err[i] <= config_.max_error))
      continue;
    const cv::Point2f p = next[i];
    if (p.x < half || p.y < half || p.x > roi_.width - 1 - half || p.y > roi_.height - 1 - half)
      continue;
    const cv::Point2f full(p.x + roi_.x, p.y + roi_.y);
    if (nearDot(full, dots))
      continue;
    (*tracked)[i] = full;
    (*ok)[i] = 1;
    ++good;
  }
  return good;
}

}  // namespace structured_light_stabilizer
