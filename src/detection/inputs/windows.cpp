// The inputs layer's windows: the planes of a frame (and of its ambient
// frame) at full resolution around a candidate (see spot_detector_planes.h).
#include <algorithm>
#include <cmath>

#include <opencv2/core/hal/intrin.hpp>

#include "detection/inputs/pixels.h"
#include "detection/inputs/planes.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

// One pixel of m: the signal, reference and third planes (8-bit DN), whether
// the signal is measured here, and whether a sample it depends on is clipped.
void FramePlanes::fillPixel(const cv::Mat& m, int x, int y, float* s, float* r, float* t, bool* sample,
                            bool* clipped) const
{
  *sample = true;
  *r = *t = 0.0f;
  if (format_ == PixelFormat::kMono8 || format_ == PixelFormat::kMono16)
  {
    const int v = format_ == PixelFormat::kMono8 ? m.ptr<uint8_t>(y)[x] : m.ptr<uint16_t>(y)[x];
    *s = format_ == PixelFormat::kMono8 ? static_cast<float>(v) : static_cast<float>(v / 257.0);
    *clipped = v >= saturation_;
    return;
  }
  if (isBayer(format_))
  {
    bool any = false;
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
        any = any || pixels::bayerRaw(m, x + dx, y + dy) >= saturation_;
    *clipped = any;
    if (!model_.colour)  // nir/white: every site sees the projector
    {
      *s = static_cast<float>(pixels::bayerRaw(m, x, y));
      return;
    }
    *sample = pixels::bayerColour(format_, x, y) == model_.signal;
    *s = static_cast<float>(pixels::bayerChannel(m, format_, x, y, model_.signal));
    *r = static_cast<float>(pixels::bayerChannel(m, format_, x, y, model_.reference));
    *t = static_cast<float>(pixels::bayerChannel(m, format_, x, y, model_.third));
    return;
  }
  if (format_ == PixelFormat::kBgr16 || format_ == PixelFormat::kRgb16)
  {
    const pixels::Interleaved L = pixels::interleavedLayout(format_);
    const uint16_t* px = m.ptr<uint16_t>(y) + x * L.bytes;
    const float rgb16[3] = {px[L.r] / 257.0f, px[L.g] / 257.0f, px[L.b] / 257.0f};  // DN, at full depth
    *clipped = px[0] >= 257 * saturation_ || px[1] >= 257 * saturation_ || px[2] >= 257 * saturation_;
    if (!model_.colour)
    {
      *s = 0.25f * (rgb16[0] + 2.0f * rgb16[1] + rgb16[2]);
      return;
    }
    *s = rgb16[model_.signal];
    *r = rgb16[model_.reference];
    *t = rgb16[model_.third];
    return;
  }
  int rgb[3];
  pixels::decodeCell(m, format_, x, y, rgb);
  *clipped = rgb[0] >= saturation_ || rgb[1] >= saturation_ || rgb[2] >= saturation_;
  if (!model_.colour)
  {
    *s = 0.25f * static_cast<float>(rgb[0] + 2 * rgb[1] + rgb[2]);
    return;
  }
  *s = static_cast<float>(rgb[model_.signal]);
  *r = static_cast<float>(rgb[model_.reference]);
  *t = static_cast<float>(rgb[model_.third]);
}

namespace
{
#if CV_SIMD128
// Sixteen pixels' bytes as four lanes of floats each, into d[0..15].
inline void storeAsFloats(const cv::v_uint8x16& v, float* d)
{
  cv::v_uint16x8 lo, hi;
  cv::v_expand(v, lo, hi);
  cv::v_uint32x4 a, b;
  cv::v_expand(lo, a, b);
  cv::v_store(d, cv::v_cvt_f32(cv::v_reinterpret_as_s32(a)));
  cv::v_store(d + 4, cv::v_cvt_f32(cv::v_reinterpret_as_s32(b)));
  cv::v_expand(hi, a, b);
  cv::v_store(d + 8, cv::v_cvt_f32(cv::v_reinterpret_as_s32(a)));
  cv::v_store(d + 12, cv::v_cvt_f32(cv::v_reinterpret_as_s32(b)));
}

// Sixteen pixels of a row with `Bytes` (3 or 4) channels from px: the
// channels so, ro, to into s, r, t, and the flags of the clipped ones
// (any of the first three channels >= saturation, 1..255).
template <int Bytes>
void interleavedChunk(const uint8_t* px, int so, int ro, int to, uint8_t saturation, bool ambient, float* s, float* r,
                      float* t, uint8_t* flags)
{
  cv::v_uint8x16 c[4];
  if constexpr (Bytes == 3)
    cv::v_load_deinterleave(px, c[0], c[1], c[2]);
  else
    cv::v_load_deinterleave(px, c[0], c[1], c[2], c[3]);
  storeAsFloats(c[so], s);
  storeAsFloats(c[ro], r);
  storeAsFloats(c[to], t);
  const cv::v_uint8x16 clipped =
      (cv::v_max(c[0], cv::v_max(c[1], c[2])) >= cv::v_setall_u8(saturation)) & cv::v_setall_u8(PlaneWindow::kClipped);
  const cv::v_uint8x16 f = ambient ? cv::v_load(flags) | clipped : clipped | cv::v_setall_u8(PlaneWindow::kSample);
  cv::v_store(flags, f);
}
#endif

// The fast path of fillWindow for interleaved 8-bit colour frames (the
// common case): the planes straight from the rows, sixteen pixels at a time.
void fillInterleaved(const cv::Mat& m, PixelFormat format, const ColourModel& model, int saturation, int cx, int cy,
                     PlaneWindow* w, float* s, float* r, float* t, bool ambient)
{
  const pixels::Interleaved L = pixels::interleavedLayout(format);
  const int offset[3] = {L.r, L.g, L.b};
  const int so = offset[model.signal], ro = offset[model.reference], to = offset[model.third];
  const int H = w->H;
  // A saturation level outside 1..255 is the same for every 8-bit pixel: the scalar loop.
  const bool simd = saturation >= 1 && saturation <= 255;
  for (int dy = -H; dy <= H; ++dy)
  {
    const uint8_t* px = m.ptr<uint8_t>(cy + dy) + (cx - H) * L.bytes;
    const int row = w->index(-H, dy);
    int k = 0;
#if CV_SIMD128
    // Chunks of sixteen, the last one ending at the row's end (it may
    // overlap the one before: the same values again, flags or-ed again).
    const int n = 2 * H + 1;
    for (int c = 0; simd && n >= 16; c += 16)
    {
      const int at = std::min(c, n - 16), i = row + at;
      const uint8_t* p = px + at * L.bytes;
      if (L.bytes == 3)
        interleavedChunk<3>(p, so, ro, to, static_cast<uint8_t>(saturation), ambient, s + i, r + i, t + i,
                            w->flags + i);
      else
        interleavedChunk<4>(p, so, ro, to, static_cast<uint8_t>(saturation), ambient, s + i, r + i, t + i,
                            w->flags + i);
      k = n;
      if (at == n - 16)
        break;
    }
#endif
    for (; k <= 2 * H; ++k, px += L.bytes)
    {
      s[row + k] = px[so];
      r[row + k] = px[ro];
      t[row + k] = px[to];
      const bool clipped = px[0] >= saturation || px[1] >= saturation || px[2] >= saturation;
      if (ambient)
        w->flags[row + k] |= clipped ? PlaneWindow::kClipped : 0;
      else
        w->flags[row + k] = static_cast<uint8_t>(PlaneWindow::kSample | (clipped ? PlaneWindow::kClipped : 0));
    }
  }
}

// The fast path for interleaved 16-bit colour frames (bgr16, rgb16): the
// planes in DN at full depth straight from the rows (fillPixel's values).
void fillInterleaved16(const cv::Mat& m, PixelFormat format, const ColourModel& model, int saturation, int cx, int cy,
                       PlaneWindow* w, float* s, float* r, float* t, bool ambient)
{
  const pixels::Interleaved L = pixels::interleavedLayout(format);
  const int offset[3] = {L.r, L.g, L.b};
  const int so = offset[model.signal], ro = offset[model.reference], to = offset[model.third];
  const int H = w->H, saturation16 = 257 * saturation;
  for (int dy = -H; dy <= H; ++dy)
  {
    const uint16_t* px = m.ptr<uint16_t>(cy + dy) + (cx - H) * L.bytes;
    const int row = w->index(-H, dy);
    for (int k = 0; k <= 2 * H; ++k, px += L.bytes)
    {
      s[row + k] = px[so] / 257.0f;
      r[row + k] = px[ro] / 257.0f;
      t[row + k] = px[to] / 257.0f;
      const bool clipped = px[0] >= saturation16 || px[1] >= saturation16 || px[2] >= saturation16;
      if (ambient)
        w->flags[row + k] |= clipped ? PlaneWindow::kClipped : 0;
      else
        w->flags[row + k] = static_cast<uint8_t>(PlaneWindow::kSample | (clipped ? PlaneWindow::kClipped : 0));
    }
  }
}

// The fast path for mono frames: the one plane, straight from the rows.
template <typename T>
void fillMono(const cv::Mat& m, int saturation, double scale, int cx, int cy, PlaneWindow* w, float* s, bool ambient)
{
  const int H = w->H;
  for (int dy = -H; dy <= H; ++dy)
  {
    const T* px = m.ptr<T>(cy + dy) + (cx - H);
    const int row = w->index(-H, dy);
    for (int k = 0; k <= 2 * H; ++k)
    {
      s[row + k] = static_cast<float>(px[k] * scale);
      const bool clipped = px[k] >= saturation;
      if (ambient)
        w->flags[row + k] |= clipped ? PlaneWindow::kClipped : 0;
      else
        w->flags[row + k] = static_cast<uint8_t>(PlaneWindow::kSample | (clipped ? PlaneWindow::kClipped : 0));
    }
  }
}

// Channel ch at the window's raw sample p (a row of the window is n samples):
// pixels::bayerChannel on the window's copy of the mosaic, whose border
// samples are the frame's reflected ones, as bayerChannel reads them.
inline int windowChannel(const int* p, int n, PixelFormat format, int x, int y, int ch)
{
  const int own = pixels::bayerColour(format, x, y);
  if (own == ch)
    return p[0];
  if (ch == kGreen)  // at a red or blue site: the four direct neighbours are green
    return (p[-1] + p[1] + p[-n] + p[n] + 2) >> 2;
  if (own == kGreen)  // red/blue at a green site: the pair left/right or above/below
    return pixels::bayerColour(format, x + 1, y) == ch ? (p[-1] + p[1] + 1) >> 1 : (p[-n] + p[n] + 1) >> 1;
  return (p[-n - 1] + p[-n + 1] + p[n - 1] + p[n + 1] + 2) >> 2;  // the four diagonal neighbours
}

// The fast path for Bayer mosaics, colour path: the window's raw samples and
// their one-pixel border read once (reflected at the frame's edges) and their
// clipping marked, each pixel's planes from its own and its neighbours'
// samples in that copy (the values of pixels::bayerChannel).
void fillBayer(const cv::Mat& m, PixelFormat format, const ColourModel& model, int saturation, int cx, int cy,
               PlaneWindow* w, float* s, float* r, float* t, bool ambient)
{
  const int H = w->H, n = 2 * H + 3;
  constexpr int kN = 2 * PlaneWindow::kMaxRadius + 3;
  int raw[kN * kN];
  bool raw_clipped[kN * kN];
  const int x0 = cx - H - 1, y0 = cy - H - 1;
  const bool inside = x0 >= 0 && y0 >= 0 && x0 + n <= m.cols && y0 + n <= m.rows;
  for (int y = 0; y < n; ++y)
  {
    int* row = raw + y * n;
    if (inside)
    {
      const uint8_t* src = m.ptr<uint8_t>(y0 + y) + x0;
      for (int x = 0; x < n; ++x)
        row[x] = src[x];
    }
    else
      for (int x = 0; x < n; ++x)
        row[x] = pixels::bayerRaw(m, x0 + x, y0 + y);
    for (int x = 0; x < n; ++x)
      raw_clipped[y * n + x] = row[x] >= saturation;
  }
  for (int dy = -H; dy <= H; ++dy)
    for (int dx = -H; dx <= H; ++dx)
    {
      const int i = w->index(dx, dy), x = cx + dx, y = cy + dy;
      bool clipped = false;
      for (int ey = 0; ey < 3 && !clipped; ++ey)
        for (int ex = 0; ex < 3; ++ex)
          clipped = clipped || raw_clipped[(dy + H + ey) * n + dx + H + ex];
      const int* p = raw + (dy + H + 1) * n + dx + H + 1;
      s[i] = static_cast<float>(windowChannel(p, n, format, x, y, model.signal));
      r[i] = static_cast<float>(windowChannel(p, n, format, x, y, model.reference));
      t[i] = static_cast<float>(windowChannel(p, n, format, x, y, model.third));
      const bool sample = pixels::bayerColour(format, x, y) == model.signal;
      if (ambient)
        w->flags[i] |= clipped ? PlaneWindow::kClipped : 0;
      else
        w->flags[i] = static_cast<uint8_t>((sample ? PlaneWindow::kSample : 0) | (clipped ? PlaneWindow::kClipped : 0));
    }
}

bool isInterleaved(PixelFormat format)
{
  return format == PixelFormat::kBgr8 || format == PixelFormat::kRgb8 || format == PixelFormat::kBgra8 ||
         format == PixelFormat::kRgba8;
}
}  // namespace

// The ambient planes of a window from the unrounded estimate (bind's
// ambient_fine), over the rounded values fillWindow read; the clipped flags
// stay the rounded frame's. Interleaved 8-bit colour and mono8 only.
void FramePlanes::fillFineAmbient(PlaneWindow* w) const
{
  if (ambient_fine_.empty() || !w->ambient)
    return;
  const int channels = ambient_fine_.channels();
  int so = 0, ro = 0, to = 0;
  if (model_.colour)
  {
    const pixels::Interleaved L = pixels::interleavedLayout(format_);
    const int offset[3] = {L.r, L.g, L.b};
    so = offset[model_.signal];
    ro = offset[model_.reference];
    to = offset[model_.third];
  }
  const int H = w->H;
  for (int dy = -H; dy <= H; ++dy)
  {
    const float* px = ambient_fine_.ptr<float>(w->cy + dy) + (w->cx - H) * channels;
    const int row = w->index(-H, dy);
    for (int k = 0; k <= 2 * H; ++k, px += channels)
    {
      if (std::isfinite(px[so]))
        w->ambient_signal[row + k] = px[so];
      if (model_.colour && std::isfinite(px[ro]))
        w->ambient_reference[row + k] = px[ro];
      if (model_.colour && std::isfinite(px[to]))
        w->ambient_third[row + k] = px[to];
    }
  }
}

void FramePlanes::fillWindow(int cx, int cy, int H, PlaneWindow* w) const
{
  w->cx = cx;
  w->cy = cy;
  w->H = H;
  w->stride = (2 * H + 1 + 3) & ~3;
  w->colour = model_.colour;
  w->ambient = !ambient_.empty();
  w->ring = isBayer(format_) ? 2 : 1;
  if (model_.colour && isInterleaved(format_))
  {
    fillInterleaved(image_, format_, model_, saturation_, cx, cy, w, w->signal, w->reference, w->third, false);
    if (w->ambient)
      fillInterleaved(ambient_, format_, model_, saturation_, cx, cy, w, w->ambient_signal, w->ambient_reference,
                      w->ambient_third, true);
    fillFineAmbient(w);
    return;
  }
  if (model_.colour && (format_ == PixelFormat::kBgr16 || format_ == PixelFormat::kRgb16))
  {
    fillInterleaved16(image_, format_, model_, saturation_, cx, cy, w, w->signal, w->reference, w->third, false);
    if (w->ambient)
      fillInterleaved16(ambient_, format_, model_, saturation_, cx, cy, w, w->ambient_signal, w->ambient_reference,
                        w->ambient_third, true);
    return;
  }
  if (model_.colour && isBayer(format_))
  {
    fillBayer(image_, format_, model_, saturation_, cx, cy, w, w->signal, w->reference, w->third, false);
    if (w->ambient)
      fillBayer(ambient_, format_, model_, saturation_, cx, cy, w, w->ambient_signal, w->ambient_reference,
                w->ambient_third, true);
    return;
  }
  if (format_ == PixelFormat::kMono8 || format_ == PixelFormat::kMono16)
  {
    const bool wide = format_ == PixelFormat::kMono16;
    for (int pass = 0; pass < (w->ambient ? 2 : 1); ++pass)
    {
      const cv::Mat& m = pass ? ambient_ : image_;
      float* s = pass ? w->ambient_signal : w->signal;
      if (wide)
        fillMono<uint16_t>(m, saturation_, 1.0 / 257.0, cx, cy, w, s, pass == 1);
      else
        fillMono<uint8_t>(m, saturation_, 1.0, cx, cy, w, s, pass == 1);
    }
    fillFineAmbient(w);
    return;
  }
  for (int dy = -H; dy <= H; ++dy)
  {
    for (int dx = -H; dx <= H; ++dx)
    {
      const int i = w->index(dx, dy);
      bool sample, clipped;
      fillPixel(image_, cx + dx, cy + dy, &w->signal[i], &w->reference[i], &w->third[i], &sample, &clipped);
      if (w->ambient)
      {
        bool ambient_sample, ambient_clipped;
        fillPixel(ambient_, cx + dx, cy + dy, &w->ambient_signal[i], &w->ambient_reference[i], &w->ambient_third[i],
                  &ambient_sample, &ambient_clipped);
        clipped = clipped || ambient_clipped;
      }
      w->flags[i] = static_cast<uint8_t>((sample ? PlaneWindow::kSample : 0) | (clipped ? PlaneWindow::kClipped : 0));
    }
  }
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
