// The epipolar identification's driver (triangulator.h lists the stages):
// gating, the tracking prior, then passes of per-component minimum-cost
// assignment with the surface prior and the neighbour check until nothing
// changes. The first pass hands the components lying on one grid line to
// the joint line reading.
#include <algorithm>

#include "triangulation/epipolar_assignment.h"
#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/triangulation/hungarian.h"

namespace structured_light_stabilizer
{
namespace detail
{

Assignment::Assignment(int n_beams, int n_spots)
  : spot_of_beam(n_beams, -1),
    beam_of_spot(n_spots, -1),
    accepted_point(n_beams, Eigen::Vector3d::Constant(kNaN)),
    contested(n_beams, 0),
    proven(n_beams, 0)
{
}

void Assignment::accept(int beam, int spot, const Eigen::Vector3d& point)
{
  spot_of_beam[beam] = spot;
  beam_of_spot[spot] = beam;
  accepted_point[beam] = point;
}

void Assignment::drop(int beam)
{
  beam_of_spot[spot_of_beam[beam]] = -1;
  spot_of_beam[beam] = -1;
  accepted_point[beam] = Eigen::Vector3d::Constant(kNaN);
}

namespace
{

// Finite "forbidden" cost: keeps the Hungarian potentials finite.
constexpr double kForbidden = 1e6;

class EpipolarAssigner
{
public:
  EpipolarAssigner(const BeamGeometry& geometry, const TriangulatorParams& params,
                   const std::vector<Eigen::Vector2d>& spots_px)
    : geometry_(geometry),
      params_(params),
      spots_px_(spots_px),
      graph_(gateCandidates(geometry, spots_px, params.max_epipolar_distance_px)),
      a_(geometry.beamCount(), static_cast<int>(spots_px.size()))
  {
    markContested();
  }

  EpipolarAssignment run(const std::vector<Eigen::Vector2d>* previous_px, const std::vector<uint8_t>* remembered);

private:
  void markContested();
  std::vector<Component> components() const;
  bool onOneGridLine(const std::vector<int>& beams) const;
  bool solvePass(int pass, bool one_sided, int* ambiguous);
  std::vector<double> componentCosts(const Component& comp, const std::vector<Eigen::Vector2d>& prior,
                                     bool use_prior) const;
  int solveComponent(const Component& comp, const std::vector<Eigen::Vector2d>& prior, bool use_prior);

  const BeamGeometry& geometry_;
  const TriangulatorParams& params_;
  const std::vector<Eigen::Vector2d>& spots_px_;
  CandidateGraph graph_;
  Assignment a_;
};

// A beam is contested when it, or one of its candidate spots, has more than
// one candidate; the flag is cleared when the pair is settled by epipolar
// evidence alone or by the tracking prior (such a pair stands on its own)
// and kept when the surface prior settled it.
void EpipolarAssigner::markContested()
{
  for (int i = 0; i < geometry_.beamCount(); ++i)
  {
    a_.contested[i] = graph_.of_beam[i].size() > 1;
    for (int k : graph_.of_beam[i])
      a_.contested[i] |= graph_.of_spot[graph_.pairs[k].spot].size() > 1;
  }
}

EpipolarAssignment EpipolarAssigner::run(const std::vector<Eigen::Vector2d>* previous_px,
                                         const std::vector<uint8_t>* remembered)
{
  EpipolarAssignment out;
  if (previous_px)
    out.tracked =
        applyTrackingPrior(geometry_, params_, spots_px_, *previous_px, &graph_, &a_, &out.track_px, remembered);
  const int max_passes = 4 + 2 * (geometry_.rows() + geometry_.cols());
  // The surface prior interpolates between accepted neighbours on opposite
  // sides: extrapolating from one side favours whatever reading puts the
  // spot on that side's surface, which an occluding edge turns into a wrong
  // beam (measured: 6 wrong in 60 axis-aligned frames when allowed). Only
  // when a pass makes no progress does the next one also extrapolate; the
  // loop ends when that makes no progress either.
  bool one_sided = false;
  for (int pass = 0; pass < max_passes; ++pass)
  {
    const bool progressed = solvePass(pass, one_sided, &out.ambiguous);
    if (!progressed && (pass > 0 || params_.prediction_tolerance_px <= 0.0))
    {
      if (one_sided)
        break;
      one_sided = true;
    }
    else if (pass > 0)
      one_sided = false;
  }
  out.beam_of_spot = a_.beam_of_spot;
  return out;
}

// One pass over the open components; returns whether the pairs changed.
// *ambiguous receives the pairs this pass could not prove.
bool EpipolarAssigner::solvePass(int pass, bool one_sided, int* ambiguous)
{
  const bool use_prior = pass > 0 && params_.prediction_tolerance_px > 0.0;
  const std::vector<Eigen::Vector2d> prior =
      use_prior ? surfacePrior(geometry_, graph_, a_, one_sided)
                : std::vector<Eigen::Vector2d>(geometry_.beamCount(), Eigen::Vector2d::Constant(kNaN));
  const std::vector<int> state_before = a_.spot_of_beam;
  *ambiguous = 0;
  std::vector<Component> lines;
  for (const Component& comp : components())
  {
    // Beams of one grid line that share candidates: their segments overlap
    // along one epipolar line (rows parallel to the baseline), where
    // order-free matching proves little; those lines are read jointly.
    if (pass == 0 && onOneGridLine(comp.beams))
      lines.push_back(comp);
    else
      *ambiguous += solveComponent(comp, prior, use_prior);
  }
  if (!lines.empty())
    readLines(geometry_, params_, spots_px_, lines, &a_);
  if (params_.prediction_tolerance_px > 0.0)
    rejectInconsistent(geometry_, params_.prediction_tolerance_px, spots_px_, &a_);
  // Progress is judged on the state after the consistency check: a pair
  // accepted and dropped again in every pass is no progress (it made the
  // loop run to max_passes: 2 ms per frame on the axis-aligned grid).
  return a_.spot_of_beam != state_before;
}

// Connected components of the candidate graph over the open beams and
// spots (depth-first from each open beam in index order).
std::vector<Component> EpipolarAssigner::components() const
{
  const int n_beams = geometry_.beamCount();
  std::vector<int> beam_comp(n_beams, -1), spot_comp(spots_px_.size(), -1);
  std::vector<Component> out;
  for (int seed = 0; seed < n_beams; ++seed)
  {
    if (beam_comp[seed] >= 0 || a_.spot_of_beam[seed] >= 0)
      continue;
    bool has_edge = false;
    for (int k : graph_.of_beam[seed])
      has_edge |= a_.beam_of_spot[graph_.pairs[k].spot] < 0;
    if (!has_edge)
      continue;
    const int id = static_cast<int>(out.size());
    out.emplace_back();
    std::vector<std::pair<bool, int>> stack{{true, seed}};  // (is a beam, index)
    beam_comp[seed] = id;
    while (!stack.empty())
    {
      const auto [is_beam, idx] = stack.back();
      stack.pop_back();
      (is_beam ? out[id].beams : out[id].spots).push_back(idx);
      for (int k : is_beam ? graph_.of_beam[idx] : graph_.of_spot[idx])
      {
        const Candidate& cand = graph_.pairs[k];
        if (is_beam && a_.beam_of_spot[cand.spot] < 0 && spot_comp[cand.spot] < 0)
        {
          spot_comp[cand.spot] = id;
          stack.push_back({false, cand.spot});
        }
        else if (!is_beam && a_.spot_of_beam[cand.beam] < 0 && beam_comp[cand.beam] < 0)
        {
          beam_comp[cand.beam] = id;
          stack.push_back({true, cand.beam});
        }
      }
    }
  }
  return out;
}

bool EpipolarAssigner::onOneGridLine(const std::vector<int>& beams) const
{
  const int cols = geometry_.cols();
  bool same_row = true, same_col = true;
  for (int i : beams)
  {
    same_row &= i / cols == beams[0] / cols;
    same_col &= i % cols == beams[0] % cols;
  }
  return beams.size() >= 2 && (same_row || same_col);
}

// Square cost matrix of a component. Rows: its beams, then one "spurious"
// row per spot; columns: its spots, then one "no spot" column per beam. A
// pair costs its gate cost (+ the squared distance from the surface prior
// in units of the tolerance); a missing dot or a spurious spot costs 1.
std::vector<double> EpipolarAssigner::componentCosts(const Component& comp, const std::vector<Eigen::Vector2d>& prior,
                                                     bool use_prior) const
{
  const int nb = static_cast<int>(comp.beams.size()), ns = static_cast<int>(comp.spots.size());
  const int n = nb + ns;
  std::vector<double> cost(static_cast<size_t>(n) * n, kForbidden);
  std::vector<int> local_spot(spots_px_.size(), -1);
  for (int b = 0; b < ns; ++b)
    local_spot[comp.spots[b]] = b;
  for (int a = 0; a < nb; ++a)
  {
    const int i = comp.beams[a];
    for (int k : graph_.of_beam[i])
    {
      const int b = local_spot[graph_.pairs[k].spot];
      if (b < 0)
        continue;
      double c = graph_.pairs[k].cost;
      if (use_prior && prior[i].allFinite())
      {
        // Distance along the segment from the predicted position.
        const double e = (spots_px_[graph_.pairs[k].spot] - prior[i]).norm() / params_.prediction_tolerance_px;
        c += e * e;
      }
      cost[a * n + b] = std::min(c, kForbidden);
    }
    cost[a * n + ns + a] = 1.0;
  }
  for (int b = 0; b < ns; ++b)
  {
    cost[(nb + b) * n + b] = 1.0;
    for (int a = 0; a < nb; ++a)
      cost[(nb + b) * n + ns + a] = 0.0;
  }
  return cost;
}

// Minimum-cost assignment of one component; a pair of the optimum is
// accepted when every assignment without it costs at least the margin
// more. Returns how many pairs of the optimum stay unproven.
int EpipolarAssigner::solveComponent(const Component& comp, const std::vector<Eigen::Vector2d>& prior, bool use_prior)
{
  const int nb = static_cast<int>(comp.beams.size()), ns = static_cast<int>(comp.spots.size());
  const int n = nb + ns;
  const std::vector<double> cost = componentCosts(comp, prior, use_prior);
  std::vector<int> col_of_row;
  const double best = solveAssignment(cost, n, &col_of_row);
  int ambiguous = 0;
  for (int a = 0; a < nb; ++a)
  {
    const int b = col_of_row[a];
    if (b >= ns || cost[a * n + b] >= kForbidden)
      continue;
    std::vector<double> alt = cost;
    alt[a * n + b] = kForbidden;
    std::vector<int> alt_cols;
    const double alt_best = solveAssignment(alt, n, &alt_cols);
    // After pass 0 the prior is the evidence: a beam without one waits (its
    // rivals' priors alone could make it look unique).
    if (!(alt_best - best >= params_.ambiguity_margin && (!use_prior || prior[comp.beams[a]].allFinite())))
    {
      ++ambiguous;
      continue;
    }
    const int i = comp.beams[a], j = comp.spots[b];
    Eigen::Vector3d p;
    if (geometry_.triangulatePixel(i, spots_px_[j], &p))
    {
      a_.contested[i] = a_.contested[i] && use_prior;
      a_.accept(i, j, p);
    }
  }
  return ambiguous;
}

}  // namespace

CandidateGraph gateCandidates(const BeamGeometry& geometry, const std::vector<Eigen::Vector2d>& spots_px,
                              double gate_px)
{
  // A brute-force scan is fine for a few hundred beams and spots; a spatial
  // index would pay off only for much larger patterns.
  const int n_beams = geometry.beamCount(), n_spots = static_cast<int>(spots_px.size());
  const double gate2 = gate_px * gate_px;
  CandidateGraph g;
  g.of_beam.resize(n_beams);
  g.of_spot.resize(n_spots);
  for (int j = 0; j < n_spots; ++j)
  {
    if (!spots_px[j].allFinite())
      continue;
    for (int i = 0; i < n_beams; ++i)
    {
      const double d2 = geometry.segmentDistance2(i, spots_px[j]);
      if (d2 <= gate2)
      {
        g.of_beam[i].push_back(static_cast<int>(g.pairs.size()));
        g.of_spot[j].push_back(static_cast<int>(g.pairs.size()));
        g.pairs.push_back({i, j, d2 / gate2});
      }
    }
  }
  return g;
}

EpipolarAssignment assignEpipolar(const BeamGeometry& geometry, const TriangulatorParams& params,
                                  const std::vector<Eigen::Vector2d>& spots_px,
                                  const std::vector<Eigen::Vector2d>* previous_px,
                                  const std::vector<uint8_t>* remembered)
{
  return EpipolarAssigner(geometry, params, spots_px).run(previous_px, remembered);
}

}  // namespace detail
}  // namespace structured_light_stabilizer
