// Clutter on the rock: green specks, olive minerals and dot-sized green blobs
// (the look-alikes a detector must cope with), fixed in the rock frame and
// lit like the rock. Scattered once per Simulator, rendered as splats.
#pragma once

#include <cstdint>
#include <vector>

#include "sim/render/frame_geometry.h"
#include "sim/render/rock_surface.h"
#include "sim/render/splat.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

struct ClutterItem
{
  double x, y;      // rock frame, m
  double radius_m;  // Gaussian sigma of the patch on the surface
  double refl[3];   // B, G, R reflectance
  bool flat_top;    // mineral patches: a soft-edged disc rather than a Gaussian
};

// Places the clutter uniformly over the rock (deterministic in seed).
std::vector<ClutterItem> scatterClutter(const ClutterParams& clutter, const RockSurface& rock, uint32_t seed);

// Appends the splat of every item in view and not hidden by the rock, lit by
// the sun (sun: DN of a white surface facing the sun, exposure included).
void addClutterSplats(const std::vector<ClutterItem>& items, const RockSurface& rock, const FrameGeometry& g,
                      const SensorParams& sensor, double sun, std::vector<Splat>* splats);

}  // namespace sim
}  // namespace structured_light_stabilizer
