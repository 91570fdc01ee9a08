#include "sensor.h"

#include <algorithm>

#include <opencv2/core.hpp>
#include <opencv2/core/hal/hal.hpp>

#include "noise.h"

namespace structured_light_stabilizer
{
namespace sim
{

SensorNoise::SensorNoise(const SensorParams& sc, uint32_t noise_seed, double t)
  : table_(normalTable()),
    read_var_(static_cast<float>(sc.read_noise_dn * sc.read_noise_dn)),
    gain_(sc.shot_noise ? static_cast<float>(sc.gain_dn_per_electron) : 0.0f),
    enabled_(read_var_ > 0.0f || gain_ > 0.0f)
{
  uint64_t frame_state = 0x243F6A8885A308D3ull ^ (static_cast<uint64_t>(noise_seed) << 32) ^ doubleBits(t);
  frame_key_ = splitmix64(&frame_state);
}

void SensorNoise::applyRow(int v, int n, float* __restrict L, float* __restrict N, float* __restrict sd) const
{
  // Locals: stores to the row might otherwise alias the members.
  const std::vector<float>& table = table_;
  const float gain = gain_, read_var = read_var_;
  uint64_t state = frame_key_ ^ (0xD1B54A32D192ED03ull * static_cast<uint64_t>(v + 1));
  for (int k = 0; k < n; k += 5)
  {
    const uint64_t r = splitmix64(&state);
    for (int q = 0; q < 5; ++q)
      N[k + q] = table[(r >> (12 * q)) & (kNormalTableSize - 1)];
  }
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

void quantizeRow(const float* L, int n, uint8_t* out)
{
  cv::Mat(1, n, CV_32F, const_cast<float*>(L)).convertTo(cv::Mat(1, n, CV_8U, out), CV_8U);
}

}  // namespace sim
}  // namespace structured_light_stabilizer
