// The brightness of the scene's two light sources, in DN: the one place where
// the simulator turns the lighting params into signal (docs/simulator.md,
// "Radiometry"). A radiometric model of the rig (sun spectrum, filters, the
// projector's power) replaces these two functions and nothing else: the rock
// (rock_render, clutter) scales with sunDn(), the dots (projector_dots) with
// dotGain(); reflectance and the camera's channel responses are applied per
// pixel after them.
#pragma once

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

// DN of a white Lambertian surface facing the sun, exposure included (0 at
// night).
inline double sunDn(const SimulatorParams& params)
{
  return params.lighting.sun_level * LightingParams::kSunFullScaleDn * params.lighting.exposure;
}

// A dot's energy scale: its peak in DN on a white surface facing the
// projector at 1 m, per unit footprint (beam sigma x distance)^2 in m^2; the
// dot's peak radiance is dotGain * cos(incidence) / (sigma * d)^2 per unit
// reflectance, so that the reference dot (kReferenceBeamSigmaRad at
// kReferenceDistanceM) is dot_to_sun_ratio times the full sun.
inline double dotGain(const SimulatorParams& params)
{
  const LightingParams& light = params.lighting;
  const double d = LightingParams::kReferenceDistanceM, s = LightingParams::kReferenceBeamSigmaRad;
  return light.dot_to_sun_ratio * LightingParams::kSunFullScaleDn * light.exposure * params.projector.power_scale * d *
         d * s * s;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
