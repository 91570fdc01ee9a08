// The lens's share of a dot's blur and brightness (docs/simulator.md): the
// defocus of the study's fixed-focus lens, diffraction, the pixel's box and
// natural vignetting. Per-dot defocus beyond the thin-lens disc, or a
// band-pass filter in front of the lens, would go here.
#pragma once

#include <Eigen/Core>

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// Variance (px^2) of the uniform box of one pixel, added to every splat.
constexpr double kPixelBoxVariance = 1.0 / 12.0;

// Diameter of confusion (m, on the sensor) of a point at distance_m
// (docs/study.md §2.1.1.4).
double diameterOfConfusion(const SensorParams& sensor, double distance_m);

// Defocus blur as a Gaussian sigma in pixels: DoC / 4, the second moment of a
// uniform disc of diameter DoC.
double defocusSigmaPx(const SensorParams& sensor, double distance_m);

// Diffraction blur (px): Gaussian approximation of the Airy core, sigma =
// 0.42 lambda N with the working f-number N = image distance / aperture.
double diffractionSigmaPx(const SensorParams& sensor, double wavelength_nm);

// Natural vignetting (cos^4 of the off-axis angle) of a camera-frame point;
// 1 when disabled.
double vignetting(const SensorParams& sensor, const Eigen::Vector3d& X_cam);

}  // namespace sim
}  // namespace structured_light_stabilizer
