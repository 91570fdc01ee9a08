// The simulated rock: a height field with its albedo and baked sun shading on
// a regular vertex grid in the rock frame (z = h(x, y), z away from the
// camera), and the ray caster that intersects it (ray_cast.cpp). Built once
// per Simulator, then read-only (shared by concurrent render() calls).
//
// Finer physics of the surface (fine texture, per-pixel albedo under a dot, a
// chessboard target) belongs here: whatever a rock point reflects.
#pragma once

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

class ChessboardPattern;

struct RockSurface
{
  // Builds the height field (relief, optional step), its slope bounds, the
  // albedo and the shading under the lighting's sun and sky.
  RockSurface(const RockParams& rock, const LightingParams& lighting);

  // Height field and its smooth gradient on a regular vertex grid over the
  // rock extent; vertex (i, j) at (x0 + i * cell, y0 + j * cell).
  int nx = 0, ny = 0;  // cells
  double cell = 0.004, inv_cell = 250.0, x0 = 0.0, y0 = 0.0, half_w = 1.0, half_h = 1.0;
  std::vector<float> h, gx, gy;
  std::vector<float> refl;    // B, G, R reflectance per vertex
  std::vector<float> sunlit;  // B, G, R reflectance * (sun cosine + sky) per vertex
  // Sunlit B, G, R and height interleaved per vertex: what a rock pixel
  // reads, in one or two cache lines, and one SIMD register per vertex.
  std::vector<float> hs;
  double hmin = 0.0, hmax = 0.0;
  double lip_x = 0.0, lip_y = 0.0;  // Lipschitz bounds of the bilinear surface
  bool planar = false;              // all heights equal: one normal everywhere
  // Per block of kBlock x kBlock cells: lowest vertex and slope bounds, for
  // the ray caster's empty-space skipping.
  static constexpr int kBlock = 8;
  struct BlockBound
  {
    double hmin, lip_x, lip_y;
  };
  int nbx = 0, nby = 0;
  std::vector<BlockBound> blocks;
  Eigen::Vector3d sun_dir = Eigen::Vector3d(0.0, 0.0, -1.0);  // rock frame, towards the sun (unit)
  double sky = 0.0;
  float nir_to_red = 1.25f;  // RockParams::nir_to_red_ratio
  // A printed chessboard instead of the rock (target_board.h): the surface is
  // then a flat slab of the board's size and its reflectance is the print's.
  std::shared_ptr<const ChessboardPattern> board;

  int vertex(int i, int j) const { return j * (nx + 1) + i; }

  bool inside(double x, double y) const { return std::abs(x) <= half_w && std::abs(y) <= half_h; }

  void locate(double x, double y, int* i, int* j, double* fx, double* fy) const
  {
    double u = (x - x0) * inv_cell, v = (y - y0) * inv_cell;
    u = std::min(std::max(u, 0.0), static_cast<double>(nx));
    v = std::min(std::max(v, 0.0), static_cast<double>(ny));
    *i = std::min(static_cast<int>(u), nx - 1);
    *j = std::min(static_cast<int>(v), ny - 1);
    *fx = u - *i;
    *fy = v - *j;
  }

  // Bilinear height and the exact gradient of the bilinear patch (the
  // surface the ray caster intersects).
  double height(double x, double y, double* dhdx = nullptr, double* dhdy = nullptr) const
  {
    int i, j;
    double fx, fy;
    locate(x, y, &i, &j, &fx, &fy);
    const float* r0 = &h[vertex(i, j)];
    const float* r1 = r0 + (nx + 1);
    const double h00 = r0[0], h10 = r0[1], h01 = r1[0], h11 = r1[1];
    const double a = h00 + fx * (h10 - h00);
    const double b = h01 + fx * (h11 - h01);
    if (dhdx)
    {
      *dhdx = ((h10 - h00) * (1.0 - fy) + (h11 - h01) * fy) * inv_cell;
      *dhdy = (b - a) * inv_cell;
    }
    return a + fy * (b - a);
  }

  // Smooth outward normal (towards the camera side, -z), from the
  // interpolated central-difference gradient: used for shading and incidence.
  Eigen::Vector3d normal(double x, double y) const
  {
    int i, j;
    double fx, fy;
    locate(x, y, &i, &j, &fx, &fy);
    const int k = vertex(i, j);
    auto bil = [&](const std::vector<float>& g)
    {
      const double a = g[k] + fx * (g[k + 1] - g[k]);
      const double b = g[k + nx + 1] + fx * (g[k + nx + 2] - g[k + nx + 1]);
      return a + fy * (b - a);
    };
    return Eigen::Vector3d(bil(gx), bil(gy), -1.0).normalized();
  }

  // Bilinear B, G, R of a per-vertex grid (refl or sunlit) at (x, y).
  void lookup3(const std::vector<float>& grid, double x, double y, float out[3]) const
  {
    int i, j;
    double fx, fy;
    locate(x, y, &i, &j, &fx, &fy);
    const float* p00 = &grid[3 * vertex(i, j)];
    const float* p01 = p00 + 3 * (nx + 1);
    const float w00 = static_cast<float>((1 - fx) * (1 - fy)), w10 = static_cast<float>(fx * (1 - fy));
    const float w01 = static_cast<float>((1 - fx) * fy), w11 = static_cast<float>(fx * fy);
    for (int c = 0; c < 3; ++c)
      out[c] = w00 * p00[c] + w10 * p00[3 + c] + w01 * p01[c] + w11 * p01[3 + c];
  }

  // Reflectance of the surface at rock-frame (x, y) in the bands B, G, R and
  // NIR (850 nm), as a projector dot sees it: blurred by a Gaussian of
  // standard deviation blur_x, blur_y (m, along x and y; the part of the
  // camera's blur that mixes neighbouring surface points into one pixel of
  // the dot, simulator.cpp). The rock's albedo grid is smooth on that scale
  // (< 1 mm against >= 2 mm cells), so the blur only matters for a printed
  // target's sharp edges.
  void reflectanceUnderDot(double x, double y, double blur_x, double blur_y, float out[4]) const;

  // First intersection of o + s d (rock frame, s >= 0) with the rock. Returns
  // false on a miss; *wall is set when the ray enters through a side wall of
  // the slab rather than the height field (ray_cast.cpp).
  bool cast(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* s_hit, bool* wall) const;

private:
  void buildRelief(const RockParams& rock);
  void computeSlopeBounds();
  void computeBlockBounds();
  void paintAlbedo(const RockParams& rock);
};

}  // namespace sim
}  // namespace structured_light_stabilizer
