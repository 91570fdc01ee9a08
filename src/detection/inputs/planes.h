// The inputs layer of the fast method (private to the core library): what a
// frame of any accepted encoding gives the detection stages, so that they do
// not each handle encodings (docs/spot_detector.md#input).
//
// Two views of a frame (and of its ambient frame, when one is given):
//  - the score grid, for the threshold pass: one score per cell (a pixel, or
//    a 2 x 2 cell of a Bayer mosaic: half the resolution, all four samples
//    read once), computed on the raw data row by row. Colour path (a colour
//    frame and a green, red or blue projector): the projector's share of the
//    cell's colour. By default (FastParams::local_colour) measured against
//    the rock's own colour around the cell: the component along the
//    projector's colour of what the rock's local colour does not explain, in
//    DN of the signal channel, against thresholds per block from the local
//    noise (local_colour.cpp; nothing is assumed of the rock's colour); else
//    the fixed contrast signal - max(w_ref reference, w_third third), in DN,
//    against one threshold. Intensity path (mono frames, nir/white
//    projectors): the intensity over its local background (an opening of
//    16 x 16-cell block means), in 1/16 DN, against a threshold per block
//    from the local noise. With an ambient frame both score frame - ambient.
//  - windows: planes at full resolution around a candidate (fillWindow): the
//    signal (the projector's colour; on a Bayer mosaic only the sites of
//    that colour are samples, flagged), the reference (the channel that
//    carries the rock's albedo with little dot light: red for green dots;
//    interpolated at every pixel), the third channel, the same planes of the
//    ambient frame, and the clipped pixels.
// Window values are in 8-bit DN (mono16 / 257). Grid cell (gx, gy) covers
// full-resolution pixels [scale gx, scale gx + scale) x [scale gy, ...).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/detection/spot_detector.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

enum Channel
{
  kRed = 0,
  kGreen = 1,
  kBlue = 2,
};

// How the projector's light shows in a colour camera's channels. The score
// weights are upper bounds of the rock's signal/reference and signal/third
// ratios (reddish rock: g/r 0.55-0.65, b/r ~0.35), so that sunlit rock of
// any albedo scores 0; the led ratios are the sensor's response to the
// projector's light in the reference and third channels relative to the
// signal channel (the colour test).
struct ColourModel
{
  bool colour = true;  // false: intensity path
  int signal = kGreen, reference = kRed, third = kBlue;
  double reference_weight = 0.75, third_weight = 1.0;
  double led_reference = 0.08, led_third = 0.22;
};

ColourModel colourModel(ProjectorColor color, bool colour_frame, const FastParams& p);

// A horizontal run of candidate cells [x0, x1] in grid row y.
struct Run
{
  int y, x0, x1;
};

// Planes around a candidate, full resolution, (2H+1)^2 pixels, rows `stride`
// floats apart (padded with zeros to a multiple of 4 lanes).
struct PlaneWindow
{
  static constexpr int kMaxRadius = 24;
  static constexpr int kStride = 52;  // 2 * kMaxRadius + 1 rounded up to 4 lanes
  static constexpr int kSize = (2 * kMaxRadius + 1) * kStride;
  enum Flag : uint8_t
  {
    kSample = 1,   // the signal plane is measured here (not a Bayer site of another colour)
    kClipped = 2,  // a sample used here (signal, reference, interpolation support; or ambient) is clipped
  };

  int cx = -1, cy = -1, H = -1, stride = 0;
  // Width of the border ring that gives the background: 2 on a Bayer
  // mosaic, whose red and blue sites miss every other row and column.
  int ring = 1;
  bool colour = false, ambient = false;
  alignas(16) float signal[kSize];
  alignas(16) float reference[kSize];
  alignas(16) float third[kSize];
  alignas(16) float ambient_signal[kSize];
  alignas(16) float ambient_reference[kSize];
  alignas(16) float ambient_third[kSize];
  uint8_t flags[kSize];

  int index(int dx, int dy) const { return (dy + H) * stride + dx + H; }
};

// The matched path's noise statistics: the smoothed difference score's
// median (centre) and robust sigma over the frame, in DN.
struct MatchedNoise
{
  float centre = 0.0f;
  double sigma = 0.0;
  bool valid = false;
};

class FramePlanes
{
public:
  // Binds a frame that passed SpotDetector's checks (ambient: empty or of the
  // same size and type) for the stages that follow; builds the intensity
  // path's background and noise maps. The frames must outlive the use.
  // fixed (valid): the matched path takes its thresholds from these
  // statistics instead of this image's (a region of a frame whose statistics
  // were measured on the whole of an earlier one; SpotDetector::detectIn).
  // ambient_fine (optional; interleaved 8-bit colour and mono8): the ambient
  // frame's unrounded values (CV_32F, its channels), which the windows read
  // instead of `ambient` where finite; `ambient` is then its rounding
  // (non-finite values: 0 in both).
  void bind(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format, ProjectorColor color, const FastParams& p,
            const MatchedNoise* fixed = nullptr, const cv::Mat& ambient_fine = cv::Mat());

  const ColourModel& model() const { return model_; }
  bool colourPath() const { return model_.colour; }
  bool hasAmbient() const { return !ambient_.empty(); }
  PixelFormat format() const { return format_; }
  int cols() const { return grid_cols_; }
  int rows() const { return grid_rows_; }
  int scale() const { return scale_; }
  int frameCols() const { return image_.cols; }
  int frameRows() const { return image_.rows; }
  const cv::Mat& image() const { return image_; }
  // Clipped at or above this (native units of the format's samples).
  int saturation() const { return saturation_; }
  // Score units per DN (colour path 1, intensity path 16).
  int unit() const { return unit_; }
  // A blob's peak score must reach this (min_peak in score units; on a Bayer
  // grid 3/4 of it: a 2 x 2 cell averages a dot's peak down by up to a
  // quarter for sigma 2 px, depending on where the dot falls in the cell).
  int peakThreshold(int min_peak) const
  {
    if (matchedPath())
      return matched_peak_;
    return scale_ == 2 ? (3 * min_peak * unit_ + 3) / 4 : min_peak * unit_;
  }
  // The same at grid cell (gx, gy): the local path's threshold of the cell's
  // block, else peakThreshold().
  int peakThresholdAt(int gx, int gy, int min_peak) const
  {
    if (!localPath() && (model_.colour || matchedPath()))
      return peakThreshold(min_peak);
    return block_peak_.at<int>(std::min(std::max(gy, 0), grid_rows_ - 1) / kBlock,
                               std::min(std::max(gx, 0), grid_cols_ - 1) / kBlock);
  }
  // How many noise sigmas a score at cell (gx, gy) stands for (the local
  // path's noise of the cell's block; the matched path's of the frame; else
  // the score over its threshold): what ranks candidates when a frame holds
  // more than the pattern can.
  double significance(int gx, int gy, double score) const;
  // Colour path without an ambient frame, FastParams::local_colour: scores
  // against the rock's local colour, thresholds per block from the noise.
  bool localPath() const { return local_; }
  // The coarse pass's threshold of each 4 x 4-cell bin (CV_8U, the coarse
  // map's size) on the local path: the bin mean's own noise; empty else.
  const cv::Mat& coarseThresholds() const { return coarse_threshold_; }
  // Colour path with an ambient frame: scores are the matched-filtered
  // difference (FastParams::matched_sigma_px), thresholds from its noise.
  bool matchedPath() const { return !matched_.empty(); }
  // The statistics the matched path used (valid only on that path).
  const MatchedNoise& matchedNoise() const { return matched_noise_; }
  // Full-resolution coordinate of a grid coordinate (centre of its cell).
  double toPixel(double g) const { return scale_ * g + 0.5 * (scale_ - 1); }

  // The runs of candidate cells of grid row gy (score at or above the
  // threshold), appended; adds every cell's score (floored at 0, capped at
  // 255) to acc[gx] when acc is not null (colour path: the coarse pass).
  void rowRuns(int gy, std::vector<Run>* runs, uint16_t* acc);
  // Score of one cell; -1 outside the grid.
  int scoreAt(int gx, int gy) const;
  // Scores of the cells gx0..gx1 of row gy (all in the grid) into out[0..]:
  // scoreAt's, with the format's dispatch once per run.
  void scoreRun(int gy, int gx0, int gx1, int* out) const;

  // The planes of the (2H+1)^2 window centred on pixel (cx, cy), which must
  // lie inside the frame (H <= PlaneWindow::kMaxRadius).
  void fillWindow(int cx, int cy, int H, PlaneWindow* w) const;

private:
  struct Triple
  {
    int c[3];  // r, g, b in native units (16-bit frames: mono, all three the same)
  };
  Triple cellAt(const cv::Mat& m, int gx, int gy) const;
  int colourScore(const Triple& t) const;
  int intensity(const Triple& t) const;  // 1/16 DN
  int levelOf(int gx, int gy) const;     // intensity path: background of the cell's block (1/16 DN)
  int thresholdOf(int gx, int gy) const;
  int cellScore(int gx, int gy) const;
  void scoreRow(int gy, int16_t* out) const;
  void buildIntensityMaps(const FastParams& p);
  bool fusedRowRuns(int gy, std::vector<Run>* runs, uint16_t* acc);
  void fillPixel(const cv::Mat& m, int x, int y, float* s, float* r, float* t, bool* sample, bool* clipped) const;

  cv::Mat image_, ambient_, ambient_fine_;
  void fillFineAmbient(PlaneWindow* w) const;
  PixelFormat format_ = PixelFormat::kBgr8;
  ColourModel model_;
  int grid_cols_ = 0, grid_rows_ = 0, scale_ = 1, unit_ = 1;
  int k_ref_ = 192, k_third_ = 256;  // score weights in 1/256
  int threshold_ = 8;                // colour path (DN)
  int saturation_ = 250;             // native units
  // Intensity path, per block of kBlock x kBlock cells: background level and
  // threshold above it (1/16 DN). The local path: the cell threshold per
  // block (DN).
  static constexpr int kBlock = 16;
  cv::Mat block_level_, block_threshold_;
  // The local path (local_colour.cpp), in 1/16 DN: the raw score of every
  // cell (CV_16S) and per 4 x 4-cell bin its background (CV_16S; a cell's
  // score is raw - background) and the raw score's cell threshold (CV_32S);
  // per block the peak threshold (CV_32S) and the score's noise sigma
  // (CV_32F); the coarse pass's thresholds.
  bool local_ = false;
  cv::Mat local_scores_, local_background_, bin_threshold_, block_peak_, block_sigma_, coarse_threshold_;
  void buildLocalColour(const FastParams& p);
  int local_row_ = -1;                         // rowRuns: the bin row of local_thr_, local_bg_
  std::vector<int16_t> local_thr_, local_bg_;  // rowRuns: per cell of that bin row
  int localScore(int gx, int gy) const
  {
    return local_scores_.at<int16_t>(gy, gx) - local_background_.at<int16_t>(gy / 4, gx / 4);
  }
  // Matched path: the smoothed difference score per cell, in 1/kMatchedUnit
  // DN above the frame's median; the peak threshold in the same units.
  static constexpr int kMatchedUnit = 8;
  cv::Mat matched_, matched_raw_, matched_smooth_;
  int matched_peak_ = 0;
  MatchedNoise matched_noise_;
  void buildMatchedScores(const FastParams& p, const MatchedNoise* fixed);
  MatchedNoise sampledNoise(const cv::Mat& smooth);
  std::vector<float> noise_sample_, noise_scratch_;  // sampledNoise's buffers, kept from frame to frame
  std::vector<int16_t> row_scores_;
  mutable std::vector<int> decoded_, decoded_ambient_;  // scoreRow's scratch (one FramePlanes per thread)
  mutable std::vector<int> decoded_triples_;            // intensityRow's
  void intensityRow(const cv::Mat& m, int gy, int* out) const;
};

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
