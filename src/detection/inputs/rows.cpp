// Reading raw rows of every accepted encoding, and the SIMD row passes of the
// threshold pass for the common ones (see spot_detector_pixels.h). A block of
// 16 cells without a candidate costs a deinterleaving load, a few
// multiply/max/saturating-subtract operations and one test, which keeps the
// pass near the memory bandwidth limit.
#include <algorithm>

#include <opencv2/core/hal/intrin.hpp>

#include "structured_light_stabilizer/common/cpu_features.h"
#include "detection/inputs/pixels.h"
#include "detection/inputs/rows_ssse3.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{
namespace pixels
{

namespace
{
// Bayer cell: r, g (rounded mean of the two greens), b.
void bayerCell(const cv::Mat& m, PixelFormat format, int gx, int gy, int* rgb)
{
  const uint8_t* r0 = m.ptr<uint8_t>(2 * gy) + 2 * gx;
  const uint8_t* r1 = m.ptr<uint8_t>(2 * gy + 1) + 2 * gx;
  const int v[4] = {r0[0], r0[1], r1[0], r1[1]};
  int green = 0;
  for (int k = 0; k < 4; ++k)
  {
    const int c = bayerColour(format, k & 1, k >> 1);
    if (c == kGreen)
      green += v[k];
    else
      rgb[c] = v[k];
  }
  rgb[kGreen] = (green + 1) >> 1;
}
}  // namespace

void decodeCell(const cv::Mat& m, PixelFormat format, int gx, int gy, int* rgb)
{
  switch (format)
  {
    case PixelFormat::kMono8:
      rgb[0] = rgb[1] = rgb[2] = m.ptr<uint8_t>(gy)[gx];
      return;
    case PixelFormat::kMono16:
      rgb[0] = rgb[1] = rgb[2] = m.ptr<uint16_t>(gy)[gx];
      return;
    case PixelFormat::kUyvy:
    case PixelFormat::kYuyv:
      yuvPixel(m.ptr<uint8_t>(gy), format == PixelFormat::kUyvy, gx, rgb);
      return;
    default:
      break;
  }
  if (isBayer(format))
  {
    bayerCell(m, format, gx, gy, rgb);
    return;
  }
  const Interleaved L = interleavedLayout(format);
  if (format == PixelFormat::kBgr16 || format == PixelFormat::kRgb16)
  {
    const uint16_t* px = m.ptr<uint16_t>(gy) + gx * L.bytes;
    rgb[0] = dn16(px[L.r]);
    rgb[1] = dn16(px[L.g]);
    rgb[2] = dn16(px[L.b]);
    return;
  }
  const uint8_t* px = m.ptr<uint8_t>(gy) + gx * L.bytes;
  rgb[0] = px[L.r];
  rgb[1] = px[L.g];
  rgb[2] = px[L.b];
}

void decodeRow(const cv::Mat& m, PixelFormat format, int gy, int n, int* out)
{
  if (format == PixelFormat::kMono8 || format == PixelFormat::kMono16)
  {
    for (int gx = 0; gx < n; ++gx)
    {
      const int v = format == PixelFormat::kMono8 ? m.ptr<uint8_t>(gy)[gx] : m.ptr<uint16_t>(gy)[gx];
      out[3 * gx] = out[3 * gx + 1] = out[3 * gx + 2] = v;
    }
    return;
  }
  if (format == PixelFormat::kBgr8 || format == PixelFormat::kRgb8 || format == PixelFormat::kBgra8 ||
      format == PixelFormat::kRgba8)
  {
    const Interleaved L = interleavedLayout(format);
    const uint8_t* px = m.ptr<uint8_t>(gy);
    for (int gx = 0; gx < n; ++gx, px += L.bytes)
    {
      out[3 * gx] = px[L.r];
      out[3 * gx + 1] = px[L.g];
      out[3 * gx + 2] = px[L.b];
    }
    return;
  }
  if (format == PixelFormat::kBgr16 || format == PixelFormat::kRgb16)
  {
    const Interleaved L = interleavedLayout(format);
    const uint16_t* px = m.ptr<uint16_t>(gy);
    for (int gx = 0; gx < n; ++gx, px += L.bytes)
    {
      out[3 * gx] = dn16(px[L.r]);
      out[3 * gx + 1] = dn16(px[L.g]);
      out[3 * gx + 2] = dn16(px[L.b]);
    }
    return;
  }
  for (int gx = 0; gx < n; ++gx)
    decodeCell(m, format, gx, gy, out + 3 * gx);
}

int bayerChannel(const cv::Mat& m, PixelFormat format, int x, int y, int ch)
{
  const int own = bayerColour(format, x, y);
  if (own == ch)
    return bayerRaw(m, x, y);
  if (ch == kGreen)  // at a red or blue site: the four direct neighbours are green
    return (bayerRaw(m, x - 1, y) + bayerRaw(m, x + 1, y) + bayerRaw(m, x, y - 1) + bayerRaw(m, x, y + 1) + 2) >> 2;
  if (own == kGreen)  // red/blue at a green site: the pair left/right or above/below
  {
    if (bayerColour(format, x + 1, y) == ch)
      return (bayerRaw(m, x - 1, y) + bayerRaw(m, x + 1, y) + 1) >> 1;
    return (bayerRaw(m, x, y - 1) + bayerRaw(m, x, y + 1) + 1) >> 1;
  }
  // Red at a blue site or blue at a red one: the four diagonal neighbours.
  return (bayerRaw(m, x - 1, y - 1) + bayerRaw(m, x + 1, y - 1) + bayerRaw(m, x - 1, y + 1) +
          bayerRaw(m, x + 1, y + 1) + 2) >>
         2;
}

}  // namespace pixels

namespace rows
{

namespace
{
// The generic score of one cell (FramePlanes::colourScore) and its verdict,
// for the tails of the SIMD loops.
inline void scalarCell(const int* rgb, const ColourModel& model, int k_ref, int k_third, int threshold, int y, int x,
                       std::vector<Run>* runs, uint16_t* acc)
{
  const int s = rgb[model.signal] - std::max((k_ref * rgb[model.reference]) >> 8, (k_third * rgb[model.third]) >> 8);
  if (acc)
    acc[x] = static_cast<uint16_t>(acc[x] + std::min(255, std::max(0, s)));
  if (s >= threshold)
    markCell(runs, y, x);
}

// Which Scale modes a pass's weights allow (see below).
inline int passModes(int k_ref, int k_third)
{
  if (k_ref <= 256 && k_third == 256)
    return 0;
  return k_ref <= 256 && k_third <= 256 ? 1 : 2;
}

#if CV_SIMD128
// (k x) >> 8 for 16 values, k in 1/256 up to 4 (k = 256 hi + lo),
// saturated at 255: the same as the scalar (k * x) >> 8 below 256. kMode 0:
// k = 256 (nothing to do), 1: k <= 256 (one 16-bit product), 2: any k. The
// colour table's weights keep the green pass at modes 1 and 0, as cheap as
// a plain greenness: the pass stays at the memory bandwidth limit.
struct Scale
{
  cv::v_uint16x8 k, hi, lo;
  explicit Scale(int w)
    : k(cv::v_setall_u16(static_cast<uint16_t>(std::min(w, 256)))),
      hi(cv::v_setall_u16(static_cast<uint16_t>(w >> 8))),
      lo(cv::v_setall_u16(static_cast<uint16_t>(w & 255)))
  {
  }
  template <int kMode>
  cv::v_uint8x16 apply(const cv::v_uint8x16& x) const
  {
    if (kMode == 0)
      return x;
    cv::v_uint16x8 a, b;
    cv::v_expand(x, a, b);
    if (kMode == 1)
      return cv::v_pack(cv::v_shr<8>(cv::v_mul_wrap(a, k)), cv::v_shr<8>(cv::v_mul_wrap(b, k)));
    a = cv::v_mul_wrap(a, hi) + cv::v_shr<8>(cv::v_mul_wrap(a, lo));
    b = cv::v_mul_wrap(b, hi) + cv::v_shr<8>(cv::v_mul_wrap(b, lo));
    return cv::v_pack(a, b);
  }
};

// Scale modes of the reference and the third channel for a pass (kModes
// 0: 1 and 0, 1: 1 and 1, 2: 2 and 2; see Scale).
constexpr int refMode(int modes)
{
  return modes == 2 ? 2 : 1;
}
constexpr int thirdMode(int modes)
{
  return modes == 0 ? 0 : modes == 1 ? 1 : 2;
}

// (a + b + 1) >> 1 for 16 values (the rounded mean of a Bayer cell's greens).
inline cv::v_uint8x16 average(const cv::v_uint8x16& a, const cv::v_uint8x16& b)
{
  cv::v_uint16x8 a0, a1, b0, b1;
  cv::v_expand(a, a0, a1);
  cv::v_expand(b, b0, b1);
  const cv::v_uint16x8 one = cv::v_setall_u16(1);
  return cv::v_pack(cv::v_shr<1>(a0 + b0 + one), cv::v_shr<1>(a1 + b1 + one));
}

// The cells of a 16-lane comparison mask that hold, as runs (few: out of
// line, so that the common case keeps no buffer on the stack).
__attribute__((noinline)) void markHitCells(const cv::v_uint8x16& m, int y, int x, std::vector<Run>* runs)
{
  alignas(16) uint8_t hit[16];
  cv::v_store(hit, m);
  for (int i = 0; i < 16; ++i)
    if (hit[i])
      markCell(runs, y, x + i);
}

inline void markHits(const cv::v_uint8x16& m, int y, int x, std::vector<Run>* runs)
{
  if (cv::v_check_any(m))
    markHitCells(m, y, x, runs);
}

// Scores s - max(k_ref r, k_third t) (saturating) of 16 cells: runs and acc.
__attribute__((always_inline)) inline void emit(const cv::v_uint8x16& s, const cv::v_uint8x16& threshold, int y, int x,
                                                std::vector<Run>* runs, uint16_t* acc)
{
  if (acc)
  {
    cv::v_uint16x8 lo, hi;
    cv::v_expand(s, lo, hi);
    cv::v_store(acc + x, cv::v_load(acc + x) + lo);
    cv::v_store(acc + x + 8, cv::v_load(acc + x + 8) + hi);
  }
  markHits(s >= threshold, y, x, runs);
}
#endif

#if CV_SIMD128
// The SIMD part of interleavedRow: cells [0, returned) of the row. kAmbient:
// score frame - ambient (saturating at 0, as the scalar score).
template <int kC, int kS, int kR, int kT, int kModes, bool kAmbient>
int interleavedSimd(const uint8_t* row, const uint8_t* ambient, int width, int y, int k_ref, int k_third, int threshold,
                    std::vector<Run>* runs, uint16_t* acc)
{
  const Scale scale_ref(k_ref), scale_third(k_third);
  const cv::v_uint8x16 vthr = cv::v_setall_u8(static_cast<uint8_t>(std::min(threshold, 255)));
  int x = 0;
  for (; x + 16 <= width; x += 16)
  {
    cv::v_uint8x16 c[4];
    if (kC == 3)
      cv::v_load_deinterleave(row + 3 * x, c[0], c[1], c[2]);
    else
      cv::v_load_deinterleave(row + 4 * x, c[0], c[1], c[2], c[3]);
    if (kAmbient)
    {
      cv::v_uint8x16 a[4];
      if (kC == 3)
        cv::v_load_deinterleave(ambient + 3 * x, a[0], a[1], a[2]);
      else
        cv::v_load_deinterleave(ambient + 4 * x, a[0], a[1], a[2], a[3]);
      for (int k = 0; k < 3; ++k)
        c[k] = c[k] - a[k];
    }
    emit(c[kS] - cv::v_max(scale_ref.apply<refMode(kModes)>(c[kR]), scale_third.apply<thirdMode(kModes)>(c[kT])), vthr,
         y, x, runs, acc);
  }
  return x;
}
#endif

// Interleaved 8-bit colour: kS, kR, kT are the byte offsets of the signal,
// reference and third channels in a pixel of kC bytes; ambient (may be
// null) the same row of the ambient frame.
// The runs of a row's hits, for interleaved3RowSsse3.
struct RunSink
{
  std::vector<Run>* runs;
  int y;
  static void add(void* context, int x, unsigned mask)
  {
    const RunSink& sink = *static_cast<const RunSink*>(context);
    for (int i = 0; i < 16; ++i)
      if (mask & (1u << i))
        markCell(sink.runs, sink.y, x + i);
  }
};

template <int kC, int kS, int kR, int kT, int kModes>
void interleavedRow(const uint8_t* row, const uint8_t* ambient, int width, int y, const ColourModel& model, int k_ref,
                    int k_third, int threshold, std::vector<Run>* runs, uint16_t* acc)
{
  int x = 0;
  if (kC == 3 && haveSsse3Kernels())
  {
    RunSink sink{runs, y};
    x = interleaved3RowSsse3(row, ambient, width, kS, kR, kT, refMode(kModes), thirdMode(kModes), k_ref, k_third,
                             threshold, acc, &RunSink::add, &sink);
  }
#if CV_SIMD128
  if (x == 0)
    x = ambient ? interleavedSimd<kC, kS, kR, kT, kModes, true>(row, ambient, width, y, k_ref, k_third, threshold, runs,
                                                                acc)
                : interleavedSimd<kC, kS, kR, kT, kModes, false>(row, ambient, width, y, k_ref, k_third, threshold,
                                                                 runs, acc);
#endif
  for (; x < width; ++x)
  {
    const uint8_t* px = row + kC * x;
    int rgb[3];
    rgb[model.signal] = px[kS];
    rgb[model.reference] = px[kR];
    rgb[model.third] = px[kT];
    if (ambient)
    {
      const uint8_t* pa = ambient + kC * x;
      rgb[model.signal] = std::max(0, rgb[model.signal] - pa[kS]);
      rgb[model.reference] = std::max(0, rgb[model.reference] - pa[kR]);
      rgb[model.third] = std::max(0, rgb[model.third] - pa[kT]);
    }
    scalarCell(rgb, model, k_ref, k_third, threshold, y, x, runs, acc);
  }
}

// Bayer: kPattern 0..3 = rggb, bggr, gbrg, grbg; kColour = the signal channel
// (green: reference red, third blue; red: green, blue; blue: red, green).
template <int kPattern, int kColour, int kModes>
void bayerRow(const cv::Mat& m, PixelFormat format, int cells, int gy, const ColourModel& model, int k_ref, int k_third,
              int threshold, std::vector<Run>* runs, uint16_t* acc)
{
  int x = 0;
#if CV_SIMD128
  const uint8_t* r0 = m.ptr<uint8_t>(2 * gy);
  const uint8_t* r1 = m.ptr<uint8_t>(2 * gy + 1);
  const Scale scale_ref(k_ref), scale_third(k_third);
  const cv::v_uint8x16 vthr = cv::v_setall_u8(static_cast<uint8_t>(std::min(threshold, 255)));
  for (; x + 16 <= cells; x += 16)
  {
    cv::v_uint8x16 e0, o0, e1, o1;
    cv::v_load_deinterleave(r0 + 2 * x, e0, o0);
    cv::v_load_deinterleave(r1 + 2 * x, e1, o1);
    // r, g1, g2, b of the pattern.
    const cv::v_uint8x16 R = kPattern == 0 ? e0 : kPattern == 1 ? o1 : kPattern == 2 ? e1 : o0;
    const cv::v_uint8x16 B = kPattern == 0 ? o1 : kPattern == 1 ? e0 : kPattern == 2 ? o0 : e1;
    const cv::v_uint8x16 G = kPattern <= 1 ? average(o0, e1) : average(e0, o1);
    const cv::v_uint8x16 S = kColour == kGreen ? G : kColour == kRed ? R : B;
    const cv::v_uint8x16 Ref = kColour == kGreen ? R : kColour == kRed ? G : R;
    const cv::v_uint8x16 T = kColour == kGreen ? B : kColour == kRed ? B : G;
    emit(S - cv::v_max(scale_ref.apply<refMode(kModes)>(Ref), scale_third.apply<thirdMode(kModes)>(T)), vthr, gy, x,
         runs, acc);
  }
#endif
  for (; x < cells; ++x)
  {
    int rgb[3];
    pixels::decodeCell(m, format, x, gy, rgb);
    scalarCell(rgb, model, k_ref, k_third, threshold, gy, x, runs, acc);
  }
}

using InterleavedPass = void (*)(const uint8_t*, const uint8_t*, int, int, const ColourModel&, int, int, int,
                                 std::vector<Run>*, uint16_t*);
using BayerPass = void (*)(const cv::Mat&, PixelFormat, int, int, const ColourModel&, int, int, int, std::vector<Run>*,
                           uint16_t*);

// Offsets (s, r, t) of the colours red, green, blue (indexed by the signal
// channel), blue-first and red-first byte orders.
template <int kC, int kModes>
InterleavedPass interleavedPassOf(bool red_first, int signal)
{
  static const InterleavedPass kBgr[3] = {&interleavedRow<kC, 2, 1, 0, kModes>, &interleavedRow<kC, 1, 2, 0, kModes>,
                                          &interleavedRow<kC, 0, 2, 1, kModes>};
  static const InterleavedPass kRgb[3] = {&interleavedRow<kC, 0, 1, 2, kModes>, &interleavedRow<kC, 1, 0, 2, kModes>,
                                          &interleavedRow<kC, 2, 0, 1, kModes>};
  return (red_first ? kRgb : kBgr)[signal];
}

template <int kC>
InterleavedPass interleavedPass(bool red_first, int signal, int modes)
{
  return modes == 0   ? interleavedPassOf<kC, 0>(red_first, signal)
         : modes == 1 ? interleavedPassOf<kC, 1>(red_first, signal)
                      : interleavedPassOf<kC, 2>(red_first, signal);
}

template <int kPattern, int kModes>
BayerPass bayerPassOf(int signal)
{
  static const BayerPass kPasses[3] = {&bayerRow<kPattern, kRed, kModes>, &bayerRow<kPattern, kGreen, kModes>,
                                       &bayerRow<kPattern, kBlue, kModes>};
  return kPasses[signal];
}

template <int kPattern>
BayerPass bayerPass(int signal, int modes)
{
  return modes == 0   ? bayerPassOf<kPattern, 0>(signal)
         : modes == 1 ? bayerPassOf<kPattern, 1>(signal)
                      : bayerPassOf<kPattern, 2>(signal);
}
}  // namespace

bool colourRowRuns(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format, const ColourModel& model,
                   int k_ref, int k_third, int threshold, int gy, std::vector<Run>* runs, uint16_t* acc)
{
  const uint8_t* ambient_row = ambient.empty() ? nullptr : ambient.ptr<uint8_t>(gy);
  if (ambient_row && isBayer(format))
    return false;
  const int modes = passModes(k_ref, k_third);
  switch (format)
  {
    case PixelFormat::kBgr8:
    case PixelFormat::kRgb8:
      interleavedPass<3>(format == PixelFormat::kRgb8, model.signal, modes)(
          image.ptr<uint8_t>(gy), ambient_row, image.cols, gy, model, k_ref, k_third, threshold, runs, acc);
      return true;
    case PixelFormat::kBgra8:
    case PixelFormat::kRgba8:
      interleavedPass<4>(format == PixelFormat::kRgba8, model.signal, modes)(
          image.ptr<uint8_t>(gy), ambient_row, image.cols, gy, model, k_ref, k_third, threshold, runs, acc);
      return true;
    case PixelFormat::kBayerRggb8:
      bayerPass<0>(model.signal, modes)(image, format, image.cols / 2, gy, model, k_ref, k_third, threshold, runs, acc);
      return true;
    case PixelFormat::kBayerBggr8:
      bayerPass<1>(model.signal, modes)(image, format, image.cols / 2, gy, model, k_ref, k_third, threshold, runs, acc);
      return true;
    case PixelFormat::kBayerGbrg8:
      bayerPass<2>(model.signal, modes)(image, format, image.cols / 2, gy, model, k_ref, k_third, threshold, runs, acc);
      return true;
    case PixelFormat::kBayerGrbg8:
      bayerPass<3>(model.signal, modes)(image, format, image.cols / 2, gy, model, k_ref, k_third, threshold, runs, acc);
      return true;
    default:
      return false;
  }
}

namespace
{
// The signed colour score of (frame - ambient) per pixel, as
// FramePlanes::scoreRow computes it: each channel's difference saturated at
// 0 (d = max(0, c - a)), then d_s - max((k_ref d_r) >> 8, (k_third d_t) >> 8).
// (k d) >> 8 = d (k >> 8) + (d (k & 255)) >> 8 exactly, in 16 bits for
// k < 128 x 256 (the caller checks).
template <int kC>
void interleavedScores(const uint8_t* row, const uint8_t* ambient, int width, int so, int ro, int to, int k_ref,
                       int k_third, int16_t* out)
{
  int x = 0;
#if CV_SIMD128
  const cv::v_uint16x8 ref_hi = cv::v_setall_u16(static_cast<uint16_t>(k_ref >> 8));
  const cv::v_uint16x8 ref_lo = cv::v_setall_u16(static_cast<uint16_t>(k_ref & 255));
  const cv::v_uint16x8 third_hi = cv::v_setall_u16(static_cast<uint16_t>(k_third >> 8));
  const cv::v_uint16x8 third_lo = cv::v_setall_u16(static_cast<uint16_t>(k_third & 255));
  const auto scaled = [](const cv::v_uint16x8& d, const cv::v_uint16x8& hi, const cv::v_uint16x8& lo)
  { return cv::v_mul_wrap(d, hi) + cv::v_shr<8>(cv::v_mul_wrap(d, lo)); };
  for (; x + 16 <= width; x += 16)
  {
    cv::v_uint8x16 c[4], a[4];
    if (kC == 3)
    {
      cv::v_load_deinterleave(row + 3 * x, c[0], c[1], c[2]);
      cv::v_load_deinterleave(ambient + 3 * x, a[0], a[1], a[2]);
    }
    else
    {
      cv::v_load_deinterleave(row + 4 * x, c[0], c[1], c[2], c[3]);
      cv::v_load_deinterleave(ambient + 4 * x, a[0], a[1], a[2], a[3]);
    }
    cv::v_uint16x8 s[2], r[2], t[2];
    cv::v_expand(c[so] - a[so], s[0], s[1]);  // uint8 subtraction saturates at 0
    cv::v_expand(c[ro] - a[ro], r[0], r[1]);
    cv::v_expand(c[to] - a[to], t[0], t[1]);
    for (int h = 0; h < 2; ++h)
    {
      const cv::v_uint16x8 m = cv::v_max(scaled(r[h], ref_hi, ref_lo), scaled(t[h], third_hi, third_lo));
      cv::v_store(out + x + 8 * h, cv::v_reinterpret_as_s16(s[h]) - cv::v_reinterpret_as_s16(m));
    }
  }
#endif
  for (; x < width; ++x)
  {
    const uint8_t* px = row + kC * x;
    const uint8_t* pa = ambient + kC * x;
    const int s = std::max(0, px[so] - pa[so]), r = std::max(0, px[ro] - pa[ro]), t = std::max(0, px[to] - pa[to]);
    out[x] = static_cast<int16_t>(s - std::max((k_ref * r) >> 8, (k_third * t) >> 8));
  }
}
// The same for 16-bit colour (bgr16, rgb16; ambient may be null), each
// sample in whole DN (pixels::dn16) as decodeRow gives it.
void interleavedScores16(const uint16_t* row, const uint16_t* ambient, int width, int so, int ro, int to, int k_ref,
                         int k_third, int16_t* out)
{
  int x = 0;
#if CV_SIMD128
  // dn16(v) = (v + 128) / 257 = (y - (y >> 8)) >> 8 with y = v + 128
  // saturated at 65535: exact for every 16-bit v (checked exhaustively).
  const cv::v_uint16x8 half = cv::v_setall_u16(128);
  const auto dn = [&half](const cv::v_uint16x8& v)
  {
    const cv::v_uint16x8 y = v + half;  // saturating
    return cv::v_shr<8>(y - cv::v_shr<8>(y));
  };
  const cv::v_uint16x8 ref_hi = cv::v_setall_u16(static_cast<uint16_t>(k_ref >> 8));
  const cv::v_uint16x8 ref_lo = cv::v_setall_u16(static_cast<uint16_t>(k_ref & 255));
  const cv::v_uint16x8 third_hi = cv::v_setall_u16(static_cast<uint16_t>(k_third >> 8));
  const cv::v_uint16x8 third_lo = cv::v_setall_u16(static_cast<uint16_t>(k_third & 255));
  for (; x + 8 <= width; x += 8)
  {
    cv::v_uint16x8 c[3], a[3];
    cv::v_load_deinterleave(row + 3 * x, c[0], c[1], c[2]);
    for (int k = 0; k < 3; ++k)
      c[k] = dn(c[k]);
    if (ambient)
    {
      cv::v_load_deinterleave(ambient + 3 * x, a[0], a[1], a[2]);
      for (int k = 0; k < 3; ++k)
        c[k] = c[k] - dn(a[k]);  // saturating at 0
    }
    const cv::v_uint16x8 r = cv::v_mul_wrap(c[ro], ref_hi) + cv::v_shr<8>(cv::v_mul_wrap(c[ro], ref_lo));
    const cv::v_uint16x8 t = cv::v_mul_wrap(c[to], third_hi) + cv::v_shr<8>(cv::v_mul_wrap(c[to], third_lo));
    cv::v_store(out + x, cv::v_reinterpret_as_s16(c[so]) - cv::v_reinterpret_as_s16(cv::v_max(r, t)));
  }
#endif
  for (; x < width; ++x)
  {
    const uint16_t* px = row + 3 * x;
    int s = pixels::dn16(px[so]), r = pixels::dn16(px[ro]), t = pixels::dn16(px[to]);
    if (ambient)
    {
      const uint16_t* pa = ambient + 3 * x;
      s = std::max(0, s - pixels::dn16(pa[so]));
      r = std::max(0, r - pixels::dn16(pa[ro]));
      t = std::max(0, t - pixels::dn16(pa[to]));
    }
    out[x] = static_cast<int16_t>(s - std::max((k_ref * r) >> 8, (k_third * t) >> 8));
  }
}
}  // namespace

bool colourScoreRow(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format, const ColourModel& model,
                    int k_ref, int k_third, int gy, int16_t* out)
{
  if (k_ref < 0 || k_third < 0 || k_ref >= 128 * 256 || k_third >= 128 * 256)
    return false;
  if (format == PixelFormat::kBgr16 || format == PixelFormat::kRgb16)
  {
    const pixels::Interleaved L = pixels::interleavedLayout(format);
    const int offset[3] = {L.r, L.g, L.b};
    interleavedScores16(image.ptr<uint16_t>(gy), ambient.empty() ? nullptr : ambient.ptr<uint16_t>(gy), image.cols,
                        offset[model.signal], offset[model.reference], offset[model.third], k_ref, k_third, out);
    return true;
  }
  if (ambient.empty())
    return false;
  const bool four = format == PixelFormat::kBgra8 || format == PixelFormat::kRgba8;
  if (!four && format != PixelFormat::kBgr8 && format != PixelFormat::kRgb8)
    return false;
  const pixels::Interleaved L = pixels::interleavedLayout(format);
  const int offset[3] = {L.r, L.g, L.b};
  const int so = offset[model.signal], ro = offset[model.reference], to = offset[model.third];
  if (four)
    interleavedScores<4>(image.ptr<uint8_t>(gy), ambient.ptr<uint8_t>(gy), image.cols, so, ro, to, k_ref, k_third, out);
  else
    interleavedScores<3>(image.ptr<uint8_t>(gy), ambient.ptr<uint8_t>(gy), image.cols, so, ro, to, k_ref, k_third, out);
  return true;
}

void monoRowRuns(const uint8_t* row, int width, int y, int block, const int* level, const int* threshold,
                 std::vector<Run>* runs)
{
  for (int x0 = 0, b = 0; x0 < width; x0 += block, ++b)
  {
    // 16 v - level >= threshold  <=>  v >= ceil((level + threshold) / 16).
    const int need = level[b] + threshold[b];
    const int lim = need <= 0 ? 0 : (need + 15) / 16;
    if (lim > 255)
      continue;
    const int x1 = std::min(width, x0 + block);
    int x = x0;
#if CV_SIMD128
    const cv::v_uint8x16 vlim = cv::v_setall_u8(static_cast<uint8_t>(lim));
    for (; x + 16 <= x1; x += 16)
    {
      markHits(cv::v_load(row + x) >= vlim, y, x, runs);
    }
#endif
    for (; x < x1; ++x)
      if (row[x] >= lim)
        markCell(runs, y, x);
  }
}

}  // namespace rows
}  // namespace fast_detector
}  // namespace structured_light_stabilizer
