// The stages of SpotMethod::kFast (private to the core library), in the
// order spot_detector_fast.cpp chains them:
//  0. FramePlanes       the inputs layer: any encoding, the projector's
//                       colour, the ambient frame (spot_detector_planes.h);
//  1. ThresholdPass     one pass over the frame's score grid: candidate cells
//                       as runs, 4 x 4 block means of the score for the
//                       coarse pass;
//  2. BlobLabeller      runs -> 8-connected blobs;
//  3. candidates        blobs worth refining (addBlobCandidates), wide dim
//                       dots from the block means (CoarseCandidates), and
//                       further dots of a blob that holds several
//                       (BlobSplitter, fed back while refining);
//  4. refinement        the dot's added light, normalised by the albedo under
//                       each pixel, in a window (refineSpot): an iteratively
//                       Gaussian-weighted centroid, or a Gaussian fit without
//                       the clipped pixels (spot_detector_refine.cpp,
//                       spot_detector_fit.cpp); the colour of the added
//                       light (measureColour, spot_detector_colour.cpp);
//  5. tests and de-duplication, spot_detector_fast.cpp.
// Stages 1-3 are in spot_detector_candidates.cpp and work in grid
// coordinates (FramePlanes: a pixel, or a 2 x 2 Bayer cell); candidates and
// everything after them are in pixels of the full frame (OpenCV convention,
// pixel centres at integers). A tracking mode (search only windows around
// last frame's dots) would replace stages 1-3 and feed stage 4 directly.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "detection/method.h"
#include "detection/inputs/planes.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

// Stage 1. Candidate cells (score >= the planes' threshold) as runs, in row
// order, and optionally the 4 x 4 block means of the score, accumulated in
// the same pass (16-bit column sums over 4 rows, then 4 columns summed). One
// pass over the frame, 16 cells at a time where SIMD is available for the
// format (spot_detector_rows.cpp), which keeps it near the memory bandwidth
// limit.
class ThresholdPass
{
public:
  static constexpr int kBin = 4;  // block size of the coarse pass (cells)

  void run(FramePlanes* planes, bool coarse);
  const std::vector<Run>& runs() const { return runs_; }
  // Block means (CV_8UC1, grid rows / kBin x cols / kBin); valid after a run() with coarse.
  const cv::Mat& coarse() const { return coarse_; }

private:
  std::vector<Run> runs_;
  cv::Mat coarse_;
  std::vector<uint16_t> column_sums_;
};

// Grid coordinates (cells).
struct Blob
{
  int count = 0;
  double sum = 0, sx = 0, sy = 0;  // score-weighted moments
  int peak = 0, peak_x = 0, peak_y = 0;
  int x0 = 1 << 30, y0 = 1 << 30, x1 = -1, y1 = -1;
};

// Stage 2. Runs -> 8-connected blobs (union-find over runs of adjacent rows),
// numbered in the order of their first run, with the score moments of their
// cells.
class BlobLabeller
{
public:
  const std::vector<Blob>& label(const std::vector<Run>& runs, const FramePlanes& planes);
  const std::vector<Blob>& blobs() const { return blobs_; }
  // Blob of each run of the last label() call.
  const std::vector<int>& runBlob() const { return run_blob_; }

private:
  std::vector<int> parent_, root_blob_, run_blob_, scores_;
  std::vector<Blob> blobs_;
};

// Where a dot may be, and how wide (pixels of the full frame).
struct Candidate
{
  double x, y, sigma0;
  int count;                     // pixels behind it (area of the reported spot)
  int x0, y0, x1, y1;            // bounds the refined centroid must stay near
  int peak_x = -1, peak_y = -1;  // strongest pixel (full-resolution blobs; centre of the cell)
  int blob = -1;                 // index in the blobs (full-resolution candidates)
  bool seed = false;             // a further local maximum of a blob (see BlobSplitter)
  double significance = 0;       // noise sigmas of its peak (FramePlanes::significance): the ranking
};

// Stage 3a. The blobs worth refining (enough pixels, a strong enough peak).
void addBlobCandidates(const std::vector<Blob>& blobs, const FastParams& p, const FramePlanes& planes,
                       std::vector<Candidate>* candidates);

// Stage 3b. Wide dim dots (sigma 3-4 px on dark rock) whose every pixel stays
// below detect_threshold still stand out in the 4 x 4 block means of the
// greenness, where the noise is 4 times lower. Blocks near a candidate
// already found are skipped.
class CoarseCandidates
{
public:
  // Appends the coarse candidates (bins at or above `threshold`, or the
  // planes' coarse thresholds on the local path); returns how many.
  int add(const cv::Mat& coarse, int threshold, double max_sigma_px, const FramePlanes& planes,
          std::vector<Candidate>* candidates);

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
  void reset(const FramePlanes& planes, const std::vector<Run>& runs, const std::vector<int>& run_blob,
             const std::vector<Blob>& blobs);
  // Whether pixel (x, y) lies in a disc already explained in this blob.
  bool explained(int blob, double x, double y) const;
  // Records the disc explained by a dot at pixel (x, y) of sigma s (pixels)
  // in c's blob and searches the blob for its next seed; false when there is
  // none. min_peak in score units.
  bool nextSeed(const Candidate& c, double x, double y, double s, int min_peak, double max_sigma_px, Candidate* seed);

private:
  // A local maximum of the score in a blob (grid units).
  struct Peak
  {
    int x, y, g;
  };
  bool prominent(int gx, int gy, int g, int radius, int min_peak) const;
  // The blob's local maxima of score >= min_peak, the highest first (in scan
  // order among equal scores): found once per blob and frame, whatever the
  // discs, which only hide some of them.
  const std::vector<Peak>& peaksOf(int blob, int min_peak);
  void rowScores(int gy, int gx0, int gx1, int* out) const;

  const FramePlanes* planes_ = nullptr;
  const std::vector<Run>* runs_ = nullptr;
  const std::vector<Blob>* blobs_ = nullptr;
  std::vector<int> run_start_, run_list_;      // runs of blob k: run_list_[run_start_[k] .. run_start_[k + 1])
  std::vector<std::vector<cv::Vec3d>> discs_;  // per blob: x, y, radius (grid units)
  std::vector<std::vector<Peak>> peaks_;       // per blob: peaksOf's list, valid when peaks_min_[k] <= min_peak
  std::vector<int> peaks_min_;                 // per blob: the min_peak of its list (INT_MAX: not searched yet)
  std::vector<int> row_scores_;                // peaksOf's scores of three rows
};

// Stage 3c, colour frames without an ambient frame: dots whose core clips
// the signal channel over several cells (a laser far brighter than the
// exposure; its core white, every channel clipped), which the colour score
// sees only as a ring. A core is an 8-connected component of clipped signal
// cells (seeded on every third cell of every third row; a smaller core is
// the Gaussian fit's); cores closer than the larger radius are one dot (a
// core split by compression artefacts); one over 1/64 of the frame (a
// clipped sky, a lamp-lit wall) is not a dot. A core is a dot when its halo,
// the band 1 to 1 + d cells from it (d = max(2 cells, r / 4), r: the radius
// of a disc of its area; the beam's edge and the lens's bloom), exceeds the
// background (the median of the band 1 + 2 d to 1 + 4 d) in the signal by at
// least min_peak and 5 standard errors of the two bands' means, with
// the colour of the projector's light: the reference's excess at most
// led_reference + max_red_excess of the signal's (the colour test's bound;
// with max_red_excess 0, the colour score's reference term), the third's at
// most the signal's. The third gets no tighter bound: cameras mix it into a
// clipped laser's halo (cyan around green dots, magenta around red ones:
// 0.15-0.68 of the signal on the photos of test/data/real).
struct ClippedCore
{
  double x = 0, y = 0;    // pixels: the centroid of its clipped cells
  double radius = 0;      // pixels: of a disc of its area
  double excess[3] = {};  // halo over background per channel (r, g, b; DN)
  double halo = 0;        // the signal's excess (DN)
  int pixels = 0;
  cv::Rect box;  // pixels
};

class ClippedCoreFinder
{
public:
  // The cores of planes' frame whose halo passes and that no spot lies on
  // (within max(2 px, r / 4) of the centroid: a Gaussian fit found that
  // dot), into *cores.
  void find(const FramePlanes& planes, const FastParams& p, const Spots& spots, std::vector<ClippedCore>* cores);

private:
  void bind(const FramePlanes& planes);
  bool clipped(int gx, int gy) const;  // the signal of grid cell (gx, gy)
  void seedCores();                    // found_
  void fillCore(int gx, int gy);       // the core through a seed, onto found_ when of a dot's size
  void mergeCores();                   // found_ -> merged_
  bool haloPasses(const FastParams& p, ClippedCore* c);

  const FramePlanes* planes_ = nullptr;
  int sat_ = 255, bytes_ = 3, offset_ = 1;  // the signal's level and place in 8-bit interleaved pixels
  bool direct_ = false;                     // 8-bit interleaved: read in place
  cv::Mat visited_;                         // at least the grid's size, 0 between calls
  std::vector<cv::Point> stack_, cells_, touched_;
  std::vector<ClippedCore> found_, merged_;
  std::vector<int> row_;                     // decoded grid row
  std::vector<int> samples_[3];              // background samples per channel
  cv::Mat mask_, inner_, near_, mid_, far_;  // the halo test's core and its dilations
};

// Result of the refinement of one candidate (stage 4).
struct SpotFit
{
  double x = 0, y = 0, sigma = 0, flux = 0;
  double sigma_major = 0;  // along the footprint's long axis (sigma: the mean of both axes)
  double amplitude = 0;    // fitted peak of the added light (DN at the dot's mean albedo)
  // Colour of the added light: reference and third excess over background
  // relative to the signal's ("red" and "blue" for a green projector).
  double red_ratio = 0, blue_ratio = 0;
  double red_slack = 0;      // how far texture alone could move the reference ratio
  double blue_slack = 0;     // and the texture-free third ratio
  double background = 0;     // local background level of the signal (DN)
  double noise = 0;          // robust spread of the window's border about its background plane (DN)
  bool on_pedestal = false;  // found by the small-window retry
  bool clipped = false;      // clipped pixels in the dot: located by the Gaussian fit without them
  bool normalised = false;   // the added light was divided by the albedo under each pixel
  bool core = false;         // a clipped core found by stage 3c (ClippedCoreFinder), not fitted
  cv::Rect window;
};

// Amplitude of a Gaussian dot from its self-weighted sum: flux = A pi sigma^2.
double gaussianAmplitude(const SpotFit& fit);

// What the refinement needs besides the planes.
struct RefineSettings
{
  int fixed_radius = 0;  // window half size; 0 = 3 sigma
  double max_sigma = 6.0;
  bool subtract_texture = true;  // colour frames: signal - (a reference + b third), the rock's mix
  bool normalise_albedo = true;
  double albedo_floor_dn = 1.0;
  double plain_radius = 0.0;  // > 0: the final centroid is the plain moment in a disc of this many sigmas
  double plain_snr = 30.0;    // ... where the dot's peak is this many times the border's residual spread
  bool albedo_plane = false;  // normalise by the ambient's plane over the window, not each pixel's
};

// The weight field of one window: the dot's added light over the rock,
// divided by the albedo under each pixel where it is known, at the signal's
// samples (0 elsewhere); rows `stride` floats apart, padded with zeros.
struct WeightWindow
{
  int cx = -1, cy = -1, H = -1, stride = 0;
  double background = 0, noise = 0;
  double density = 1;  // fraction of the window's pixels where the signal is sampled (Bayer: 1/2 or 1/4)
  bool normalised = false;
  bool any_clipped = false;
  alignas(16) float vals[PlaneWindow::kSize];
  uint8_t usable[PlaneWindow::kSize];  // a sample, not clipped, not next to a clipped pixel (blooming)
};

// Scratch of the refinement (large: keep one per detector).
struct RefineScratch
{
  PlaneWindow planes;
  WeightWindow weights;
};

// Stage 4a. Iteratively Gaussian-weighted centroid of the weight field around
// pixel (x0, y0), starting from sigma0; a Gaussian fit without the clipped
// pixels when the dot has some. False when the fit finds no signal or leaves
// its window. Fills every SpotFit field but the colour; scratch->planes holds
// the final window's planes.
bool refineSpot(const FramePlanes& planes, const RefineSettings& rs, double x0, double y0, double sigma0,
                int fixed_radius, RefineScratch* scratch, SpotFit* out);

// The clipped plateau of the signal nearest to (x, y) in the window: its
// centroid and its half width across the columns. False when the window has
// no clipped sample (spot_detector_fit.cpp).
bool clippedPlateau(const PlaneWindow& pw, double x, double y, cv::Point2d* centre, double* half_width);

// Fits A exp(-r^2 / 2 sigma^2) to the usable pixels of w by Gauss-Newton,
// from fit's x, y, sigma; updates them, amplitude and flux. False (fit
// untouched) when too few pixels are usable or it does not converge.
bool fitGaussian(const WeightWindow& w, double max_sigma, SpotFit* fit);

// Stage 4b. Colour of the fitted spot's added light from the final window's
// planes: fills red_ratio, red_slack, blue_ratio (NaN when there is no signal
// excess over the rock).
void measureColour(const PlaneWindow& w, const ColourModel& model, double max_slack, SpotFit* fit);

// g[j] = exp(k (e0 + j)^2) for j in [0, n), by the recurrence
// g(e + 1) = g(e) exp(k (2e + 1)) outwards from the sample nearest the
// centre (where g is largest, so that an underflow only meets values that
// are below it anyway): four exp() instead of n, to 1e-13 relative.
inline void gaussianRun(double e0, double k, int n, double* g)
{
  const int c = std::min(n - 1, std::max(0, static_cast<int>(std::lround(-e0))));
  const double ec = e0 + c, step = std::exp(2.0 * k);
  g[c] = std::exp(k * ec * ec);
  double up = std::exp(k * (2.0 * ec + 1.0)), down = std::exp(k * (1.0 - 2.0 * ec));
  for (int j = c + 1; j < n; ++j, up *= step)
    g[j] = g[j - 1] * up;
  for (int j = c - 1; j >= 0; --j, down *= step)
    g[j] = g[j + 1] * down;
}

// Solves the symmetric 3 x 3 system with upper triangle s = (s00, s01, s02,
// s11, s12, s22) for x by Cramer's rule; false (x untouched) when |det| <=
// min_det. The hot paths' planes: cv::solve's general entry costs twenty
// times the arithmetic here.
inline bool solveSymmetric3(const double s[6], const double b[3], double min_det, double x[3])
{
  const double c00 = s[3] * s[5] - s[4] * s[4], c01 = s[2] * s[4] - s[1] * s[5], c02 = s[1] * s[4] - s[2] * s[3];
  const double det = s[0] * c00 + s[1] * c01 + s[2] * c02;
  if (!(std::abs(det) > min_det))
    return false;
  const double c11 = s[0] * s[5] - s[2] * s[2], c12 = s[1] * s[2] - s[0] * s[4], c22 = s[0] * s[3] - s[1] * s[1];
  x[0] = (c00 * b[0] + c01 * b[1] + c02 * b[2]) / det;
  x[1] = (c01 * b[0] + c11 * b[1] + c12 * b[2]) / det;
  x[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det;
  return true;
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
