// The threshold pass's rows of 3-byte pixels (bgr8, rgb8) with SSSE3
// (spot_detector_rows_ssse3.cpp): the baseline instruction set (SSE2) has no
// byte shuffle, and its 3-channel deinterleave costs 40 instructions per 16
// pixels, a third of the pass; pshufb does it in 15. Built only for x86 with
// GCC or Clang (SLS_SSSE3_ROWS), used only where haveSsse3Kernels() (cpu_features.h); the
// scores, runs and sums are those of rows::colourRowRuns, bit for bit.
#pragma once

#include <cstdint>

namespace structured_light_stabilizer
{
namespace fast_detector
{
namespace rows
{

// Receives the hits of 16 pixels from x on: bit i of mask = pixel x + i.
using HitSink = void (*)(void* context, int x, unsigned mask);

// Scores s - max(scale_ref(r), scale_third(t)) (saturating; with `ambient`,
// each channel minus the ambient frame's first) of the pixels [0, returned)
// of a row of `width` 3-byte pixels, 16 at a time; so, ro, to: the byte of
// the signal, reference and third channel in a pixel; ref_mode, third_mode:
// 0 identity, 1 (v k) >> 8 for k <= 256, 2 (v hi) + ((v lo) >> 8), hi, lo
// the two bytes of k, saturated at 255. The scores are added (saturating)
// to acc[x] when acc is not null; those >= threshold (<= 255) go to `hits`.
int interleaved3RowSsse3(const uint8_t* row, const uint8_t* ambient, int width, int so, int ro, int to, int ref_mode,
                         int third_mode, int k_ref, int k_third, int threshold, uint16_t* acc, HitSink hits,
                         void* context);

}  // namespace rows
}  // namespace fast_detector
}  // namespace structured_light_stabilizer
