// SpotDetector: input checks, the registry of detection methods, the study's
// row sort and the debug drawing. The methods are in spot_detector_baseline.cpp
// and spot_detector_fast.cpp, the params' checks in spot_detector_params.cpp.
// See the contract in spot_detector.h.
#include "structured_light_stabilizer/spot_detector.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "spot_detector_method.h"

namespace structured_light_stabilizer
{

namespace
{
// The registry: one row per detection method. SpotDetector, the params'
// sanitize() and the method names all read it.
struct MethodEntry
{
  SpotMethod method;
  const char* name;  // the ~method value (cfg/SpotDetector.cfg lists it too)
  std::unique_ptr<SpotDetectionMethod> (*make)();
};

const MethodEntry kMethods[] = {
    {SpotMethod::kBaseline, "baseline", &makeBaselineMethod},
    {SpotMethod::kFast, "fast", &makeFastMethod},
};

const MethodEntry* findMethod(SpotMethod method)
{
  for (const MethodEntry& entry : kMethods)
    if (entry.method == method)
      return &entry;
  return nullptr;
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

const char* spotMethodName(SpotMethod method)
{
  const MethodEntry* entry = findMethod(method);
  return entry ? entry->name : "unknown";
}

bool spotMethodFromName(const std::string& name, SpotMethod* method)
{
  for (const MethodEntry& entry : kMethods)
  {
    if (name == entry.name)
    {
      *method = entry.method;
      return true;
    }
  }
  return false;
}

bool isRegisteredMethod(SpotMethod method)
{
  return findMethod(method) != nullptr;
}

// ---------------------------------------------------------------------------

SpotDetector::SpotDetector(const SpotDetectorParams& params)
{
  setParams(params);
}

SpotDetector::~SpotDetector() = default;
SpotDetector::SpotDetector(SpotDetector&&) noexcept = default;
SpotDetector& SpotDetector::operator=(SpotDetector&&) noexcept = default;

std::vector<std::string> SpotDetector::setParams(const SpotDetectorParams& params)
{
  const SpotMethod previous = params_.method;
  params_ = params;
  std::vector<std::string> changes = params_.sanitize();
  // A new method object only when the method changes: the scratch of the
  // current one stays warm across parameter updates.
  if (!method_ || params_.method != previous)
    method_ = findMethod(params_.method)->make();
  return changes;
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
  StageTimer timer;
  result = method_->detect(image, format, params_, debug, timings);
  if (timings)
    timings->total_ms = timer.lap();
  return result;
}

// ---------------------------------------------------------------------------

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
// Debug image.

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

cv::Mat drawSpotDebugImage(const cv::Mat& image, PixelFormat format, const Spots& spots, const SpotDetectorDebug& debug)
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
