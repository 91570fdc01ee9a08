// The seam between SpotDetector and its detection methods (private to the
// core library).
//
// Adding a method: a SpotMethod value and a Params group in spot_detector.h,
// one file spot_detector_<name>.cpp that implements SpotDetectionMethod and a
// factory declared below, and one row in the registry (kMethods in
// spot_detector.cpp), which also gives the method its ~method name.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <string>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/detection/spot_detector.h"

namespace structured_light_stabilizer
{

class SpotDetectionMethod
{
public:
  virtual ~SpotDetectionMethod() = default;

  // image has passed SpotDetector's checks: not empty, the format's depth
  // and channel count; ambient is empty or of the same size and type.
  // params are sanitized. debug and timings (either may be null) arrive
  // reset to their defaults; total_ms is SpotDetector's.
  virtual SpotDetectionResult detect(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                                     const SpotDetectorParams& params, SpotDetectorDebug* debug,
                                     SpotDetectorTimings* timings) = 0;

  // Region search (SpotDetector::detectIn): between beginRegions and
  // endRegions, detect() is called on regions of one frame of `frame` size.
  // A method whose thresholds come from the statistics of a whole frame uses
  // those of the last whole frame it saw, and says here whether it has them
  // (of a frame of that size, recent enough by its own rule: the fast method
  // renews them after 30 region frames); false, with the reason: search the
  // whole frame instead.
  virtual bool regionStatistics(bool /*with_ambient*/, PixelFormat /*format*/, const cv::Size& /*frame*/,
                                const SpotDetectorParams& /*params*/, std::string* /*why*/) const
  {
    return true;
  }
  virtual void beginRegions() {}
  virtual void endRegions() {}
  // New parameters: statistics kept from earlier frames no longer apply.
  virtual void resetStatistics() {}
};

// How far a spot's refinement reached from its centroid (px): 3 sigma of its
// fit and a pixel (the fast method), or its region's radius (the baseline).
inline double reachOf(const Spot& s, const SpotQuality* q)
{
  if (q && q->sigma_px > 0)
    return 3.0 * q->sigma_px + 1.0;
  return std::sqrt(std::max(1.0f, s.area) / detail::kPi) + 1.0;
}

// Whether a spot found in `region` had its window cut by an edge of the
// region that is not the frame's (SpotDetector::detectIn leaves it out).
inline bool cutByRegion(const Spot& s, double reach, const cv::Rect& region, const cv::Size& frame)
{
  const bool left = region.x > 0 && s.x - reach < region.x;
  const bool top = region.y > 0 && s.y - reach < region.y;
  const bool right = region.x + region.width < frame.width && s.x + reach > region.x + region.width - 1;
  const bool bottom = region.y + region.height < frame.height && s.y + reach > region.y + region.height - 1;
  return left || top || right || bottom;
}

std::unique_ptr<SpotDetectionMethod> makeBaselineMethod();  // spot_detector_baseline.cpp
std::unique_ptr<SpotDetectionMethod> makeFastMethod();      // spot_detector_fast.cpp

// Whether the registry has a row for this method (SpotDetectorParams::sanitize).
bool isRegisteredMethod(SpotMethod method);

// Wall time of consecutive stages: each lap() returns the ms since the last
// one (or since construction).
class StageTimer
{
public:
  double lap()
  {
    const Clock::time_point now = Clock::now();
    const double ms = std::chrono::duration<double, std::milli>(now - last_).count();
    last_ = now;
    return ms;
  }

private:
  using Clock = std::chrono::steady_clock;
  Clock::time_point last_ = Clock::now();
};

}  // namespace structured_light_stabilizer
