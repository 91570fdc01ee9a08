// The sensor's share of a frame: shot and read noise on the linear radiance,
// clipping and 8-bit quantisation, one row at a time. Blooming at clipping,
// Bayer output or a different bit depth would go here.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// Noise of one frame. The draws are seeded per (noise_seed, t, exposure,
// row), so rows are independent and the result does not depend on the thread
// count. `exposure` tells apart exposures rendered at one time t (0: the
// projector-on frame, 1: the projector-off one): two exposures of a real
// camera never share their noise, so an ambient frame rendered at an
// on-frame's own time must not cancel the on-frame's noise.
class SensorNoise
{
public:
  SensorNoise(const SensorParams& sensor, uint32_t noise_seed, double t, uint32_t exposure = 0);

  // False when both shot and read noise are off (applyRow would do nothing).
  bool enabled() const { return enabled_; }

  // Clips row v's linear radiance L (n values, DN) at 0 and adds shot noise
  // (variance L * gain) and read noise. N: scratch of n + 5 floats, sd: of n;
  // the three must not overlap (restrict: the loops vectorise without
  // run-time overlap checks).
  void applyRow(int v, int n, float* __restrict L, float* __restrict N, float* __restrict sd) const;
  // The charge path (SensorReadout::chargePath): shot noise only, clipped
  // at 0, then after the full well the read noise from its own stream.
  void applyShotRow(int v, int n, float* __restrict L, float* __restrict N, float* __restrict sd) const;
  void applyReadRow(int v, int n, float* __restrict L, float* __restrict N) const;

private:
  void normals(uint64_t key, int v, int n, float* __restrict N) const;

  const std::vector<float>& table_;  // standard normal quantiles (noise.h)
  float read_var_;                   // DN^2
  float gain_;                       // DN per electron, 0 without shot noise
  bool enabled_;
  uint64_t frame_key_;
};

// Rounds and saturates n linear values (DN) to 8 bits.
void quantizeRow(const float* L, int n, uint8_t* out);

// The sensor's output (SensorParams::output) from the render buffer's
// radiance (B, G, R per pixel, DN): which signal each pixel records (all
// three channels, the mono sum, or its Bayer site's channel) and how it is
// written out. The signal goes through the noise in between.
class SensorReadout
{
public:
  SensorReadout(const SensorParams& sensor, const float mono_weights[3]);

  // The OpenCV type of the image and of SimFrame::linear.
  int imageType() const;
  int linearType() const { return mono_ ? CV_32FC1 : CV_32FC3; }
  // Values per row of the recorded signal: 3 * width (bgr8, rgb8, bgr16,
  // rgb16) or width.
  int samplesPerRow(int width) const { return colour_ ? 3 * width : width; }
  // True when the charge must be clipped or bloomed between the shot and
  // the read noise (full well below the 8-bit range, or blooming on).
  bool chargePath() const { return charge_path_; }
  float fullWell() const { return full_well_; }
  // Bayer: the buffer channel (0 B, 1 G, 2 R) recorded at pixel (u, v).
  int bayerChannel(int u, int v) const { return bayer_[(v & 1) * 2 + (u & 1)]; }

  // The recorded signal of row v from the radiance L (3 * width floats):
  // L itself for colour outputs, else written to S (width floats).
  float* record(int v, int width, float* L, float* S) const;
  // The largest noise-free value the pixel u of row v records (for
  // SimFrame::clipped): any channel of a colour or Bayer camera (a dot
  // covers every site), the mono sum.
  float pixelPeak(int u, const float* L) const;
  // Writes row v of the image from the noisy signal S.
  void write(int v, const float* S, cv::Mat* image) const;

private:
  bool colour_, mono_, bayer_on_, swap_rb_, sixteen_;
  int step_;  // 16-bit outputs: the converter's step in 16-bit units
  bool charge_path_;
  float full_well_;
  float w_[3];
  int bayer_[4];  // channel at (u & 1, v & 1): index (v & 1) * 2 + (u & 1)
};

// Charge above the full well of a frame of recorded signals (CV_32FC1, one
// row per image row, channels interleaved: each column of the matrix is one
// channel of one image column): clipped (Blooming::kNone) or spilled along
// its column, half up and half down, into pixels with room (kColumn); what
// leaves the frame is lost, the rest is conserved.
void spillCharge(Blooming blooming, float full_well, cv::Mat* charge);

}  // namespace sim
}  // namespace structured_light_stabilizer
