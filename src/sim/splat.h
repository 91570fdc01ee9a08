// Image-space Gaussians ("splats"): how projector dots (added light) and
// clutter patches (reflectance blended over the rock) reach the pixels. The
// frame is composed row by row, so a splat is applied one row at a time.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "rock_surface.h"
#include "structured_light_stabilizer/camera_model.h"

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
};

// What makes a projector dot's pixels follow the reflectance under each of
// them (docs/simulator.md, "Per-pixel albedo under a dot"). The beam's
// footprint (image covariance A) is blurred by the camera (B, S = A + B);
// the light that reaches image point x came from surface points distributed
// as N(c + A S^-1 (x - c), A - A S^-1 A) (the product of two Gaussians), so
// pixel x receives G_S(x - c) times the reflectance at that point, blurred by
// that covariance: exact for any albedo, with the tangent plane of the hit
// point mapping image offsets to the surface.
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

  // The factor of each channel at image offset (du, dv) from the centre.
  void factors(const RockSurface& surface, double du, double dv, float out[3]) const
  {
    float rho[4];
    surface.reflectanceUnderDot(x0 + K[0] * du + K[1] * dv, y0 + K[2] * du + K[3] * dv, blur_x, blur_y, rho);
    for (int c = 0; c < 3; ++c)
      out[c] = mix[c][0] * rho[0] + mix[c][1] * rho[1] + mix[c][2] * rho[2] + mix[c][3] * rho[3];
  }
};

// Sets the inverse covariance and the rows of a splat of covariance S (px^2);
// false when it is degenerate or outside the image.
bool setSplatShape(Splat* sp, const Eigen::Matrix2d& S, double q_max, int height);

// Applies a splat to row v (CV_32FC3 pixels, `width` of them); a dot with
// an albedo (sp.albedo >= 0) needs `albedo` and `surface`.
void applySplatRow(const Splat& sp, int v, int width, float* row, const DotAlbedo* albedo = nullptr,
                   const RockSurface* surface = nullptr);

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
