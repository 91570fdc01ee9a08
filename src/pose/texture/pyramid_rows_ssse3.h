// The vertical sums of one cv::pyrDown step for one channel of a bgr8 / rgb8
// image, with SSSE3 (pyramid_rows_ssse3.cpp): TextureTracker's
// half-resolution level reads one channel of the frame. The baseline
// instruction set (SSE2) has no byte shuffle, so without it the sums are taken
// over all three channels of the interleaved rows and the wanted one picked
// out afterwards, three times the work. Built only for x86 with GCC or Clang
// (SLS_SSSE3_ROWS), used only where haveSsse3Kernels() (cpu_features.h); the sums are the
// generic path's, exactly (integers).
#pragma once

#include <cstdint>

namespace structured_light_stabilizer
{
namespace pyramid_rows
{

// For the pixels [0, returned) of five rows r[0..4] of `width` 3-byte pixels
// (returned: a multiple of 16, at most width), the channel `channel`'s
// column sums r0 + 4 r1 + 6 r2 + 4 r3 + r4, split by column parity: pixel 2i
// goes to even[i], pixel 2i + 1 to odd[i].
int channelSums3Ssse3(const uint8_t* const r[5], int width, int channel, int32_t* even, int32_t* odd);

}  // namespace pyramid_rows
}  // namespace structured_light_stabilizer
