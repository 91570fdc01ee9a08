// The sensor's share of a frame: shot and read noise on the linear radiance,
// clipping and 8-bit quantisation, one row at a time. Blooming at clipping,
// Bayer output or a different bit depth would go here.
#pragma once

#include <cstdint>
#include <vector>

#include "structured_light_stabilizer/sim/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// Noise of one frame. The draws are seeded per (noise_seed, t, row), so rows
// are independent and the result does not depend on the thread count.
class SensorNoise
{
public:
  SensorNoise(const SensorParams& sensor, uint32_t noise_seed, double t);

  // False when both shot and read noise are off (applyRow would do nothing).
  bool enabled() const { return enabled_; }

  // Clips row v's linear radiance L (n values, DN) at 0 and adds shot noise
  // (variance L * gain) and read noise. N: scratch of n + 5 floats, sd: of n;
  // the three must not overlap (restrict: the loops vectorise without
  // run-time overlap checks).
  void applyRow(int v, int n, float* __restrict L, float* __restrict N, float* __restrict sd) const;

private:
  const std::vector<float>& table_;  // standard normal quantiles (noise.h)
  float read_var_;                   // DN^2
  float gain_;                       // DN per electron, 0 without shot noise
  bool enabled_;
  uint64_t frame_key_;
};

// Rounds and saturates n linear values (DN) to 8 bits.
void quantizeRow(const float* L, int n, uint8_t* out);

}  // namespace sim
}  // namespace structured_light_stabilizer
