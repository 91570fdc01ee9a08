// The SSSE3 rows of the threshold pass (see spot_detector_rows_ssse3.h).
// Compiled with -mssse3 where SLS_SSSE3_ROWS is set (CMakeLists.txt), so it
// uses raw intrinsics only and defines nothing inline that another file could
// share (std:: templates, OpenCV's universal intrinsics): no function built
// for SSSE3 can stand in for a baseline one at link time.
#include "detection/inputs/rows_ssse3.h"

#if defined(SLS_SSSE3_ROWS) && defined(__SSSE3__)
#include <tmmintrin.h>

namespace structured_light_stabilizer
{
namespace fast_detector
{
namespace rows
{
namespace
{
// pshufb masks of channel ch from the three 16-byte parts of 48 bytes: output
// byte j is byte 3j + ch of the 48, where it falls in that part.
struct Deinterleave
{
  __m128i mask[3][3];  // [channel][part]
  Deinterleave()
  {
    alignas(16) int8_t m[16];
    for (int ch = 0; ch < 3; ++ch)
      for (int part = 0; part < 3; ++part)
      {
        for (int j = 0; j < 16; ++j)
        {
          const int i = 3 * j + ch - 16 * part;
          m[j] = static_cast<int8_t>(i >= 0 && i < 16 ? i : -128);
        }
        mask[ch][part] = _mm_load_si128(reinterpret_cast<const __m128i*>(m));
      }
  }
};

// One channel's three masks, held in registers through a row.
struct Channel
{
  __m128i m0, m1, m2;
  Channel(const Deinterleave& d, int ch) : m0(d.mask[ch][0]), m1(d.mask[ch][1]), m2(d.mask[ch][2]) {}
  __m128i operator()(__m128i a, __m128i b, __m128i c) const
  {
    return _mm_or_si128(_mm_or_si128(_mm_shuffle_epi8(a, m0), _mm_shuffle_epi8(b, m1)), _mm_shuffle_epi8(c, m2));
  }
};

struct Scale
{
  __m128i k, hi, lo;
  explicit Scale(int w)
    : k(_mm_set1_epi16(static_cast<short>(w < 256 ? w : 256))),
      hi(_mm_set1_epi16(static_cast<short>(w >> 8))),
      lo(_mm_set1_epi16(static_cast<short>(w & 255)))
  {
  }
  template <int kMode>
  __m128i apply(__m128i x) const
  {
    if (kMode == 0)
      return x;
    const __m128i zero = _mm_setzero_si128();
    __m128i a = _mm_unpacklo_epi8(x, zero), b = _mm_unpackhi_epi8(x, zero);
    if (kMode == 1)
      return _mm_packus_epi16(_mm_srli_epi16(_mm_mullo_epi16(a, k), 8), _mm_srli_epi16(_mm_mullo_epi16(b, k), 8));
    a = _mm_add_epi16(_mm_mullo_epi16(a, hi), _mm_srli_epi16(_mm_mullo_epi16(a, lo), 8));
    b = _mm_add_epi16(_mm_mullo_epi16(b, hi), _mm_srli_epi16(_mm_mullo_epi16(b, lo), 8));
    // min(v, 255) as unsigned 16-bit before the (signed) saturating pack
    const __m128i max8 = _mm_set1_epi16(255);
    return _mm_packus_epi16(_mm_subs_epu16(a, _mm_subs_epu16(a, max8)), _mm_subs_epu16(b, _mm_subs_epu16(b, max8)));
  }
};

template <int kRefMode, int kThirdMode, bool kAmbient>
int scoreRow(const uint8_t* row, const uint8_t* ambient, int width, int so, int ro, int to, int k_ref, int k_third,
             int threshold, uint16_t* acc, HitSink hits, void* context)
{
  static const Deinterleave kSplit;
  const Channel signal(kSplit, so), reference(kSplit, ro), third(kSplit, to);
  const Scale scale_ref(k_ref), scale_third(k_third);
  const __m128i thr = _mm_set1_epi8(static_cast<char>(threshold < 255 ? threshold : 255));
  const __m128i zero = _mm_setzero_si128();
  int x = 0;
  for (; x + 16 <= width; x += 16)
  {
    const __m128i* p = reinterpret_cast<const __m128i*>(row + 3 * x);
    const __m128i a = _mm_loadu_si128(p), b = _mm_loadu_si128(p + 1), c = _mm_loadu_si128(p + 2);
    __m128i s = signal(a, b, c), r = reference(a, b, c), t = third(a, b, c);
    if (kAmbient)
    {
      const __m128i* q = reinterpret_cast<const __m128i*>(ambient + 3 * x);
      const __m128i d = _mm_loadu_si128(q), e = _mm_loadu_si128(q + 1), f = _mm_loadu_si128(q + 2);
      s = _mm_subs_epu8(s, signal(d, e, f));
      r = _mm_subs_epu8(r, reference(d, e, f));
      t = _mm_subs_epu8(t, third(d, e, f));
    }
    const __m128i score = _mm_subs_epu8(
        s, _mm_max_epu8(scale_ref.template apply<kRefMode>(r), scale_third.template apply<kThirdMode>(t)));
    if (acc)
    {
      __m128i* sums = reinterpret_cast<__m128i*>(acc + x);
      _mm_storeu_si128(sums, _mm_adds_epu16(_mm_loadu_si128(sums), _mm_unpacklo_epi8(score, zero)));
      _mm_storeu_si128(sums + 1, _mm_adds_epu16(_mm_loadu_si128(sums + 1), _mm_unpackhi_epi8(score, zero)));
    }
    const unsigned hit = static_cast<unsigned>(_mm_movemask_epi8(_mm_cmpeq_epi8(_mm_max_epu8(score, thr), score)));
    if (hit)
      hits(context, x, hit);
  }
  return x;
}

template <int kRefMode, int kThirdMode>
int scoreRowOf(const uint8_t* row, const uint8_t* ambient, int width, int so, int ro, int to, int k_ref, int k_third,
               int threshold, uint16_t* acc, HitSink hits, void* context)
{
  return ambient ? scoreRow<kRefMode, kThirdMode, true>(row, ambient, width, so, ro, to, k_ref, k_third, threshold, acc,
                                                        hits, context)
                 : scoreRow<kRefMode, kThirdMode, false>(row, ambient, width, so, ro, to, k_ref, k_third, threshold,
                                                         acc, hits, context);
}
}  // namespace

int interleaved3RowSsse3(const uint8_t* row, const uint8_t* ambient, int width, int so, int ro, int to, int ref_mode,
                         int third_mode, int k_ref, int k_third, int threshold, uint16_t* acc, HitSink hits,
                         void* context)
{
  if (ref_mode == 1 && third_mode == 0)
    return scoreRowOf<1, 0>(row, ambient, width, so, ro, to, k_ref, k_third, threshold, acc, hits, context);
  if (ref_mode == 1 && third_mode == 1)
    return scoreRowOf<1, 1>(row, ambient, width, so, ro, to, k_ref, k_third, threshold, acc, hits, context);
  if (ref_mode == 2 && third_mode == 2)
    return scoreRowOf<2, 2>(row, ambient, width, so, ro, to, k_ref, k_third, threshold, acc, hits, context);
  return 0;  // no such pass: the caller scores the row
}

}  // namespace rows
}  // namespace fast_detector
}  // namespace structured_light_stabilizer

#else

namespace structured_light_stabilizer
{
namespace fast_detector
{
namespace rows
{
// Not built for SSSE3: the caller scores every row itself.
int interleaved3RowSsse3(const uint8_t*, const uint8_t*, int, int, int, int, int, int, int, int, int, uint16_t*,
                         HitSink, void*)
{
  return 0;
}
}  // namespace rows
}  // namespace fast_detector
}  // namespace structured_light_stabilizer

#endif
