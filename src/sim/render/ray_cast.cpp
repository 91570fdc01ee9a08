// Ray casting against the rock's height field (RockSurface::cast).
//
// Conservative Lipschitz steps never skip the first root, so occlusion and
// self-shadowing come out right; Newton refines the root to 1e-12 m once the
// ray is within 0.2 mm of the surface.
#include "sim/render/rock_surface.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

// The part [s0, s1] of the ray o + s d (s >= 0) inside the slab that holds
// the surface: between its lowest and highest point and within the side
// walls. False when the ray misses the slab.
bool clipToSlab(const RockSurface& rock, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* s0, double* s1,
                bool* entered_by_wall)
{
  *s0 = std::max(0.0, (rock.hmin - o.z()) / d.z());
  *s1 = (rock.hmax - o.z()) / d.z();
  if (*s1 < 0.0)
    return false;
  *entered_by_wall = false;
  const double half[2] = {rock.half_w, rock.half_h};
  for (int a = 0; a < 2; ++a)
  {
    if (std::abs(d[a]) < 1e-15)
    {
      if (std::abs(o[a]) > half[a])
        return false;
      continue;
    }
    const double ta = (-half[a] - o[a]) / d[a], tb = (half[a] - o[a]) / d[a];
    const double lo = std::min(ta, tb), hi = std::max(ta, tb);
    if (lo > *s0)
    {
      *s0 = lo;
      *entered_by_wall = true;
    }
    *s1 = std::min(*s1, hi);
  }
  return !(*s0 > *s1);  // a NaN is refused later, by refine()
}

// Height of the surface above the ray's point at s (> 0: the ray is still in front).
double gapAt(const RockSurface& rock, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double s)
{
  return rock.height(o.x() + s * d.x(), o.y() + s * d.y()) - (o.z() + s * d.z());
}

// March over blocks of kBlock x kBlock cells from s (where the gap is *gap)
// until the gap is below 0.2 mm: inside a block the ray cannot meet the
// surface while it is below the block's lowest vertex, and from there
// Lipschitz steps with the block's own slope bound (the global one, k, is set
// by the steepest spot of the whole rock) never skip the first root; a step
// never leaves the block. False when the ray leaves the slab first.
bool march(const RockSurface& rock, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double k, double s1,
           double* s_io, double* gap_io)
{
  const double block_m = RockSurface::kBlock * rock.cell;
  double s = *s_io, gap = *gap_io;
  for (int it = 0; it < 4000 && gap > 2e-4; ++it)
  {
    const double px = o.x() + s * d.x(), py = o.y() + s * d.y();
    const int bi = std::min(std::max(static_cast<int>(std::floor((px - rock.x0) / block_m)), 0), rock.nbx - 1);
    const int bj = std::min(std::max(static_cast<int>(std::floor((py - rock.y0) / block_m)), 0), rock.nby - 1);
    double s_exit = s1;
    if (d.x() > 1e-15)
      s_exit = std::min(s_exit, (rock.x0 + (bi + 1) * block_m - o.x()) / d.x());
    else if (d.x() < -1e-15)
      s_exit = std::min(s_exit, (rock.x0 + bi * block_m - o.x()) / d.x());
    if (d.y() > 1e-15)
      s_exit = std::min(s_exit, (rock.y0 + (bj + 1) * block_m - o.y()) / d.y());
    else if (d.y() < -1e-15)
      s_exit = std::min(s_exit, (rock.y0 + bj * block_m - o.y()) / d.y());
    s_exit = std::max(s_exit, s);  // rounding at a boundary
    const RockSurface::BlockBound& bb = rock.blocks[static_cast<size_t>(bj) * rock.nbx + bi];
    const double s_reach = (bb.hmin - o.z()) / d.z();  // below the block's lowest vertex before this
    double next;
    if (s_reach >= s_exit)
      next = s_exit + 1e-9;  // passes over the whole block
    else if (s_reach > s)
      next = s_reach;  // the gap is measured again there
    else
      next = std::min(s + gap / (d.z() + bb.lip_x * std::abs(d.x()) + bb.lip_y * std::abs(d.y())), s_exit + 1e-9);
    // Progress at least as fast as the global bound allows.
    s = std::max(next, s + gap / k);
    if (s > s1)
      return false;
    gap = gapAt(rock, o, d, s);
  }
  *s_io = s;
  *gap_io = gap;
  return !(gap > 2e-4);  // else it skims the surface for too long: count as a miss
}

// Newton on the bilinear patch from s, where the gap is small; grazing steps
// fall back to the safe Lipschitz step k. False when it does not converge or
// ends beyond the slab.
bool refine(const RockSurface& rock, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double k, double s1,
            double* s_io, double gap)
{
  double s = *s_io;
  for (int n = 0; n < 20; ++n)
  {
    double hx, hy;
    const double x = o.x() + s * d.x(), y = o.y() + s * d.y();
    gap = rock.height(x, y, &hx, &hy) - (o.z() + s * d.z());
    if (std::abs(gap) < 1e-12)
      break;
    const double slope = hx * d.x() + hy * d.y() - d.z();
    if (slope >= -1e-9)
    {
      s += std::max(gap, 0.0) / k;  // grazing: keep the safe step
      continue;
    }
    s -= gap / slope;
  }
  if (!(std::abs(gap) < 1e-9) || s > s1 + 1e-9)
    return false;
  *s_io = s;
  return true;
}

}  // namespace

bool RockSurface::cast(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double* s_hit, bool* wall) const
{
  *wall = false;
  if (!(d.z() > 1e-12))
    return false;
  double s0, s1;
  bool entered_by_wall;
  if (!clipToSlab(*this, o, d, &s0, &s1, &entered_by_wall))
    return false;
  // Rate at which the gap h - z can shrink per unit of s.
  const double k = d.z() + lip_x * std::abs(d.x()) + lip_y * std::abs(d.y());
  double s = s0;
  double gap = gapAt(*this, o, d, s);
  if (gap <= 0.0)
  {
    if (entered_by_wall && s0 > 0.0)
    {
      *s_hit = s0;
      *wall = true;
      return true;
    }
    return false;  // starts inside the rock
  }
  if (!march(*this, o, d, k, s1, &s, &gap) || !refine(*this, o, d, k, s1, &s, gap))
    return false;
  *s_hit = s;
  return true;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
