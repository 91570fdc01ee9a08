// Joint reading of the grid lines whose beams share an epipolar line (rows
// parallel to the baseline), where order-free matching proves little
// (docs/triangulator.md).
//
// Each line gets a few ordered readings (order-preserving matchings along
// the line by dynamic programming, with depth smoothness between
// neighbouring beams: the best one, the best through every candidate pair,
// the best without each pair of the best one); the lines are chained (row r
// next to r + 1, smoothness over the 8-neighbourhood) and solved exactly by
// min-sum dynamic programming; a second round adds the readings that are
// best given the neighbouring lines' optimum. A pair is accepted when every
// reading without it costs at least ambiguity_margin more (min-marginals)
// and its group of dots cannot slide along the line (a free beam next to it
// and no smooth link to dots that cannot slide: an object in front of the
// rock). Accepted beams are flagged proven.
#include <algorithm>
#include <cmath>

#include "triangulation/epipolar_assignment.h"
#include "triangulation/line_readings.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace detail
{

namespace
{

constexpr int kRounds = 2;  // a third round added nothing in 500 test frames

// The joint reading of a set of grid lines, see the top of this file.
class LineReader
{
public:
  LineReader(const BeamGeometry& geometry, const TriangulatorParams& params,
             const std::vector<Eigen::Vector2d>& spots_px, Assignment* assignment)
    : geometry_(geometry), params_(params), spots_px_(spots_px), a_(*assignment), cols_(geometry.cols())
  {
  }

  void read(const std::vector<Component>& components);

private:
  // Per beam: pixel and point (NaN = no dot).
  struct Layout
  {
    std::vector<Eigen::Vector2d> px;
    std::vector<Eigen::Vector3d> pt;
  };

  int posOf(int orient, int beam) const { return orient == 0 ? beam % cols_ : beam / cols_; }
  int lineOf(int orient, int beam) const { return orient == 0 ? beam / cols_ : beam % cols_; }
  int beamAt(const GridLine& line, int pos) const
  {
    return line.orient == 0 ? line.line * cols_ + pos : pos * cols_ + line.line;
  }
  void collectLines(const std::vector<Component>& components);
  void buildPairs(GridLine& line) const;
  void buildSmoothness(GridLine& line) const;
  void chainLines();
  const std::vector<double>& pairCosts(int t);
  double pairwise(int t, int h, int g);
  void solveChain();
  bool addContextReadings();
  std::vector<Eigen::Vector3d> chainOptimum() const;
  Layout chainLayout() const;
  bool smooth(const Layout& map, int a, int b) const;
  std::vector<char> nextToFreeBeam(const Layout& map) const;
  std::vector<char> anchoredBeams(const Layout& map, const std::vector<char>& candidate) const;
  std::vector<char> slidingBeams() const;
  void acceptProven(const std::vector<char>& sliding);

  const BeamGeometry& geometry_;
  const TriangulatorParams& params_;
  const std::vector<Eigen::Vector2d>& spots_px_;
  Assignment& a_;
  const int cols_;
  std::vector<GridLine> lines_;
  std::vector<int> order_;  // lines with pairs, chained: rows, then columns, in index order
  // Smoothness between the readings h of line order_[t] and g of
  // order_[t + 1]: a sum over positions of a cost between two pairs,
  // tabulated per pair of pairs (pair_cost_[t]); P_[t][h][g] is extended as
  // readings are added.
  std::vector<std::vector<double>> pair_cost_;
  std::vector<std::vector<std::vector<double>>> P_;
};

void LineReader::read(const std::vector<Component>& components)
{
  if (params_.prediction_tolerance_px <= 0.0)
    return;
  collectLines(components);
  for (GridLine& line : lines_)
  {
    buildPairs(line);
    buildSmoothness(line);
  }
  chainLines();
  if (order_.empty())
    return;
  // Round 0: readings from each line alone. Later rounds add the readings
  // that are best given the neighbouring lines' current optimum: when a
  // line's own evidence ties (a missing dot lets part of a row shift), the
  // reading its neighbours agree with may not be among the first ones.
  for (int n : order_)
  {
    lines_[n].last_extra.assign(lines_[n].pairs.size(), 0.0);
    addBestReadings(&lines_[n], lines_[n].last_extra);
  }
  solveChain();
  for (int round = 1; round < kRounds; ++round)
  {
    if (!addContextReadings())
      break;
    solveChain();
  }
  acceptProven(slidingBeams());
}

// One line per grid row (column) holding the open beams and spots of its
// components; components spanning several rows and columns are skipped.
void LineReader::collectLines(const std::vector<Component>& components)
{
  for (const Component& comp : components)
  {
    const std::vector<int>& cb = comp.beams;
    bool same_row = true, same_col = true;
    for (int i : cb)
    {
      same_row &= i / cols_ == cb[0] / cols_;
      same_col &= i % cols_ == cb[0] % cols_;
    }
    if (!same_row && !same_col)
      continue;
    const int orient = same_row ? 0 : 1;
    const int index = same_row ? cb[0] / cols_ : cb[0] % cols_;
    auto it = std::find_if(lines_.begin(), lines_.end(),
                           [&](const GridLine& l) { return l.orient == orient && l.line == index; });
    if (it == lines_.end())
    {
      lines_.emplace_back();
      it = lines_.end() - 1;
      it->orient = orient;
      it->line = index;
    }
    for (int i : cb)
      if (a_.spot_of_beam[i] < 0)
        it->beams.push_back(i);
    for (int j : comp.spots)
      if (a_.beam_of_spot[j] < 0)
        it->spots.push_back(j);
  }
}

// Orders the beams and spots along the line and lists its candidate pairs,
// each with its data cost: the epipolar cost plus the smoothness to the
// accepted grid neighbours. A line without a usable direction gets none.
void LineReader::buildPairs(GridLine& line) const
{
  std::sort(line.beams.begin(), line.beams.end(),
            [&](int x, int y) { return posOf(line.orient, x) < posOf(line.orient, y); });
  const int m = line.m(), q = line.q();
  if (m == 0 || q == 0)
    return;
  // Image direction of increasing position along the line: on a surface
  // without overhangs the dots keep the beams' order along it.
  const std::vector<EpipolarSegment>& seg = geometry_.segments();
  const auto mid = [&](int i) { return 0.5 * (seg[i].near_px + seg[i].far_px); };
  const Eigen::Vector2d dir = m >= 2 ? Eigen::Vector2d(mid(line.beams.back()) - mid(line.beams.front()))
                                     : Eigen::Vector2d(seg[line.beams[0]].far_px - seg[line.beams[0]].near_px);
  if (!(dir.norm() > 1e-9))
    return;
  std::sort(line.spots.begin(), line.spots.end(),
            [&](int x, int y) { return spots_px_[x].dot(dir) < spots_px_[y].dot(dir); });
  line.k_of_pos.assign(line.orient == 0 ? cols_ : geometry_.rows(), -1);
  for (int k = 0; k < m; ++k)
    line.k_of_pos[posOf(line.orient, line.beams[k])] = k;
  const double gate2 = square(params_.max_epipolar_distance_px);
  line.pair_of.assign(static_cast<size_t>(m) * q, -1);
  for (int k = 0; k < m; ++k)
  {
    const int i = line.beams[k];
    for (int l = 0; l < q; ++l)
    {
      const Eigen::Vector2d& px = spots_px_[line.spots[l]];
      const double d2 = geometry_.segmentDistance2(i, px);
      Eigen::Vector3d pt;
      if (!(d2 <= gate2) || !geometry_.triangulatePixel(i, px, &pt))
        continue;
      double data = d2 / gate2;
      int nb[8];
      geometry_.neighbours(i, nb);
      for (int n2 : nb)
        if (n2 >= 0 && a_.spot_of_beam[n2] >= 0)
          data += geometry_.smoothnessCost(i, px, a_.accepted_point[n2]);
      line.pair_of[k * q + l] = static_cast<int>(line.pairs.size());
      line.pairs.push_back({k, l, data, pt});
    }
  }
}

// Smoothness between consecutive matches of a reading: only between grid
// neighbours. Comparing across a gap (a missing dot) also fixed two
// end-of-row dots in 500 test frames but let dots on an object in front of
// the rock be read two columns over (at nearly the rock's depth) in the
// permutation test.
void LineReader::buildSmoothness(GridLine& line) const
{
  const int np = line.np();
  line.S.assign(static_cast<size_t>(np) * np, 0.0);
  for (int a2 = 0; a2 < np; ++a2)
    for (int b2 = 0; b2 < np; ++b2)
    {
      const LinePair& pa = line.pairs[a2];
      const LinePair& pb = line.pairs[b2];
      if (pb.k > pa.k && pb.l > pa.l &&
          posOf(line.orient, line.beams[pb.k]) == posOf(line.orient, line.beams[pa.k]) + 1)
        line.S[a2 * np + b2] = geometry_.smoothnessCost(line.beams[pb.k], spots_px_[line.spots[pb.l]], pa.point);
    }
}

// The lines with pairs, in chain order; consecutive lines of the same
// orientation are grid neighbours.
void LineReader::chainLines()
{
  for (int n = 0; n < static_cast<int>(lines_.size()); ++n)
    if (!lines_[n].pairs.empty())
      order_.push_back(n);
  std::sort(order_.begin(), order_.end(),
            [&](int a, int b)
            {
              return lines_[a].orient != lines_[b].orient ? lines_[a].orient < lines_[b].orient
                                                          : lines_[a].line < lines_[b].line;
            });
  pair_cost_.resize(order_.size());
  P_.resize(order_.size());
}

// Smoothness of every pair of pairs whose beams are neighbours across the
// lines order_[t] and order_[t + 1] (computed once).
const std::vector<double>& LineReader::pairCosts(int t)
{
  std::vector<double>& cache = pair_cost_[t];
  if (!cache.empty())
    return cache;
  const GridLine& a = lines_[order_[t]];
  const GridLine& b = lines_[order_[t + 1]];
  const size_t npb = b.pairs.size();
  cache.assign(a.pairs.size() * npb, 0.0);
  for (size_t pa = 0; pa < a.pairs.size(); ++pa)
  {
    const int pos = posOf(a.orient, a.beams[a.pairs[pa].k]);
    for (size_t pb = 0; pb < npb; ++pb)
    {
      const int kb = b.pairs[pb].k;
      if (std::abs(posOf(b.orient, b.beams[kb]) - pos) <= 1)
        cache[pa * npb + pb] =
            geometry_.smoothnessCost(b.beams[kb], spots_px_[b.spots[b.pairs[pb].l]], a.pairs[pa].point);
    }
  }
  return cache;
}

// Smoothness between reading h of line order_[t] and reading g of the next
// line: over the neighbours across, straight and diagonal.
double LineReader::pairwise(int t, int h, int g)
{
  const GridLine& a = lines_[order_[t]];
  const GridLine& b = lines_[order_[t + 1]];
  const int npb = static_cast<int>(b.pairs.size());
  const std::vector<double>& cache = pairCosts(t);
  double p = 0.0;
  for (size_t ka = 0; ka < a.beams.size(); ++ka)
  {
    const int pa = a.reading_pair[h][ka];
    if (pa < 0)
      continue;
    const int pos = posOf(a.orient, a.beams[ka]);
    for (int other = std::max(0, pos - 1); other <= std::min<int>(b.k_of_pos.size() - 1, pos + 1); ++other)
    {
      const int kb = b.k_of_pos[other];
      const int pb = kb >= 0 ? b.reading_pair[g][kb] : -1;
      if (pb < 0)
        continue;
      p += cache[pa * npb + pb];
    }
  }
  return p;
}

// Exact min-sum over the chain: forward and backward messages give every
// reading's min-marginal (the cost of the best joint reading that uses it)
// and each line's reading in the joint optimum (map).
void LineReader::solveChain()
{
  const int count = static_cast<int>(order_.size());
  std::vector<std::vector<double>> fwd(count), bwd(count);
  for (int t = 0; t < count; ++t)
  {
    const GridLine& a = lines_[order_[t]];
    fwd[t].assign(a.reading.size(), 0.0);
    bwd[t].assign(a.reading.size(), 0.0);
    if (t + 1 == count)
      continue;
    const GridLine& b = lines_[order_[t + 1]];
    const bool linked = a.orient == b.orient && b.line == a.line + 1;
    P_[t].resize(a.reading.size());
    for (size_t h = 0; h < a.reading.size(); ++h)
      for (size_t g = P_[t][h].size(); g < b.reading.size(); ++g)
        P_[t][h].push_back(linked ? pairwise(t, static_cast<int>(h), static_cast<int>(g)) : 0.0);
  }
  for (int t = 1; t < count; ++t)
  {
    const GridLine& a = lines_[order_[t - 1]];
    for (size_t g = 0; g < fwd[t].size(); ++g)
    {
      double v = kInf;
      for (size_t h = 0; h < a.reading.size(); ++h)
        v = std::min(v, fwd[t - 1][h] + a.unary[h] + P_[t - 1][h][g]);
      fwd[t][g] = v;
    }
  }
  for (int t = count - 2; t >= 0; --t)
  {
    const GridLine& b = lines_[order_[t + 1]];
    for (size_t h = 0; h < bwd[t].size(); ++h)
    {
      double v = kInf;
      for (size_t g = 0; g < b.reading.size(); ++g)
        v = std::min(v, bwd[t + 1][g] + b.unary[g] + P_[t][h][g]);
      bwd[t][h] = v;
    }
  }
  for (int t = 0; t < count; ++t)
  {
    GridLine& line = lines_[order_[t]];
    line.marginal.resize(line.reading.size());
    line.map = 0;
    for (size_t h = 0; h < line.reading.size(); ++h)
    {
      line.marginal[h] = line.unary[h] + fwd[t][h] + bwd[t][h];
      if (line.marginal[h] < line.marginal[line.map])
        line.map = static_cast<int>(h);
    }
  }
}

// Point of every beam in the chain's optimum (NaN = none).
std::vector<Eigen::Vector3d> LineReader::chainOptimum() const
{
  std::vector<Eigen::Vector3d> current(geometry_.beamCount(), Eigen::Vector3d::Constant(kNaN));
  for (int n : order_)
  {
    const GridLine& line = lines_[n];
    for (int k = 0; k < line.m(); ++k)
      if (line.reading[line.map][k] >= 0)
        current[line.beams[k]] = line.pairs[line.pairIn(line.map, k)].point;
  }
  return current;
}

// One round: every line gets the readings that are best given its
// neighbouring lines' optimum (their smoothness as an extra cost per pair).
// Returns whether any reading was added.
bool LineReader::addContextReadings()
{
  const std::vector<Eigen::Vector3d> current = chainOptimum();
  int added = 0;
  for (int n : order_)
  {
    GridLine& line = lines_[n];
    std::vector<double> extra(line.pairs.size(), 0.0);
    for (size_t p2 = 0; p2 < line.pairs.size(); ++p2)
    {
      const int i = line.beams[line.pairs[p2].k];
      int nb[8];
      geometry_.neighbours(i, nb);
      for (int n2 : nb)
        if (n2 >= 0 && lineOf(line.orient, n2) != line.line && current[n2].allFinite())
          extra[p2] += geometry_.smoothnessCost(i, spots_px_[line.spots[line.pairs[p2].l]], current[n2]);
    }
    // Unchanged neighbours give the same readings again.
    if (extra == line.last_extra)
      continue;
    line.last_extra = extra;
    added += addBestReadings(&line, extra);
  }
  return added > 0;
}

// Pixel and point of every beam: the pairs accepted before, and the chain's
// optimum (NaN = none).
LineReader::Layout LineReader::chainLayout() const
{
  const int n_beams = geometry_.beamCount();
  Layout map{std::vector<Eigen::Vector2d>(n_beams, Eigen::Vector2d::Constant(kNaN)),
             std::vector<Eigen::Vector3d>(n_beams, Eigen::Vector3d::Constant(kNaN))};
  for (int i = 0; i < n_beams; ++i)
    if (a_.spot_of_beam[i] >= 0)
    {
      map.px[i] = spots_px_[a_.spot_of_beam[i]];
      map.pt[i] = a_.accepted_point[i];
    }
  for (int n : order_)
  {
    const GridLine& line = lines_[n];
    for (int k = 0; k < line.m(); ++k)
      if (line.reading[line.map][k] >= 0)
      {
        map.px[line.beams[k]] = spots_px_[line.spots[line.reading[line.map][k]]];
        map.pt[line.beams[k]] = line.pairs[line.pairIn(line.map, k)].point;
      }
  }
  return map;
}

// Whether the dot of beam b lies smoothly next to the dot of beam a.
bool LineReader::smooth(const Layout& map, int a, int b) const
{
  return geometry_.smoothnessCost(b, map.px[b], map.pt[a]) < 1.0;
}

// The dots of runs along a line (matched positions smoothly linked, across
// gaps too) that have a free beam before or after them.
std::vector<char> LineReader::nextToFreeBeam(const Layout& map) const
{
  std::vector<char> candidate(geometry_.beamCount(), 0);
  for (int n : order_)
  {
    const GridLine& line = lines_[n];
    const int n_pos = static_cast<int>(line.k_of_pos.size());
    const auto free = [&](int pos) { return !map.pt[beamAt(line, pos)].allFinite(); };
    std::vector<int> run;
    const auto close = [&]()
    {
      if (run.empty())
        return;
      const bool free_before = run.front() > 0 && free(run.front() - 1);
      const bool free_after = run.back() + 1 < n_pos && free(run.back() + 1);
      if (free_before || free_after)
        for (int pos : run)
          candidate[beamAt(line, pos)] = 1;
      run.clear();
    };
    for (int pos = 0; pos < n_pos; ++pos)
    {
      if (free(pos))
        continue;
      if (!run.empty() && !smooth(map, beamAt(line, run.back()), beamAt(line, pos)))
        close();
      run.push_back(pos);
    }
    close();
  }
  return candidate;
}

// The dots that cannot slide (not candidates) and those smoothly linked to
// them through the 8-neighbourhood.
std::vector<char> LineReader::anchoredBeams(const Layout& map, const std::vector<char>& candidate) const
{
  const int n_beams = geometry_.beamCount();
  std::vector<char> anchored(n_beams, 0);
  std::vector<int> stack;
  for (int i = 0; i < n_beams; ++i)
    if (map.pt[i].allFinite() && !candidate[i])
    {
      anchored[i] = 1;
      stack.push_back(i);
    }
  while (!stack.empty())
  {
    const int i = stack.back();
    stack.pop_back();
    int nb[8];
    geometry_.neighbours(i, nb);
    for (int n2 : nb)
      if (n2 >= 0 && !anchored[n2] && map.pt[n2].allFinite() && smooth(map, i, n2))
      {
        anchored[n2] = 1;
        stack.push_back(n2);
      }
  }
  return anchored;
}

// Groups of dots that can slide along their lines. With rows parallel to
// the baseline, a run of dots along a line next to a free beam (a gap or
// the end of the line) can be read shifted by one beam at no cost in data;
// the reading is fixed only by depth smoothness with dots that cannot
// shift. An object in front of the rock is such a group: its dots are cut
// off from the rock by depth edges, and parallax hides the rock behind it
// from the camera, leaving free beams next to it, so the whole patch can
// shift (its depth changes, nothing contradicts it) and the smoothness
// prior even prefers the shift that hides its edge in the gap. Dots of a
// group that can slide and is not smoothly linked to one that cannot are
// flagged (left unassigned).
std::vector<char> LineReader::slidingBeams() const
{
  const Layout map = chainLayout();
  const std::vector<char> candidate = nextToFreeBeam(map);
  const std::vector<char> anchored = anchoredBeams(map, candidate);
  std::vector<char> sliding(geometry_.beamCount(), 0);
  for (int i = 0; i < geometry_.beamCount(); ++i)
    sliding[i] = candidate[i] && !anchored[i];
  return sliding;
}

// A pair stands when every reading of its line without it costs at least
// the margin more and its group cannot slide.
void LineReader::acceptProven(const std::vector<char>& sliding)
{
  for (int n : order_)
  {
    const GridLine& line = lines_[n];
    const std::vector<int>& best = line.reading[line.map];
    for (int k = 0; k < line.m(); ++k)
    {
      if (best[k] < 0 || sliding[line.beams[k]])
        continue;
      double alt = kInf;
      for (size_t h = 0; h < line.reading.size(); ++h)
        if (line.reading[h][k] != best[k])
          alt = std::min(alt, line.marginal[h]);
      if (!(alt - line.marginal[line.map] >= params_.ambiguity_margin) || !std::isfinite(alt))
        continue;
      const int i = line.beams[k];
      a_.accept(i, line.spots[best[k]], line.pairs[line.pairIn(line.map, k)].point);
      a_.proven[i] = 1;
    }
  }
}

}  // namespace

void readLines(const BeamGeometry& geometry, const TriangulatorParams& params,
               const std::vector<Eigen::Vector2d>& spots_px, const std::vector<Component>& lines,
               Assignment* assignment)
{
  LineReader(geometry, params, spots_px, assignment).read(lines);
}

}  // namespace detail
}  // namespace structured_light_stabilizer
