#include "structured_light_stabilizer/pose/texture_tracker.h"

#include "structured_light_stabilizer/common/cpu_features.h"
#include "pose/texture/pyramid_rows_ssse3.h"

#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "structured_light_stabilizer/common/math.h"

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

bool TextureTracker::readable(const cv::Mat& image)
{
  const int t = image.type();
  return !image.empty() && (t == CV_8UC1 || t == CV_8UC3 || t == CV_16UC1 || t == CV_16UC3);
}

cv::Mat TextureTracker::channelOf(const cv::Mat& image, int channel, const cv::Rect& roi)
{
  if (!readable(image) || (image.channels() == 3 && (channel < 0 || channel > 2)))
    return cv::Mat();
  if (image.type() == CV_8UC1)
    return image(roi);
  cv::Mat out;
  if (image.channels() == 3)
    cv::extractChannel(image(roi), out, channel);
  else
    out = image(roi);
  if (out.depth() == CV_16U)
    out.convertTo(out, CV_8U, k16BitTo8Bit);
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
// Noise is estimated per block of this many pixels (shot noise follows the brightness).
constexpr int kNoiseBlock = 32;
// Immerkaer's operator (the difference of two Laplacians): flat on any
// linear or quadratic brightness, 36 sigma^2 on white noise.
const float kImmerkaer[9] = {1, -2, 1, -2, 4, -2, 1, -2, 1};
}  // namespace

void TextureTracker::clear()
{
  features_.clear();
  levels_.clear();
  templates_.clear();
  frame_.release();
  frame_ok_ = false;
  frame_levels_.clear();
  frame_pyramid_.clear();
  frame_pyramid_ready_ = false;
  warp_cache_.clear();
  reference_pyramid_.clear();
  reference_levels_.clear();
  noise_map_.release();
  reference_noise_ = 0.0;
  used_levels_ = 0;
  roi_ = cv::Rect();
}

// J. Immerkaer, "Fast noise variance estimation", CVIU 64(2), 1996, with the
// median of the absolute response per block instead of the mean: the dots and
// the edges of the texture, a small part of each block, then barely count.
void TextureTracker::estimateNoise(const cv::Mat& roi_image)
{
  cv::Mat response;
  cv::filter2D(roi_image, response, CV_32F, cv::Mat(3, 3, CV_32F, const_cast<float*>(kImmerkaer)));
  response = cv::abs(response);
  const int bx = (roi_image.cols + kNoiseBlock - 1) / kNoiseBlock,
            by = (roi_image.rows + kNoiseBlock - 1) / kNoiseBlock;
  noise_map_.create(by, bx, CV_32F);
  std::vector<float> block, all;
  for (int j = 0; j < by; ++j)
    for (int i = 0; i < bx; ++i)
    {
      const cv::Rect r = cv::Rect(i * kNoiseBlock, j * kNoiseBlock, kNoiseBlock, kNoiseBlock) &
                         cv::Rect(1, 1, roi_image.cols - 2, roi_image.rows - 2);
      block.clear();
      for (int y = r.y; y < r.y + r.height; ++y)
        block.insert(block.end(), response.ptr<float>(y) + r.x, response.ptr<float>(y) + r.x + r.width);
      // |N(0, 6 sigma)| has its median at 0.6745 * 6 sigma.
      const float sigma = block.empty() ? 0.0f : detail::median(block) / (6.0f * 0.6745f);
      noise_map_.at<float>(j, i) = sigma;
      all.push_back(sigma);
    }
  reference_noise_ = detail::median(all);
}

double TextureTracker::noiseAt(const cv::Point2f& roi_point) const
{
  if (noise_map_.empty())
    return 0.0;
  const int i = std::min(std::max(static_cast<int>(roi_point.x) / kNoiseBlock, 0), noise_map_.cols - 1);
  const int j = std::min(std::max(static_cast<int>(roi_point.y) / kNoiseBlock, 0), noise_map_.rows - 1);
  return noise_map_.at<float>(j, i);
}

// The `roi` part of `image`'s channel (one pass for bgr8) as CV_32F, lightly
// blurred when asked.
bool TextureTracker::floatChannel(const cv::Mat& image, int channel, const cv::Rect& roi, cv::Mat* scratch,
                                  cv::Mat* out) const
{
  if (!readable(image) || (image.channels() == 3 && (channel < 0 || channel > 2)))
    return false;
  const double scale = image.depth() == CV_16U ? k16BitTo8Bit : 1.0;  // 8-bit DN, unrounded
  if (image.channels() == 3)
  {
    cv::extractChannel(image(roi), *scratch, channel);
    scratch->convertTo(*out, CV_32F, scale);
  }
  else
    image(roi).convertTo(*out, CV_32F, scale);
  if (config_.smooth_sigma_px > 0.0)
    cv::GaussianBlur(*out, *out, cv::Size(0, 0), config_.smooth_sigma_px);
  return true;
}

namespace
{
int reflect101(int i, int n)
{
  return i < 0 ? -i : (i >= n ? 2 * n - 2 - i : i);
}

// One cv::pyrDown step from one 8-bit channel of `image`'s `roi` (CN
// interleaved channels) straight to CV_32F: the same 5-tap binomial kernel
// and reflected border, without rounding the result to whole 8-bit levels
// (at level 1 that rounding would add 0.29 DN of noise to the 0.3 DN the
// sensor leaves), without a full-resolution float copy and without
// extracting the channel into a full-frame plane first. The vertical sums
// run over whole interleaved rows (they vectorise); all sums are exact
// integers (of 16 bits for 8-bit pixels, of 32 for 16-bit ones). *sums is
// one row of them, kept from frame to frame. Output in 8-bit DN: 16-bit
// pixels (MSB-aligned, the ROS convention) are scaled by 255/65535.
template <int CN, typename T, typename Sum>
void pyrDownToFloat(const cv::Mat& image, int channel, const cv::Rect& roi, std::vector<Sum>* sums, cv::Mat* dst)
{
  const int W = roi.width, H = roi.height, w = (W + 1) / 2, h = (H + 1) / 2, n = W * CN;
  dst->create(h, w, CV_32F);
  sums->resize(static_cast<size_t>(n));
  Sum* c = sums->data();
  const size_t first = static_cast<size_t>(roi.x) * CN;
  const float scale = (1.0f / 256.0f) * (sizeof(T) == 2 ? static_cast<float>(TextureTracker::k16BitTo8Bit) : 1.0f);
  // One row of the channel's vertical sums by column parity (exact: below
  // 2^31 for 16-bit pixels); kept per thread.
  thread_local std::vector<int32_t> split;
  split.resize(static_cast<size_t>(2 * w));
  int32_t* even = split.data();
  int32_t* odd = even + w;
  // A column's sum (reflected at the borders) from the split rows.
  auto col = [&](int x)
  {
    const int j = std::min(std::max(reflect101(x, W), 0), W - 1);
    return (j & 1) ? odd[j >> 1] : even[j >> 1];
  };
  const bool ssse3 = CN == 3 && sizeof(T) == 1 && haveSsse3Kernels();
  for (int y = 0; y < h; ++y)
  {
    const T* r0 = image.ptr<T>(roi.y + reflect101(2 * y - 2, H)) + first;
    const T* r1 = image.ptr<T>(roi.y + reflect101(2 * y - 1, H)) + first;
    const T* r2 = image.ptr<T>(roi.y + 2 * y) + first;
    const T* r3 = image.ptr<T>(roi.y + reflect101(2 * y + 1, H)) + first;
    const T* r4 = image.ptr<T>(roi.y + reflect101(2 * y + 2, H)) + first;
    // The channel's sums split into even and odd columns, contiguous, so
    // that the horizontal taps of the interior outputs (2x - 2 >= 0,
    // 2x + 2 < W) vectorise: e[x-1] + e[x+1] + 4 (o[x-1] + o[x]) + 6 e[x].
    // bgr8 with SSSE3: the channel's bytes shuffled out of 16 pixels at a
    // time, and only its sums taken; the columns after them as below.
    int done = 0;
    if (ssse3)
    {
      const uint8_t* const rows[5] = {reinterpret_cast<const uint8_t*>(r0), reinterpret_cast<const uint8_t*>(r1),
                                      reinterpret_cast<const uint8_t*>(r2), reinterpret_cast<const uint8_t*>(r3),
                                      reinterpret_cast<const uint8_t*>(r4)};
      done = pyramid_rows::channelSums3Ssse3(rows, W, channel, even, odd);
    }
    for (int x = done * CN; x < n; ++x)
      c[x] = static_cast<Sum>(Sum(r0[x]) + r4[x] + 4 * (Sum(r1[x]) + r3[x]) + 6 * Sum(r2[x]));
    for (int i = done / 2; i < w; ++i)
      even[i] = c[2 * i * CN + channel];
    for (int i = done / 2; i < W / 2; ++i)
      odd[i] = c[(2 * i + 1) * CN + channel];
    float* o = dst->ptr<float>(y);
    const int last_inner = (W - 3) / 2;
    for (int x = 1; x <= last_inner; ++x)
      o[x] = static_cast<float>(even[x - 1] + even[x + 1] + 4 * (odd[x - 1] + odd[x]) + 6 * even[x]) * scale;
    for (int x = 0; x < w; x = x == 0 ? std::max(1, last_inner + 1) : x + 1)
    {
      const int xc = 2 * x;
      const uint32_t sum =
          uint32_t(col(xc - 2)) + col(xc + 2) + 4 * (uint32_t(col(xc - 1)) + col(xc + 1)) + 6 * uint32_t(col(xc));
      o[x] = static_cast<float>(sum) * scale;
    }
  }
}
}  // namespace

// The refinement's float levels first_level .. `levels` - 1 of the ROI
// (those below first_level left empty) and, into `half` when given, at half
// resolution (level 1 in 8 bits), the base of the Lucas-Kanade pyramid: with the refinement to
// follow, pyramidal tracking only has to land within a pixel, at a quarter
// of the cost.
bool TextureTracker::buildLevels(const cv::Mat& image, int channel, int first_level, int levels,
                                 std::vector<cv::Mat>* float_levels, cv::Mat* half)
{
  float_levels->resize(static_cast<size_t>(std::max(levels, 2)));
  if (first_level <= 0 || config_.smooth_sigma_px > 0.0)
  {
    if (!floatChannel(image, channel, roi_, &scratch_, &(*float_levels)[0]))
      return false;
    cv::pyrDown((*float_levels)[0], (*float_levels)[1]);
  }
  else
  {
    // The tracked channel is read in place from the caller's image (nothing
    // kept that could alias it once its message is freed).
    (*float_levels)[0].release();
    const bool colour = channel >= 0 && channel <= 2;
    if (image.type() == CV_8UC3 && colour)
      pyrDownToFloat<3, uint8_t>(image, channel, roi_, &row_sums_, &(*float_levels)[1]);
    else if (image.type() == CV_8UC1)
      pyrDownToFloat<1, uint8_t>(image, 0, roi_, &row_sums_, &(*float_levels)[1]);
    else if (image.type() == CV_16UC3 && colour)
      pyrDownToFloat<3, uint16_t>(image, channel, roi_, &row_sums16_, &(*float_levels)[1]);
    else if (image.type() == CV_16UC1)
      pyrDownToFloat<1, uint16_t>(image, 0, roi_, &row_sums16_, &(*float_levels)[1]);
    else
      return false;
  }
  for (size_t l = 2; l < float_levels->size(); ++l)
    cv::pyrDown((*float_levels)[l - 1], (*float_levels)[l]);
  if (half)
    (*float_levels)[1].convertTo(*half, CV_8U);
  return true;
}

// Corners for windows on `level`, found on the level above (a quarter of the
// pixels; the whole image at full resolution costs ~20 ms) and returned in
// full-image pixels, on whole pixels of `level`.
std::vector<cv::Point2f> TextureTracker::findCorners(int level, const cv::Rect& feature_region,
                                                     const std::vector<cv::Point2f>& dots) const
{
  const int search = std::min(level + 1, static_cast<int>(reference_levels_.size()) - 1);
  const double to_search = 1.0 / static_cast<double>(1 << search);
  const cv::Mat& image = reference_levels_[static_cast<size_t>(search)];
  const cv::Rect region =
      cv::Rect(cvCeil((feature_region.x - roi_.x) * to_search), cvCeil((feature_region.y - roi_.y) * to_search),
               cvFloor(feature_region.width * to_search), cvFloor(feature_region.height * to_search)) &
      cv::Rect(0, 0, image.cols, image.rows);
  std::vector<cv::Point2f> corners, out;
  if (region.area() <= 0)
    return out;
  // Mask out the dots so that no corner is a dot's edge.
  cv::Mat mask(region.size(), CV_8UC1, cv::Scalar(255));
  const int radius = cvCeil(config_.dot_clearance_px * to_search) + 1;
  for (const cv::Point2f& d : dots)
    cv::circle(
        mask, cv::Point(cvRound((d.x - roi_.x) * to_search) - region.x, cvRound((d.y - roi_.y) * to_search) - region.y),
        radius, cv::Scalar(0), cv::FILLED);
  const double min_distance = std::max(1.0, config_.min_distance_px * to_search);
  cv::goodFeaturesToTrack(image(region), corners, config_.max_features, config_.quality, min_distance, mask, 3);
  const float scale = static_cast<float>(1 << search);
  for (const cv::Point2f& c : corners)
    out.emplace_back((c.x + region.x) * scale + roi_.x, (c.y + region.y) * scale + roi_.y);
  return out;
}

// Every corner of every level whose window carries texture clearly above
// the noise, with the 1-sigma its shift would have.
std::vector<TextureTracker::Candidate> TextureTracker::candidates(const std::vector<cv::Point2f>& dots,
                                                                  const cv::Rect& feature_region) const
{
  std::vector<Candidate> pool;
  const int top = config_.photometric_refinement ? config_.max_level : 0;
  Template t;
  for (int level = std::min(config_.min_level, top); level <= top; ++level)
    for (const cv::Point2f& p : findCorners(level, feature_region, dots))
    {
      if (nearDot(p, dots) || !buildTemplate(p, level, dots, &t))
        continue;
      const Information info = information(t, level);
      if (info.signal_min >= config_.min_snr * info.noise_energy && info.sigma_px <= config_.max_sigma_px)
        pool.push_back({p, level, info.sigma_px});
    }
  return pool;
}

// The candidates that carry the most information per area of rock first
// (a window of level L spans 4^L times the area of a level-0 one, and keeps
// others away from it: four fine windows of 1-sigma s are worth one coarse
// window of s / 2), each at least min_distance_px and half the larger window
// from those already chosen (overlapping windows share their errors).
void TextureTracker::choose(std::vector<Candidate> pool)
{
  std::stable_sort(pool.begin(), pool.end(),
                   [](const Candidate& a, const Candidate& b)
                   { return a.sigma_px * (1 << a.level) < b.sigma_px * (1 << b.level); });
  const double window = config_.photometric_refinement ? config_.refinement_window_px : config_.window_px;
  for (const Candidate& c : pool)
  {
    if (static_cast<int>(features_.size()) >= config_.max_features)
      break;
    bool apart = true;
    for (size_t k = 0; k < features_.size() && apart; ++k)
    {
      const double spacing = std::max(config_.min_distance_px, 0.5 * window * (1 << std::max(c.level, levels_[k])));
      const cv::Point2f d = c.position - features_[k];
      apart = d.x * d.x + d.y * d.y >= spacing * spacing;
    }
    if (!apart)
      continue;
    features_.push_back(c.position);
    levels_.push_back(c.level);
  }
}

int TextureTracker::setReference(const cv::Mat& image, int channel, const cv::Rect& region,
                                 const std::vector<cv::Point2f>& dots)
{
  clear();
  if (!readable(image))
    return 0;
  image_size_ = image.size();
  const cv::Rect full(0, 0, image.cols, image.rows);
  const int half = windowHalf(0);
  // Features need a whole window inside the image.
  const cv::Rect inner(half, half, std::max(0, image.cols - 2 * half), std::max(0, image.rows - 2 * half));
  const cv::Rect feature_region = region & inner;
  if (feature_region.area() <= 0)
    return 0;
  const int m = config_.roi_margin_px;
  roi_ = cv::Rect(feature_region.x - m, feature_region.y - m, feature_region.width + 2 * m,
                  feature_region.height + 2 * m) &
         full;
  const cv::Mat roi_image = prepare(image, channel, roi_);
  if (roi_image.empty())
  {
    clear();
    return 0;
  }
  // The noise of what the refinement reads: a 16-bit image unrounded (its
  // 8-bit rounding would add 0.29 levels RMS that the float levels lack).
  cv::Mat unrounded;
  if (image.depth() == CV_16U && floatChannel(image, channel, roi_, &scratch_, &unrounded))
    estimateNoise(unrounded);
  else
    estimateNoise(roi_image);
  const cv::Size win(config_.window_px, config_.window_px);
  if (config_.photometric_refinement)
  {
    // Levels up to max_level + 1: the last one only to find corners for the one below.
    cv::Mat half;
    // Level 0 too at the lock: corners for level-0 windows are found on level 1 of it.
    if (!buildLevels(image, channel, 0, config_.max_level + 2, &reference_levels_, &half))
    {
      clear();
      return 0;
    }
    cv::buildOpticalFlowPyramid(half, reference_pyramid_, win, std::max(config_.pyramid_levels - 1, 0), true);
  }
  else
  {
    cv::Mat half;
    if (!buildLevels(image, channel, 0, 2, &reference_levels_, &half))
    {
      clear();
      return 0;
    }
    cv::buildOpticalFlowPyramid(roi_image, reference_pyramid_, win, config_.pyramid_levels, true);
  }
  if (config_.photometric_refinement)
    choose(candidates(dots, feature_region));
  else
    for (const cv::Point2f& p : findCorners(0, feature_region, dots))
      if (!nearDot(p, dots) && static_cast<int>(features_.size()) < config_.max_features)
      {
        features_.push_back(p);
        levels_.push_back(0);
      }
  templates_.assign(features_.size(), Template());
  first_level_ = config_.max_level;
  for (size_t i = 0; i < features_.size() && config_.photometric_refinement; ++i)
  {
    buildTemplate(features_[i], levels_[i], dots, &templates_[i]);
    used_levels_ = std::max(used_levels_, levels_[i] + 1);
    first_level_ = std::min(first_level_, levels_[i]);
  }
  // Warped templates are sampled from the levels in use.
  reference_levels_.resize(static_cast<size_t>(std::max(used_levels_, 1)));
  if (features_.empty())
    clear();
  return static_cast<int>(features_.size());
}

void TextureTracker::retain(const std::vector<uint8_t>& keep)
{
  std::vector<cv::Point2f> kept;
  std::vector<int> kept_levels;
  std::vector<Template> kept_templates;
  for (size_t i = 0; i < features_.size() && i < keep.size(); ++i)
    if (keep[i])
    {
      kept.push_back(features_[i]);
      kept_levels.push_back(levels_[i]);
      if (i < templates_.size())
        kept_templates.push_back(std::move(templates_[i]));
    }
  features_.swap(kept);
  levels_.swap(kept_levels);
  templates_.swap(kept_templates);
  warp_cache_.clear();
  if (features_.empty())
    clear();
}

bool TextureTracker::setFrame(const cv::Mat& image, int channel)
{
  // The buffers are kept from frame to frame (no allocation once running).
  frame_pyramid_ready_ = false;
  frame_ok_ = false;
  if (features_.empty() || image.empty() || image.size() != image_size_)
    return false;
  // The refinement's sums vectorise on floats; frame_ is the Lucas-Kanade
  // base (half resolution with the refinement).
  if (config_.photometric_refinement)
    frame_ok_ = buildLevels(image, channel, first_level_, used_levels_, &frame_levels_, nullptr);
  else
  {
    frame_ = prepare(image, channel, roi_);
    frame_ok_ = !frame_.empty();
  }
  return frame_ok_;
}

bool TextureTracker::accept(const cv::Point2f& p, int level, const std::vector<cv::Point2f>& dots,
                            cv::Point2f* full) const
{
  const float half = static_cast<float>(windowHalf(level));
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
  if (!frame_ok_ || predicted.size() != n || (!which.empty() && which.size() != n))
    return 0;
  const cv::Point2f offset(static_cast<float>(roi_.x), static_cast<float>(roi_.y));
  // cv::pyrDown centres pixel x of the half image on pixel 2x.
  const bool half = config_.photometric_refinement;
  const float scale = half ? 0.5f : 1.0f;
  std::vector<size_t> index;
  std::vector<cv::Point2f> prev, next;
  for (size_t i = 0; i < n; ++i)
  {
    if (!which.empty() && !which[i])
      continue;
    index.push_back(i);
    const cv::Point2f& p = predicted[i];
    const cv::Point2f from = features_[i] - offset, to = std::isfinite(p.x) && std::isfinite(p.y) ? p - offset : from;
    prev.emplace_back(from.x * scale, from.y * scale);
    next.emplace_back(to.x * scale, to.y * scale);
  }
  if (index.empty())
    return 0;
  const cv::Size win(config_.window_px, config_.window_px);
  const int levels = half ? std::max(config_.pyramid_levels - 1, 0) : config_.pyramid_levels;
  if (!frame_pyramid_ready_)
  {
    // The 8-bit base from the refinement's half level, made only when a
    // pyramidal track needs it (most frames are refined from the motion
    // filter's prediction: no pyramid).
    if (half)
      frame_levels_[1].convertTo(frame_, CV_8U);
    cv::buildOpticalFlowPyramid(frame_, frame_pyramid_, win, levels, false);
    frame_pyramid_ready_ = true;
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
    const cv::Point2f at(next[k].x / scale, next[k].y / scale);
    if (!status[k] || !(err[k] <= config_.max_error) || !accept(at, 0, dots, &full))
      continue;
    (*tracked)[index[k]] = full;
    (*ok)[index[k]] = 1;
    ++good;
  }
  return good;
}

}  // namespace structured_light_stabilizer
