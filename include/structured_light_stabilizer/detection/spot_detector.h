// Detection of the projected dots and their sub-pixel centroids
// (docs/spot_detector.md).
//
// Contract: detect() takes one frame in any encoding a ROS camera driver
// sends for this use (PixelFormat: bgr8/rgb8/bgra8/rgba8, bgr16/rgb16,
// mono8, mono16, the four 8-bit Bayer patterns, yuv422 UYVY and YUYV; any
// row step, ROIs
// welcome) and, optionally, an ambient frame of the same format and size
// (projector off, aligned to this frame: strobed daylight operation, or a
// projector-off capture of a calibration view). It returns the dots found as
// Spots in pixel coordinates of the full frame (OpenCV convention: pixel
// centres at integer coordinates, x = column, y = row). Bad input (empty,
// wrong depth/channel count for the stated format, an ambient frame of
// another size or type) is refused with a reason, never thrown. Two methods,
// chosen by SpotDetectorParams::method (the registry is in
// spot_detector.cpp):
//  - kBaseline (spot_detector_baseline.cpp): the study's chain
//    (docs/study.md §2.4), kept faithful as the yardstick: box blur -> HSV ->
//    inRange -> N erosions then N dilations (3x3 rect) -> 4-connected regions
//    -> minimum pixel count -> centroid weighted by S (formulas 2.31-2.32) ->
//    row sort (the top `cols` centroids form a row, sorted by x; repeat),
//    which numbers the beams. Frames that are not bgr8-like are converted to
//    bgr8 (or mono8) first; it ignores the ambient frame.
//  - kFast (default; spot_detector_fast.cpp): reads every encoding through
//    one inputs layer (spot_detector_planes.h: the signal plane of the
//    projector's colour and a reference plane that carries the rock's albedo
//    with little dot light), thresholds the projector-colour score in one
//    pass over the raw data (a Bayer mosaic per 2 x 2 cell), groups runs into
//    blobs and refines each in a window: the dot's added light, normalised by
//    the albedo under each pixel (from the ambient frame, else from the
//    reference plane in daylight), with an iteratively Gaussian-weighted
//    centroid, or a Gaussian fit that leaves clipped pixels out. Every
//    plausible dot is reported with a quality (SNR); beams are left
//    unassigned (-1): the Triangulator assigns them, and rejects clutter, by
//    the epipolar constraint.
// Not thread-safe per instance (scratch buffers); use one detector per thread.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/common/params.h"
#include "structured_light_stabilizer/common/projector_color.h"
#include "structured_light_stabilizer/common/spot.h"

namespace structured_light_stabilizer
{

// The encodings of sensor_msgs/image_encodings the detector reads. Bayer
// patterns name the colours of the top-left 2 x 2 cell (rggb: R at (0, 0)).
// yuv422 is UYVY (U0 Y0 V0 Y1), yuv422_yuy2 YUYV (Y0 U0 Y1 V0), both
// BT.601 with video-range luma, as OpenCV and cv_bridge convert them.
enum class PixelFormat
{
  kBgr8,
  kRgb8,
  kBgra8,
  kRgba8,
  kMono8,
  kMono16,
  kBayerRggb8,
  kBayerBggr8,
  kBayerGbrg8,
  kBayerGrbg8,
  kUyvy,
  kYuyv,
  kBgr16,  // a colour camera of more than 8 bits (12-bit converters, MSB-aligned)
  kRgb16,
};

// Parses a sensor_msgs/image_encodings name ("bgr8", "bayer_rggb8", "mono16",
// "16UC1", "yuv422", "yuv422_yuy2", ...). Returns false for anything this
// detector does not accept (float, 16-bit colour, 32-bit, ...).
bool pixelFormatFromEncoding(const std::string& encoding, PixelFormat* format);
// The sensor_msgs name of a format ("bgr8", "yuv422", ...).
const char* encodingName(PixelFormat format);
// The names pixelFormatFromEncoding() accepts, comma-separated (for messages).
const char* acceptedEncodings();
// cv::Mat channels and element depth of a frame in this format (Bayer: 1,
// CV_8U; mono16: 1, CV_16U; yuv422: 2, CV_8U).
int channelCount(PixelFormat format);
int matDepth(PixelFormat format);
inline int matType(PixelFormat format)
{
  return CV_MAKETYPE(matDepth(format), channelCount(format));
}
bool isBayer(PixelFormat format);
// Whether the format carries colour (Bayer, RGB and YUV do; mono does not).
bool hasColour(PixelFormat format);

// The projector's colour (~projector_color, projector_color.h): nir and
// white are found by intensity (a monochrome camera, or an unfiltered one
// that sees the projector in every channel); green, red and blue by the
// colour of the light they add to the rock on a colour camera (on a mono
// camera they too fall back to intensity).

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
#define SLS_PARAMS_STRUCT BaselineParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/detection/baseline_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  std::string validate() const;
  std::vector<std::string> sanitize();
};

// The fast method's colour test: a dot adds the projector's light to the rock
// under it, so the colour of that added light is the sensor's response to the
// projector. Named for the green projector (signal = green, reference = red,
// third = blue); a red projector tests green and blue against red, a blue one
// red and green against blue, with the responses of
// spot_detector_planes.cpp's colour table (a typical colour sensor at 650
// and 450 nm); no test for nir/white or mono frames. led_*_ratio = the
// sensor's red (blue) response to the projector relative to green
// (calibrate: excess / green excess of a dot on any frame). The third-channel
// test runs on texture-free signals (signal and third minus the rock's own
// multiple of the reference) and rejects olive minerals, grey, white and
// bluish clutter when the added light's third/signal ratio differs from the
// projector's by more than max_chroma_error. The reference carries the rock
// texture, so its tests carry a slack for the texture around the spot:
// reference/signal above led_red_ratio + max_red_excess (olive, yellow
// minerals: R = G) rejects; below led_red_ratio - max_red_deficit too, but
// texture at full sun trips that one, so it is off (0) by default. With an
// ambient frame the added light is measured directly (frame - ambient).
struct ColourTestParams
{
#define SLS_PARAMS_STRUCT ColourTestParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/detection/colour_test_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  std::string validate() const;
  std::vector<std::string> sanitize();
};

// SpotMethod::kFast.
struct FastParams
{
#define SLS_PARAMS_STRUCT FastParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/detection/fast_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  std::string validate() const;
  std::vector<std::string> sanitize();
};

struct SpotDetectorParams
{
#define SLS_PARAMS_STRUCT SpotDetectorParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/detection/spot_detector_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  std::string validate() const;
  // Also replaces a method that is not registered by kFast.
  std::vector<std::string> sanitize();
};

// Per-stage wall times of the last detect() call (ms). Baseline stages:
// blur, hsv, in_range, opening, labelling, centroids, sort; fast stages:
// threshold (the pass over the frame, and the intensity path's background
// map), labelling (runs -> blobs -> candidates), refine (refinement, tests,
// de-duplication).
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
  std::vector<cv::Rect> regions;  // detectIn: the regions searched (empty: the whole frame)
  std::vector<cv::Rect> windows;  // fast: refinement window of each kept spot
  std::vector<double> sigmas_px;  // fast: fitted sigma of each kept spot
  std::vector<cv::Vec2d> chroma;  // fast: (reference, third) excess / signal excess of each kept spot
  int candidates = 0;             // blobs/regions considered before rejection
  int coarse_candidates = 0;      // fast: extra candidates from the 4 x 4 binned pass
  int fitted = 0;                 // fast: spots located by the Gaussian fit without their clipped pixels
  int seeded = 0;                 // fast, detectIn: dots refined from the last frame's (tracked_seeds), unsearched
  // Fast: candidates dropped, where and why (drawn in the debug image).
  struct Rejection
  {
    double x, y;
    std::string reason;
  };
  std::vector<Rejection> rejected;
};

// How well the fast method measured one spot (the Triangulator may weigh or
// rank by it; the baseline leaves it at its defaults).
struct SpotQuality
{
  // Fitted peak of the dot's added light over the noise of its surroundings
  // (robust spread of the window's border about its background plane, which
  // also counts texture the reference plane did not explain).
  float snr = 0.0f;
  float sigma_px = 0.0f;           // fitted Gaussian sigma (mean of both axes)
  bool clipped = false;            // clipped pixels left out by a Gaussian fit
  bool albedo_normalised = false;  // the added light was divided by the albedo under each pixel
};

struct SpotDetectionResult
{
  bool ok = false;
  std::string error;  // why the frame was refused (ok == false)
  std::string note;   // what the detector left out of an accepted frame, and why (empty: nothing)
  Spots spots;
  std::vector<SpotQuality> quality;  // parallel to spots (fast method; empty for the baseline)
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
  // With an ambient frame: the same scene with the projector off, in the
  // same format and size, aligned to `image` (a strobed camera's off frame,
  // motion-compensated to this frame's time, or a projector-off capture of
  // a static view). Its DN must be the frame's (it is subtracted): a
  // predicted albedo image must be scaled to the frame's ambient light.
  // Empty = none (as the overload above). For bgr8/rgb8/bgra8/rgba8/mono8
  // frames it may also be CV_32F with the frame's channels: a motion-
  // compensated estimate kept unrounded (AmbientCompensationParams::
  // unrounded), which the refinement reads as it is (the threshold pass
  // reads it rounded); non-finite values read as 0.
  SpotDetectionResult detect(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                             SpotDetectorDebug* debug = nullptr, SpotDetectorTimings* timings = nullptr);
  // Detection in regions of the frame only (SpotSearchPlanner::plan; empty:
  // the whole frame), spots in frame coordinates. Regions are merged where
  // that costs few pixels (mergeSearchRegions); a dot so near a region's inner
  // edge that its refinement window was cut is left out (a region that ends at
  // the frame's edge cuts nothing): another region, or the next frame, has it
  // whole. A dot found in two overlapping regions is kept once.
  SpotDetectionResult detectIn(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                               const std::vector<cv::Rect>& regions, SpotDetectorDebug* debug = nullptr,
                               SpotDetectorTimings* timings = nullptr);
  // Whether detectIn() searches regions: the fast method (the study's chain
  // searches the whole frame).
  bool canSearchRegions() const;
  // Whether the fast method has what a region search of this frame needs:
  // colour frames with an ambient frame take their matched filter's
  // thresholds from the noise of the whole frame, measured on the last frame
  // searched whole (of this size, with these parameters, at most 30 region
  // frames ago). false (with the reason): detectIn searches the whole frame,
  // which renews them; the caller's planner should count it as a full search.
  bool hasRegionStatistics(bool with_ambient, PixelFormat format, const cv::Size& frame,
                           std::string* why = nullptr) const;

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

// Converts any accepted format to a bgr8 image (shares data when already
// bgr8): Bayer demosaiced (bilinear), mono16 scaled by 1/257, yuv422 as
// cv::cvtColor does. For display and the baseline; the fast method reads the
// raw data.
cv::Mat toBgr(const cv::Mat& image, PixelFormat format);

}  // namespace structured_light_stabilizer
