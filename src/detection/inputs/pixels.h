// Reading the raw data of each accepted encoding (private to the core
// library; used by the inputs layer, spot_detector_planes.h): colour triples
// of a grid cell (a pixel, or a 2 x 2 Bayer cell), of a row of cells, and of
// one full-resolution pixel of a Bayer mosaic by interpolation; and the SIMD
// row passes of the common formats (spot_detector_rows.cpp). Values in native
// units (mono16: 16-bit), r, g, b order.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "detection/inputs/planes.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{
namespace pixels
{

// Offsets of r, g, b in an interleaved pixel and its size, in elements
// (bytes; 16-bit words for bgr16/rgb16).
struct Interleaved
{
  int r, g, b, bytes;
};

inline Interleaved interleavedLayout(PixelFormat format)
{
  switch (format)
  {
    case PixelFormat::kRgb8:
    case PixelFormat::kRgb16:
      return {0, 1, 2, 3};
    case PixelFormat::kBgra8:
      return {2, 1, 0, 4};
    case PixelFormat::kRgba8:
      return {0, 1, 2, 4};
    default:
      return {2, 1, 0, 3};
  }
}

// Colour (kRed, kGreen, kBlue) of the Bayer site (x, y).
inline int bayerColour(PixelFormat format, int x, int y)
{
  // Colours of the 2 x 2 cell, row-major: (0,0), (1,0), (0,1), (1,1).
  static const int kCells[4][4] = {
      {kRed, kGreen, kGreen, kBlue},  // rggb
      {kBlue, kGreen, kGreen, kRed},  // bggr
      {kGreen, kBlue, kRed, kGreen},  // gbrg
      {kGreen, kRed, kBlue, kGreen},  // grbg
  };
  const int pattern = static_cast<int>(format) - static_cast<int>(PixelFormat::kBayerRggb8);
  return kCells[pattern][(y & 1) * 2 + (x & 1)];
}

// BT.601 video-range YUV -> RGB with OpenCV's fixed-point coefficients (what
// cv::cvtColor(COLOR_YUV2BGR_UYVY) and cv_bridge give).
inline void yuvToRgb(int y, int u, int v, int* rgb)
{
  constexpr int kCy = 1220542, kCub = 2116026, kCug = -409993, kCvg = -852492, kCvr = 1673527, kShift = 20;
  const int yy = std::max(0, y - 16) * kCy, uu = u - 128, vv = v - 128, half = 1 << (kShift - 1);
  rgb[0] = std::min(255, std::max(0, (yy + half + kCvr * vv) >> kShift));
  rgb[1] = std::min(255, std::max(0, (yy + half + kCvg * vv + kCug * uu) >> kShift));
  rgb[2] = std::min(255, std::max(0, (yy + half + kCub * uu) >> kShift));
}

// r, g, b of pixel x in a yuv422 row (UYVY or YUYV).
inline void yuvPixel(const uint8_t* row, bool uyvy, int x, int* rgb)
{
  const uint8_t* pair = row + 4 * (x / 2);
  const int y = uyvy ? pair[1 + 2 * (x & 1)] : pair[2 * (x & 1)];
  const int u = uyvy ? pair[0] : pair[1], v = uyvy ? pair[2] : pair[3];
  yuvToRgb(y, u, v, rgb);
}

// r, g, b of grid cell (gx, gy): a pixel, or a Bayer 2 x 2 cell (green: the
// rounded mean of its two sites, as the SIMD pass computes it).
void decodeCell(const cv::Mat& m, PixelFormat format, int gx, int gy, int* rgb);
// The same for cells 0 .. n-1 of grid row gy, into out[3 gx + k].
void decodeRow(const cv::Mat& m, PixelFormat format, int gy, int n, int* out);

// A 16-bit colour sample in whole 8-bit DN (v / 257, rounded): the
// threshold pass of bgr16/rgb16 runs in DN like the 8-bit formats; the
// windows read the samples at full depth (FramePlanes::fillPixel).
inline int dn16(int v)
{
  return (v + 128) / 257;
}

// Intensity of a cell in 1/16 DN: mono 16 v (mono16: 16 v / 257), colour
// 16 (r + 2 g + b) / 4.
inline int intensity16(PixelFormat format, const int* rgb)
{
  if (format == PixelFormat::kMono8)
    return 16 * rgb[0];
  if (format == PixelFormat::kMono16)
    return (16 * rgb[0] + 128) / 257;
  return 4 * (rgb[0] + 2 * rgb[1] + rgb[2]);
}

// Raw sample of a Bayer mosaic with the coordinates reflected into the frame
// (reflection by an even offset keeps the site's colour).
inline int bayerRaw(const cv::Mat& m, int x, int y)
{
  x = x < 0 ? -x : (x >= m.cols ? 2 * (m.cols - 1) - x : x);
  y = y < 0 ? -y : (y >= m.rows ? 2 * (m.rows - 1) - y : y);
  x = std::min(std::max(x, 0), m.cols - 1);
  y = std::min(std::max(y, 0), m.rows - 1);
  return m.ptr<uint8_t>(y)[x];
}

// Channel ch at pixel (x, y) of a Bayer mosaic: the sample where the site has
// that colour, else the bilinear mean of the nearest sites of it.
int bayerChannel(const cv::Mat& m, PixelFormat format, int x, int y, int ch);

}  // namespace pixels

namespace rows
{
// Appends candidate cell (x, y) to the runs, extending the last run when it
// ends next to it.
inline void markCell(std::vector<Run>* runs, int y, int x)
{
  if (!runs->empty() && runs->back().y == y && runs->back().x1 == x - 1)
    runs->back().x1 = x;
  else
    runs->push_back({y, x, x});
}

// SIMD row passes of the threshold pass, 16 cells at a time; both append the
// runs of candidate cells of grid row gy and are exact equivalents of the
// generic scoring (FramePlanes::scoreRow). colourRowRuns: interleaved 8-bit
// colour frames (with or without an ambient frame: empty = none) and Bayer
// frames without one, colour path; false for the others (the caller then
// scores generically). acc (may be null) accumulates the scores.
bool colourRowRuns(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format, const ColourModel& model,
                   int k_ref, int k_third, int threshold, int gy, std::vector<Run>* runs, uint16_t* acc);
// The colour path's signed scores of one row (FramePlanes::scoreRow's
// values, exactly): interleaved 8-bit colour frames with an ambient frame of
// the same type (SIMD), 16-bit colour frames with or without one; false for
// the others (the caller then scores generically).
bool colourScoreRow(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format, const ColourModel& model,
                    int k_ref, int k_third, int gy, int16_t* out);
// mono8 intensity path: candidate where 16 v - level >= threshold, both
// constant over blocks of `block` pixels (level[], threshold[] per block).
void monoRowRuns(const uint8_t* row, int width, int y, int block, const int* level, const int* threshold,
                 std::vector<Run>* runs);
}  // namespace rows

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
