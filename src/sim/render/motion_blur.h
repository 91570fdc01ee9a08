// Exposure-time motion blur (SensorParams::exposure_time_s > 0): the
// frame is the sum of sub-exposures spread evenly over the exposure, the rig
// at its pose of each instant; the ground truth stays the instant t (the
// middle of the exposure). Off (exposure_time_s = 0), none of this runs.
#pragma once

#include <functional>
#include <vector>

#include "sim/render/frame_geometry.h"
#include "sim/render/rock_render.h"
#include "sim/render/rock_surface.h"
#include "sim/render/splat.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// Where the rig stands at time tau (the request's arm correction included).
using GeometryAt = std::function<FrameGeometry(double tau)>;

// The centres of n equal slices of [t - exposure / 2, t + exposure / 2].
std::vector<double> subExposureTimes(double t, double exposure_s, int n);

// The dots over the exposure: the splats of m sub-exposures, each with 1 / m
// of the light, m at least sensor.exposure_samples and enough that the
// fastest dot moves <= 0.5 px between two (its smear looks continuous, not
// beaded; at most 256).
void renderBlurredDots(const SimulatorParams& params, const ProjectorCalibration& projector, const RockSurface& rock,
                       const GeometryAt& geometry, double t, std::vector<Splat>* splats,
                       std::vector<DotAlbedo>* albedo);

// The rock's radiance averaged over sensor.exposure_samples sub-exposures
// (rows as renderRockSamples). In a buffer kept per calling thread: valid
// until that thread's next call.
const float* renderBlurredRock(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor,
                               const GeometryAt& geometry, double t, double sun);

}  // namespace sim
}  // namespace structured_light_stabilizer
