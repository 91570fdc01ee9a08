// The scenes of benchmark_spot_detector's whole-frame frames (dot sigma
// 1.5-4 px, sun 0.5 and 1, clutter), shared with time_spot_detector, which
// writes them for detectors of other versions (docs/performance.md).
#pragma once

#include <cmath>

#include "structured_light_stabilizer/sim/render/simulator.h"

namespace structured_light_stabilizer
{
namespace test
{
// Frame i (render it at t = 0.1 i), the dots `brightness` times as bright.
inline SimulatorParams benchmarkFrameParams(int i, double brightness = 1.0)
{
  const double beams[] = {0.0014, 0.002, 0.0028, 0.0038};
  const double suns[] = {1.0, 0.5};
  SimulatorParams cfg = studySimulatorParams();  // comparable with the figures measured before
  cfg.projector.beam_sigma_rad = beams[i % 4];
  cfg.lighting.sun_level = suns[(i / 4) % 2];
  cfg.lighting.dot_to_sun_ratio *= std::pow(cfg.projector.beam_sigma_rad / 0.002, 2.0) * brightness;
  cfg.clutter.green_specks = 20;
  cfg.clutter.olive_minerals = 20;
  cfg.clutter.green_blobs = 5;
  cfg.rock.seed = 1000 + i;
  cfg.motion.jitter_translation_m = 0.002;
  return cfg;
}
}  // namespace test
}  // namespace structured_light_stabilizer
