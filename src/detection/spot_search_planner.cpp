// SpotSearchPlanner: the regions of the next frame where dots can be (see
// spot_search_planner.h for the geometry behind it).
#include "structured_light_stabilizer/detection/spot_search_planner.h"

#include <algorithm>
#include <cmath>

namespace structured_light_stabilizer
{

namespace
{
constexpr double kSigmaWindows = 4.0;  // a dot's window: 4 sigma each side (the refinement uses 3)
constexpr double kDefaultSigma = 4.0;  // px, a dot of unknown size (the baseline reports none)

// Regions start and end on multiples of this many pixels (or at the frame's
// edge): a Bayer cell and a yuv422 pixel pair stay whole, and so do the fast
// method's coarse blocks (4 cells: 8 px on a Bayer mosaic), so that a
// region's blocks are the whole frame's and the region finds what a full
// search finds there.
constexpr int kAlign = 8;

// `r` widened to aligned coordinates and clipped to the frame.
cv::Rect alignedClip(const cv::Rect& r, const cv::Size& frame)
{
  const int x0 = std::max(0, r.x) / kAlign * kAlign, y0 = std::max(0, r.y) / kAlign * kAlign;
  const int x1 = std::min(frame.width, (r.x + r.width + kAlign - 1) / kAlign * kAlign);
  const int y1 = std::min(frame.height, (r.y + r.height + kAlign - 1) / kAlign * kAlign);
  return x1 > x0 && y1 > y0 ? cv::Rect(x0, y0, x1 - x0, y1 - y0) : cv::Rect();
}

// Whether one box over both wastes little: at most a quarter more pixels
// than the two cover (each region costs a call; a merged box, its pixels).
bool worthMerging(const cv::Rect& a, const cv::Rect& b)
{
  const double cover = static_cast<double>(a.area()) + b.area() - (a & b).area();
  return (a | b).area() <= 1.25 * cover;
}
}  // namespace

std::string SpotSearchParams::validate() const
{
  if (!std::isfinite(track_margin_px) || track_margin_px < 0 || track_margin_px > 1000)
    return "search track_margin_px " + std::to_string(track_margin_px) + " out of [0, 1000]";
  if (track_band_rows < 0)
    return "search track_band_rows " + std::to_string(track_band_rows) + " is negative";
  if (full_search_every < 0)
    return "full_search_every " + std::to_string(full_search_every) + " is negative";
  return std::string();
}

std::vector<std::string> SpotSearchParams::sanitize()
{
  std::vector<std::string> changes;
  if (!std::isfinite(track_margin_px) || track_margin_px < 0 || track_margin_px > 1000)
  {
    changes.push_back("search track_margin_px " + std::to_string(track_margin_px) + " out of [0, 1000]: 8 used");
    track_margin_px = 8.0;
  }
  if (track_band_rows < 0)
  {
    changes.push_back("search track_band_rows " + std::to_string(track_band_rows) + " negative: 0 used (no band)");
    track_band_rows = 0;
  }
  if (full_search_every < 0)
  {
    changes.push_back("full_search_every " + std::to_string(full_search_every) + " negative: 0 used");
    full_search_every = 0;
  }
  return changes;
}

std::vector<cv::Rect> mergeSearchRegions(const std::vector<cv::Rect>& regions, const cv::Size& frame)
{
  std::vector<cv::Rect> out;
  out.reserve(regions.size());
  for (const cv::Rect& r : regions)
  {
    const cv::Rect c = alignedClip(r, frame);
    if (c.area() > 0)
      out.push_back(c);
  }
  // Merge pairs into their bounding box where that wastes little, until no
  // pair is worth it, always the first such pair (i, j) in the order of the
  // list. A merged box can reach further boxes, but only pairs with the grown
  // box i can have become worth merging: those before it are looked at first
  // (the first pair in order), then i's pairs after it again. The same boxes
  // as starting over after each merge, in about n^2 / 2 tests and n more per
  // merge instead of n^2 / 2 per merge (a planner's band merges with ten
  // dots' windows).
  // Regions may still overlap: SpotDetector::detectIn keeps one of a dot
  // found twice.
  const auto erase = [&out](size_t k) { out.erase(out.begin() + static_cast<std::ptrdiff_t>(k)); };
  size_t i = 0;
  while (i < out.size())
  {
    size_t j = i + 1;
    while (j < out.size() && !worthMerging(out[i], out[j]))
      ++j;
    if (j == out.size())
    {
      ++i;
      continue;
    }
    out[i] |= out[j];
    erase(j);
    for (size_t k = 0; k < i;)  // i grew: a box before it may now take it
    {
      if (!worthMerging(out[k], out[i]))
      {
        ++k;
        continue;
      }
      out[k] |= out[i];
      erase(i);
      i = k;
      k = 0;
    }
  }
  std::sort(out.begin(), out.end(),
            [](const cv::Rect& a, const cv::Rect& b) { return a.y != b.y ? a.y < b.y : a.x < b.x; });
  return out;
}

SpotSearchPlanner::SpotSearchPlanner(const SpotSearchParams& params)
{
  setParams(params);
}

std::vector<std::string> SpotSearchPlanner::setParams(const SpotSearchParams& params)
{
  params_ = params;
  std::vector<std::string> changes = params_.sanitize();
  reset();
  return changes;
}

void SpotSearchPlanner::reset()
{
  need_full_ = true;
  full_reason_ = "start";
  dots_.clear();
  radius_.clear();
}

void SpotSearchPlanner::requestFullSearch(const std::string& why)
{
  if (need_full_)
    return;  // the reason already given stays
  need_full_ = true;
  full_reason_ = why;
}

std::vector<cv::Rect> SpotSearchPlanner::plan(const cv::Size& frame)
{
  ++frames_;
  if (frame != frame_)
  {
    frame_ = frame;
    need_full_ = true;
    full_reason_ = "frame size " + std::to_string(frame.width) + "x" + std::to_string(frame.height);
  }
  if (params_.full_search_every > 0 && since_full_ + 1 >= params_.full_search_every && !need_full_)
  {
    need_full_ = true;
    full_reason_ = "every " + std::to_string(params_.full_search_every) + " frames";
  }
  last_full_ = !params_.track || need_full_;
  if (last_full_)
  {
    ++full_searches_;
    since_full_ = 0;
    return {};
  }
  ++since_full_;
  std::vector<cv::Rect> regions;
  regions.reserve(dots_.size() + 1);
  for (size_t i = 0; i < dots_.size(); ++i)
  {
    const int h = static_cast<int>(std::ceil(radius_[i] + params_.track_margin_px));
    regions.emplace_back(static_cast<int>(std::floor(dots_[i].x)) - h, static_cast<int>(std::floor(dots_[i].y)) - h,
                         2 * h + 2, 2 * h + 2);
  }
  if (params_.track_band_rows > 0)
  {
    // Consecutive bands overlap by the reach of a dot's refinement (3 sigma
    // and a pixel, for sigma up to 4 px) on each side, so that a dot cut by
    // one band's edge lies whole inside the next.
    const int bands = std::max(1, (frame.height + params_.track_band_rows - 1) / params_.track_band_rows);
    band_ = (band_ + 1) % bands;
    const int overlap = static_cast<int>(std::ceil(3.0 * kDefaultSigma + 1.0));
    regions.emplace_back(0, band_ * params_.track_band_rows - overlap, frame.width, params_.track_band_rows + 2 * overlap);
  }
  return mergeSearchRegions(regions, frame);
}

void SpotSearchPlanner::update(const SpotDetectionResult& result)
{
  if (!result.ok)
  {
    reset();
    full_reason_ = "refused frame";
    return;
  }
  // Dots of the last frame with no dot of this one within their window.
  size_t lost = 0;
  if (!last_full_)
  {
    for (size_t i = 0; i < dots_.size(); ++i)
    {
      const double reach = radius_[i] + params_.track_margin_px;
      const bool found = std::any_of(
          result.spots.begin(), result.spots.end(),
          [&](const Spot& s) { return std::abs(s.x - dots_[i].x) <= reach && std::abs(s.y - dots_[i].y) <= reach; });
      lost += found ? 0 : 1;
    }
  }
  need_full_ = lost > std::max<size_t>(2, dots_.size() / 10);
  if (need_full_)
    full_reason_ = "lost " + std::to_string(lost) + " of " + std::to_string(dots_.size()) + " dots";
  dots_.clear();
  radius_.clear();
  for (size_t i = 0; i < result.spots.size(); ++i)
  {
    const double sigma =
        i < result.quality.size() && result.quality[i].sigma_px > 0 ? result.quality[i].sigma_px : kDefaultSigma;
    dots_.emplace_back(result.spots[i].x, result.spots[i].y);
    radius_.push_back(kSigmaWindows * sigma + 1.0);
  }
  if (dots_.empty())
  {
    need_full_ = true;
    full_reason_ = "no dot";
  }
}

}  // namespace structured_light_stabilizer
