#include "sim/render/splat.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <Eigen/LU>

namespace structured_light_stabilizer
{
namespace sim
{

bool setSplatShape(Splat* sp, const Eigen::Matrix2d& S, double q_max, int height)
{
  const double det = S.determinant();
  if (!(det > 0.0) || !std::isfinite(sp->cx) || !std::isfinite(sp->cy))
    return false;
  const Eigen::Matrix2d Si = S.inverse();
  sp->a = Si(0, 0);
  sp->b = Si(0, 1);
  sp->c = Si(1, 1);
  sp->q_max = q_max;
  // The ellipse q <= q_max spans +-sqrt(q_max S_yy) rows.
  const double half = std::sqrt(q_max * S(1, 1));
  sp->v0 = static_cast<int>(std::max(0.0, std::ceil(sp->cy - half)));
  sp->v1 = static_cast<int>(std::min(height - 1.0, std::floor(sp->cy + half)));
  return sp->v0 <= sp->v1;
}

// The pixels of the row inside q <= q_max solve a quadratic; along them
// exp(-q/2) follows the recurrence g(u+1) = g(u) r(u), r(u+1) = r(u) exp(-a),
// three exp() per row instead of one per pixel (S always holds the pixel box,
// so a <= 12 and the factors stay far from under- or overflow).
void applySplatRow(const Splat& sp, int v, int width, float* row, const DotAlbedo* albedo, const RockSurface* surface)
{
  const double dy = v - sp.cy;
  const double disc = sp.b * sp.b * dy * dy - sp.a * (sp.c * dy * dy - sp.q_max);
  if (!(disc >= 0.0))
    return;
  const double root = std::sqrt(disc);
  const double ua = std::max(0.0, std::ceil(sp.cx + (-sp.b * dy - root) / sp.a));
  const double ub = std::min(width - 1.0, std::floor(sp.cx + (-sp.b * dy + root) / sp.a));
  if (!(ua <= ub))
    return;
  const int u0 = static_cast<int>(ua), u1 = static_cast<int>(ub);
  const double dx0 = u0 - sp.cx;
  double g = std::exp(-0.5 * (sp.a * dx0 * dx0 + 2.0 * sp.b * dx0 * dy + sp.c * dy * dy));
  double r = std::exp(-0.5 * (sp.a * (2.0 * dx0 + 1.0) + 2.0 * sp.b * dy));
  const double k = std::exp(-sp.a);
  float* px = row + 3 * u0;
  if (sp.albedo >= 0)
  {
    for (int u = u0; u <= u1; ++u, px += 3, g *= r, r *= k)
    {
      float f[3] = {albedo->f0[0], albedo->f0[1], albedo->f0[2]};
      if (g >= albedo->g_lookup)
        albedo->factors(*surface, u - sp.cx, dy, f);
      for (int ch = 0; ch < 3; ++ch)
        px[ch] += static_cast<float>(sp.value[ch] * f[ch] * g);
    }
    return;
  }
  if (!sp.blend)
  {
    for (int u = u0; u <= u1; ++u, px += 3, g *= r, r *= k)
      for (int ch = 0; ch < 3; ++ch)
        px[ch] += static_cast<float>(sp.value[ch] * g);
    return;
  }
  for (int u = u0; u <= u1; ++u, px += 3, g *= r, r *= k)
  {
    const double w = sp.flat_top ? std::min(1.0, 2.5 * g) : g;
    if (w < 1e-3)
      continue;
    for (int ch = 0; ch < 3; ++ch)
      px[ch] = static_cast<float>((1.0 - w) * px[ch] + w * sp.value[ch]);
  }
}

void addDotMoments(const Splat& sp, const DotAlbedo& albedo, const RockSurface& surface, int channel, int width,
                   DotMoments* m)
{
  for (int v = sp.v0; v <= sp.v1; ++v)
  {
    // The row's pixels inside q <= q_max, as applySplatRow() finds them.
    const double dy = v - sp.cy;
    const double disc = sp.b * sp.b * dy * dy - sp.a * (sp.c * dy * dy - sp.q_max);
    if (!(disc >= 0.0))
      continue;
    const double root = std::sqrt(disc);
    const int u0 = static_cast<int>(std::max(0.0, std::ceil(sp.cx + (-sp.b * dy - root) / sp.a)));
    const int u1 = static_cast<int>(std::min(width - 1.0, std::floor(sp.cx + (-sp.b * dy + root) / sp.a)));
    for (int u = u0; u <= u1; ++u)
    {
      const double dx = u - sp.cx;
      const double g = sp.value[channel] * std::exp(-0.5 * (sp.a * dx * dx + 2.0 * sp.b * dx * dy + sp.c * dy * dy));
      float f[3];
      albedo.factors(surface, dx, dy, f);
      // The footprint: the same light without the reflectance (its
      // incidence factor on relief, 1 on a plane or a board).
      float rho[4], shade = 1.0f;
      if (!surface.board)
        albedo.rockFactors(surface, static_cast<float>(dx), static_cast<float>(dy), rho, &shade);
      const double light = g * f[channel], footprint = g * (albedo.incidence ? shade : 1.0f);
      m->w += light;
      m->wx += light * u;
      m->wy += light * v;
      m->fw += footprint;
      m->fwx += footprint * u;
      m->fwy += footprint * v;
    }
  }
}

Eigen::Matrix<double, 2, 3> projectionJacobian(const CameraModel& cam, const Eigen::Vector3d& X)
{
  Eigen::Matrix<double, 2, 3> J;
  const double step = 1e-6 * std::max(X.norm(), 1e-3);
  for (int a = 0; a < 3; ++a)
  {
    Eigen::Vector3d e = Eigen::Vector3d::Zero();
    e[a] = step;
    const cv::Point2d p = cam.project(X + e), m = cam.project(X - e);
    J(0, a) = (p.x - m.x) / (2.0 * step);
    J(1, a) = (p.y - m.y) / (2.0 * step);
  }
  return J;
}

SplatRows::SplatRows(std::vector<Splat> splats, std::vector<DotAlbedo> albedo, const RockSurface& surface, int height)
  : splats_(std::move(splats)), albedo_(std::move(albedo)), surface_(surface), bands_((height + kBand - 1) / kBand)
{
  for (size_t k = 0; k < splats_.size(); ++k)
    for (int band = splats_[k].v0 / kBand; band <= splats_[k].v1 / kBand; ++band)
      bands_[band].push_back(static_cast<int>(k));
}

void SplatRows::applyRow(int v, int width, float* row) const
{
  for (int k : bands_[v / kBand])
    if (v >= splats_[k].v0 && v <= splats_[k].v1)
    {
      const Splat& sp = splats_[k];
      applySplatRow(sp, v, width, row, sp.albedo >= 0 ? &albedo_[sp.albedo] : nullptr, &surface_);
    }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
