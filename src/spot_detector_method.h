// The seam between SpotDetector and its detection methods (private to the
// core library).
//
// Adding a method: a SpotMethod value and a Params group in spot_detector.h,
// one file spot_detector_<name>.cpp that implements SpotDetectionMethod and a
// factory declared below, and one row in the registry (kMethods in
// spot_detector.cpp), which also gives the method its ~method name.
#pragma once

#include <chrono>
#include <memory>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/spot_detector.h"

namespace structured_light_stabilizer
{

class SpotDetectionMethod
{
public:
  virtual ~SpotDetectionMethod() = default;

  // image has passed SpotDetector's checks: not empty, 8-bit, as many
  // channels as format has. params are sanitized. debug and timings (either
  // may be null) arrive reset to their defaults; total_ms is SpotDetector's.
  virtual SpotDetectionResult detect(const cv::Mat& image, PixelFormat format, const SpotDetectorParams& params,
                                     SpotDetectorDebug* debug, SpotDetectorTimings* timings) = 0;
};

std::unique_ptr<SpotDetectionMethod> makeBaselineMethod();  // spot_detector_baseline.cpp
std::unique_ptr<SpotDetectionMethod> makeFastMethod();      // spot_detector_fast.cpp

// Whether the registry has a row for this method (SpotDetectorParams::sanitize).
bool isRegisteredMethod(SpotMethod method);

// Where the colour channels of one pixel are: byte offsets of r, g, b and the
// pixel size in bytes (mono8: all three are the one byte).
struct PixelLayout
{
  int r, g, b, step;
};

inline PixelLayout layoutOf(PixelFormat format)
{
  switch (format)
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
