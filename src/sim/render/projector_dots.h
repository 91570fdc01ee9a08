// The projector's dots: each beam ray-cast onto the rock, its ground truth
// (hit point, pixel, visibility, blur, peak) and the splat of its light in
// the image. Projector colours, strobing or per-dot optics would change this
// part (and kDotResponseBgr for the colour).
#pragma once

#include <vector>

#include "sim/render/frame_geometry.h"
#include "sim/render/rock_surface.h"
#include "sim/render/splat.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

namespace structured_light_stabilizer
{
namespace sim
{

// Fills frame's per-beam ground truth (points, pixels, blur_sigma_px,
// visible, peak_dn; NaN / 0 for beams that miss or are hidden) and appends
// the splat of every visible dot, with its per-pixel albedo (the splat's
// albedo indexes `albedo`, where it is appended).
void renderDots(const SimulatorParams& params, const ProjectorCalibration& projector, const RockSurface& rock,
                const FrameGeometry& g, SimFrame* frame, std::vector<Splat>* splats, std::vector<DotAlbedo>* albedo);

}  // namespace sim
}  // namespace structured_light_stabilizer
