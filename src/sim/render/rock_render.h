// The rock's sunlit radiance in the image: ray casts through a lattice of
// rock samples (every rock_subsample-th pixel), upsampled to the full frame.
// Between samples the surface point is interpolated, not the radiance: each
// pixel then reads the rock's reflectance at its own point, as the dots'
// light does (splat.h, DotAlbedo), so that texture finer than two samples is
// in the ambient light as in the dots. Only the geometry of light leaving the
// rock lives here; what the rock reflects is RockSurface's, what the sensor
// does with it sensor.h's.
#pragma once

#include <cstddef>
#include <vector>

#include "sim/render/frame_geometry.h"
#include "sim/render/rock_surface.h"
#include "structured_light_stabilizer/calibration/camera_model.h"

namespace structured_light_stabilizer
{
namespace sim
{

// Reflectance of the terrain behind the rock (B, G, R), lit like the rock.
constexpr double kBackgroundBgr[3] = {0.015, 0.025, 0.045};

// Rock sample lattice: sample (i, j) is the ray through pixel
// (sub * i + (sub - 1) / 2, sub * j + (sub - 1) / 2). Built once per Simulator.
struct RockSampling
{
  RockSampling(const CameraModel& cam, int subsample);

  int sub = 1, rw = 0, rh = 0;
  std::vector<float> ray_lut;  // (x/z, y/z) per rock sample, only with lens distortion
  // Full-resolution pixel u -> samples i0, i1 and the weight of i1 (same for rows).
  std::vector<int> up_i0, up_i1, up_j0, up_j1;
  std::vector<float> up_wx, up_wy;

  // Floats per row of sample radiance: B, G, R per sample plus one of slack
  // (and of sample hit points: x, y, scale).
  size_t stride() const { return 3 * static_cast<size_t>(rw) + 1; }

  // Row v of the full-resolution frame (3 * width floats into L) from the
  // samples (rows of stride()), blended bilinearly; T is scratch of 3 * rw
  // floats. The three buffers must not overlap (restrict: lets the compiler
  // vectorise the interleaved loops without run-time overlap checks).
  void upsampleRow(const float* __restrict samples, int v, int width, float* __restrict L, float* __restrict T) const;

  // Then, where the samples around a pixel all hit the rock's height field
  // near each other (`hits`: rock-frame x, y and the radiance scale per
  // sample, x NaN elsewhere), the pixel's radiance from the rock's sunlit
  // reflectance at the interpolated point instead of the blend. T as above.
  void sharpenRow(const RockSurface& rock, const float* __restrict hits, int v, int width, float* __restrict L,
                  float* __restrict T) const;
};

// What renderRockSamples() gives: the radiance per sample, and the surface
// point per sample where the height field was hit (nullptr when the sampling
// is every pixel, for a chessboard target, and for motion blur's sum of
// sub-exposures).
struct RockSamples
{
  const float* radiance = nullptr;
  const float* hits = nullptr;
};

// Renders the radiance (B, G, R in DN, before noise) of every rock sample at
// one instant. sun: DN of a white surface facing the sun (exposure included),
// > 0. The result is in buffers kept per calling thread between frames (a
// fresh 3 MB buffer per frame costs its page faults): valid until that
// thread's next call. A chessboard target (rock.board) is rendered by
// target_board.h instead.
RockSamples renderRockSamples(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor,
                              const FrameGeometry& g, double sun);

}  // namespace sim
}  // namespace structured_light_stabilizer
