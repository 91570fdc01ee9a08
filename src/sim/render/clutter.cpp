#include "sim/render/clutter.h"

#include <cmath>
#include <random>

#include "sim/render/optics.h"

namespace structured_light_stabilizer
{
namespace sim
{

std::vector<ClutterItem> scatterClutter(const ClutterParams& cl, const RockSurface& rock, uint32_t seed)
{
  std::vector<ClutterItem> items;
  std::mt19937 rng(seed * 2654435761u + 17u);
  std::uniform_real_distribution<double> ux(-rock.half_w, rock.half_w), uy(-rock.half_h, rock.half_h), u01(0.0, 1.0);
  for (int n = 0; n < cl.green_specks; ++n)
    items.push_back({ux(rng), uy(rng), 0.0008 + 0.0012 * u01(rng), {0.10, 0.40, 0.10}, false});
  for (int n = 0; n < cl.olive_minerals; ++n)
  {
    // Olive / green-brown: R = G > B (hue 60 deg, between the rock's ~20 deg
    // and a dot's 85-115 deg), half saturated, darker than a dot.
    const double v = 0.10 + 0.08 * u01(rng);
    items.push_back({ux(rng), uy(rng), 0.006 + 0.012 * u01(rng), {0.45 * v, 1.0 * v, 1.0 * v}, true});
  }
  for (int n = 0; n < cl.green_blobs; ++n)
    items.push_back({ux(rng), uy(rng), 0.0025 + 0.0015 * u01(rng), {0.14, 0.60, 0.08}, false});
  return items;
}

void addClutterSplats(const std::vector<ClutterItem>& items, const RockSurface& rock, const FrameGeometry& g,
                      const SensorParams& sensor, double sun, std::vector<Splat>* splats)
{
  const CameraModel& cam = sensor.camera;
  const int W = cam.width, H = cam.height;
  for (const ClutterItem& item : items)
  {
    const Eigen::Vector3d X_rock(item.x, item.y, rock.height(item.x, item.y));
    const Eigen::Vector3d X = g.T_cr * X_rock;
    if (!(X.z() > 0.0))
      continue;
    const cv::Point2d p = cam.project(X);
    if (!(p.x > -20 && p.y > -20 && p.x < W + 20 && p.y < H + 20) || occludedFromCamera(rock, g, X_rock))
      continue;
    // The patch is a disc on the tangent plane, seen through the projection.
    const Eigen::Vector3d n_rock = rock.normal(item.x, item.y);
    const Eigen::Vector3d n = g.T_cr.linear() * n_rock;
    const Eigen::Matrix3d Ss = item.radius_m * item.radius_m * (Eigen::Matrix3d::Identity() - n * n.transpose());
    const Eigen::Matrix<double, 2, 3> J = projectionJacobian(cam, X);
    const Eigen::Matrix2d S = J * Ss * J.transpose() + kPixelBoxVariance * Eigen::Matrix2d::Identity();
    const double shade = (std::max(0.0, n_rock.dot(rock.sun_dir)) + rock.sky) * sun * vignetting(sensor, X);
    Splat sp;
    sp.cx = p.x;
    sp.cy = p.y;
    sp.blend = true;
    sp.flat_top = item.flat_top;
    for (int c = 0; c < 3; ++c)
      sp.value[c] = static_cast<float>(item.refl[c] * shade);
    // Patches end where their weight drops below 1e-3.
    if (setSplatShape(&sp, S, -2.0 * std::log(item.flat_top ? 1e-3 / 2.5 : 1e-3), H))
      splats->push_back(sp);
  }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
