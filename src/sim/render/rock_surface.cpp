#include "sim/render/rock_surface.h"

#include "sim/render/noise.h"
#include "sim/render/target_board.h"

namespace structured_light_stabilizer
{
namespace sim
{

RockSurface::RockSurface(const RockParams& rc, const LightingParams& lighting)
{
  half_w = 0.5 * rc.width_m;
  half_h = 0.5 * rc.height_m;
  // Cells of a fifth of the finest texture feature, within [2, 5] mm, then
  // stretched so that a whole number of them spans the rock.
  double finest = rc.texture_scale_m / 5.0;
  if (rc.fine_texture_period_m > 0.0)
    finest = std::min(finest, rc.fine_texture_period_m / 8.0);  // its octaves of period / 2 and / 4
  cell = std::min(std::max(finest, 0.002), 0.005);
  nx = std::max(2, static_cast<int>(std::ceil(rc.width_m / cell)));
  ny = std::max(2, static_cast<int>(std::ceil(rc.height_m / cell)));
  cell = std::max(rc.width_m / nx, rc.height_m / ny);
  inv_cell = 1.0 / cell;
  x0 = -0.5 * nx * cell;
  y0 = -0.5 * ny * cell;
  const size_t nv = static_cast<size_t>(nx + 1) * (ny + 1);
  h.resize(nv);
  gx.resize(nv);
  gy.resize(nv);
  refl.resize(3 * nv);
  sunlit.resize(3 * nv);

  buildRelief(rc);
  computeSlopeBounds();
  computeBlockBounds();
  sun_dir = lighting.sun_direction.normalized();
  sky = lighting.sky_ambient;
  nir_to_red = static_cast<float>(rc.nir_to_red_ratio);
  paintAlbedo(rc);

  hs.resize(4 * nv);
  for (size_t k = 0; k < nv; ++k)
  {
    for (int c = 0; c < 3; ++c)
      hs[4 * k + c] = sunlit[3 * k + c];
    hs[4 * k + 3] = h[k];
  }
}

void RockSurface::reflectanceUnderDot(double x, double y, double blur_x, double blur_y, float out[4]) const
{
  if (board)
  {
    const float rho = static_cast<float>(board->reflectance(x, y, blur_x, blur_y));
    out[0] = out[1] = out[2] = out[3] = rho;  // a grey print, also in the NIR
    return;
  }
  lookup3(refl, x, y, out);
  out[3] = std::min(1.0f, nir_to_red * out[2]);
}

// Relief: smooth 10-40 cm features (what a 5 cm dot spacing samples) plus a
// millimetre roughness, scaled to the requested peak-to-peak, plus the step.
void RockSurface::buildRelief(const RockParams& rc)
{
  const int vx = nx + 1, vy = ny + 1;
  const uint32_t seed = rc.seed;
  const NoiseOctaves smooth = {{0.40, 1.0}, {0.22, 0.55}, {0.12, 0.30}};
  const NoiseOctaves rough = {{0.02, 1.0}, {0.011, 0.6}};
  std::vector<double> raw(static_cast<size_t>(vx) * vy);
  double rmin = 1e300, rmax = -1e300;
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const double x = x0 + i * cell, y = y0 + j * cell;
      const double v = fractalNoise(x, y, seed, smooth) + 0.015 * fractalNoise(x, y, seed ^ 0xA5A5u, rough);
      raw[static_cast<size_t>(j) * vx + i] = v;
      rmin = std::min(rmin, v);
      rmax = std::max(rmax, v);
    }
  }
  const double span = rmax - rmin;
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const size_t k = static_cast<size_t>(j) * vx + i;
      double z = span > 0.0 ? rc.relief_m * ((raw[k] - rmin) / span - 0.5) : 0.0;
      if (rc.step_height_m != 0.0)
        z += (x0 + i * cell > rc.step_x_m ? 0.5 : -0.5) * rc.step_height_m;
      h[k] = static_cast<float>(z);
    }
  }
}

// Height range, global Lipschitz bounds and the central-difference gradient
// used for shading.
void RockSurface::computeSlopeBounds()
{
  const int vx = nx + 1, vy = ny + 1;
  hmin = 1e300;
  hmax = -1e300;
  double lx = 0.0, ly = 0.0;
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const int k = vertex(i, j);
      hmin = std::min(hmin, static_cast<double>(h[k]));
      hmax = std::max(hmax, static_cast<double>(h[k]));
      if (i < nx)
        lx = std::max(lx, std::abs(static_cast<double>(h[k + 1]) - h[k]));
      if (j < ny)
        ly = std::max(ly, std::abs(static_cast<double>(h[k + vx]) - h[k]));
      const int il = std::max(i - 1, 0), ir = std::min(i + 1, nx);
      const int jd = std::max(j - 1, 0), ju = std::min(j + 1, ny);
      gx[k] = static_cast<float>((h[vertex(ir, j)] - h[vertex(il, j)]) / ((ir - il) * cell));
      gy[k] = static_cast<float>((h[vertex(i, ju)] - h[vertex(i, jd)]) / ((ju - jd) * cell));
    }
  }
  // Float storage rounds the heights; widen the bounds by a hair so the slab
  // test never clips a true hit.
  hmin -= 1e-6;
  hmax += 1e-6;
  planar = lx == 0.0 && ly == 0.0;
  lip_x = lx / cell * 1.001 + 1e-9;
  lip_y = ly / cell * 1.001 + 1e-9;
}

// Block bounds over the vertices of each block's cells (its border
// included): the bilinear surface lies above the lowest vertex of its cell
// and its slope is bounded by the steepest cell edge.
void RockSurface::computeBlockBounds()
{
  const int vx = nx + 1, vy = ny + 1;
  nbx = (nx + kBlock - 1) / kBlock;
  nby = (ny + kBlock - 1) / kBlock;
  blocks.assign(static_cast<size_t>(nbx) * nby, {1e300, 0.0, 0.0});
  for (int j = 0; j < vy; ++j)
  {
    for (int i = 0; i < vx; ++i)
    {
      const int k = vertex(i, j);
      const double dxh = i < nx ? std::abs(static_cast<double>(h[k + 1]) - h[k]) : 0.0;
      const double dyh = j < ny ? std::abs(static_cast<double>(h[k + vx]) - h[k]) : 0.0;
      // A vertex on a block border belongs to the blocks on both sides.
      for (int bj = std::max(0, (j - 1) / kBlock); bj <= std::min(nby - 1, j / kBlock); ++bj)
        for (int bi = std::max(0, (i - 1) / kBlock); bi <= std::min(nbx - 1, i / kBlock); ++bi)
        {
          BlockBound& b = blocks[static_cast<size_t>(bj) * nbx + bi];
          b.hmin = std::min(b.hmin, static_cast<double>(h[k]) - 1e-6);
          b.lip_x = std::max(b.lip_x, dxh / cell * 1.001 + 1e-9);
          b.lip_y = std::max(b.lip_y, dyh / cell * 1.001 + 1e-9);
        }
    }
  }
}

// Fine texture (grain, lichen, weathering at 1-3 cm): a factor per channel
// around 1, mostly brightness (all channels alike) with a quarter of the
// amplitude as hue (R against B), as a rock's grains differ more in
// brightness than in colour; optionally green against red
// (fine_texture_green: colour texture). Octaves of period / 2 and period / 4
// (value noise features of size s repeat over about 2 s).
struct FineTexture
{
  explicit FineTexture(const RockParams& rc)
    : on(rc.fine_texture_period_m > 0.0),
      amplitude(rc.fine_texture_amplitude),
      green(rc.fine_texture_green),
      seed(rc.seed),
      octaves({{0.5 * rc.fine_texture_period_m, 1.0}, {0.25 * rc.fine_texture_period_m, 0.5}})
  {
  }

  // Factors for B, G, R at (x, y); identity when off.
  void factors(double x, double y, double f[3]) const
  {
    f[0] = f[1] = f[2] = 1.0;
    if (!on)
      return;
    // tanh(2.5 n): the two-octave noise n has a standard deviation of about
    // 0.3, so the brightness factor reaches about 1 +- amplitude.
    const double brightness = amplitude * std::tanh(2.5 * fractalNoise(x, y, seed ^ 0x7F4A7C15u, octaves));
    const double hue = 0.25 * amplitude * std::tanh(2.5 * fractalNoise(x, y, seed ^ 0x2545F491u, octaves));
    f[0] = (1.0 + brightness) * (1.0 - hue);
    f[1] = 1.0 + brightness;
    f[2] = (1.0 + brightness) * (1.0 + hue);
    if (green > 0.0)
      f[1] *= 1.0 + green * std::tanh(2.5 * fractalNoise(x, y, seed ^ 0x6A09E667u, octaves));
  }

  bool on;
  double amplitude;
  double green;
  uint32_t seed;
  NoiseOctaves octaves;
};

// Albedo: reddish by default (R > G > B; RockParams::green_to_red,
// blue_to_red), features from 25 cm down to texture_scale_m,
// R in [albedo_min, albedo_max]; G and B follow with a slowly varying hue;
// times the optional fine texture, within [0, 1]. The sun and sky shading is
// baked per vertex (sunlit).
void RockSurface::paintAlbedo(const RockParams& rc)
{
  const FineTexture fine(rc);
  const uint32_t seed = rc.seed;
  NoiseOctaves tex;
  for (double s = 0.25, w = 1.0; s >= rc.texture_scale_m * 0.999; s *= 0.5, w *= 0.75)
    tex.push_back({s, w});
  if (tex.empty())
    tex.push_back({rc.texture_scale_m, 1.0});
  tex.push_back({rc.texture_scale_m, 0.6});
  const NoiseOctaves hue = {{0.30, 1.0}, {0.08, 0.5}};
  // albedo_min == albedo_max: a uniform albedo in every channel (no hue).
  const double hue_on = rc.albedo_max > rc.albedo_min ? 1.0 : 0.0;
  for (int j = 0; j <= ny; ++j)
  {
    for (int i = 0; i <= nx; ++i)
    {
      const int k = vertex(i, j);
      const double x = x0 + i * cell, y = y0 + j * cell;
      const double n = fractalNoise(x, y, seed ^ 0x51ED27u, tex);
      const double a01 = 0.5 + 0.5 * std::tanh(3.0 * n);
      const double r = rc.albedo_min + (rc.albedo_max - rc.albedo_min) * a01;
      const double g = r * (rc.green_to_red + hue_on * 0.10 * fractalNoise(x, y, seed ^ 0x3C6EF3u, hue));
      const double b = r * (rc.blue_to_red + hue_on * 0.08 * fractalNoise(x, y, seed ^ 0x1B873593u, hue));
      double f[3];
      fine.factors(x, y, f);
      float* rf = &refl[3 * static_cast<size_t>(k)];
      rf[0] = static_cast<float>(std::min(1.0, b * f[0]));
      rf[1] = static_cast<float>(std::min(1.0, g * f[1]));
      rf[2] = static_cast<float>(std::min(1.0, r * f[2]));
      const Eigen::Vector3d nrm = Eigen::Vector3d(gx[k], gy[k], -1.0).normalized();
      const double shade = std::max(0.0, nrm.dot(sun_dir)) + sky;
      for (int c = 0; c < 3; ++c)
        sunlit[3 * static_cast<size_t>(k) + c] = static_cast<float>(rf[c] * shade);
    }
  }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
