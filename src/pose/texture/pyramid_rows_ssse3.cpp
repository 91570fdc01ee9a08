// SSSE3 vertical sums of one channel for a pyrDown step: see
// pyramid_rows_ssse3.h. The only file (with spot_detector_rows_ssse3.cpp)
// built with -mssse3; its functions run only where the CPU has SSSE3.
#include "pose/texture/pyramid_rows_ssse3.h"

#if defined(SLS_SSSE3_ROWS)
#include <tmmintrin.h>
#endif

namespace structured_light_stabilizer
{
namespace pyramid_rows
{

#if defined(SLS_SSSE3_ROWS)

namespace
{
// 16 pixels (48 bytes, three loads) to their channel bytes: lanes 0-7 the
// even pixels 0, 2, .., 14, lanes 8-15 the odd ones. masks[k] picks from the
// k-th 16 bytes (-1: none).
struct Masks
{
  __m128i m[3];
  explicit Masks(int channel)
  {
    alignas(16) int8_t b[3][16];
    for (int lane = 0; lane < 16; ++lane)
    {
      const int pixel = lane < 8 ? 2 * lane : 2 * (lane - 8) + 1, byte = 3 * pixel + channel;
      for (int k = 0; k < 3; ++k)
        b[k][lane] = static_cast<int8_t>(byte / 16 == k ? byte % 16 : -1);
    }
    for (int k = 0; k < 3; ++k)
      m[k] = _mm_load_si128(reinterpret_cast<const __m128i*>(b[k]));
  }
};

inline __m128i channelBytes(const uint8_t* p, const Masks& masks)
{
  const __m128i a = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)), masks.m[0]);
  const __m128i b = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 16)), masks.m[1]);
  const __m128i c = _mm_shuffle_epi8(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p + 32)), masks.m[2]);
  return _mm_or_si128(_mm_or_si128(a, b), c);
}

// 1 4 6 4 1 of five 16-bit lanes (at most 16 x 255: no overflow).
inline __m128i binomial(__m128i v0, __m128i v1, __m128i v2, __m128i v3, __m128i v4)
{
  const __m128i outer = _mm_add_epi16(v0, v4), inner = _mm_add_epi16(v1, v3);
  const __m128i six = _mm_add_epi16(_mm_slli_epi16(v2, 2), _mm_slli_epi16(v2, 1));
  return _mm_add_epi16(_mm_add_epi16(outer, _mm_slli_epi16(inner, 2)), six);
}

inline void store32(int32_t* out, __m128i v16)
{
  const __m128i zero = _mm_setzero_si128();
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out), _mm_unpacklo_epi16(v16, zero));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 4), _mm_unpackhi_epi16(v16, zero));
}
}  // namespace

int channelSums3Ssse3(const uint8_t* const r[5], int width, int channel, int32_t* even, int32_t* odd)
{
  const Masks masks(channel);
  const __m128i zero = _mm_setzero_si128();
  int x = 0;
  for (; x + 16 <= width; x += 16)
  {
    __m128i e[5], o[5];
    for (int i = 0; i < 5; ++i)
    {
      const __m128i v = channelBytes(r[i] + 3 * x, masks);
      e[i] = _mm_unpacklo_epi8(v, zero);
      o[i] = _mm_unpackhi_epi8(v, zero);
    }
    store32(even + x / 2, binomial(e[0], e[1], e[2], e[3], e[4]));
    store32(odd + x / 2, binomial(o[0], o[1], o[2], o[3], o[4]));
  }
  return x;
}

#else

int channelSums3Ssse3(const uint8_t* const[5], int, int, int32_t*, int32_t*)
{
  return 0;
}

#endif

}  // namespace pyramid_rows
}  // namespace structured_light_stabilizer
