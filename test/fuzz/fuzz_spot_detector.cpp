// libFuzzer target: the spot detector core on arbitrary image bytes.
//
// Input layout (little endian): [0] pixel format (mod 12, every encoding),
// [1..2] width - 1 (mod 160), [3..4] height - 1 (mod 160), [5] row padding
// in bytes (mod 16), [6] flags: bit 0 method (fast/baseline), bit 1 debug
// output, bits 2-3 pick a parameter variant, bits 4-6 the projector colour
// (mod 5), bit 7 an ambient frame (the same bytes read backwards); [7..10]
// parameter bytes. The rest is the pixel data, repeated to fill the image (an
// image built from few bytes is mostly flat, many bytes give noise and dots).
// Both methods run on every image, the one picked by bit 0 with the
// variant's parameters (run through sanitize() as the nodelet does), on the
// whole image and in regions (SpotDetector::detectIn: regions from the
// parameter bytes, then SpotSearchPlanner's plan after the frame). The
// detector must return ok with finite centroids inside the image, or refuse
// with a message; never crash, hang or throw.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/detection/spot_search_planner.h"

namespace
{
using namespace structured_light_stabilizer;

void check(const SpotDetectionResult& r, const cv::Mat& image)
{
  if (!r.ok)
  {
    if (r.error.empty())
      std::abort();  // refused without saying why
    return;
  }
  for (const Spot& s : r.spots)
  {
    if (!std::isfinite(s.x) || !std::isfinite(s.y))
      std::abort();
    // Centroids are weighted means of pixels of the image.
    if (s.x < -0.5 || s.y < -0.5 || s.x > image.cols - 0.5 || s.y > image.rows - 0.5)
      std::abort();
  }
}

SpotDetectorParams variant(uint8_t flags, const uint8_t* p)
{
  SpotDetectorParams params;
  params.method = (flags & 1) ? SpotMethod::kBaseline : SpotMethod::kFast;
  switch ((flags >> 2) % 4)
  {
    case 0:
      break;  // defaults
    case 1:   // extremes of the baseline knobs, possibly inconsistent
    {
      BaselineParams& b = params.baseline;
      b.blur_kernel = p[0] % 32;
      b.h_min = p[1] % 180;
      b.h_max = p[2] % 180;
      b.erosions = p[3] % 4;
      b.dilations = p[0] % 4;
      b.min_area = p[1] % 8;
      b.max_area = p[2] % 3 == 0 ? 0 : p[3];
      b.baseline_weight = (p[3] & 1) ? BaselineWeight::kValue : BaselineWeight::kSaturation;
      break;
    }
    case 2:  // extremes of the fast detector's knobs
    {
      FastParams& f = params.fast;
      f.detect_threshold = 1 + p[0] % 255;
      f.min_peak = 1 + p[1] % 255;
      f.coarse_threshold = p[2] % 8;
      f.window_radius_px = p[3] % 25;
      f.min_pixels = 1 + p[0] % 3;
      f.min_sigma_px = (p[1] % 40) * 0.1;
      f.max_sigma_px = 0.3 + (p[2] % 40) * 0.5;
      f.subtract_rock_texture = p[3] & 1;
      f.normalise_albedo = p[2] & 1;
      f.albedo_floor_dn = (p[0] % 8) * 0.5;
      break;
    }
    default:  // everything lenient
    {
      FastParams& f = params.fast;
      f.intensity_snr = (p[3] % 10) * 0.5;
      f.mono_threshold = 1 + p[3] % 4;
      f.colour_test.max_chroma_error = (p[0] % 100) * 0.1;
      f.red_weight = (p[1] % 11) * 0.1;
      f.saturation_level = 1 + p[2] % 255;
      f.min_peak = 1;
      f.detect_threshold = 1;
      f.min_sigma_px = 0.0;
      break;
    }
  }
  params.projector_color = static_cast<ProjectorColor>((flags >> 4) % 5);
  params.projector_rows = 1 + p[3] % 10;
  params.projector_cols = 1 + p[0] % 10;
  params.sanitize();
  return params;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size)
{
  constexpr size_t kHeader = 11;
  if (size < kHeader)
    return 0;
  const PixelFormat format = static_cast<PixelFormat>(data[0] % 12);
  const int width = 1 + (data[1] | data[2] << 8) % 160;
  const int height = 1 + (data[3] | data[4] << 8) % 160;
  const size_t bytes = static_cast<size_t>(channelCount(format)) * (matDepth(format) == CV_16U ? 2 : 1);
  const size_t step = (static_cast<size_t>(width) * bytes + data[5] % 16 + 1) & ~size_t(1);  // 16-bit rows stay aligned
  const uint8_t flags = data[6];
  const uint8_t* params = data + 7;
  const uint8_t* pixels = data + kHeader;
  const size_t n = size - kHeader;

  // A buffer of step * height bytes honouring the step, as a message's data.
  std::vector<uint8_t> buffer(step * height), backwards(step * height);
  for (size_t i = 0; i < buffer.size(); ++i)
  {
    buffer[i] = n > 0 ? pixels[i % n] : 0;
    backwards[i] = n > 0 ? pixels[n - 1 - i % n] : 0;
  }
  const cv::Mat image(height, width, matType(format), buffer.data(), step);
  const cv::Mat ambient = (flags & 128) ? cv::Mat(height, width, matType(format), backwards.data(), step) : cv::Mat();

  const bool want_debug = flags & 2;
  const SpotDetectorParams picked = variant(flags, params);
  for (const SpotMethod method :
       {picked.method, picked.method == SpotMethod::kFast ? SpotMethod::kBaseline : SpotMethod::kFast})
  {
    SpotDetectorParams p = picked;
    p.method = method;
    SpotDetector detector(p);
    SpotDetectorDebug debug;
    SpotDetectorTimings timings;
    const SpotDetectionResult r = detector.detect(image, ambient, format, want_debug ? &debug : nullptr, &timings);
    check(r, image);
    if (want_debug && r.ok)
      (void)drawSpotDebugImage(image, format, r.spots, debug);
    // Tracking: regions from the parameter bytes, anywhere, even outside the
    // image or empty, then the planner's own plan after this frame.
    const std::vector<cv::Rect> regions = {
        cv::Rect(params[0] - 64, params[1] - 64, params[2], params[3]),
        cv::Rect(width / 2 - params[0] % 8, height / 2 - params[1] % 8, params[2] % 32 + 1, params[3] % 32 + 1)};
    check(detector.detectIn(image, ambient, format, regions, want_debug ? &debug : nullptr, &timings), image);
    SpotSearchPlanner planner;
    planner.update(r);
    check(detector.detectIn(image, ambient, format, planner.plan(image.size())), image);
  }
  return 0;
}
