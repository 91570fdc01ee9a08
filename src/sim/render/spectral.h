// The colours of the scene as the camera's channels see them (
// docs/simulator.md, "Colours and sensor outputs"). The rock is rendered in
// three reflectance bands (B, G, R: what a colour camera's channels see of
// sunlight); a projector dot samples the reflectance of its own band (B, G,
// R or NIR) and reaches each channel with that channel's relative response
// to its light. A monochrome camera sums the bands of the sunlit rock with
// its own weights, and sees a dot with response 1.
//
// Brightness units: a dot's signal in its primary channel, per unit
// reflectance of its band, is what dot_to_sun_ratio refers to (brightness.h),
// so the colour changes where the light goes, not how bright the dot is.
#pragma once

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

struct CameraSpectrum
{
  // Signal of image channel c (B, G, R of the render buffer) per unit
  // reflectance of band k (B, G, R, NIR), relative to the primary channel.
  // A monochrome camera's three rows are equal (its buffer channels are
  // summed with mono_weights, which add up to 1).
  float dot_mix[3][4] = {};
  int primary = 1;  // the buffer channel of SimFrame::peak_dn
  bool mono = false;
  // A monochrome silicon sensor's share of the sunlit B, G, R bands (its
  // visible response under daylight; the sun's NIR is left to the
  // radiometric model's filters).
  float mono_weights[3] = {0.25f, 0.40f, 0.35f};
};

CameraSpectrum cameraSpectrum(ProjectorColor color, SensorOutput output);

}  // namespace sim
}  // namespace structured_light_stabilizer
