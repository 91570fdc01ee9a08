// Measurements on simulator frames shared by the simulator's gtests
// (test_simulator.cpp, test_simulator_physics.cpp).
#pragma once

#include <algorithm>
#include <cmath>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/sim/simulator.h"

namespace sim_measure
{

namespace sls = structured_light_stabilizer;

// Intensity centroid and second moments of one channel around a point.
struct Moments
{
  double x = 0, y = 0, sxx = 0, syy = 0, sum = 0;
};

inline Moments channelMoments(const cv::Mat& img, int channel, const cv::Point2d& c, int half)
{
  Moments m;
  const int u0 = std::max(0, static_cast<int>(std::round(c.x)) - half);
  const int u1 = std::min(img.cols - 1, static_cast<int>(std::round(c.x)) + half);
  const int v0 = std::max(0, static_cast<int>(std::round(c.y)) - half);
  const int v1 = std::min(img.rows - 1, static_cast<int>(std::round(c.y)) + half);
  double sx = 0, sy = 0, sxx = 0, syy = 0, s = 0;
  for (int v = v0; v <= v1; ++v)
    for (int u = u0; u <= u1; ++u)
    {
      double w;
      if (img.depth() == CV_32F)
        w = img.ptr<float>(v)[3 * u + channel];
      else
        w = img.ptr<uint8_t>(v)[3 * u + channel];
      s += w;
      sx += w * u;
      sy += w * v;
      sxx += w * u * u;
      syy += w * v * v;
    }
  m.sum = s;
  if (s > 0)
  {
    m.x = sx / s;
    m.y = sy / s;
    m.sxx = sxx / s - m.x * m.x;
    m.syy = syy / s - m.y * m.y;
  }
  return m;
}

inline sls::SimulatorParams nightNoNoise()
{
  sls::SimulatorParams c;
  c.lighting.sun_level = 0.0;  // no rock background under the dots
  c.sensor.read_noise_dn = 0.0;
  c.sensor.shot_noise = false;
  c.keep_linear = true;
  return c;
}

// Sunlit at sun_level, noise-free, keeping the linear radiance.
inline sls::SimulatorParams sunlitNoNoise(double sun_level)
{
  sls::SimulatorParams c;
  c.lighting.sun_level = sun_level;
  c.sensor.read_noise_dn = 0.0;
  c.sensor.shot_noise = false;
  c.keep_linear = true;
  return c;
}

}  // namespace sim_measure
