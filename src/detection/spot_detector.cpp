// SpotDetector: input checks, the registry of detection methods, the study's
// row sort and the debug drawing. The methods are in spot_detector_baseline.cpp
// and spot_detector_fast.cpp, the params' checks in spot_detector_params.cpp.
// See the contract in spot_detector.h.
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/detection/spot_search_planner.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "detection/method.h"
#include "structured_light_stabilizer/common/math.h"

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

// The encodings, their sensor_msgs names and cv::Mat shape.
struct FormatEntry
{
  PixelFormat format;
  const char* name;
  int channels, depth;
};

const FormatEntry kFormats[] = {
    {PixelFormat::kBgr8, "bgr8", 3, CV_8U},
    {PixelFormat::kRgb8, "rgb8", 3, CV_8U},
    {PixelFormat::kBgra8, "bgra8", 4, CV_8U},
    {PixelFormat::kRgba8, "rgba8", 4, CV_8U},
    {PixelFormat::kMono8, "mono8", 1, CV_8U},
    {PixelFormat::kMono16, "mono16", 1, CV_16U},
    {PixelFormat::kBayerRggb8, "bayer_rggb8", 1, CV_8U},
    {PixelFormat::kBayerBggr8, "bayer_bggr8", 1, CV_8U},
    {PixelFormat::kBayerGbrg8, "bayer_gbrg8", 1, CV_8U},
    {PixelFormat::kBayerGrbg8, "bayer_grbg8", 1, CV_8U},
    {PixelFormat::kUyvy, "yuv422", 2, CV_8U},
    {PixelFormat::kYuyv, "yuv422_yuy2", 2, CV_8U},
    {PixelFormat::kBgr16, "bgr16", 3, CV_16U},
    {PixelFormat::kRgb16, "rgb16", 3, CV_16U},
};

const FormatEntry& formatEntry(PixelFormat format)
{
  for (const FormatEntry& e : kFormats)
    if (e.format == format)
      return e;
  return kFormats[0];
}

std::string checkImage(const cv::Mat& image, PixelFormat format, const char* what)
{
  const std::string w(what);
  if (image.empty() || image.rows <= 0 || image.cols <= 0)
    return w + " is empty";
  if (image.dims != 2)
    return w + " is not two-dimensional";
  if (image.depth() != matDepth(format))
    return w + " depth does not fit " + encodingName(format) + " (" + (matDepth(format) == CV_16U ? "16" : "8") +
           "-bit unsigned expected, type " + std::to_string(image.type()) + ")";
  if (image.channels() != channelCount(format))
    return w + " has " + std::to_string(image.channels()) + " channels, " + encodingName(format) + " needs " +
           std::to_string(channelCount(format));
  if (isBayer(format) && (image.rows < 2 || image.cols < 2))
    return w + " is smaller than one 2 x 2 Bayer cell";
  if ((format == PixelFormat::kUyvy || format == PixelFormat::kYuyv) && image.cols % 2 != 0)
    return w + " has an odd width: yuv422 pairs pixels";
  return std::string();
}

// An ambient estimate kept unrounded (ambient_compensation.h,
// AmbientCompensationParams::unrounded): CV_32F with the frame's channels,
// for the interleaved 8-bit formats.
bool unroundedAmbientFits(const cv::Mat& ambient, PixelFormat format)
{
  const bool interleaved8 = format == PixelFormat::kBgr8 || format == PixelFormat::kRgb8 ||
                            format == PixelFormat::kBgra8 || format == PixelFormat::kRgba8 ||
                            format == PixelFormat::kMono8;
  return interleaved8 && ambient.depth() == CV_32F && ambient.channels() == channelCount(format);
}

std::string checkInput(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format)
{
  std::string error = checkImage(image, format, "image");
  if (error.empty() && !ambient.empty())
  {
    if (ambient.depth() != CV_32F || !unroundedAmbientFits(ambient, format))
      error = checkImage(ambient, format, "ambient image");
    if (error.empty() && ambient.size() != image.size())
      error = "ambient image is " + std::to_string(ambient.cols) + "x" + std::to_string(ambient.rows) + ", the image " +
              std::to_string(image.cols) + "x" + std::to_string(image.rows);
  }
  return error;
}

// Clears the outputs; the result's error says why the frames cannot be read.
SpotDetectionResult startDetection(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                                   SpotDetectorDebug* debug, SpotDetectorTimings* timings)
{
  if (debug)
    *debug = SpotDetectorDebug();
  if (timings)
    *timings = SpotDetectorTimings();
  SpotDetectionResult result;
  result.error = checkInput(image, ambient, format);
  return result;
}
}  // namespace

bool pixelFormatFromEncoding(const std::string& encoding, PixelFormat* format)
{
  for (const FormatEntry& e : kFormats)
  {
    if (encoding == e.name)
    {
      *format = e.format;
      return true;
    }
  }
  // Aliases: OpenCV type names for the mono formats, and the other names drivers use for YUYV.
  if (encoding == "8UC1")
    *format = PixelFormat::kMono8;
  else if (encoding == "16UC1")
    *format = PixelFormat::kMono16;
  else if (encoding == "yuyv" || encoding == "yuv422_yuyv")
    *format = PixelFormat::kYuyv;
  else if (encoding == "uyvy")
    *format = PixelFormat::kUyvy;
  else
    return false;
  return true;
}

const char* encodingName(PixelFormat format)
{
  return formatEntry(format).name;
}

const char* acceptedEncodings()
{
  return "bgr8, rgb8, bgra8, rgba8, mono8 (8UC1), mono16 (16UC1), bayer_rggb8, bayer_bggr8, bayer_gbrg8, "
         "bayer_grbg8, yuv422 (UYVY), yuv422_yuy2 (YUYV)";
}

int channelCount(PixelFormat format)
{
  return formatEntry(format).channels;
}

int matDepth(PixelFormat format)
{
  return formatEntry(format).depth;
}

bool isBayer(PixelFormat format)
{
  return format == PixelFormat::kBayerRggb8 || format == PixelFormat::kBayerBggr8 ||
         format == PixelFormat::kBayerGbrg8 || format == PixelFormat::kBayerGrbg8;
}

bool hasColour(PixelFormat format)
{
  return format != PixelFormat::kMono8 && format != PixelFormat::kMono16;
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
  method_->resetStatistics();
  return changes;
}

SpotDetectionResult SpotDetector::detect(const cv::Mat& image, PixelFormat format, SpotDetectorDebug* debug,
                                         SpotDetectorTimings* timings)
{
  return detect(image, cv::Mat(), format, debug, timings);
}

SpotDetectionResult SpotDetector::detect(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                                         SpotDetectorDebug* debug, SpotDetectorTimings* timings)
{
  SpotDetectionResult result = startDetection(image, ambient, format, debug, timings);
  if (!result.error.empty())
    return result;
  StageTimer timer;
  result = method_->detect(image, ambient, format, params_, debug, timings);
  if (timings)
    timings->total_ms = timer.lap();
  return result;
}

namespace
{
void addTimings(const SpotDetectorTimings& t, SpotDetectorTimings* sum)
{
  sum->blur_ms += t.blur_ms;
  sum->hsv_ms += t.hsv_ms;
  sum->in_range_ms += t.in_range_ms;
  sum->opening_ms += t.opening_ms;
  sum->labelling_ms += t.labelling_ms;
  sum->centroids_ms += t.centroids_ms;
  sum->sort_ms += t.sort_ms;
  sum->threshold_ms += t.threshold_ms;
  sum->refine_ms += t.refine_ms;
}

void addDebug(const SpotDetectorDebug& d, const cv::Point& at, SpotDetectorDebug* sum)
{
  for (cv::Rect w : d.windows)
    sum->windows.push_back(w + at);
  sum->sigmas_px.insert(sum->sigmas_px.end(), d.sigmas_px.begin(), d.sigmas_px.end());
  sum->chroma.insert(sum->chroma.end(), d.chroma.begin(), d.chroma.end());
  for (const SpotDetectorDebug::Rejection& r : d.rejected)
    sum->rejected.push_back({r.x + at.x, r.y + at.y, r.reason});
  sum->candidates += d.candidates;
  sum->coarse_candidates += d.coarse_candidates;
  sum->fitted += d.fitted;
  sum->seeded += d.seeded;
}
}  // namespace

bool SpotDetector::canSearchRegions() const
{
  return params_.method == SpotMethod::kFast;
}

bool SpotDetector::hasRegionStatistics(bool with_ambient, PixelFormat format, const cv::Size& frame,
                                       std::string* why) const
{
  return method_->regionStatistics(with_ambient, format, frame, params_, why);
}

SpotDetectionResult SpotDetector::detectIn(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                                           const std::vector<cv::Rect>& regions, SpotDetectorDebug* debug,
                                           SpotDetectorTimings* timings)
{
  if (regions.empty() || !canSearchRegions() || !hasRegionStatistics(!ambient.empty(), format, image.size()))
    return detect(image, ambient, format, debug, timings);
  SpotDetectionResult result = startDetection(image, ambient, format, debug, timings);
  if (!result.error.empty())
    return result;
  struct RegionScope  // the method's region mode, also on an early return
  {
    SpotDetectionMethod* m;
    explicit RegionScope(SpotDetectionMethod* method) : m(method) { m->beginRegions(); }
    ~RegionScope() { m->endRegions(); }
  } scope(method_.get());
  StageTimer timer;
  std::vector<std::pair<Spot, SpotQuality>> found;
  const std::vector<cv::Rect> merged = mergeSearchRegions(regions, image.size());
  if (debug)
    debug->regions = merged;
  for (const cv::Rect& region : merged)
  {
    SpotDetectorDebug d;
    SpotDetectorTimings t;
    const cv::Mat roi_ambient = ambient.empty() ? ambient : ambient(region);
    SpotDetectionResult part = method_->detect(image(region), roi_ambient, format, params_, debug ? &d : nullptr, &t);
    if (!part.ok)
    {
      part.error = "region " + std::to_string(region.width) + "x" + std::to_string(region.height) + "+" +
                   std::to_string(region.x) + "+" + std::to_string(region.y) + ": " + part.error;
      return part;
    }
    for (size_t k = 0; k < part.spots.size(); ++k)
    {
      Spot s = part.spots[k];
      s.x += region.x;
      s.y += region.y;
      const SpotQuality q = k < part.quality.size() ? part.quality[k] : SpotQuality();
      if (!cutByRegion(s, reachOf(s, k < part.quality.size() ? &q : nullptr), region, image.size()) &&
          std::none_of(found.begin(), found.end(),
                       [&](const std::pair<Spot, SpotQuality>& f)
                       { return std::abs(f.first.x - s.x) < 1.0 && std::abs(f.first.y - s.y) < 1.0; }))
        found.emplace_back(s, q);
    }
    if (timings)
      addTimings(t, timings);
    if (debug)
      addDebug(d, region.tl(), debug);
  }
  for (const auto& f : found)
    result.spots.push_back(f.first);
  sortIntoRows(&result.spots, params_.projector_cols, params_.projector_rows, params_.method == SpotMethod::kBaseline);
  const bool with_quality = params_.method != SpotMethod::kBaseline;
  for (size_t k = 0; with_quality && k < result.spots.size(); ++k)
    for (const auto& f : found)
      if (f.first.x == result.spots[k].x && f.first.y == result.spots[k].y)
      {
        result.quality.push_back(f.second);
        break;
      }
  if (timings)
    timings->total_ms = timer.lap();
  result.ok = true;
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
  // OpenCV names a Bayer pattern by the second row's first two sites (as cv_bridge maps them).
  static const std::pair<PixelFormat, int> kCodes[] = {
      {PixelFormat::kRgb8, cv::COLOR_RGB2BGR},           {PixelFormat::kBgra8, cv::COLOR_BGRA2BGR},
      {PixelFormat::kRgba8, cv::COLOR_RGBA2BGR},         {PixelFormat::kMono8, cv::COLOR_GRAY2BGR},
      {PixelFormat::kBayerRggb8, cv::COLOR_BayerBG2BGR}, {PixelFormat::kBayerBggr8, cv::COLOR_BayerRG2BGR},
      {PixelFormat::kBayerGbrg8, cv::COLOR_BayerGR2BGR}, {PixelFormat::kBayerGrbg8, cv::COLOR_BayerGB2BGR},
      {PixelFormat::kUyvy, cv::COLOR_YUV2BGR_UYVY},      {PixelFormat::kYuyv, cv::COLOR_YUV2BGR_YUY2},
  };
  if (format == PixelFormat::kBgr8)
    return image;
  cv::Mat out;
  if (format == PixelFormat::kMono16)
  {
    cv::Mat mono;
    image.convertTo(mono, CV_8U, 1.0 / 257.0);
    cv::cvtColor(mono, out, cv::COLOR_GRAY2BGR);
    return out;
  }
  if (format == PixelFormat::kBgr16 || format == PixelFormat::kRgb16)
  {
    image.convertTo(out, CV_8U, 1.0 / 257.0);
    if (format == PixelFormat::kRgb16)
      cv::cvtColor(out, out, cv::COLOR_RGB2BGR);
    return out;
  }
  for (const auto& code : kCodes)
  {
    if (code.first != format)
      continue;
    if (isBayer(format))
    {
      // Demosaicing wants a few pixels around each one: pad by an even
      // reflection (which keeps the pattern) and crop back.
      cv::Mat padded, colour;
      cv::copyMakeBorder(image, padded, 2, 2, 2, 2, cv::BORDER_REFLECT_101);
      cv::cvtColor(padded, colour, code.second);
      return colour(cv::Rect(2, 2, image.cols, image.rows)).clone();
    }
    cv::cvtColor(image, out, code.second);
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
  // The regions searched when tracking (dark blue), the refinement windows (magenta).
  for (const cv::Rect& r : debug.regions)
    cv::rectangle(out, r, cv::Scalar(128, 64, 0), 1);
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
