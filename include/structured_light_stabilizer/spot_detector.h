// Detection of the projected green dots and their sub-pixel centroids
// (docs/spot_detector.md).
//
// Contract: detect() takes one 8-bit image (bgr8, rgb8, bgra8, rgba8 or mono8,
// any row step, ROIs welcome) and returns the dots found in it as Spots in
// pixel coordinates (OpenCV convention: pixel centres at integer coordinates,
// x = column, y = row). Bad input (empty, wrong depth/channel count for the
// stated format) is refused with a reason, never thrown. Two methods, chosen by
// SpotDetectorParams::method (the registry is in spot_detector.cpp):
//  - kBaseline (spot_detector_baseline.cpp): the study's chain
//    (docs/study.md §2.4), kept faithful as the yardstick: box blur -> HSV ->
//    inRange -> N erosions then N dilations (3x3 rect) -> 4-connected regions
//    -> minimum pixel count -> centroid weighted by S (formulas 2.31-2.32) ->
//    row sort (the top `cols` centroids form a row, sorted by x; repeat),
//    which numbers the beams.
//  - kFast (default; spot_detector_fast.cpp): one SIMD pass thresholds the
//    greenness g - max(k r, b) in the raw frame, runs are grouped into blobs
//    (one candidate per dot when bright greenish rock bridges several), and
//    each is refined in a fixed window on the background-subtracted green
//    channel with an iteratively Gaussian-weighted centroid (the star-tracker
//    way), so mask edge pixels flickering in and out no longer move the
//    centroid. Beams are left unassigned (-1): the Triangulator assigns them
//    by the epipolar constraint.
// Not thread-safe per instance (scratch buffers); use one detector per thread.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/spot.h"

namespace structured_light_stabilizer
{

enum class PixelFormat
{
  kBgr8,
  kRgb8,
  kBgra8,
  kRgba8,
  kMono8,
};

// Parses a sensor_msgs/image_encodings name ("bgr8", ...). Returns false for
// anything this detector does not accept (16-bit, float, Bayer, YUV, ...).
bool pixelFormatFromEncoding(const std::string& encoding, PixelFormat* format);
int channelCount(PixelFormat format);

enum class SpotMethod
{
  kBaseline = 0,
  kFast = 1,
};

// The method's name as the nodelet's ~method parameter spells it ("baseline",
// "fast"); "unknown" for a value that is not registered.
const char* spotMethodName(SpotMethod method);
// Parses such a name; false (and *method untouched) when no method has it.
bool spotMethodFromName(const std::string& name, SpotMethod* method);

// Which pixel value weighs the baseline's centroid (formulas 2.31-2.32).
enum class BaselineWeight
{
  kSaturation = 0,  // the study: S of HSV
  kValue = 1,       // V of HSV (better on saturated cores; not the study)
};

// Every field below is named as the SpotDetector nodelet's parameter that
// sets it (cfg/SpotDetector.cfg; ~projector_rows/cols). sanitize() makes the
// values usable and returns one line per change made (min > max swapped, even
// kernels made odd, out-of-range values clamped); validate() is empty when
// sanitize() would change nothing, otherwise its first line.

// The study's trackbars (figure 2.8), for SpotMethod::kBaseline. OpenCV HSV
// units: H in [0, 179] (half degrees), S and V in [0, 255]. The study's hue
// window 60-180 deg is H 30-90 here.
struct BaselineParams
{
  int blur_kernel = 1;  // box low-pass kernel size (odd, 1 = off, as in the study's unit test)
  int h_min = 16, h_max = 90;
  int s_min = 60, s_max = 255;
  int v_min = 35, v_max = 255;
  // The study used 4 + 4 for dots of ~300 px; our dots (sigma ~2 px, ~50 px)
  // vanish after 4 erosions, so the default is one of each.
  int erosions = 1;
  int dilations = 1;
  int min_area = 5;  // pixels; smaller regions are dismissed (study: "insignificant number")
  int max_area = 0;  // pixels; 0 = no upper bound (not in the study)
  BaselineWeight baseline_weight = BaselineWeight::kSaturation;

  std::string validate() const;
  std::vector<std::string> sanitize();
};

// The fast method's colour test. A dot adds the projector's light to the rock
// under it, so the colour of that added light is the sensor's response to the
// projector (mostly green, some blue and red through the Bayer filters;
// calibrate led_*_ratio = excess / green excess from any frame). The blue
// test runs on texture-free signals (green and blue minus the rock's own
// multiple of red) and rejects olive minerals, grey, white and bluish clutter
// when the added light's blue/green differs from the LED's by more than
// max_chroma_error. Red is the texture reference, so the red tests carry a
// slack for the rock texture around the spot: red/green above led_red_ratio +
// max_red_excess (olive, yellow minerals: R = G) rejects; below led_red_ratio
// - max_red_deficit (a green mineral replaces red rock, so red drops where
// green rises) too, but texture at full sun trips that one, so it is off (0)
// by default.
struct ColourTestParams
{
  double led_red_ratio = 0.08;
  double led_blue_ratio = 0.22;
  double max_red_excess = 0.4;
  double max_red_deficit = 0.0;
  double max_chroma_error = 0.15;

  std::string validate() const;
  std::vector<std::string> sanitize();
};

// The fast method's frame-level consistency (when at least
// consistency_min_spots survive). The dots of one frame share the projector's
// beam and power, so they share a size (sigma) and an energy relative to the
// rock they light (flux over the local background level: the
// projector/sun irradiance ratio, up to incidence and shading); a speck or a
// mineral is a reflectance patch, whose size and energy follow its own area
// and reflectance. Hard bounds, relative to the frame's medians: sigma below
// min_sigma_fraction (unless the long axis keeps at least halfway from there
// to the median: a dot foreshortened by a slope, while a speck is small both
// ways) or above max_sigma_factor (specks, mineral patches), peak contrast
// over the background above max_contrast_factor (sunlit green minerals),
// energy below min_energy_fraction (a patch the projector does not light).
// Joint bound: a spot whose sigma is outside [size_band_low, size_band_high]
// AND whose energy is outside [energy_band_low, energy_band_high] x the
// medians is clutter (a dot on a slope may be larger or dimmer than its
// peers, rarely both; a speck is smaller and brighter or dimmer). 0 disables
// each bound.
struct FrameCheckParams
{
  double min_sigma_fraction = 0.9;
  double max_sigma_factor = 1.6;
  double max_contrast_factor = 4.0;
  double min_energy_fraction = 0.15;
  double size_band_low = 0.92;
  double size_band_high = 1.15;
  double energy_band_low = 0.6;
  double energy_band_high = 1.6;
  int consistency_min_spots = 8;

  std::string validate() const;
  std::vector<std::string> sanitize();
};

// SpotMethod::kFast.
struct FastParams
{
  // Threshold pass and candidates. Greenness g - max(red_weight * r, b):
  // reddish rock (g/r 0.55-0.65) scores 0 with red_weight 0.75 while the dot
  // keeps ~94 % of its peak.
  double red_weight = 0.75;
  int detect_threshold = 8;  // DN of greenness for a candidate pixel
  int min_peak = 14;         // DN; a blob's strongest greenness (mono8: intensity) must reach this
  int mono_threshold = 128;  // DN of intensity for a candidate pixel in mono8 frames
  int min_pixels = 2;        // candidate pixels per blob
  // Coarse pass: mean greenness over 4 x 4 blocks at least this (DN) makes a
  // candidate too (wide dim dots); 0 = off. Not used for mono8.
  int coarse_threshold = 3;

  // Refinement.
  int window_radius_px = 0;  // half size of the refinement window; 0 = from the blob's size
  // Centroid weight g - kappa r, kappa = the rock's green/red ratio around the
  // dot: removes the sunlit rock texture under the dot (false: g alone).
  bool subtract_rock_texture = true;
  double min_sigma_px = 1.1;  // accepted range of the fitted Gaussian sigma (specks are sharper than dots)
  double max_sigma_px = 6.0;

  ColourTestParams colour_test;
  int saturation_level = 250;  // DN; pixels at or above are clipped (excluded from the colour test)
  FrameCheckParams frame_checks;

  std::string validate() const;
  std::vector<std::string> sanitize();
};

struct SpotDetectorParams
{
  SpotMethod method = SpotMethod::kFast;
  // The study's row sort: both methods return their spots in row-major
  // order; the baseline also numbers the beams by it.
  int projector_rows = 10;
  int projector_cols = 10;
  BaselineParams baseline;
  FastParams fast;

  std::string validate() const;
  // Also replaces a method that is not registered by kFast.
  std::vector<std::string> sanitize();
};

// Per-stage wall times of the last detect() call (ms). Baseline stages:
// blur, hsv, in_range, opening, labelling, centroids, sort; fast stages:
// threshold (the SIMD pass), labelling (runs -> blobs -> candidates), refine
// (refinement, tests, de-duplication, frame checks).
struct SpotDetectorTimings
{
  double blur_ms = 0, hsv_ms = 0, in_range_ms = 0, opening_ms = 0, labelling_ms = 0, centroids_ms = 0, sort_ms = 0;
  double threshold_ms = 0, refine_ms = 0;
  double total_ms = 0;
};

// Optional outputs for the debug image.
struct SpotDetectorDebug
{
  cv::Mat mask;                   // baseline: final binary mask (after the opening)
  std::vector<cv::Rect> windows;  // fast: refinement window of each kept spot
  std::vector<double> sigmas_px;  // fast: fitted sigma of each kept spot
  std::vector<cv::Vec2d> chroma;  // fast: (red, blue) excess / green excess of each kept spot
  int candidates = 0;             // blobs/regions considered before rejection
  int coarse_candidates = 0;      // fast: extra candidates from the 4 x 4 binned pass
  // Fast: candidates dropped, where and why (drawn in the debug image).
  struct Rejection
  {
    double x, y;
    std::string reason;
  };
  std::vector<Rejection> rejected;
};

struct SpotDetectionResult
{
  bool ok = false;
  std::string error;  // why the frame was refused (ok == false)
  Spots spots;
};

class SpotDetectionMethod;  // one detection method (spot_detector_method.h)

class SpotDetector
{
public:
  explicit SpotDetector(const SpotDetectorParams& params = SpotDetectorParams());
  ~SpotDetector();
  SpotDetector(SpotDetector&&) noexcept;
  SpotDetector& operator=(SpotDetector&&) noexcept;

  // Params are sanitized on the way in; the returned lines say what changed.
  std::vector<std::string> setParams(const SpotDetectorParams& params);
  const SpotDetectorParams& params() const { return params_; }

  SpotDetectionResult detect(const cv::Mat& image, PixelFormat format, SpotDetectorDebug* debug = nullptr,
                             SpotDetectorTimings* timings = nullptr);

private:
  SpotDetectorParams params_;
  // The object of params_.method, with its scratch buffers (reused across
  // frames: no per-frame allocation in the hot path).
  std::unique_ptr<SpotDetectionMethod> method_;
};

// The study's row sort (docs/study.md §2.4.3): repeatedly take the `cols`
// spots closest to the top of the image, order them by x, append them as a
// row. When assign_beams is set, spot k of the sorted list gets beam k (if k <
// rows * cols; -1 beyond), which is only right when every dot was found, as
// the study itself says.
void sortIntoRows(Spots* spots, int cols, int rows, bool assign_beams);

// Draws the detections on a bgr8 copy of the frame: region contours
// (baseline) or refinement windows (fast), a cross on each centroid and the
// beam number when assigned.
cv::Mat drawSpotDebugImage(const cv::Mat& image, PixelFormat format, const Spots& spots,
                           const SpotDetectorDebug& debug);

// Converts any accepted format to a bgr8 image (shares data when already bgr8).
cv::Mat toBgr(const cv::Mat& image, PixelFormat format);

}  // namespace structured_light_stabilizer
