// The stages of SpotMethod::kFast (private to the core library), in the
// order spot_detector_fast.cpp chains them:
//  1. ThresholdPass     one pass over the frame: candidate pixels as runs,
//                       4 x 4 block means of the score for the coarse pass;
//  2. BlobLabeller      runs -> 8-connected blobs;
//  3. candidates        blobs worth refining (addBlobCandidates), wide dim
//                       dots from the block means (CoarseCandidates), and
//                       further dots of a blob that holds several
//                       (BlobSplitter, fed back while refining);
//  4. refinement        Gaussian-weighted centroid in a window (refineSpot)
//                       and the colour of the added light (measureColour),
//                       spot_detector_refine.cpp;
//  5. tests, de-duplication and frame checks, spot_detector_fast.cpp.
// Stages 1-3 are in spot_detector_candidates.cpp. All coordinates are pixels
// of the full frame (OpenCV convention, pixel centres at integers).
#pragma once

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "spot_detector_method.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

// Greenness of one pixel: g - max(k r, b), floored at 0, k = red_weight in
// 1/256 units. Reddish rock (g/r about 0.55-0.65) scores 0 whatever its
// albedo or the sun; the projector's 520 nm light raises g far more than r or
// b; grey, white and bluish clutter scores 0 too.
inline int greenness(const uint8_t* px, const PixelLayout& L, int k256)
{
  return std::max(0, int(px[L.g]) - std::max((k256 * int(px[L.r])) >> 8, int(px[L.b])));
}

// The per-pixel score that finds dots: greenness in colour frames, the
// intensity in mono8 ones. The threshold pass computes the same score 16
// pixels at a time (rowRuns in spot_detector_candidates.cpp): a new score
// (another projector colour, a ratio to an ambient frame) changes both.
struct PixelScore
{
  PixelLayout layout;
  int k256;  // red_weight in 1/256 units
  bool mono;

  PixelScore(PixelFormat format, double red_weight);
  int at(const uint8_t* px) const { return mono ? int(px[0]) : greenness(px, layout, k256); }
  // Greenness at (x, y) of the frame; -1 outside it (colour frames only).
  int greennessAt(const cv::Mat& image, int x, int y) const
  {
    return x < 0 || y < 0 || x >= image.cols || y >= image.rows
               ? -1
               : greenness(image.ptr<uint8_t>(y) + x * layout.step, layout, k256);
  }
};

// A horizontal run of candidate pixels [x0, x1] in row y.
struct Run
{
  int y, x0, x1;
};

// Stage 1. Candidate pixels (score >= threshold) as runs, in row order, and
// optionally the 4 x 4 block means of the score, accumulated in the same pass
// (16-bit column sums over 4 rows, then 4 columns summed). One pass over the
// frame, 16 pixels at a time where SIMD is available, which keeps it near the
// memory bandwidth limit.
class ThresholdPass
{
public:
  static constexpr int kBin = 4;  // block size of the coarse pass

  void run(const cv::Mat& image, PixelFormat format, int threshold, int k256, bool coarse);
  const std::vector<Run>& runs() const { return runs_; }
  // Block means (CV_8UC1, rows / kBin x cols / kBin); valid after a run() with coarse.
  const cv::Mat& coarse() const { return coarse_; }

private:
  std::vector<Run> runs_;
  cv::Mat coarse_;
  std::vector<uint16_t> column_sums_;
};

struct Blob
{
  int count = 0;
  double sum = 0, sx = 0, sy = 0;  // score-weighted moments
  int peak = 0, peak_x = 0, peak_y = 0;
  int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1;
};

// Stage 2. Runs -> 8-connected blobs (union-find over runs of adjacent rows),
// numbered in the order of their first run, with the score moments of their
// pixels.
class BlobLabeller
{
public:
  const std::vector<Blob>& label(const std::vector<Run>& runs, const cv::Mat& image, const PixelScore& score);
  const std::vector<Blob>& blobs() const { return blobs_; }
  // Blob of each run of the last label() call.
  const std::vector<int>& runBlob() const { return run_blob_; }

private:
  std::vector<int> parent_, root_blob_, run_blob_;
  std::vector<Blob> blobs_;
};

// Where a dot may be, and how wide.
struct Candidate
{
  double x, y, sigma0;
  int count;                     // pixels behind it (area of the reported spot)
  int x0, y0, x1, y1;            // bounds the refined centroid must stay near
  int peak_x = -1, peak_y = -1;  // strongest pixel (full-resolution blobs)
  int blob = -1;                 // index in the blobs (full-resolution candidates)
  bool seed = false;             // a further local maximum of a blob (see BlobSplitter)
};

// Stage 3a. The blobs worth refining (enough pixels, a strong enough peak).
void addBlobCandidates(const std::vector<Blob>& blobs, const FastParams& p, bool mono,
                       std::vector<Candidate>* candidates);

// Stage 3b. Wide dim dots (sigma 3-4 px on dark rock) whose every pixel stays
// below detect_threshold still stand out in the 4 x 4 block means of the
// greenness, where the noise is 4 times lower. Blocks near a candidate
// already found are skipped.
class CoarseCandidates
{
public:
  // Appends the coarse candidates; returns how many.
  int add(const cv::Mat& coarse, int threshold, double max_sigma_px, std::vector<Candidate>* candidates);

private:
  cv::Mat mask_;
  std::vector<cv::Point> stack_;
};

// Stage 3c. A blob can hold several dots: sunlit rock whose green/red ratio
// is above red_weight bridges neighbours (at full sun on bright rock the
// greenness between two dots 35 px apart stays above detect_threshold). Each
// dot refined in a blob explains a disc of 3 sigma; a blob larger than what
// it explains is searched for the strongest local maximum of the greenness
// outside the discs, which becomes a candidate of its own.
class BlobSplitter
{
public:
  // Indexes the runs of each blob (counting sort by blob) and forgets the
  // discs of the last frame. The arguments must outlive the frame's use.
  void reset(const cv::Mat& image, const PixelScore& score, const std::vector<Run>& runs,
             const std::vector<int>& run_blob, const std::vector<Blob>& blobs);
  // Whether (x, y) lies in a disc already explained in this blob.
  bool explained(int blob, double x, double y) const;
  // Records the disc explained by a dot at (x, y) of sigma s in c's blob and
  // searches the blob for its next seed; false when there is none.
  bool nextSeed(const Candidate& c, double x, double y, double s, int min_peak, double max_sigma_px, Candidate* seed);

private:
  bool prominent(int x, int y, int g, int radius, int min_peak) const;

  const cv::Mat* image_ = nullptr;
  const PixelScore* score_ = nullptr;
  const std::vector<Run>* runs_ = nullptr;
  const std::vector<Blob>* blobs_ = nullptr;
  std::vector<int> run_start_, run_list_;      // runs of blob k: run_list_[run_start_[k] .. run_start_[k + 1])
  std::vector<std::vector<cv::Vec3d>> discs_;  // per blob: x, y, radius
};

// Result of the refinement of one candidate (stage 4).
struct SpotFit
{
  double x = 0, y = 0, sigma = 0, flux = 0;
  double sigma_major = 0;                // along the footprint's long axis (sigma: the mean of both axes)
  double red_ratio = 0, blue_ratio = 0;  // excess over background relative to green's
  double red_slack = 0;                  // how far texture alone could move the red ratio
  double background = 0;                 // local background level of the weight channel (DN)
  bool on_pedestal = false;              // found by the small-window retry
  bool clipped = false;                  // green core saturated: sigma inflated, flux short
  cv::Rect window;
};

// Amplitude of a Gaussian dot from its self-weighted sum: flux = A pi sigma^2.
double gaussianAmplitude(const SpotFit& fit);

// Stage 4a. Iteratively Gaussian-weighted centroid of the weight channel `ch`
// (minus kappa times red_ch, when red_ch >= 0) around (x0, y0), starting
// from sigma0; window half size fixed_radius, or 0 for 3 sigma. False when
// the fit finds no signal or leaves its window. Fills x, y, sigma,
// sigma_major, flux, background and window.
bool refineSpot(const cv::Mat& img, int pixel_bytes, int ch, int red_ch, double x0, double y0, double sigma0,
                int fixed_radius, double max_sigma, SpotFit* out);

// Stage 4b. Colour of the fitted spot's added light: fills red_ratio,
// red_slack, blue_ratio (NaN when there is no green excess over the rock).
void measureColour(const cv::Mat& img, const PixelLayout& L, int saturation, double led_red, double led_blue,
                   SpotFit* fit);

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
