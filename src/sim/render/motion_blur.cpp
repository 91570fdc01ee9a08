#include "sim/render/motion_blur.h"

#include <algorithm>
#include <cmath>

#include "sim/render/projector_dots.h"

namespace structured_light_stabilizer
{
namespace sim
{

std::vector<double> subExposureTimes(double t, double exposure_s, int n)
{
  std::vector<double> times(n);
  for (int k = 0; k < n; ++k)
    times[k] = t + exposure_s * ((k + 0.5) / n - 0.5);
  return times;
}

void renderBlurredDots(const SimulatorParams& params, const ProjectorCalibration& projector, const RockSurface& rock,
                       const GeometryAt& geometry, double t, std::vector<Splat>* splats, std::vector<DotAlbedo>* albedo)
{
  const double T = params.sensor.exposure_time_s;
  // The fastest dot's smear, from its pixels at the ends of the exposure.
  SimFrame first, last;
  std::vector<Splat> unused;
  std::vector<DotAlbedo> unused_albedo;
  renderDots(params, projector, rock, geometry(t - 0.5 * T), &first, &unused, &unused_albedo);
  renderDots(params, projector, rock, geometry(t + 0.5 * T), &last, &unused, &unused_albedo);
  double smear = 0.0;
  for (size_t b = 0; b < first.pixels.size(); ++b)
    if (first.visible[b] && last.visible[b])
      smear = std::max(smear, std::hypot(last.pixels[b].x - first.pixels[b].x, last.pixels[b].y - first.pixels[b].y));
  const int m = std::min(256, std::max(params.sensor.exposure_samples, static_cast<int>(std::ceil(2.0 * smear))));
  SimulatorParams sub = params;
  sub.projector.power_scale /= m;
  for (double tau : subExposureTimes(t, T, m))
  {
    SimFrame scratch;
    renderDots(sub, projector, rock, geometry(tau), &scratch, splats, albedo);
  }
}

const float* renderBlurredRock(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor,
                               const GeometryAt& geometry, double t, double sun)
{
  static thread_local std::vector<float> sum;
  const int n = sensor.exposure_samples;
  sum.assign(sampling.stride() * sampling.rh, 0.0f);
  for (double tau : subExposureTimes(t, sensor.exposure_time_s, n))
  {
    const float* rows = renderRockSamples(rock, sampling, sensor, geometry(tau), sun / n).radiance;
    for (size_t k = 0; k < sum.size(); ++k)
      sum[k] += rows[k];
  }
  return sum.data();
}

}  // namespace sim
}  // namespace structured_light_stabilizer
