// The tracking prior of the epipolar identification: last frame's dots,
// moved by the pattern's common image motion, settle the beams whose dot is
// unmistakably where it was (docs/triangulator.md).
//
// Where beam i's dot was last frame, moved by the median shift of the
// pattern (the rig's jitter moves all dots nearly alike), then by an affine
// map of the image (the rig's roll and change of scale move dots differently
// across the image), predicts where it is now within tracking_radius_px;
// depth changes move a dot along its own segment by much less between
// frames. A beam whose only nearby candidate is a spot near no other beam's
// prediction is settled before anything else (the consistency check leaves
// it: it is no longer contested).
#include <Eigen/Dense>

#include "triangulation/epipolar_assignment.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace detail
{

namespace
{

using Affine = Eigen::Matrix<double, 6, 1>;  // x' = a0 x + a1 y + a2, y' = a3 x + a4 y + a5

struct PriorInput
{
  const BeamGeometry& geometry;
  const std::vector<Eigen::Vector2d>& spots_px;
  const std::vector<Eigen::Vector2d>& previous_px;
  const CandidateGraph& graph;
};

// Median image shift from each primed beam's previous dot to its nearest
// candidate within half a beam pitch; false with fewer than three such
// beams. *primed counts the beams that had a dot.
bool medianShift(const PriorInput& in, double radius, Eigen::Vector2d* shift, int* primed)
{
  const double pitch = in.geometry.beamPitchPx();
  const double search = pitch > 0.0 ? 0.5 * pitch : 4.0 * radius;
  std::vector<double> dx, dy;
  *primed = 0;
  for (int i = 0; i < in.geometry.beamCount(); ++i)
  {
    const Eigen::Vector2d& q = in.previous_px[i];
    if (!q.allFinite())
      continue;
    ++*primed;
    int nearest = -1;
    double best = search;
    for (int k : in.graph.of_beam[i])
    {
      const double d = (in.spots_px[in.graph.pairs[k].spot] - q).norm();
      if (d < best)
      {
        best = d;
        nearest = in.graph.pairs[k].spot;
      }
    }
    if (nearest >= 0)
    {
      dx.push_back(in.spots_px[nearest].x() - q.x());
      dy.push_back(in.spots_px[nearest].y() - q.y());
    }
  }
  if (dx.size() < 3)
    return false;
  *shift = Eigen::Vector2d(median(dx), median(dy));
  return true;
}

// Least-squares affine map from the previous dots to their only candidate
// within twice the radius of the shifted positions; the pure shift when
// fewer than six beams give one (or the fit is degenerate). *spread (when
// given) is the robust per-axis spread of those pairs about the map: how far
// the dots moved beyond the pattern's common motion (centroid noise, depth
// changes); NaN with fewer than eight pairs.
Affine fitAffine(const PriorInput& in, const Eigen::Vector2d& shift, double radius, double* spread = nullptr)
{
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> used;  // (previous, now)
  Eigen::Matrix<double, 6, 6> ata = Eigen::Matrix<double, 6, 6>::Zero();
  Affine atb = Affine::Zero();
  int fit_pairs = 0;
  for (int i = 0; i < in.geometry.beamCount(); ++i)
  {
    const Eigen::Vector2d& q = in.previous_px[i];
    if (!q.allFinite())
      continue;
    int nearest = -1, near = 0;
    for (int k : in.graph.of_beam[i])
      if ((in.spots_px[in.graph.pairs[k].spot] - q - shift).norm() <= 2.0 * radius)
      {
        nearest = in.graph.pairs[k].spot;
        ++near;
      }
    if (near != 1)
      continue;
    used.push_back({q, in.spots_px[nearest]});
    for (int axis = 0; axis < 2; ++axis)
    {
      Affine a = Affine::Zero();
      a(3 * axis) = q.x();
      a(3 * axis + 1) = q.y();
      a(3 * axis + 2) = 1.0;
      ata += a * a.transpose();
      atb += a * in.spots_px[nearest](axis);
    }
    ++fit_pairs;
  }
  Affine affine;
  affine << 1.0, 0.0, shift.x(), 0.0, 1.0, shift.y();
  if (fit_pairs >= 6)
  {
    const Affine x = ata.ldlt().solve(atb);
    if (x.allFinite())
      affine = x;
  }
  if (spread)
  {
    std::vector<double> r;
    for (const auto& u : used)
      r.push_back((Eigen::Vector2d(affine(0) * u.first.x() + affine(1) * u.first.y() + affine(2),
                                   affine(3) * u.first.x() + affine(4) * u.first.y() + affine(5)) -
                   u.second)
                      .norm());
    // The median of a 2-D Gaussian distance is 1.18 sigma.
    *spread = r.size() >= 8 ? median(r) / 1.1774 : kNaN;
  }
  return affine;
}

// Where every primed beam's dot is predicted now (NaN = unprimed), and the
// candidates within the radius of it: per beam the last one found and how
// many, per spot how many beams claim it.
struct Prediction
{
  std::vector<Eigen::Vector2d> track_px;
  std::vector<int> near_spot, near_count, claims;

  // The beam has exactly one candidate near its prediction, claimed by no other beam.
  bool unique(int beam) const { return near_count[beam] == 1 && claims[near_spot[beam]] == 1; }
};

// Where every primed beam's dot is predicted by the affine map (NaN = unprimed).
std::vector<Eigen::Vector2d> affinePrediction(const PriorInput& in, const Affine& affine)
{
  std::vector<Eigen::Vector2d> out(in.geometry.beamCount(), Eigen::Vector2d::Constant(kNaN));
  for (int i = 0; i < in.geometry.beamCount(); ++i)
  {
    const Eigen::Vector2d& q = in.previous_px[i];
    if (q.allFinite())
      out[i] = Eigen::Vector2d(affine(0) * q.x() + affine(1) * q.y() + affine(2),
                               affine(3) * q.x() + affine(4) * q.y() + affine(5));
  }
  return out;
}

// The candidates within `radius` of each primed beam's prediction: per beam
// the last one found and how many, per spot how many beams claim it.
Prediction gather(const PriorInput& in, const std::vector<Eigen::Vector2d>& track_px, const std::vector<double>& radius)
{
  const int n_beams = in.geometry.beamCount();
  Prediction p;
  p.track_px = track_px;
  p.near_spot.assign(n_beams, -1);
  p.near_count.assign(n_beams, 0);
  p.claims.assign(in.spots_px.size(), 0);
  for (int i = 0; i < n_beams; ++i)
  {
    if (!track_px[i].allFinite())
      continue;
    for (int k : in.graph.of_beam[i])
    {
      const int j = in.graph.pairs[k].spot;
      if ((in.spots_px[j] - track_px[i]).norm() <= radius[i])
      {
        p.near_spot[i] = j;
        ++p.near_count[i];
        ++p.claims[j];
      }
    }
  }
  return p;
}

// The local flow: what the affine map misses (a dot sliding over a slope
// moves along its segment as its depth changes) varies smoothly across the
// rock, so each primed beam's prediction is corrected by the mean miss of
// its grid neighbours found unmistakably near theirs. *spread: the robust
// per-axis spread of the found beams about their corrected predictions
// (their own miss is not used for their own correction); NaN with fewer than
// eight.
std::vector<Eigen::Vector2d> localFlow(const PriorInput& in, const Prediction& first, double* spread)
{
  const int n_beams = in.geometry.beamCount();
  std::vector<Eigen::Vector2d> miss(n_beams, Eigen::Vector2d::Constant(kNaN));
  for (int i = 0; i < n_beams; ++i)
    if (first.unique(i))
      miss[i] = in.spots_px[first.near_spot[i]] - first.track_px[i];
  std::vector<Eigen::Vector2d> out = first.track_px;
  std::vector<double> r;
  for (int i = 0; i < n_beams; ++i)
  {
    if (!out[i].allFinite())
      continue;
    int nb[8];
    in.geometry.neighbours(i, nb);
    Eigen::Vector2d sum = Eigen::Vector2d::Zero();
    int n = 0;
    for (int j : nb)
      if (j >= 0 && miss[j].allFinite())
      {
        sum += miss[j];
        ++n;
      }
    if (n >= 2)
      out[i] += sum / n;
    if (miss[i].allFinite() && n >= 2)
      r.push_back((in.spots_px[first.near_spot[i]] - out[i]).norm());
  }
  // The median of a 2-D Gaussian distance is 1.18 sigma.
  *spread = r.size() >= 8 ? median(r) / 1.1774 : kNaN;
  return out;
}

// A beam that had a dot last frame may only take a spot near its
// prediction: a spurious spot on the segment of a dot that vanished this
// frame lands at a depth of its own. Forbidden pairs leave the candidate lists.
void forbidFarFromTrack(const std::vector<Eigen::Vector2d>& spots_px, const std::vector<Eigen::Vector2d>& track_px,
                        const std::vector<double>& radius, CandidateGraph* graph)
{
  const auto far_from_track = [&](int k)
  {
    const Candidate& cand = graph->pairs[k];
    return track_px[cand.beam].allFinite() && (spots_px[cand.spot] - track_px[cand.beam]).norm() > radius[cand.beam];
  };
  for (auto& list : graph->of_beam)
    list.erase(std::remove_if(list.begin(), list.end(), far_from_track), list.end());
  for (auto& list : graph->of_spot)
    list.erase(std::remove_if(list.begin(), list.end(), far_from_track), list.end());
}

}  // namespace

double trackingRadius(const TriangulatorParams& params, double spread_px)
{
  // 5 sigma of a 2-D Gaussian: a dot leaves it once in 270 000 frames; a
  // spurious spot falls into it 1 / (5 sigma / radius)^2 less often.
  if (!std::isfinite(spread_px) || params.tracking_sigmas <= 0.0)
    return params.tracking_radius_px;
  return std::min(params.tracking_radius_px,
                  std::max(params.min_tracking_radius_px, params.tracking_sigmas * spread_px));
}

int applyTrackingPrior(const BeamGeometry& geometry, const TriangulatorParams& params,
                       const std::vector<Eigen::Vector2d>& spots_px, const std::vector<Eigen::Vector2d>& previous_px,
                       CandidateGraph* graph, Assignment* assignment, std::vector<Eigen::Vector2d>* track_px,
                       const std::vector<uint8_t>* remembered)
{
  const int n_beams = geometry.beamCount();
  if (static_cast<int>(previous_px.size()) != n_beams)
    return -1;
  const PriorInput in{geometry, spots_px, previous_px, *graph};
  Eigen::Vector2d shift;
  int primed = 0;
  if (!medianShift(in, params.tracking_radius_px, &shift, &primed))
    return -1;
  const std::vector<double> broad(n_beams, params.tracking_radius_px);
  const Prediction first = gather(in, affinePrediction(in, fitAffine(in, shift, params.tracking_radius_px)), broad);
  double spread = kNaN;
  const std::vector<Eigen::Vector2d> track = localFlow(in, first, &spread);
  // A remembered beam (its dot missing last frame too) was predicted over
  // more frames: twice the radius.
  const double radius = trackingRadius(params, spread);
  std::vector<double> radii(n_beams, radius);
  for (int i = 0; i < n_beams; ++i)
    if (remembered && i < static_cast<int>(remembered->size()) && (*remembered)[i])
      radii[i] = std::min(params.tracking_radius_px, 2.0 * radius);
  const Prediction p = gather(in, track, radii);
  int unique = 0;
  for (int i = 0; i < n_beams; ++i)
    unique += p.unique(i);
  // Too few dots where they were: a jump or a new scene, not a prior.
  if (!(unique >= 3 && 2 * unique >= primed))
    return -1;
  int tracked = 0;
  for (int i = 0; i < n_beams; ++i)
  {
    Eigen::Vector3d point;
    if (!p.unique(i) || !geometry.triangulatePixel(i, spots_px[p.near_spot[i]], &point))
      continue;
    assignment->accept(i, p.near_spot[i], point);
    assignment->contested[i] = 0;
    ++tracked;
  }
  forbidFarFromTrack(spots_px, p.track_px, radii, graph);
  if (track_px)
    *track_px = p.track_px;
  return tracked;
}

}  // namespace detail
}  // namespace structured_light_stabilizer
