// The surface prior of the epipolar identification: where a beam's dot
// should be given the accepted dots around it (docs/triangulator.md). Used
// to settle ambiguous pairs (surfacePrior) and to drop accepted dots that
// contradict their neighbours (rejectInconsistent).
#include <algorithm>

#include "triangulation/epipolar_assignment.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace detail
{

namespace
{

// Tolerance of a one-sided (extrapolated) surface prediction, in units of
// prediction_tolerance_px, for uncontested pairs.
constexpr double kExtrapolationTolerance = 1.25;

// The accepted beams of the 8-neighbourhood (row by row) and the sides on
// which they lie.
struct Neighbourhood
{
  std::vector<Eigen::Vector3d> points;
  bool up = false, down = false, left = false, right = false;
};

Neighbourhood acceptedNeighbours(const BeamGeometry& geometry, int beam, const Assignment& a)
{
  const int rows = geometry.rows(), cols = geometry.cols();
  const int r = beam / cols, c = beam % cols;
  Neighbourhood n;
  for (int rr = std::max(0, r - 1); rr <= std::min(rows - 1, r + 1); ++rr)
    for (int cc = std::max(0, c - 1); cc <= std::min(cols - 1, c + 1); ++cc)
    {
      const int k = rr * cols + cc;
      if (k == beam || a.spot_of_beam[k] < 0)
        continue;
      n.points.push_back(a.accepted_point[k]);
      n.up |= rr < r;
      n.down |= rr > r;
      n.left |= cc < c;
      n.right |= cc > c;
    }
  return n;
}

// How many of the `support` points put the dot of `beam`, at their depth,
// within `within_px` of the spot pixel.
int agreeing(const BeamGeometry& geometry, int beam, const Eigen::Vector2d& spot_px,
             const std::vector<Eigen::Vector3d>& support, double within_px)
{
  int agree = 0;
  for (const Eigen::Vector3d& q : support)
    agree += (geometry.pixelAtDepth(beam, q.z()) - spot_px).norm() <= within_px;
  return agree;
}

// A dot with fewer than three accepted neighbours: too few to tell a
// spurious spot from a dot on a small object (always so in 1 x N patterns),
// so it is kept unless a wider plane disagrees, or the pair was contested
// (only neighbours can confirm those), or it is isolated in depth.
bool keepSparse(const BeamGeometry& geometry, double tol, int beam, const Eigen::Vector2d& spot_px,
                const Neighbourhood& near, const Assignment& a)
{
  // A corner or a sparse spot: the plane through the accepted beams within
  // two rows and columns may still confirm it. A dot with no rival but no
  // wide plane either is kept (1 x N patterns, isolated dots); a wide plane
  // that disagrees drops it.
  std::vector<Eigen::Vector3d> wide;
  Eigen::Vector2d px;
  const bool have_plane =
      supportOf(geometry, beam, a, &wide) >= 1 && wide.size() >= 3 && geometry.predictPixel(beam, wide, &px);
  const bool confirmed = have_plane && (px - spot_px).norm() <= tol;
  // Two neighbours that both disagree by more than half the beam pitch: a
  // spot at a depth of its own (a one-dot object) is indistinguishable from
  // a spurious spot on the segment of a missing dot, and the latter is the
  // likelier.
  const bool isolated =
      near.points.size() >= 2 && agreeing(geometry, beam, spot_px, near.points, geometry.smoothnessScalePx()) == 0;
  return !((have_plane && !confirmed) || (a.contested[beam] && !confirmed) || isolated);
}

// A dot with three or more accepted neighbours: kept when it lies on their
// local plane, or at the depth of at least two of them (the dots of a small
// object in front of the rock).
bool keepSupported(const BeamGeometry& geometry, double tol, int beam, const Eigen::Vector2d& spot_px,
                   const Neighbourhood& near, const Assignment& a)
{
  // A prediction from neighbours missing on one side (the pattern's border,
  // or a hole as wide as the 8-neighbourhood) extrapolates the local plane
  // by about one beam pitch; its error grows with the curvature of the rock
  // (a dot at the pattern's edge at 1 m on a 15 cm relief: 5.1 px off). An
  // uncontested pair (its spot the only candidate of its beam, and the beam
  // the only one of its spot) gets the extrapolation's wider tolerance.
  const bool extrapolated = !(near.up && near.down && near.left && near.right);
  const double tol_here = extrapolated && !a.contested[beam] ? kExtrapolationTolerance * tol : tol;
  Eigen::Vector2d px;
  if (geometry.predictPixel(beam, near.points, &px) && (px - spot_px).norm() <= tol_here)
    return true;
  return agreeing(geometry, beam, spot_px, near.points, tol) >= 2;
}

}  // namespace

int supportOf(const BeamGeometry& geometry, int beam, const Assignment& a, std::vector<Eigen::Vector3d>* support)
{
  const Neighbourhood near = acceptedNeighbours(geometry, beam, a);
  if ((near.up && near.down) || (near.left && near.right))
  {
    *support = near.points;
    return 2;
  }
  // One side only: extrapolate from a plane through the accepted beams
  // within two rows/columns, which needs at least three of them. Points on
  // one grid line give no plane (its tilt about that line would be
  // arbitrary): require two rows and two columns.
  const int rows = geometry.rows(), cols = geometry.cols();
  const int r = beam / cols, c = beam % cols;
  support->clear();
  int row_mask = 0, col_mask = 0;
  for (int rr = std::max(0, r - 2); rr <= std::min(rows - 1, r + 2); ++rr)
    for (int cc = std::max(0, c - 2); cc <= std::min(cols - 1, c + 2); ++cc)
      if ((rr != r || cc != c) && a.spot_of_beam[rr * cols + cc] >= 0)
      {
        support->push_back(a.accepted_point[rr * cols + cc]);
        row_mask |= 1 << (rr - r + 2);
        col_mask |= 1 << (cc - c + 2);
      }
  const auto bits = [](int m) { return __builtin_popcount(static_cast<unsigned>(m)); };
  return support->size() >= 3 && bits(row_mask) >= 2 && bits(col_mask) >= 2 ? 1 : 0;
}

std::vector<Eigen::Vector2d> surfacePrior(const BeamGeometry& geometry, const CandidateGraph& graph,
                                          const Assignment& a, bool one_sided)
{
  std::vector<Eigen::Vector2d> prior(geometry.beamCount(), Eigen::Vector2d::Constant(kNaN));
  for (int i = 0; i < geometry.beamCount(); ++i)
  {
    if (a.spot_of_beam[i] >= 0 || graph.of_beam[i].empty())
      continue;
    std::vector<Eigen::Vector3d> support;
    const int level = supportOf(geometry, i, a, &support);
    if (level < 2 && !(level == 1 && one_sided))
      continue;
    Eigen::Vector2d px;
    if (geometry.predictPixel(i, support, &px))
      prior[i] = px;
  }
  return prior;
}

void rejectInconsistent(const BeamGeometry& geometry, double tolerance_px, const std::vector<Eigen::Vector2d>& spots_px,
                        Assignment* assignment)
{
  // A spurious spot that happens to lie on the segment of a beam whose dot
  // is missing lands at a random depth and disagrees with the neighbours.
  // Decisions use the state before this sweep.
  std::vector<int> reject;
  for (int i = 0; i < geometry.beamCount(); ++i)
  {
    const int j = assignment->spot_of_beam[i];
    // Pairs proven by the joint reading of their grid line already passed a
    // stronger test with the same neighbours (the depth smoothness of every
    // alternative reading, with the margin).
    if (j < 0 || assignment->proven[i])
      continue;
    const Neighbourhood near = acceptedNeighbours(geometry, i, *assignment);
    const bool keep = near.points.size() < 3 ? keepSparse(geometry, tolerance_px, i, spots_px[j], near, *assignment)
                                             : keepSupported(geometry, tolerance_px, i, spots_px[j], near, *assignment);
    if (!keep)
      reject.push_back(i);
  }
  for (int i : reject)
    assignment->drop(i);
}

}  // namespace detail
}  // namespace structured_light_stabilizer
