#include "sim/render/optics.h"

#include <cmath>

namespace structured_light_stabilizer
{
namespace sim
{

double diameterOfConfusion(const SensorParams& s, double r)
{
  const double rf = s.focus_distance_m, f = s.focal_length_m;
  return s.aperture_diameter_m * std::abs(r - rf) / r * f / (rf - f);
}

double defocusSigmaPx(const SensorParams& s, double distance_m)
{
  return diameterOfConfusion(s, distance_m) / 4.0 / s.pixel_size_m;
}

double diffractionSigmaPx(const SensorParams& s, double wavelength_nm)
{
  const double image_dist = 1.0 / (1.0 / s.focal_length_m - 1.0 / s.focus_distance_m);
  return 0.42 * wavelength_nm * 1e-9 * image_dist / s.aperture_diameter_m / s.pixel_size_m;
}

double vignetting(const SensorParams& s, const Eigen::Vector3d& X_cam)
{
  if (!s.natural_vignetting)
    return 1.0;
  const double q = 1.0 + (X_cam.x() * X_cam.x() + X_cam.y() * X_cam.y()) / (X_cam.z() * X_cam.z());
  return 1.0 / (q * q);
}

}  // namespace sim
}  // namespace structured_light_stabilizer
