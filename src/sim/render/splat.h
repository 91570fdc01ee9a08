// Image-space Gaussians ("splats"): how projector dots (added light) and
// clutter patches (reflectance blended over the rock) reach the pixels. The
// frame is composed row by row, so a splat is applied one row at a time.
#pragma once

#include <algorithm>
#include <vector>

#include <Eigen/Core>

#include "sim/render/rock_surface.h"
#include "structured_light_stabilizer/calibration/camera_model.h"

namespace structured_light_stabilizer
{
namespace sim
{

// An image-space Gaussian (inverse covariance a, b, c in px^-2 about the
// centre cx, cy), cut where q = a dx^2 + 2 b dx dy + c dy^2 exceeds q_max:
// a projector dot (added) or a clutter patch (blended over the rock).
struct Splat
{
  double cx = 0.0, cy = 0.0;
  double a = 0.0, b = 0.0, c = 0.0;
  double q_max = 0.0;
  int v0 = 0, v1 = -1;                  // rows it touches (inclusive)
  float value[3] = {0.0f, 0.0f, 0.0f};  // B, G, R amplitude (dot) or radiance (patch)
  bool blend = false;                   // patch: out = (1 - w) out + w value
  bool flat_top = false;                // patch: w = min(1, 2.5 g), a soft-edged disc
  int albedo = -1;                      // dot: index of its DotAlbedo in SplatRows, -1 = none
  int beam = -1;                        // dot: the projector beam whose light it is
};

// What makes a projector dot's pixels follow the surface under each of them
// (docs/simulator.md, "Per-pixel albedo under a dot", "Incidence under a
// dot"). The beam's footprint (image covariance A) is blurred by the camera
// (B, S = A + B); the light that reaches image point x came from surface
// points distributed as N(c + A S^-1 (x - c), A - A S^-1 A) (the product of
// two Gaussians), so pixel x receives G_S(x - c) times the reflectance at
// that point, blurred by that covariance: exact for any albedo, with the
// tangent plane of the hit point mapping image offsets to the surface.
// On relief (`incidence`), the same point also carries what the tangent
// plane gets wrong about the beam's irradiance there (rockFactors()).
struct DotAlbedo
{
  double x0 = 0.0, y0 = 0.0;           // rock-frame (x, y) of the hit point, m
  double K[4] = {0.0, 0.0, 0.0, 0.0};  // row-major 2x2: image offset (px) -> rock (x, y) offset of the mean point
  double blur_x = 0.0, blur_y = 0.0;   // m, the blur of the reflectance along rock x and y
  // Signal in each image channel (B, G, R) per unit reflectance of each band
  // (B, G, R, NIR), times the splat's value.
  float mix[3][4] = {};
  // Where the dot's Gaussian falls below g_lookup (its value below ~0.02 DN)
  // its pixels take the factors of the hit point, f0, instead of a look-up.
  double g_lookup = 0.0;
  float f0[3] = {0.0f, 0.0f, 0.0f};
  // On relief (false on a planar surface, where the tangent plane is exact):
  // what incidenceFactor() needs, filled by projector_dots.cpp. Rock frame;
  // lengths in grid cells.
  bool incidence = false;
  struct Incidence
  {
    float beam[3] = {0.0f, 0.0f, 1.0f};  // beam direction (unit)
    float view[3] = {0.0f, 0.0f, 1.0f};  // camera ray to the hit (unit)
    float inv_cos_hit = 1.0f;            // 1 / cos(incidence) at the hit (the splat's amplitude holds it)
    float z = 0.0f;                      // the hit's height
    float gx = 0.0f, gy = 0.0f;          // the tangent plane's slopes (the rock's smooth normal at the hit)
    // r.w per grid offset (x, y): the tangent-plane point's offset from the
    // beam's axis (r) dotted with the camera ray's part across the beam (w);
    // and w.w.
    float omega[2] = {0.0f, 0.0f};
    float ww = 0.0f;
    float inv_sigma2 = 0.0f;  // 1 / (the beam's sigma at the hit)^2
  } inc;

  // The factor of each channel at image offset (du, dv) from the centre.
  void factors(const RockSurface& surface, double du, double dv, float out[3]) const
  {
    float rho[4];
    float shade = 1.0f;
    if (surface.board)
      surface.reflectanceUnderDot(x0 + K[0] * du + K[1] * dv, y0 + K[2] * du + K[3] * dv, blur_x, blur_y, rho);
    else
      rockFactors(surface, static_cast<float>(du), static_cast<float>(dv), rho, &shade);
    for (int c = 0; c < 3; ++c)
      out[c] = mix[c][0] * rho[0] + mix[c][1] * rho[1] + mix[c][2] * rho[2] + mix[c][3] * rho[3];
    if (incidence)
      for (int c = 0; c < 3; ++c)
        out[c] *= shade;
  }

  // The rock's bilinear albedo grid read in grid units (what most dot pixels
  // cost): the map to rock (x, y) folded into one to grid coordinates, in
  // float, the indices clamped to the grid.
  void prepareGrid(const RockSurface& surface)
  {
    const double ic = surface.inv_cell;
    gu0 = static_cast<float>((x0 - surface.x0) * ic);
    gv0 = static_cast<float>((y0 - surface.y0) * ic);
    for (int k = 0; k < 4; ++k)
      Kg[k] = static_cast<float>(K[k] * ic);
  }

  // The rock's reflectance rho (B, G, R, NIR) at image offset (du, dv) and,
  // with `incidence`, *shade: incidenceFactor() there.
  void rockFactors(const RockSurface& surface, float du, float dv, float rho[4], float* shade) const
  {
    const float gu = gu0 + Kg[0] * du + Kg[1] * dv, gv = gv0 + Kg[2] * du + Kg[3] * dv;
    const float u = std::min(std::max(gu, 0.0f), static_cast<float>(surface.nx));
    const float v = std::min(std::max(gv, 0.0f), static_cast<float>(surface.ny));
    const int i = std::min(static_cast<int>(u), surface.nx - 1), j = std::min(static_cast<int>(v), surface.ny - 1);
    const float fx = u - i, fy = v - j;
    const size_t k = static_cast<size_t>(surface.vertex(i, j));
    const float* p00 = &surface.refl[3 * k];
    const float* p01 = p00 + 3 * (surface.nx + 1);
    for (int c = 0; c < 3; ++c)
    {
      const float a = p00[c] + fx * (p00[3 + c] - p00[c]), b = p01[c] + fx * (p01[3 + c] - p01[c]);
      rho[c] = a + fy * (b - a);
    }
    rho[3] = std::min(1.0f, surface.nir_to_red * rho[2]);
    if (incidence)
      *shade = incidenceFactor(surface, k, fx, fy, gu - gu0, gv - gv0);
  }

  // The beam's irradiance on the rock seen at the tangent-plane point
  // (grid offset dx, dy from the hit, in cell k at fractions fx, fy) over
  // the tangent plane's there (what the splat holds). The rock is the
  // bilinear height field the ray caster (and so the truth) meets: it lies
  // delta beyond the tangent plane there, so the camera ray through the
  // tangent-plane point meets it s = delta / (view . (-normal)) farther on
  // (one Newton step: exact on the cell's patch to first order), and that
  // point lies off the beam's axis by r + s w instead of r; the beam's
  // Gaussian there is exp(-(2 s r.w + s^2 w.w) / (2 sigma^2)) times the
  // tangent plane's. The irradiance also takes cos(incidence) at the patch's
  // own normal. The two belong together: a patch turned from the beam is
  // dimmer, but the same power spreads over more of it (docs/simulator.md,
  // "Incidence under a dot").
  float incidenceFactor(const RockSurface& surface, size_t k, float fx, float fy, float dx, float dy) const
  {
    const float* h0 = &surface.h[k];
    const float* h1 = h0 + surface.nx + 1;
    const float ic = static_cast<float>(surface.inv_cell);
    const float ha = h0[0] + fx * (h0[1] - h0[0]), hb = h1[0] + fx * (h1[1] - h1[0]);
    const float delta = (ha + fy * (hb - ha)) * ic - (inc.z + inc.gx * dx + inc.gy * dy);
    // The patch's gradient dh/dx, dh/dy; its outward normal is (gx, gy, -1) / |.|.
    const float gx = ((h0[1] - h0[0]) + fy * ((h1[1] - h1[0]) - (h0[1] - h0[0]))) * ic, gy = (hb - ha) * ic;
    const float cos_i = (inc.beam[2] - inc.beam[0] * gx - inc.beam[1] * gy) / std::sqrt(1.0f + gx * gx + gy * gy);
    const float s = delta / std::max(0.05f, inc.view[2] - inc.view[0] * gx - inc.view[1] * gy);
    const float e = -(s * (inc.omega[0] * dx + inc.omega[1] * dy) + 0.5f * s * s * inc.ww) * inc.inv_sigma2;
    return std::max(0.0f, cos_i) * inc.inv_cos_hit * std::exp(std::min(e, 2.0f));
  }

  float gu0 = 0.0f, gv0 = 0.0f, Kg[4] = {0.0f, 0.0f, 0.0f, 0.0f};  // prepareGrid()
};

// Sets the inverse covariance and the rows of a splat of covariance S (px^2);
// false when it is degenerate or outside the image.
bool setSplatShape(Splat* sp, const Eigen::Matrix2d& S, double q_max, int height);

// Applies a splat to row v (CV_32FC3 pixels, `width` of them); a dot with
// an albedo (sp.albedo >= 0) needs `albedo` and `surface`.
void applySplatRow(const Splat& sp, int v, int width, float* row, const DotAlbedo* albedo = nullptr,
                   const RockSurface* surface = nullptr);

// Sums over the pixels of a dot's splat (with its DotAlbedo) of its
// noise-free light in buffer channel `channel`: the weight and its first
// moments in pixel coordinates, for the light as rendered and for the light
// over the reflectance under each pixel (the beam's footprint as relief and
// incidence shape it, texture divided out). Ground truth for the tools
// (SimFrame::light_centroids); rendering does not read it.
struct DotMoments
{
  double w = 0.0, wx = 0.0, wy = 0.0;     // the light
  double fw = 0.0, fwx = 0.0, fwy = 0.0;  // the footprint
};
void addDotMoments(const Splat& sp, const DotAlbedo& albedo, const RockSurface& surface, int channel, int width,
                   DotMoments* m);

// 2x3 Jacobian of the (distorted) projection at a camera-frame point: maps a
// covariance on the rock to one in the image.
Eigen::Matrix<double, 2, 3> projectionJacobian(const CameraModel& cam, const Eigen::Vector3d& X);

// The splats of a frame indexed by bands of rows, applied to one row in the
// order they were added (patches before dots: a dot lights the patch too).
class SplatRows
{
public:
  // albedo: the DotAlbedo of the splats that name one; surface: what they
  // read (kept by reference: must outlive this object).
  SplatRows(std::vector<Splat> splats, std::vector<DotAlbedo> albedo, const RockSurface& surface, int height);

  void applyRow(int v, int width, float* row) const;

private:
  static constexpr int kBand = 16;
  std::vector<Splat> splats_;
  std::vector<DotAlbedo> albedo_;
  const RockSurface& surface_;
  std::vector<std::vector<int>> bands_;  // per band of kBand rows: indices into splats_, in order
};

}  // namespace sim
}  // namespace structured_light_stabilizer
