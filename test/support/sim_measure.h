// Measurements on simulator frames shared by the simulator's gtests
// (test_simulator.cpp, test_simulator_physics.cpp).
#pragma once

#include <algorithm>
#include <cmath>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

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

// The image centroid of beam k's dot as the beam's power lands on the rock,
// from the renderer's ray caster and camera model only (an independent
// calculation of where the dot's light goes): the beam's cross-section
// (Gaussian, beam_sigma_rad about its direction) cut into sub-rays on a
// `n` x `n` grid over +-4.5 sigma, each cast onto the rock
// (Simulator::intersect, the height field the truth uses) and projected. A
// Lambertian surface sends a sub-ray's power P towards the lens in
// proportion to P cos(theta_cam) / distance^2, whatever the incidence (a
// slanted patch spreads the same power over more area), so each sub-ray
// weighs its share of the beam times that; the normal comes from the hits
// of two neighbouring rays (eps sigma apart). Left out: vignetting (the
// simulator applies it per dot), the camera's view of each sub-ray's hit
// (tested on the beam's axis only, as by the simulator), albedo (it must be
// uniform). NaN when a sub-ray misses.
inline cv::Point2d subRayCentroid(const sls::Simulator& sim, int k, double t, int n = 41, double eps = 0.01)
{
  const sls::BeamRay& beam = sim.projector().beams[k];
  const double sigma = sim.params().projector.beam_sigma_rad;
  const Eigen::Vector3d b = beam.direction.normalized();
  const Eigen::Vector3d e1 = b.unitOrthogonal(), e2 = b.cross(e1);
  const double span = 4.5, h = 2.0 * span / (n - 1);
  auto cast = [&](double a1, double a2, Eigen::Vector3d* p)
  { return sim.intersect(t, beam.origin, (b + sigma * (a1 * e1 + a2 * e2)).normalized(), p); };
  double sw = 0.0, sx = 0.0, sy = 0.0;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
    {
      const double a1 = -span + i * h, a2 = -span + j * h;
      Eigen::Vector3d p, p1, p2;
      if (!cast(a1, a2, &p) || !cast(a1 + eps, a2, &p1) || !cast(a1, a2 + eps, &p2))
        return cv::Point2d(std::nan(""), std::nan(""));
      const Eigen::Vector3d normal = (p1 - p).cross(p2 - p).normalized();
      const double cos_cam = std::abs(normal.dot(p.normalized()));
      const double w = std::exp(-0.5 * (a1 * a1 + a2 * a2)) * cos_cam / p.squaredNorm();
      const cv::Point2d x = sim.camera().project(p);
      sw += w;
      sx += w * x.x;
      sy += w * x.y;
    }
  return cv::Point2d(sx / sw, sy / sw);
}

inline sls::SimulatorParams nightNoNoise()
{
  sls::SimulatorParams c = sls::studySimulatorParams();  // the study's brightness: the clipping cases
  c.lighting.sun_level = 0.0;                            // no rock background under the dots
  c.sensor.read_noise_dn = 0.0;
  c.sensor.shot_noise = false;
  c.keep_linear = true;
  return c;
}

// Sunlit at sun_level, noise-free, keeping the linear radiance.
inline sls::SimulatorParams sunlitNoNoise(double sun_level)
{
  sls::SimulatorParams c = sls::studySimulatorParams();
  c.lighting.sun_level = sun_level;
  c.sensor.read_noise_dn = 0.0;
  c.sensor.shot_noise = false;
  c.keep_linear = true;
  return c;
}

}  // namespace sim_measure
