#include "structured_light_stabilizer/triangulator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include <Eigen/Dense>

#include "structured_light_stabilizer/spot_detector.h"

namespace structured_light_stabilizer
{

namespace
{

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Finite "forbidden" cost: keeps the Hungarian potentials finite.
constexpr double kForbidden = 1e6;

// Minimum-cost perfect matching of a square cost matrix (Kuhn-Munkres with
// potentials, O(n^3)). Returns the total cost; (*col_of_row)[r] = column.
double solveAssignment(const std::vector<double>& cost, int n, std::vector<int>* col_of_row)
{
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> u(n + 1, 0.0), v(n + 1, 0.0), minv(n + 1);
  std::vector<int> p(n + 1, 0), way(n + 1, 0);
  std::vector<char> used(n + 1);
  for (int i = 1; i <= n; ++i)
  {
    p[0] = i;
    int j0 = 0;
    std::fill(minv.begin(), minv.end(), inf);
    std::fill(used.begin(), used.end(), 0);
    do
    {
      used[j0] = 1;
      const int i0 = p[j0];
      double delta = inf;
      int j1 = 0;
      for (int j = 1; j <= n; ++j)
      {
        if (used[j])
          continue;
        const double cur = cost[(i0 - 1) * n + (j - 1)] - u[i0] - v[j];
        if (cur < minv[j])
        {
          minv[j] = cur;
          way[j] = j0;
        }
        if (minv[j] < delta)
        {
          delta = minv[j];
          j1 = j;
        }
      }
      for (int j = 0; j <= n; ++j)
      {
        if (used[j])
        {
          u[p[j]] += delta;
          v[j] -= delta;
        }
        else
        {
          minv[j] -= delta;
        }
      }
      j0 = j1;
    } while (p[j0] != 0);
    do
    {
      const int j1 = way[j0];
      p[j0] = p[j1];
      j0 = j1;
    } while (j0);
  }
  col_of_row->assign(n, -1);
  double total = 0.0;
  for (int j = 1; j <= n; ++j)
  {
    (*col_of_row)[p[j] - 1] = j - 1;
    total += cost[(p[j] - 1) * n + (j - 1)];
  }
  return total;
}

// Squared distance of p to the segment [a, b], and the position of its
// projection along the segment (0 at a, 1 at b).
double segmentDistance2(const Eigen::Vector2d& p, const Eigen::Vector2d& a, const Eigen::Vector2d& b)
{
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  double t = len2 > 0.0 ? (p - a).dot(ab) / len2 : 0.0;
  t = std::min(1.0, std::max(0.0, t));
  return (a + t * ab - p).squaredNorm();
}

// Tolerance of a one-sided (extrapolated) surface prediction, in units of
// prediction_tolerance_px, for uncontested pairs.
constexpr double kExtrapolationTolerance = 1.25;

struct Candidate
{
  int beam;
  int spot;
  double cost;  // (distance / gate)^2, in [0, 1]
};

}  // namespace

std::string TriangulatorParams::validate() const
{
  std::ostringstream why;
  if (!(min_depth > 0.0) || !(max_depth > min_depth) || !std::isfinite(max_depth))
    why << "depth range [" << min_depth << ", " << max_depth << "] m must satisfy 0 < min < max; ";
  if (!(max_epipolar_distance_px > 0.0) || !std::isfinite(max_epipolar_distance_px))
    why << "max_epipolar_distance_px = " << max_epipolar_distance_px << " must be > 0; ";
  if (!(max_ray_gap > 0.0) || !std::isfinite(max_ray_gap))
    why << "max_ray_gap = " << max_ray_gap << " m must be > 0; ";
  if (!(ambiguity_margin >= 0.0) || !std::isfinite(ambiguity_margin))
    why << "ambiguity_margin = " << ambiguity_margin << " must be >= 0; ";
  if (!(prediction_tolerance_px >= 0.0) || !std::isfinite(prediction_tolerance_px))
    why << "prediction_tolerance_px = " << prediction_tolerance_px << " must be >= 0; ";
  if (!(tracking_radius_px > 0.0) || !std::isfinite(tracking_radius_px))
    why << "tracking_radius_px = " << tracking_radius_px << " must be > 0; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

bool triangulateBeam(const Eigen::Vector3d& camera_ray, const BeamRay& beam, Eigen::Vector3d* point, double* gap)
{
  const Eigen::Vector3d v = camera_ray.normalized();
  const Eigen::Vector3d u = beam.direction.normalized();
  const Eigen::Vector3d& o = beam.origin;
  // Minimise |o + s u - t v|^2 over the beam parameter s and the camera-ray
  // parameter t (camera centre at the origin).
  const double b = u.dot(v);
  const double denom = 1.0 - b * b;
  if (!(denom > 1e-12))
    return false;
  const double t = (v.dot(o) - b * u.dot(o)) / denom;
  const double s = t * b - u.dot(o);
  const Eigen::Vector3d on_beam = o + s * u;
  if (point)
    *point = on_beam;
  if (gap)
    *gap = (on_beam - t * v).norm();
  return std::isfinite(s) && std::isfinite(t);
}

std::vector<int> rowSortOrder(const Spots& spots, int cols)
{
  // The detector's sort reorders the spots themselves; tag them with their
  // index to read the order back.
  Spots tagged = spots;
  for (size_t k = 0; k < tagged.size(); ++k)
    tagged[k].beam = static_cast<int>(k);
  sortIntoRows(&tagged, cols, 0, false);
  std::vector<int> order(tagged.size());
  for (size_t k = 0; k < tagged.size(); ++k)
    order[k] = tagged[k].beam;
  return order;
}

Triangulator::Triangulator(const CameraModel& camera, const ProjectorCalibration& projector,
                           const TriangulatorParams& params)
  : camera_(camera), projector_(projector), params_(params)
{
  std::string why = camera_.validate();
  if (!why.empty())
    throw std::invalid_argument("camera model: " + why);
  why = projector_.validate();
  if (!why.empty())
    throw std::invalid_argument("projector calibration: " + why);
  why = params_.validate();
  if (!why.empty())
    throw std::invalid_argument("triangulator config: " + why);
  segments_.resize(projector_.beams.size());
  for (size_t i = 0; i < projector_.beams.size(); ++i)
  {
    const BeamRay& b = projector_.beams[i];
    // Parameterised by camera depth z: s = (z - o_z) / u_z (u_z > 0 is
    // guaranteed by validate()).
    const auto at_depth = [&](double z) { return b.pointAt((z - b.origin.z()) / b.direction.z()); };
    segments_[i].near_px = projectUndistorted(at_depth(params_.min_depth));
    segments_[i].far_px = projectUndistorted(at_depth(params_.max_depth));
  }
  // Smoothness scale: half the image distance between neighbouring beams
  // (median over the grid, at mid-range depth), so that reading a dot as its
  // neighbour's (a shift by one column) costs the cap while the relief
  // between neighbours costs little at any depth. Without neighbours: twice
  // the prediction tolerance.
  std::vector<double> pitch;
  const auto mid = [&](int i) { return 0.5 * (segments_[i].near_px + segments_[i].far_px); };
  for (int i = 0; i < projector_.beamCount(); ++i)
  {
    if ((i + 1) % projector_.cols != 0)
      pitch.push_back((mid(i + 1) - mid(i)).norm());
    if (i + projector_.cols < projector_.beamCount())
      pitch.push_back((mid(i + projector_.cols) - mid(i)).norm());
  }
  beam_pitch_px_ = 0.0;
  if (!pitch.empty())
  {
    std::nth_element(pitch.begin(), pitch.begin() + pitch.size() / 2, pitch.end());
    beam_pitch_px_ = pitch[pitch.size() / 2];
  }
  smoothness_scale_px_ = beam_pitch_px_ > 0.0 ? 0.5 * beam_pitch_px_ : 2.0 * params_.prediction_tolerance_px;
}

Eigen::Vector2d Triangulator::projectUndistorted(const Eigen::Vector3d& p) const
{
  return Eigen::Vector2d(camera_.fx * p.x() / p.z() + camera_.cx, camera_.fy * p.y() / p.z() + camera_.cy);
}

Eigen::Vector2d Triangulator::undistortPixel(double x, double y) const
{
  if (!std::isfinite(x) || !std::isfinite(y))
    return Eigen::Vector2d(kNaN, kNaN);
  const Eigen::Vector2d n = camera_.normalize(cv::Point2d(x, y));
  return Eigen::Vector2d(camera_.fx * n.x() + camera_.cx, camera_.fy * n.y() + camera_.cy);
}

bool Triangulator::predictPixel(int beam, const std::vector<Eigen::Vector3d>& support, Eigen::Vector2d* px) const
{
  if (support.empty())
    return false;
  const BeamRay& b = projector_.beams[beam];
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : support)
    centroid += p;
  centroid /= static_cast<double>(support.size());
  // Local plane through the neighbours when they span one, else the
  // fronto-parallel plane at their mean depth.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  if (support.size() >= 3)
  {
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (const auto& p : support)
      cov += (p - centroid) * (p - centroid).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(cov);
    // Collinear supports (smallest two eigenvalues tiny) give no plane.
    if (es.eigenvalues()(1) > 1e-2 * es.eigenvalues()(2))
      normal = es.eigenvectors().col(0);
  }
  const double denom = normal.dot(b.direction);
  if (std::abs(denom) < 1e-6)
    return false;
  const double s = normal.dot(centroid - b.origin) / denom;
  const Eigen::Vector3d hit = b.pointAt(s);
  if (!(hit.z() > 0.0))
    return false;
  *px = projectUndistorted(hit);
  return px->allFinite();
}

int Triangulator::supportOf(int beam, const std::vector<int>& spot_of_beam,
                            const std::vector<Eigen::Vector3d>& accepted_point,
                            std::vector<Eigen::Vector3d>* support) const
{
  const int rows = projector_.rows, cols = projector_.cols;
  const int r = beam / cols, c = beam % cols;
  bool up = false, down = false, left = false, right = false;
  support->clear();
  for (int rr = std::max(0, r - 1); rr <= std::min(rows - 1, r + 1); ++rr)
  {
    for (int cc = std::max(0, c - 1); cc <= std::min(cols - 1, c + 1); ++cc)
    {
      const int k = rr * cols + cc;
      if (k == beam || spot_of_beam[k] < 0)
        continue;
      support->push_back(accepted_point[k]);
      up |= rr < r;
      down |= rr > r;
      left |= cc < c;
      right |= cc > c;
    }
  }
  if ((up && down) || (left && right))
    return 2;
  // One side only: extrapolate from a plane through the accepted beams
  // within two rows/columns, which needs at least three of them.
  // Points on one grid line give no plane (its tilt about that line would be
  // arbitrary): require two rows and two columns.
  support->clear();
  int row_mask = 0, col_mask = 0;
  for (int rr = std::max(0, r - 2); rr <= std::min(rows - 1, r + 2); ++rr)
    for (int cc = std::max(0, c - 2); cc <= std::min(cols - 1, c + 2); ++cc)
      if ((rr != r || cc != c) && spot_of_beam[rr * cols + cc] >= 0)
      {
        support->push_back(accepted_point[rr * cols + cc]);
        row_mask |= 1 << (rr - r + 2);
        col_mask |= 1 << (cc - c + 2);
      }
  const auto bits = [](int m) { return __builtin_popcount(static_cast<unsigned>(m)); };
  return support->size() >= 3 && bits(row_mask) >= 2 && bits(col_mask) >= 2 ? 1 : 0;
}

void Triangulator::rejectInconsistent(const std::vector<Eigen::Vector2d>& spots_px,
                                      const std::vector<char>& contested, const std::vector<char>& proven,
                                      std::vector<int>* spot_of_beam,
                                      std::vector<int>* beam_of_spot,
                                      std::vector<Eigen::Vector3d>* accepted_point) const
{
  // A dot is kept when it agrees with the surface of its accepted
  // neighbours: with the local plane through them, or with the depth of at
  // least two of them, which keeps the dots of
  // a small object in front of the rock. A spurious spot that happens to lie
  // on the segment of a beam whose dot is missing lands at a random depth
  // and fails both. Decisions use the state before this sweep.
  const double tol = params_.prediction_tolerance_px;
  const int rows = projector_.rows, cols = projector_.cols;
  std::vector<int> reject;
  // Neighbours at whose depth beam i would be within tol of spot j.
  const auto agreeing = [&](int i, int j, const std::vector<Eigen::Vector3d>& support, double within) {
    const BeamRay& b = projector_.beams[i];
    int agree = 0;
    for (const Eigen::Vector3d& q : support)
    {
      const Eigen::Vector2d at_q = projectUndistorted(b.pointAt((q.z() - b.origin.z()) / b.direction.z()));
      agree += (at_q - spots_px[j]).norm() <= within;
    }
    return agree;
  };
  for (int i = 0; i < projector_.beamCount(); ++i)
  {
    const int j = (*spot_of_beam)[i];
    // Pairs proven by the joint reading of their grid line already passed a
    // stronger test with the same neighbours (the depth smoothness of every
    // alternative reading, with the margin).
    if (j < 0 || proven[i])
      continue;
    const int r = i / cols, c = i % cols;
    std::vector<Eigen::Vector3d> support;
    for (int rr = std::max(0, r - 1); rr <= std::min(rows - 1, r + 1); ++rr)
      for (int cc = std::max(0, c - 1); cc <= std::min(cols - 1, c + 1); ++cc)
        if ((rr != r || cc != c) && (*spot_of_beam)[rr * cols + cc] >= 0)
          support.push_back((*accepted_point)[rr * cols + cc]);
    // Too few neighbours to tell a spurious spot from a dot on a small
    // object (always so in 1 x N patterns): keep it, unless the pair was
    // contested (the spot or the beam had other candidates, as along the
    // shared epipolar lines of a grid whose rows are parallel to the
    // baseline), where only neighbours can confirm it.
    if (support.size() < 3)
    {
      // A corner or a sparse spot: the plane through the accepted beams
      // within two rows and columns may still confirm it.
      // A dot with no rival but no wide plane either is kept (1 x N
      // patterns, isolated dots); a wide plane that disagrees drops it.
      std::vector<Eigen::Vector3d> wide;
      Eigen::Vector2d px;
      const bool have_plane = supportOf(i, *spot_of_beam, *accepted_point, &wide) >= 1 && wide.size() >= 3 &&
                              predictPixel(i, wide, &px);
      const bool confirmed = have_plane && (px - spots_px[j]).norm() <= tol;
      // Two neighbours that both disagree by more than half the beam pitch:
      // a spot at a depth of its own (a one-dot object) is
      // indistinguishable from a spurious spot on the segment of a missing
      // dot, and the latter is the likelier.
      const bool isolated = support.size() >= 2 && agreeing(i, j, support, smoothness_scale_px_) == 0;
      if ((have_plane && !confirmed) || (contested[i] && !confirmed) || isolated)
        reject.push_back(i);
      continue;
    }
    Eigen::Vector2d px;
    // A prediction from neighbours missing on one side extrapolates the local
    // plane by about one beam pitch; its error grows with the curvature of
    // the rock (a dot at the pattern's edge at 1 m on a 15 cm relief: 5.1 px
    // off). An
    // uncontested pair (its spot the only candidate of its beam, and the
    // beam the only one of its spot) gets the extrapolation's wider tolerance.
    bool up = false, down = false, left = false, right = false;
    for (int rr = std::max(0, r - 1); rr <= std::min(rows - 1, r + 1); ++rr)
      for (int cc = std::max(0, c - 1); cc <= std::min(cols - 1, c + 1); ++cc)
        if ((rr != r || cc != c) && (*spot_of_beam)[rr * cols + cc] >= 0)
        {
          up |= rr < r;
          down |= rr > r;
          left |= cc < c;
          right |= cc > c;
        }
    // On the pattern's border (or next to a hole as wide as the
    // 8-neighbourhood) the plane is extrapolated across the missing side.
    const bool extrapolated = !(up && down && left && right);
    const double tol_here = extrapolated && !contested[i] ? kExtrapolationTolerance * tol : tol;
    if (predictPixel(i, support, &px) && (px - spots_px[j]).norm() <= tol_here)
      continue;
    if (agreeing(i, j, support, tol) < 2)
      reject.push_back(i);
  }
  for (int i : reject)
  {
    (*beam_of_spot)[(*spot_of_beam)[i]] = -1;
    (*spot_of_beam)[i] = -1;
    (*accepted_point)[i] = Eigen::Vector3d::Constant(kNaN);
  }
}

bool Triangulator::triangulatePixel(int beam, const Eigen::Vector2d& px, Eigen::Vector3d* p) const
{
  const Eigen::Vector3d ray((px.x() - camera_.cx) / camera_.fx, (px.y() - camera_.cy) / camera_.fy, 1.0);
  double gap = 0.0;
  return triangulateBeam(ray, projector_.beams[beam], p, &gap);
}

double Triangulator::smoothnessCost(int beam, const Eigen::Vector2d& px, const Eigen::Vector3d& q) const
{
  const BeamRay& b = projector_.beams[beam];
  const Eigen::Vector2d at_q = projectUndistorted(b.pointAt((q.z() - b.origin.z()) / b.direction.z()));
  const double e = (at_q - px).norm() / smoothness_scale_px_;
  return std::isfinite(e) ? std::min(1.0, e * e) : 1.0;
}

int Triangulator::resolveLines(const std::vector<std::pair<std::vector<int>, std::vector<int>>>& lines,
                               const std::vector<Eigen::Vector2d>& spots_px, std::vector<int>* spot_of_beam,
                               std::vector<int>* beam_of_spot, std::vector<Eigen::Vector3d>* accepted_point,
                               std::vector<char>* proven) const
{
  if (params_.prediction_tolerance_px <= 0.0)
    return 0;
  const int rows = projector_.rows, cols = projector_.cols;
  const double gate2 = params_.max_epipolar_distance_px * params_.max_epipolar_distance_px;
  const double inf = std::numeric_limits<double>::infinity();
  // Readings up to this much above a line's best are kept as hypotheses: a
  // reading shifted by one column costs the best + 0 or + 2 (a missing end
  // dot, a spurious one); the neighbouring lines have to decide.
  const double window = 2.5;
  constexpr int kRounds = 2;  // a third round added nothing in 500 test frames

  struct Pair
  {
    int k, l;              // local beam (along the line) and local spot (along the image line)
    double data;           // epipolar cost + smoothness to accepted grid neighbours
    Eigen::Vector3d point;
  };
  struct Node
  {
    int orient = 0;  // 0: a grid row, 1: a grid column
    int line = 0;    // its row (column) index
    std::vector<int> beams, spots;         // open ones, in order along the line
    std::vector<Pair> pairs;               // in (k, l) order
    std::vector<int> pair_of;              // k * spots + l -> pair, -1 = not a candidate
    std::vector<double> S;                 // smoothness of consecutive matches, pairs x pairs
    std::vector<std::vector<int>> reading; // per hypothesis: local spot per local beam, -1 = none
    std::vector<double> unary;             // its cost within the line
    std::vector<std::vector<int>> reading_pair;  // the same as pair indices
    std::vector<int> k_of_pos;             // local beam at each position along the line, -1 = none
    std::vector<double> last_extra;        // the neighbours' costs of the last generation
    std::vector<double> marginal;          // min-marginal over the chain
    int map = 0;                           // hypothesis of the chain's optimum
  };
  const auto posOf = [&](int orient, int beam) { return orient == 0 ? beam % cols : beam / cols; };

  // One node per grid line: the open beams and spots of its components.
  std::vector<Node> nodes;
  for (const auto& comp : lines)
  {
    const std::vector<int>& cb = comp.first;
    bool same_row = true, same_col = true;
    for (int i : cb)
    {
      same_row &= i / cols == cb[0] / cols;
      same_col &= i % cols == cb[0] % cols;
    }
    if (!same_row && !same_col)
      continue;
    const int orient = same_row ? 0 : 1;
    const int line = same_row ? cb[0] / cols : cb[0] % cols;
    auto it = std::find_if(nodes.begin(), nodes.end(),
                           [&](const Node& nd) { return nd.orient == orient && nd.line == line; });
    if (it == nodes.end())
    {
      nodes.emplace_back();
      it = nodes.end() - 1;
      it->orient = orient;
      it->line = line;
    }
    for (int i : cb)
      if ((*spot_of_beam)[i] < 0)
        it->beams.push_back(i);
    for (int j : comp.second)
      if ((*beam_of_spot)[j] < 0)
        it->spots.push_back(j);
  }
  // The 8-neighbourhood of a beam in the grid (-1 outside).
  const auto neighbours = [&](int i, int out[8]) {
    const int r = i / cols, c = i % cols;
    int n = 0;
    for (int dr = -1; dr <= 1; ++dr)
      for (int dc = -1; dc <= 1; ++dc)
        if (dr != 0 || dc != 0)
          out[n++] = r + dr >= 0 && r + dr < rows && c + dc >= 0 && c + dc < cols ? (r + dr) * cols + c + dc : -1;
  };
  const auto lineOf = [&](int orient, int beam) { return orient == 0 ? beam / cols : beam % cols; };

  // Candidate pairs of every node.
  for (Node& nd : nodes)
  {
    std::sort(nd.beams.begin(), nd.beams.end(),
              [&](int x, int y) { return posOf(nd.orient, x) < posOf(nd.orient, y); });
    const int m = static_cast<int>(nd.beams.size()), q = static_cast<int>(nd.spots.size());
    if (m == 0 || q == 0)
      continue;
    // Image direction of increasing position along the line: on a surface
    // without overhangs the dots keep the beams' order along it.
    const auto mid = [&](int i) { return 0.5 * (segments_[i].near_px + segments_[i].far_px); };
    const Eigen::Vector2d dir = m >= 2 ? Eigen::Vector2d(mid(nd.beams.back()) - mid(nd.beams.front()))
                                       : Eigen::Vector2d(segments_[nd.beams[0]].far_px - segments_[nd.beams[0]].near_px);
    if (!(dir.norm() > 1e-9))
      continue;
    std::sort(nd.spots.begin(), nd.spots.end(),
              [&](int x, int y) { return spots_px[x].dot(dir) < spots_px[y].dot(dir); });
    nd.k_of_pos.assign(nd.orient == 0 ? cols : rows, -1);
    for (int k = 0; k < m; ++k)
      nd.k_of_pos[posOf(nd.orient, nd.beams[k])] = k;
    nd.pair_of.assign(static_cast<size_t>(m) * q, -1);
    for (int k = 0; k < m; ++k)
    {
      const int i = nd.beams[k];
      for (int l = 0; l < q; ++l)
      {
        const Eigen::Vector2d& px = spots_px[nd.spots[l]];
        const double d2 = segmentDistance2(px, segments_[i].near_px, segments_[i].far_px);
        Eigen::Vector3d pt;
        if (!(d2 <= gate2) || !triangulatePixel(i, px, &pt))
          continue;
        double data = d2 / gate2;
        int nb[8];
        neighbours(i, nb);
        for (int n2 : nb)
          if (n2 >= 0 && (*spot_of_beam)[n2] >= 0)
            data += smoothnessCost(i, px, (*accepted_point)[n2]);
        nd.pair_of[k * q + l] = static_cast<int>(nd.pairs.size());
        nd.pairs.push_back({k, l, data, pt});
      }
    }
    const int np = static_cast<int>(nd.pairs.size());
    nd.S.assign(static_cast<size_t>(np) * np, 0.0);
    for (int a2 = 0; a2 < np; ++a2)
      for (int b2 = 0; b2 < np; ++b2)
      {
        const Pair& pa = nd.pairs[a2];
        const Pair& pb = nd.pairs[b2];
        // Only between grid neighbours: comparing across a gap (a missing
        // dot) also fixed two end-of-row dots in 500 test frames but let
        // dots on an object in front of the rock be read two columns over
        // (at nearly the rock's depth) in the permutation test.
        if (pb.k > pa.k && pb.l > pa.l &&
            posOf(nd.orient, nd.beams[pb.k]) == posOf(nd.orient, nd.beams[pa.k]) + 1)
          nd.S[a2 * np + b2] = smoothnessCost(nd.beams[pb.k], spots_px[nd.spots[pb.l]], pa.point);
      }
  }

  // Cost of a reading within its line: data, a beam without a spot or a
  // spot without a beam 1 each, smoothness between neighbouring matches.
  const auto readingCost = [&](const Node& nd, const std::vector<int>& rd) {
    const int m = static_cast<int>(nd.beams.size()), q = static_cast<int>(nd.spots.size());
    const int np = static_cast<int>(nd.pairs.size());
    double u = 0.0;
    int matched = 0, prev = -1;
    for (int k = 0; k < m; ++k)
    {
      if (rd[k] < 0)
        continue;
      const int p2 = nd.pair_of[k * q + rd[k]];
      u += nd.pairs[p2].data;
      if (prev >= 0)
        u += nd.S[prev * np + p2];
      prev = p2;
      ++matched;
    }
    return u + (m - matched) + (q - matched);
  };

  // Adds to a node the readings that are best under the cost data + extra
  // (per pair): the best one, the best through every pair within the
  // window, and the best without each pair of the best one. This is an
  // order-preserving matching with smoothness between consecutive matches,
  // by dynamic programming over the pairs (F: best reading ending with a
  // pair, B: best reading starting with it). Returns how many were new.
  const auto generate = [&](Node& nd, const std::vector<double>& extra) {
    const int m = static_cast<int>(nd.beams.size()), q = static_cast<int>(nd.spots.size());
    const int np = static_cast<int>(nd.pairs.size());
    const auto cost = [&](int p2) { return nd.pairs[p2].data + extra[p2]; };
    // First pair of each beam: predecessors of a pair are the pairs of
    // earlier beams only.
    std::vector<int> block(np);
    for (int p2 = 0; p2 < np; ++p2)
      block[p2] = p2 > 0 && nd.pairs[p2 - 1].k == nd.pairs[p2].k ? block[p2 - 1] : p2;
    // F and pred must hold a run without `forbid` up to `forbid` (the values
    // before the forbidden pair do not depend on it).
    const auto forward = [&](int forbid, std::vector<double>* F, std::vector<int>* pred) {
      for (int p2 = std::max(0, forbid); p2 < np; ++p2)
      {
        if (p2 == forbid)
        {
          (*F)[p2] = inf;
          (*pred)[p2] = -1;
          continue;
        }
        const Pair& pb = nd.pairs[p2];
        double best_in = pb.k + pb.l;
        int from = -1;
        for (int p1 = 0; p1 < block[p2]; ++p1)
        {
          const Pair& pa = nd.pairs[p1];
          if (p1 == forbid || pa.l >= pb.l)
            continue;
          const double v = (*F)[p1] + (pb.k - pa.k - 1) + (pb.l - pa.l - 1) + nd.S[p1 * np + p2];
          if (v < best_in)
          {
            best_in = v;
            from = p1;
          }
        }
        (*F)[p2] = cost(p2) + best_in;
        (*pred)[p2] = from;
      }
    };
    const auto bestEnd = [&](const std::vector<double>& F, double* total) {
      *total = m + q;
      int end = -1;
      for (int p2 = 0; p2 < np; ++p2)
      {
        const double v = F[p2] + (m - 1 - nd.pairs[p2].k) + (q - 1 - nd.pairs[p2].l);
        if (v < *total)
        {
          *total = v;
          end = p2;
        }
      }
      return end;
    };
    std::vector<double> B(np, inf);
    std::vector<int> succ(np, -1);
    for (int p2 = np - 1; p2 >= 0; --p2)
    {
      const Pair& pa = nd.pairs[p2];
      double best_out = (m - 1 - pa.k) + (q - 1 - pa.l);
      for (int p3 = p2 + 1; p3 < np; ++p3)
      {
        const Pair& pb = nd.pairs[p3];
        if (!(pb.k > pa.k && pb.l > pa.l))
          continue;
        const double v = B[p3] + (pb.k - pa.k - 1) + (pb.l - pa.l - 1) + nd.S[p2 * np + p3];
        if (v < best_out)
        {
          best_out = v;
          succ[p2] = p3;
        }
      }
      B[p2] = cost(p2) + best_out;
    }
    std::vector<std::vector<int>> found;
    const auto trace = [&](const std::vector<int>& pred, int p2, bool forward_too) {
      std::vector<int> rd(m, -1);
      for (int p1 = p2; p1 >= 0; p1 = pred[p1])
        rd[nd.pairs[p1].k] = nd.pairs[p1].l;
      if (forward_too && p2 >= 0)
        for (int p3 = succ[p2]; p3 >= 0; p3 = succ[p3])
          rd[nd.pairs[p3].k] = nd.pairs[p3].l;
      found.push_back(rd);
    };
    std::vector<double> F(np, inf);
    std::vector<int> pred(np, -1);
    forward(-1, &F, &pred);
    double best = 0.0;
    const int end = bestEnd(F, &best);
    trace(pred, end, false);
    std::vector<int> best_pairs;
    for (int p2 = end; p2 >= 0; p2 = pred[p2])
      best_pairs.push_back(p2);
    for (int p2 = 0; p2 < np; ++p2)
      if (F[p2] + B[p2] - cost(p2) <= best + window)
        trace(pred, p2, true);
    std::vector<double> Fx;
    std::vector<int> predx;
    for (int p2 : best_pairs)
    {
      Fx = F;
      predx = pred;
      forward(p2, &Fx, &predx);
      double total = 0.0;
      trace(predx, bestEnd(Fx, &total), false);
    }
    int added = 0;
    for (const std::vector<int>& rd : found)
    {
      if (std::find(nd.reading.begin(), nd.reading.end(), rd) != nd.reading.end())
        continue;
      nd.reading.push_back(rd);
      nd.unary.push_back(readingCost(nd, rd));
      std::vector<int> rp(m, -1);
      for (int k = 0; k < m; ++k)
        if (rd[k] >= 0)
          rp[k] = nd.pair_of[k * q + rd[k]];
      nd.reading_pair.push_back(rp);
      ++added;
    }
    return added;
  };

  // Lines with readings, chained in order; consecutive lines of the same
  // orientation are grid neighbours.
  std::vector<int> order;
  for (int n = 0; n < static_cast<int>(nodes.size()); ++n)
    if (!nodes[n].pairs.empty())
      order.push_back(n);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return nodes[a].orient != nodes[b].orient ? nodes[a].orient < nodes[b].orient : nodes[a].line < nodes[b].line;
  });
  const int count = static_cast<int>(order.size());
  if (count == 0)
    return 0;
  // Smoothness between the readings h of line a and g of the next line b:
  // a sum over positions of a cost between two pairs, tabulated per pair of
  // pairs; the reading-by-reading tables are extended as readings are added.
  std::vector<std::vector<double>> pair_cost(count);
  std::vector<std::vector<std::vector<double>>> P(count);  // P[t][h][g]: order[t] with order[t + 1]
  const auto pairwise = [&](int t, int h, int g) {
    const Node& a = nodes[order[t]];
    const Node& b = nodes[order[t + 1]];
    const int npb = static_cast<int>(b.pairs.size());
    std::vector<double>& cache = pair_cost[t];
    if (cache.empty())
    {
      // Every pair of pairs whose beams are neighbours across the lines.
      cache.assign(a.pairs.size() * b.pairs.size(), 0.0);
      for (size_t pa = 0; pa < a.pairs.size(); ++pa)
      {
        const int pos = posOf(a.orient, a.beams[a.pairs[pa].k]);
        for (size_t pb = 0; pb < b.pairs.size(); ++pb)
        {
          const int kb = b.pairs[pb].k;
          if (std::abs(posOf(b.orient, b.beams[kb]) - pos) <= 1)
            cache[pa * npb + pb] = smoothnessCost(b.beams[kb], spots_px[b.spots[b.pairs[pb].l]], a.pairs[pa].point);
        }
      }
    }
    double p = 0.0;
    for (size_t ka = 0; ka < a.beams.size(); ++ka)
    {
      const int pa = a.reading_pair[h][ka];
      if (pa < 0)
        continue;
      // The neighbours across, straight and diagonal.
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
  };
  // Exact min-sum over the chain: forward and backward messages give every
  // reading's min-marginal (the cost of the best joint reading that uses it).
  const auto solveChain = [&]() {
    std::vector<std::vector<double>> fwd(count), bwd(count);
    for (int t = 0; t < count; ++t)
    {
      const Node& a = nodes[order[t]];
      fwd[t].assign(a.reading.size(), 0.0);
      bwd[t].assign(a.reading.size(), 0.0);
      if (t + 1 == count)
        continue;
      const Node& b = nodes[order[t + 1]];
      const bool linked = a.orient == b.orient && b.line == a.line + 1;
      P[t].resize(a.reading.size());
      for (size_t h = 0; h < a.reading.size(); ++h)
        for (size_t g = P[t][h].size(); g < b.reading.size(); ++g)
          P[t][h].push_back(linked ? pairwise(t, static_cast<int>(h), static_cast<int>(g)) : 0.0);
    }
    for (int t = 1; t < count; ++t)
    {
      const Node& a = nodes[order[t - 1]];
      for (size_t g = 0; g < fwd[t].size(); ++g)
      {
        double v = inf;
        for (size_t h = 0; h < a.reading.size(); ++h)
          v = std::min(v, fwd[t - 1][h] + a.unary[h] + P[t - 1][h][g]);
        fwd[t][g] = v;
      }
    }
    for (int t = count - 2; t >= 0; --t)
    {
      const Node& b = nodes[order[t + 1]];
      for (size_t h = 0; h < bwd[t].size(); ++h)
      {
        double v = inf;
        for (size_t g = 0; g < b.reading.size(); ++g)
          v = std::min(v, bwd[t + 1][g] + b.unary[g] + P[t][h][g]);
        bwd[t][h] = v;
      }
    }
    for (int t = 0; t < count; ++t)
    {
      Node& nd = nodes[order[t]];
      nd.marginal.resize(nd.reading.size());
      nd.map = 0;
      for (size_t h = 0; h < nd.reading.size(); ++h)
      {
        nd.marginal[h] = nd.unary[h] + fwd[t][h] + bwd[t][h];
        if (nd.marginal[h] < nd.marginal[nd.map])
          nd.map = static_cast<int>(h);
      }
    }
  };

  // Round 0: readings from each line alone. Later rounds add the readings
  // that are best given the neighbouring lines' current optimum: when a
  // line's own evidence ties (a missing dot lets part of a row shift), the
  // reading its neighbours agree with may not be among the first ones.
  for (int t = 0; t < count; ++t)
  {
    Node& nd = nodes[order[t]];
    nd.last_extra.assign(nd.pairs.size(), 0.0);
    generate(nd, nd.last_extra);
  }
  solveChain();
  std::vector<Eigen::Vector3d> current(projector_.beamCount());
  for (int round = 1; round < kRounds; ++round)
  {
    std::fill(current.begin(), current.end(), Eigen::Vector3d::Constant(kNaN));
    for (int t = 0; t < count; ++t)
    {
      const Node& nd = nodes[order[t]];
      const int q = static_cast<int>(nd.spots.size());
      for (size_t k = 0; k < nd.beams.size(); ++k)
        if (nd.reading[nd.map][k] >= 0)
          current[nd.beams[k]] = nd.pairs[nd.pair_of[k * q + nd.reading[nd.map][k]]].point;
    }
    int added = 0;
    for (int t = 0; t < count; ++t)
    {
      Node& nd = nodes[order[t]];
      std::vector<double> extra(nd.pairs.size(), 0.0);
      for (size_t p2 = 0; p2 < nd.pairs.size(); ++p2)
      {
        const int i = nd.beams[nd.pairs[p2].k];
        int nb[8];
        neighbours(i, nb);
        for (int n2 : nb)
          if (n2 >= 0 && lineOf(nd.orient, n2) != nd.line && current[n2].allFinite())
            extra[p2] += smoothnessCost(i, spots_px[nd.spots[nd.pairs[p2].l]], current[n2]);
      }
      // Unchanged neighbours give the same readings again.
      if (extra == nd.last_extra)
        continue;
      nd.last_extra = extra;
      added += generate(nd, extra);
    }
    if (added == 0)
      break;
    solveChain();
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
  // left unassigned.
  const int n_beams = projector_.beamCount();
  std::vector<Eigen::Vector2d> map_px(n_beams, Eigen::Vector2d::Constant(kNaN));
  std::vector<Eigen::Vector3d> map_pt(n_beams, Eigen::Vector3d::Constant(kNaN));
  for (int i = 0; i < n_beams; ++i)
    if ((*spot_of_beam)[i] >= 0)
    {
      map_px[i] = spots_px[(*spot_of_beam)[i]];
      map_pt[i] = (*accepted_point)[i];
    }
  for (int t = 0; t < count; ++t)
  {
    const Node& nd = nodes[order[t]];
    const int q = static_cast<int>(nd.spots.size());
    for (size_t k = 0; k < nd.beams.size(); ++k)
      if (nd.reading[nd.map][k] >= 0)
      {
        map_px[nd.beams[k]] = spots_px[nd.spots[nd.reading[nd.map][k]]];
        map_pt[nd.beams[k]] = nd.pairs[nd.pair_of[k * q + nd.reading[nd.map][k]]].point;
      }
  }
  const auto smooth = [&](int a, int b) { return smoothnessCost(b, map_px[b], map_pt[a]) < 1.0; };
  std::vector<char> candidate(n_beams, 0);
  for (int t = 0; t < count; ++t)
  {
    const Node& nd = nodes[order[t]];
    const int n_pos = static_cast<int>(nd.k_of_pos.size());
    const auto beamAt = [&](int pos) { return nd.orient == 0 ? nd.line * cols + pos : pos * cols + nd.line; };
    std::vector<int> run;  // matched positions smoothly linked along the line (across gaps too)
    const auto close = [&]() {
      if (run.empty())
        return;
      const bool free_before = run.front() > 0 && !map_pt[beamAt(run.front() - 1)].allFinite();
      const bool free_after = run.back() + 1 < n_pos && !map_pt[beamAt(run.back() + 1)].allFinite();
      if (free_before || free_after)
        for (int pos : run)
          candidate[beamAt(pos)] = 1;
      run.clear();
    };
    for (int pos = 0; pos < n_pos; ++pos)
    {
      if (!map_pt[beamAt(pos)].allFinite())
        continue;
      if (!run.empty() && !smooth(beamAt(run.back()), beamAt(pos)))
        close();
      run.push_back(pos);
    }
    close();
  }
  std::vector<char> anchored(n_beams, 0);
  std::vector<int> stack;
  for (int i = 0; i < n_beams; ++i)
    if (map_pt[i].allFinite() && !candidate[i])
    {
      anchored[i] = 1;
      stack.push_back(i);
    }
  while (!stack.empty())
  {
    const int i = stack.back();
    stack.pop_back();
    int nb[8];
    neighbours(i, nb);
    for (int n2 : nb)
      if (n2 >= 0 && !anchored[n2] && map_pt[n2].allFinite() && smooth(i, n2))
      {
        anchored[n2] = 1;
        stack.push_back(n2);
      }
  }
  std::vector<char> sliding(n_beams, 0);
  for (int i = 0; i < n_beams; ++i)
    sliding[i] = candidate[i] && !anchored[i];

  // A pair stands when every reading of its line without it costs at least
  // the margin more.
  int accepted = 0;
  for (int t = 0; t < count; ++t)
  {
    const Node& nd = nodes[order[t]];
    const int q = static_cast<int>(nd.spots.size());
    const std::vector<int>& best = nd.reading[nd.map];
    for (size_t k = 0; k < nd.beams.size(); ++k)
    {
      if (best[k] < 0 || sliding[nd.beams[k]])
        continue;
      double alt = inf;
      for (size_t h = 0; h < nd.reading.size(); ++h)
        if (nd.reading[h][k] != best[k])
          alt = std::min(alt, nd.marginal[h]);
      if (!(alt - nd.marginal[nd.map] >= params_.ambiguity_margin) || !std::isfinite(alt))
        continue;
      const int i = nd.beams[k], j = nd.spots[best[k]];
      (*spot_of_beam)[i] = j;
      (*beam_of_spot)[j] = i;
      (*accepted_point)[i] = nd.pairs[nd.pair_of[k * q + best[k]]].point;
      (*proven)[i] = 1;
      ++accepted;
    }
  }
  return accepted;
}

std::vector<int> Triangulator::assignEpipolar(const std::vector<Eigen::Vector2d>& spots_px, int* ambiguous_out,
                                              const std::vector<Eigen::Vector2d>* previous_px,
                                              int* tracked_out) const
{
  const int n_beams = projector_.beamCount();
  const int n_spots = static_cast<int>(spots_px.size());
  const double gate2 = params_.max_epipolar_distance_px * params_.max_epipolar_distance_px;

  // Gated candidates. A brute-force scan is fine for a few hundred beams and
  // spots; a spatial index would pay off only for much larger patterns.
  std::vector<Candidate> candidates;
  std::vector<std::vector<int>> cand_of_beam(n_beams), cand_of_spot(n_spots);
  for (int j = 0; j < n_spots; ++j)
  {
    if (!spots_px[j].allFinite())
      continue;
    for (int i = 0; i < n_beams; ++i)
    {
      const double d2 = segmentDistance2(spots_px[j], segments_[i].near_px, segments_[i].far_px);
      if (d2 <= gate2)
      {
        cand_of_beam[i].push_back(static_cast<int>(candidates.size()));
        cand_of_spot[j].push_back(static_cast<int>(candidates.size()));
        candidates.push_back({i, j, d2 / gate2});
      }
    }
  }

  // A beam is contested when it, or one of its candidate spots, has more
  // than one candidate, and it was settled with the surface prior (a pair
  // accepted on epipolar evidence alone stands on its own).
  std::vector<char> contested(n_beams, 0), proven(n_beams, 0);
  for (int i = 0; i < n_beams; ++i)
  {
    contested[i] = cand_of_beam[i].size() > 1;
    for (int k : cand_of_beam[i])
      contested[i] |= cand_of_spot[candidates[k].spot].size() > 1;
  }

  std::vector<int> beam_of_spot(n_spots, -1), spot_of_beam(n_beams, -1);
  std::vector<Eigen::Vector3d> accepted_point(n_beams, Eigen::Vector3d::Constant(kNaN));
  int ambiguous = 0;

  const auto triangulateCandidate = [&](int beam, int spot, Eigen::Vector3d* p) {
    return triangulatePixel(beam, spots_px[spot], p);
  };

  // Tracking prior. Where beam i's dot was last frame, moved by the median
  // shift of the pattern (the rig's jitter moves all dots nearly alike),
  // predicts where it is now within tracking_radius_px; depth changes move a
  // dot along its own segment by much less between frames. A beam whose only
  // nearby candidate is a spot near no other beam's prediction is settled
  // before anything else and is proven (the consistency check leaves it).
  std::vector<Eigen::Vector2d> track_px(n_beams, Eigen::Vector2d::Constant(kNaN));
  int tracked = -1;
  if (previous_px && static_cast<int>(previous_px->size()) == n_beams)
  {
    const double search = beam_pitch_px_ > 0.0 ? 0.5 * beam_pitch_px_ : 4.0 * params_.tracking_radius_px;
    std::vector<double> dx, dy;
    int with_prior = 0;
    for (int i = 0; i < n_beams; ++i)
    {
      const Eigen::Vector2d& q = (*previous_px)[i];
      if (!q.allFinite())
        continue;
      ++with_prior;
      int nearest = -1;
      double best = search;
      for (int k : cand_of_beam[i])
      {
        const double d = (spots_px[candidates[k].spot] - q).norm();
        if (d < best)
        {
          best = d;
          nearest = candidates[k].spot;
        }
      }
      if (nearest >= 0)
      {
        dx.push_back(spots_px[nearest].x() - q.x());
        dy.push_back(spots_px[nearest].y() - q.y());
      }
    }
    if (dx.size() >= 3)
    {
      const auto median = [](std::vector<double> v) {
        std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
        return v[v.size() / 2];
      };
      const Eigen::Vector2d shift(median(dx), median(dy));
      const double radius = params_.tracking_radius_px;
      // Then an affine map of the image (the rig's roll and change of scale
      // move dots differently across the image) fitted to the nearest
      // candidates within twice the radius of the shifted positions.
      Eigen::Matrix<double, 6, 6> ata = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> atb = Eigen::Matrix<double, 6, 1>::Zero();
      int fit_pairs = 0;
      for (int i = 0; i < n_beams; ++i)
      {
        const Eigen::Vector2d& q = (*previous_px)[i];
        if (!q.allFinite())
          continue;
        int nearest = -1, near = 0;
        for (int k : cand_of_beam[i])
          if ((spots_px[candidates[k].spot] - q - shift).norm() <= 2.0 * radius)
          {
            nearest = candidates[k].spot;
            ++near;
          }
        if (near != 1)
          continue;
        for (int axis = 0; axis < 2; ++axis)
        {
          Eigen::Matrix<double, 6, 1> a = Eigen::Matrix<double, 6, 1>::Zero();
          a(3 * axis) = q.x();
          a(3 * axis + 1) = q.y();
          a(3 * axis + 2) = 1.0;
          ata += a * a.transpose();
          atb += a * spots_px[nearest](axis);
        }
        ++fit_pairs;
      }
      Eigen::Matrix<double, 6, 1> affine;
      affine << 1.0, 0.0, shift.x(), 0.0, 1.0, shift.y();
      if (fit_pairs >= 6)
      {
        const Eigen::Matrix<double, 6, 1> x = ata.ldlt().solve(atb);
        if (x.allFinite())
          affine = x;
      }
      std::vector<int> near_spot(n_beams, -1), near_count(n_beams, 0), claims(n_spots, 0);
      for (int i = 0; i < n_beams; ++i)
      {
        const Eigen::Vector2d& q = (*previous_px)[i];
        if (!q.allFinite())
          continue;
        track_px[i] = Eigen::Vector2d(affine(0) * q.x() + affine(1) * q.y() + affine(2),
                                      affine(3) * q.x() + affine(4) * q.y() + affine(5));
        for (int k : cand_of_beam[i])
        {
          const int j = candidates[k].spot;
          if ((spots_px[j] - track_px[i]).norm() <= radius)
          {
            near_spot[i] = j;
            ++near_count[i];
            ++claims[j];
          }
        }
      }
      int unique = 0;
      for (int i = 0; i < n_beams; ++i)
        unique += near_count[i] == 1 && claims[near_spot[i]] == 1;
      if (unique >= 3 && 2 * unique >= with_prior)
      {
        tracked = 0;
        for (int i = 0; i < n_beams; ++i)
        {
          if (near_count[i] != 1 || claims[near_spot[i]] != 1)
            continue;
          Eigen::Vector3d p;
          if (!triangulateCandidate(i, near_spot[i], &p))
            continue;
          spot_of_beam[i] = near_spot[i];
          beam_of_spot[near_spot[i]] = i;
          accepted_point[i] = p;
          contested[i] = 0;
          ++tracked;
        }
      }
      else
      {
        track_px.assign(n_beams, Eigen::Vector2d::Constant(kNaN));
      }
    }
  }
  // A beam that had a dot last frame may only take a spot near its
  // prediction: a spurious spot on the segment of a dot that vanished this
  // frame lands at a depth of its own. Forbidden pairs are removed from the
  // candidate lists.
  if (tracked >= 0)
  {
    const auto far_from_track = [&](const Candidate& cand) {
      return track_px[cand.beam].allFinite() &&
             (spots_px[cand.spot] - track_px[cand.beam]).norm() > params_.tracking_radius_px;
    };
    for (auto& list : cand_of_beam)
      list.erase(std::remove_if(list.begin(), list.end(), [&](int k) { return far_from_track(candidates[k]); }),
                 list.end());
    for (auto& list : cand_of_spot)
      list.erase(std::remove_if(list.begin(), list.end(), [&](int k) { return far_from_track(candidates[k]); }),
                 list.end());
  }
  if (tracked_out)
    *tracked_out = tracked;

  const auto onOneGridLine = [&](const std::vector<int>& beams) {
    const int cols = projector_.cols;
    bool same_row = true, same_col = true;
    for (int i : beams)
    {
      same_row &= i / cols == beams[0] / cols;
      same_col &= i % cols == beams[0] % cols;
    }
    return beams.size() >= 2 && (same_row || same_col);
  };
  const int max_passes = 4 + 2 * (projector_.rows + projector_.cols);
  // Only interpolation between accepted neighbours on opposite sides is
  // used: extrapolating from one side favours whatever reading puts the spot
  // on that side's surface, which an occluding edge turns into a wrong beam
  // (measured: 6 wrong in 60 axis-aligned frames when allowed).
  bool one_sided = false;
  for (int pass = 0; pass < max_passes; ++pass)
  {
    const bool use_prior = pass > 0 && params_.prediction_tolerance_px > 0.0;
    // Prior pixel of every unaccepted beam from its accepted neighbours.
    std::vector<Eigen::Vector2d> prior(n_beams, Eigen::Vector2d::Constant(kNaN));
    if (use_prior)
    {
      for (int i = 0; i < n_beams; ++i)
      {
        if (spot_of_beam[i] >= 0 || cand_of_beam[i].empty())
          continue;
        std::vector<Eigen::Vector3d> support;
        const int level = supportOf(i, spot_of_beam, accepted_point, &support);
        if (level < 2 && !(level == 1 && one_sided))
          continue;
        Eigen::Vector2d px;
        if (predictPixel(i, support, &px))
          prior[i] = px;
      }
    }

    // Connected components of the candidate graph over what is still open.
    std::vector<int> beam_comp(n_beams, -1), spot_comp(n_spots, -1);
    std::vector<std::pair<std::vector<int>, std::vector<int>>> components;
    for (int seed = 0; seed < n_beams; ++seed)
    {
      if (beam_comp[seed] >= 0 || spot_of_beam[seed] >= 0)
        continue;
      bool has_edge = false;
      for (int k : cand_of_beam[seed])
        has_edge |= beam_of_spot[candidates[k].spot] < 0;
      if (!has_edge)
        continue;
      const int id = static_cast<int>(components.size());
      components.emplace_back();
      std::vector<std::pair<bool, int>> stack{{true, seed}};
      beam_comp[seed] = id;
      while (!stack.empty())
      {
        const auto [is_beam, idx] = stack.back();
        stack.pop_back();
        if (is_beam)
        {
          components[id].first.push_back(idx);
          for (int k : cand_of_beam[idx])
          {
            const int s = candidates[k].spot;
            if (beam_of_spot[s] < 0 && spot_comp[s] < 0)
            {
              spot_comp[s] = id;
              stack.push_back({false, s});
            }
          }
        }
        else
        {
          components[id].second.push_back(idx);
          for (int k : cand_of_spot[idx])
          {
            const int b = candidates[k].beam;
            if (spot_of_beam[b] < 0 && beam_comp[b] < 0)
            {
              beam_comp[b] = id;
              stack.push_back({true, b});
            }
          }
        }
      }
    }

    const std::vector<int> state_before = spot_of_beam;
    int newly_accepted = 0;
    int pass_ambiguous = 0;
    std::vector<std::pair<std::vector<int>, std::vector<int>>> line_components;
    for (const auto& comp : components)
    {
      const std::vector<int>& beams = comp.first;
      const std::vector<int>& spots = comp.second;
      const int nb = static_cast<int>(beams.size());
      const int ns = static_cast<int>(spots.size());
      const int n = nb + ns;
      if (pass == 0 && onOneGridLine(beams))
      {
        // Beams of one grid line that share candidates: their segments
        // overlap along one epipolar line, where order-free matching proves
        // little; the lines are read jointly below.
        line_components.push_back(comp);
        continue;
      }
      // Rows: beams then one "spurious" row per spot; columns: spots then
      // one "no spot" column per beam.
      std::vector<double> cost(static_cast<size_t>(n) * n, kForbidden);
      std::vector<int> local_spot(n_spots, -1);
      for (int b = 0; b < ns; ++b)
        local_spot[spots[b]] = b;
      for (int a = 0; a < nb; ++a)
      {
        const int i = beams[a];
        for (int k : cand_of_beam[i])
        {
          const int b = local_spot[candidates[k].spot];
          if (b < 0)
            continue;
          double c = candidates[k].cost;
          if (use_prior && prior[i].allFinite())
          {
            // Distance along the segment from the predicted position.
            const double e = (spots_px[candidates[k].spot] - prior[i]).norm() / params_.prediction_tolerance_px;
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
      std::vector<int> col_of_row;
      const double best = solveAssignment(cost, n, &col_of_row);
      int component_ambiguous = 0;
      for (int a = 0; a < nb; ++a)
      {
        const int b = col_of_row[a];
        if (b >= ns || cost[a * n + b] >= kForbidden)
          continue;
        // The pair stands only if every assignment without it is clearly worse.
        std::vector<double> alt = cost;
        alt[a * n + b] = kForbidden;
        std::vector<int> alt_cols;
        const double alt_best = solveAssignment(alt, n, &alt_cols);
        // After pass 0 the prior is the evidence: a beam without one waits
        // (its rivals' priors alone could make it look unique).
        if (alt_best - best >= params_.ambiguity_margin && (!use_prior || prior[beams[a]].allFinite()))
        {
          const int i = beams[a], j = spots[b];
          Eigen::Vector3d p;
          if (triangulateCandidate(i, j, &p))
          {
            contested[i] = contested[i] && use_prior;
            spot_of_beam[i] = j;
            beam_of_spot[j] = i;
            accepted_point[i] = p;
            ++newly_accepted;
          }
        }
        else
        {
          ++component_ambiguous;
        }
      }
      pass_ambiguous += component_ambiguous;
    }
    if (pass == 0 && !line_components.empty())
    {
      // Order-free matching cannot tell apart beams sharing an epipolar line
      // (rows parallel to the baseline): read those lines jointly.
      newly_accepted +=
          resolveLines(line_components, spots_px, &spot_of_beam, &beam_of_spot, &accepted_point, &proven);
    }
    ambiguous = pass_ambiguous;
    if (params_.prediction_tolerance_px > 0.0)
      rejectInconsistent(spots_px, contested, proven, &spot_of_beam, &beam_of_spot, &accepted_point);
    // Progress is judged on the state after the consistency check: a pair
    // accepted and dropped again in every pass is no progress (it made the
    // loop run to max_passes: 2 ms per frame on the axis-aligned grid).
    const bool progressed = spot_of_beam != state_before;
    if (!progressed && (pass > 0 || params_.prediction_tolerance_px <= 0.0))
    {
      if (one_sided)
        break;
      one_sided = true;
    }
    else if (pass > 0)
      one_sided = false;
  }
  if (ambiguous_out)
    *ambiguous_out = ambiguous;
  return beam_of_spot;
}

TriangulationResult Triangulator::process(const Spots& spots) const
{
  return process(spots, nullptr);
}

TriangulationResult Triangulator::process(const Spots& spots, const TriangulationResult* previous) const
{
  const int n_beams = projector_.beamCount();
  TriangulationResult res;
  res.points.assign(n_beams, Eigen::Vector3d::Constant(kNaN));
  res.ray_gap.assign(n_beams, kNaN);
  res.intensity.assign(n_beams, 0.0f);
  res.spot_of_beam.assign(n_beams, -1);
  res.beam_of_spot.assign(spots.size(), -1);

  std::vector<Eigen::Vector2d> undistorted(spots.size());
  for (size_t j = 0; j < spots.size(); ++j)
  {
    undistorted[j] = undistortPixel(spots[j].x, spots[j].y);
    if (!undistorted[j].allFinite())
      ++res.dropped_nan;
  }

  std::vector<int> beam_of_spot(spots.size(), -1);
  if (params_.assignment == BeamAssignment::kSort)
  {
    Spots finite;
    std::vector<int> index;
    for (size_t j = 0; j < spots.size(); ++j)
    {
      if (undistorted[j].allFinite())
      {
        finite.push_back(spots[j]);
        index.push_back(static_cast<int>(j));
      }
    }
    const std::vector<int> order = rowSortOrder(finite, projector_.cols);
    for (size_t k = 0; k < order.size() && static_cast<int>(k) < n_beams; ++k)
      beam_of_spot[index[order[k]]] = static_cast<int>(k);
  }
  else
  {
    std::vector<Eigen::Vector2d> previous_px;
    if (previous && static_cast<int>(previous->points.size()) == n_beams)
    {
      previous_px.assign(n_beams, Eigen::Vector2d::Constant(kNaN));
      for (int i = 0; i < n_beams; ++i)
        if (previous->points[i].allFinite() && previous->points[i].z() > 0.0)
          previous_px[i] = projectUndistorted(previous->points[i]);
    }
    beam_of_spot = assignEpipolar(undistorted, &res.ambiguous);
    if (!previous_px.empty())
    {
      // The prior and the single frame can each be wrong where the other is
      // right. On a grid whose rows are parallel to the baseline, a depth
      // change of one beam pitch of disparity between two frames makes the
      // pattern look unmoved, each dot where its row neighbour was: the
      // prior then reads every row shifted by a column, which the single
      // frame (seeing the rows' ends) does not. Conversely the single frame
      // may read an object's dots shifted along their rows where the prior
      // does not. A spot the two give to different beams is given to none;
      // when that happens to more than max(2, half the spots they agree
      // on), only the pairs both agree on are kept and the prior counts as
      // not used.
      int ambiguous = 0, tracked = -1;
      const std::vector<int> with_prior = assignEpipolar(undistorted, &ambiguous, &previous_px, &tracked);
      if (tracked >= 0)
      {
        int agree = 0, disagree = 0;
        for (size_t j = 0; j < spots.size(); ++j)
          if (beam_of_spot[j] >= 0 && with_prior[j] >= 0)
            (beam_of_spot[j] == with_prior[j] ? agree : disagree) += 1;
        const bool trusted = disagree <= std::max(2, agree / 2);
        for (size_t j = 0; j < spots.size(); ++j)
        {
          // A beam without a prior gets only what the single frame proves.
          const bool unprimed = with_prior[j] >= 0 && !previous_px[with_prior[j]].allFinite();
          const bool conflict = (beam_of_spot[j] >= 0 && with_prior[j] >= 0 && beam_of_spot[j] != with_prior[j]) ||
                                (unprimed && beam_of_spot[j] != with_prior[j]);
          if (conflict || (!trusted && beam_of_spot[j] != with_prior[j]))
            beam_of_spot[j] = -1;
          else if (trusted)
            beam_of_spot[j] = with_prior[j];
        }
        if (trusted)
        {
          res.ambiguous = ambiguous;
          res.tracked = tracked;
        }
      }
    }
  }

  double gap_sum = 0.0;
  for (size_t j = 0; j < spots.size(); ++j)
  {
    const int i = beam_of_spot[j];
    if (i < 0)
    {
      ++res.unassigned_spots;
      continue;
    }
    const Eigen::Vector3d ray((undistorted[j].x() - camera_.cx) / camera_.fx,
                              (undistorted[j].y() - camera_.cy) / camera_.fy, 1.0);
    Eigen::Vector3d p;
    double gap = 0.0;
    if (!triangulateBeam(ray, projector_.beams[i], &p, &gap) || !(gap <= params_.max_ray_gap))
    {
      ++res.rejected_gap;
      continue;
    }
    if (!(p.z() >= params_.min_depth && p.z() <= params_.max_depth))
    {
      ++res.rejected_depth;
      continue;
    }
    res.points[i] = p;
    res.ray_gap[i] = gap;
    res.intensity[i] = spots[j].intensity;
    res.spot_of_beam[i] = static_cast<int>(j);
    res.beam_of_spot[j] = i;
    ++res.valid_points;
    gap_sum += gap;
  }
  res.mean_ray_gap = res.valid_points > 0 ? gap_sum / res.valid_points : 0.0;
  return res;
}

}  // namespace structured_light_stabilizer
