#include "sim/render/sensor.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <opencv2/core.hpp>
#include <opencv2/core/hal/hal.hpp>

#include "sim/render/noise.h"

namespace structured_light_stabilizer
{
namespace sim
{

SensorNoise::SensorNoise(const SensorParams& sc, uint32_t noise_seed, double t, uint32_t exposure)
  : table_(normalTable()),
    read_var_(static_cast<float>(sc.read_noise_dn * sc.read_noise_dn)),
    gain_(sc.shot_noise ? static_cast<float>(sc.gain_dn_per_electron) : 0.0f),
    enabled_(read_var_ > 0.0f || gain_ > 0.0f)
{
  uint64_t frame_state = 0x243F6A8885A308D3ull ^ (static_cast<uint64_t>(noise_seed) << 32) ^ doubleBits(t);
  frame_key_ = splitmix64(&frame_state);
  if (exposure != 0)  // exposure 0 keeps the keys every scene was built and measured with
  {
    frame_state ^= 0x9E3779B97F4A7C15ull * exposure;
    frame_key_ = splitmix64(&frame_state);
  }
}

// n (rounded up to 5) standard normal deviates for row v of stream `key`.
void SensorNoise::normals(uint64_t key, int v, int n, float* __restrict N) const
{
  const float* __restrict table = table_.data();
  uint64_t state = key ^ (0xD1B54A32D192ED03ull * static_cast<uint64_t>(v + 1));
  for (int k = 0; k < n; k += 5)
  {
    const uint64_t r = splitmix64(&state);
    for (int q = 0; q < 5; ++q)
      N[k + q] = table[(r >> (12 * q)) & (kNormalTableSize - 1)];
  }
}

void SensorNoise::applyRow(int v, int n, float* __restrict L, float* __restrict N, float* __restrict sd) const
{
  // Locals: stores to the row might otherwise alias the members.
  const float gain = gain_, read_var = read_var_;
  normals(frame_key_, v, n, N);
  // Simple loops that vectorise: clip, standard deviation (shot + read), the
  // noisy value.
  for (int k = 0; k < n; ++k)
    L[k] = std::max(L[k], 0.0f);
  for (int k = 0; k < n; ++k)
    sd[k] = L[k] * gain + read_var;
  cv::hal::sqrt32f(sd, sd, n);
  for (int k = 0; k < n; ++k)
    L[k] += sd[k] * N[k];
}

void SensorNoise::applyShotRow(int v, int n, float* __restrict L, float* __restrict N, float* __restrict sd) const
{
  const float gain = gain_;
  normals(frame_key_, v, n, N);
  for (int k = 0; k < n; ++k)
    L[k] = std::max(L[k], 0.0f);
  for (int k = 0; k < n; ++k)
    sd[k] = L[k] * gain;
  cv::hal::sqrt32f(sd, sd, n);
  for (int k = 0; k < n; ++k)
    L[k] = std::max(0.0f, L[k] + sd[k] * N[k]);
}

void SensorNoise::applyReadRow(int v, int n, float* __restrict L, float* __restrict N) const
{
  const float read_sd = std::sqrt(read_var_);
  normals(frame_key_ ^ 0x5851F42D4C957F2Dull, v, n, N);
  for (int k = 0; k < n; ++k)
    L[k] += read_sd * N[k];
}

void quantizeRow(const float* L, int n, uint8_t* out)
{
  cv::Mat(1, n, CV_32F, const_cast<float*>(L)).convertTo(cv::Mat(1, n, CV_8U, out), CV_8U);
}

SensorReadout::SensorReadout(const SensorParams& sensor, const float mono_weights[3])
  : colour_(sensor.output == SensorOutput::kBgr8 || sensor.output == SensorOutput::kRgb8 ||
            sensor.output == SensorOutput::kBgr16 || sensor.output == SensorOutput::kRgb16),
    mono_(isMonochrome(sensor.output)),
    bayer_on_(isBayer(sensor.output)),
    swap_rb_(sensor.output == SensorOutput::kRgb8 || sensor.output == SensorOutput::kRgb16),
    sixteen_(sensor.output == SensorOutput::kMono16 || sensor.output == SensorOutput::kBgr16 ||
             sensor.output == SensorOutput::kRgb16),
    step_(1 << (16 - std::min(16, std::max(8, sensor.output_bits)))),
    charge_path_(sensor.blooming != Blooming::kNone || sensor.full_well_dn < 255.0),
    full_well_(static_cast<float>(sensor.full_well_dn)),
    w_{mono_weights[0], mono_weights[1], mono_weights[2]},
    bayer_{1, 1, 1, 1}
{
  // Sites (u & 1, v & 1) in the order (0, 0), (1, 0), (0, 1), (1, 1).
  switch (sensor.output)
  {
    case SensorOutput::kBayerRggb8:
      bayer_[0] = 2, bayer_[3] = 0;
      break;
    case SensorOutput::kBayerBggr8:
      bayer_[0] = 0, bayer_[3] = 2;
      break;
    case SensorOutput::kBayerGbrg8:
      bayer_[1] = 0, bayer_[2] = 2;
      break;
    case SensorOutput::kBayerGrbg8:
      bayer_[1] = 2, bayer_[2] = 0;
      break;
    default:
      break;
  }
}

int SensorReadout::imageType() const
{
  return CV_MAKETYPE(sixteen_ ? CV_16U : CV_8U, colour_ ? 3 : 1);
}

float* SensorReadout::record(int v, int width, float* L, float* S) const
{
  if (colour_)
    return L;
  if (mono_)
  {
    for (int u = 0; u < width; ++u)
      S[u] = w_[0] * L[3 * u] + w_[1] * L[3 * u + 1] + w_[2] * L[3 * u + 2];
    return S;
  }
  const int* site = &bayer_[(v & 1) * 2];
  for (int u = 0; u < width; ++u)
    S[u] = L[3 * u + site[u & 1]];
  return S;
}

float SensorReadout::pixelPeak(int u, const float* L) const
{
  const float* p = L + 3 * u;
  return mono_ ? w_[0] * p[0] + w_[1] * p[1] + w_[2] * p[2] : std::max(p[0], std::max(p[1], p[2]));
}

void SensorReadout::write(int v, const float* S, cv::Mat* image) const
{
  const int n = colour_ ? 3 * image->cols : image->cols;
  if (sixteen_)
  {
    // The 8-bit range (and so the default full well) over the 16 bits, in
    // the converter's steps.
    uint16_t* out = image->ptr<uint16_t>(v);
    if (step_ == 1)
      cv::Mat(1, n, CV_32F, const_cast<float*>(S)).convertTo(cv::Mat(1, n, CV_16U, out), CV_16U, 257.0);
    else
    {
      const int top = 65535 / step_;  // the converter's largest code (4095 at 12 bits)
      for (int i = 0; i < n; ++i)
        out[i] = static_cast<uint16_t>(std::min(top, std::max(0, cvRound(S[i] * (257.0f / step_)))) * step_);
    }
    if (swap_rb_)
      for (int u = 0; u < image->cols; ++u)
        std::swap(out[3 * u], out[3 * u + 2]);
    return;
  }
  uint8_t* out = image->ptr<uint8_t>(v);
  quantizeRow(S, n, out);
  if (swap_rb_)
    for (int u = 0; u < image->cols; ++u)
      std::swap(out[3 * u], out[3 * u + 2]);
}

void spillCharge(Blooming blooming, float full_well, cv::Mat* charge)
{
  const int H = charge->rows, n = charge->cols;
  if (blooming == Blooming::kNone)
  {
    cv::min(*charge, full_well, *charge);
    return;
  }
  // Each saturated pixel's excess, half of it carried down the column and
  // half up, dropped into the first pixels with room on the way.
  // Kept per thread (a new frame-sized buffer per call cost its page faults).
  thread_local cv::Mat excess;
  cv::subtract(*charge, full_well, excess);
  cv::max(excess, 0.0f, excess);
  cv::min(*charge, full_well, *charge);
  std::vector<float> carry(n);
  for (int pass = 0; pass < 2; ++pass)
  {
    std::fill(carry.begin(), carry.end(), 0.0f);
    for (int i = 0; i < H; ++i)
    {
      const int v = pass == 0 ? i : H - 1 - i;
      float* q = charge->ptr<float>(v);
      const float* x = excess.ptr<float>(v);
      for (int k = 0; k < n; ++k)
      {
        carry[k] += 0.5f * x[k];
        const float put = std::min(full_well - q[k], carry[k]);
        q[k] += put;
        carry[k] -= put;
      }
    }
  }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
