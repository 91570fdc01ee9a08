// SpotMethod::kBaseline: the study's detection chain (docs/study.md §2.4),
// stage by stage, with OpenCV calls as it made them. It is the performance
// and accuracy yardstick of the fast method, so it stays faithful to the
// study: do not optimise it.
#include <cstdint>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "detection/method.h"

namespace structured_light_stabilizer
{

namespace
{
class BaselineMethod : public SpotDetectionMethod
{
public:
  SpotDetectionResult detect(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                             const SpotDetectorParams& params, SpotDetectorDebug* debug,
                             SpotDetectorTimings* timings) override;

private:
  const cv::Mat& lowPass(const cv::Mat& image, int kernel);
  int colourMask(const cv::Mat& src, PixelFormat format, const BaselineParams& p, SpotDetectorTimings* tm,
                 StageTimer* timer);
  void opening(int erosions, int dilations);
  Spots weightedCentroids(int regions, int weight_channel, const BaselineParams& p) const;

  // Scratch reused across frames.
  cv::Mat converted_, blurred_, hsv_, mask_, labels_, stats_, centroids_;
};

// The study's chain works on what its camera gave, BGR (or grey): other
// encodings are converted first (counted in the blur stage); the ambient
// frame is not the study's and is ignored.
SpotDetectionResult BaselineMethod::detect(const cv::Mat& image, const cv::Mat& /*ambient*/, PixelFormat format,
                                           const SpotDetectorParams& params, SpotDetectorDebug* debug,
                                           SpotDetectorTimings* timings)
{
  const BaselineParams& p = params.baseline;
  StageTimer timer;
  SpotDetectorTimings tm;
  const bool native = format == PixelFormat::kBgr8 || format == PixelFormat::kRgb8 || format == PixelFormat::kBgra8 ||
                      format == PixelFormat::kRgba8 || format == PixelFormat::kMono8;
  if (format == PixelFormat::kMono16)
    image.convertTo(converted_, CV_8U, 1.0 / 257.0);
  else if (!native)
    converted_ = toBgr(image, format);
  const cv::Mat& frame = native ? image : converted_;
  format = native ? format : (format == PixelFormat::kMono16 ? PixelFormat::kMono8 : PixelFormat::kBgr8);
  const cv::Mat& src = lowPass(frame, p.blur_kernel);
  tm.blur_ms = timer.lap();
  const int weight_channel = colourMask(src, format, p, &tm, &timer);
  opening(p.erosions, p.dilations);
  tm.opening_ms = timer.lap();
  // The study's recursive flood fill visits left/right/up/down: 4-connectivity.
  const int regions = cv::connectedComponentsWithStats(mask_, labels_, stats_, centroids_, 4, CV_32S);
  tm.labelling_ms = timer.lap();
  SpotDetectionResult result;
  result.spots = weightedCentroids(regions, weight_channel, p);
  tm.centroids_ms = timer.lap();
  sortIntoRows(&result.spots, params.projector_cols, params.projector_rows, true);
  tm.sort_ms = timer.lap();

  if (debug)
  {
    debug->mask = mask_.clone();
    debug->candidates = regions - 1;
  }
  if (timings)
    *timings = tm;
  result.ok = true;
  return result;
}

// Low-pass filter; kernel 1 "does nothing" (docs/study.md §2.4.1).
const cv::Mat& BaselineMethod::lowPass(const cv::Mat& image, int kernel)
{
  if (kernel <= 1)
    return image;
  cv::blur(image, blurred_, cv::Size(kernel, kernel));
  return blurred_;
}

// HSV, then inRange into mask_; hsv_ is left holding the centroid weights.
// Returns the weight's channel in hsv_.
int BaselineMethod::colourMask(const cv::Mat& src, PixelFormat format, const BaselineParams& p, SpotDetectorTimings* tm,
                               StageTimer* timer)
{
  if (format == PixelFormat::kMono8)
  {
    // Intensity only: the mask is the V window, the weight is V.
    cv::inRange(src, cv::Scalar(p.v_min), cv::Scalar(p.v_max), mask_);
    hsv_ = src;
    tm->in_range_ms = timer->lap();
    return 0;
  }
  const bool rgb_order = format == PixelFormat::kRgb8 || format == PixelFormat::kRgba8;
  cv::cvtColor(src, hsv_, rgb_order ? cv::COLOR_RGB2HSV : cv::COLOR_BGR2HSV);
  tm->hsv_ms = timer->lap();
  cv::inRange(hsv_, cv::Scalar(p.h_min, p.s_min, p.v_min), cv::Scalar(p.h_max, p.s_max, p.v_max), mask_);
  tm->in_range_ms = timer->lap();
  return p.baseline_weight == BaselineWeight::kSaturation ? 1 : 2;
}

// N erosions then N dilations with a 3x3 rectangle.
void BaselineMethod::opening(int erosions, int dilations)
{
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3));
  if (erosions > 0)
    cv::erode(mask_, mask_, kernel, cv::Point(-1, -1), erosions);
  if (dilations > 0)
    cv::dilate(mask_, mask_, kernel, cv::Point(-1, -1), dilations);
}

// Formulas 2.31-2.32 with I = S (or V), over each region's pixels; regions
// outside [min_area, max_area] are dismissed.
Spots BaselineMethod::weightedCentroids(int regions, int weight_channel, const BaselineParams& p) const
{
  std::vector<double> sw(regions, 0.0), sx(regions, 0.0), sy(regions, 0.0);
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
  Spots spots;
  for (int l = 1; l < regions; ++l)
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
    spots.push_back(s);
  }
  return spots;
}
}  // namespace

std::unique_ptr<SpotDetectionMethod> makeBaselineMethod()
{
  return std::make_unique<BaselineMethod>();
}

}  // namespace structured_light_stabilizer
