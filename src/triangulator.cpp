#include "structured_light_stabilizer/triangulator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include <Eigen/Dense>

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

struct Candidate
{
  int beam;
  int spot;
  double cost;  // (distance / gate)^2, in [0, 1]
};

}  // namespace

std::string TriangulatorOptions::validate() const
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

std::vector<int> sortIntoRows(const Spots& spots, int cols)
{
  std::vector<int> order(spots.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return spots[a].y < spots[b].y; });
  if (cols <= 0)
    return order;
  for (size_t start = 0; start < order.size(); start += static_cast<size_t>(cols))
  {
    const auto end = order.begin() + static_cast<long>(std::min(order.size(), start + static_cast<size_t>(cols)));
    std::stable_sort(order.begin() + static_cast<long>(start), end,
                     [&](int a, int b) { return spots[a].x < spots[b].x; });
  }
  return order;
}

Triangulator::Triangulator(const CameraModel& camera, const ProjectorCalibration& projector,
                           const TriangulatorOptions& config)
  : camera_(camera), projector_(projector), config_(config)
{
  std::string why = camera_.validate();
  if (!why.empty())
    throw std::invalid_argument("camera model: " + why);
  why = projector_.validate();
  if (!why.empty())
    throw std::invalid_argument("projector calibration: " + why);
  why = config_.validate();
  if (!why.empty())
    throw std::invalid_argument("triangulator config: " + why);
  segments_.resize(projector_.beams.size());
  for (size_t i = 0; i < projector_.beams.size(); ++i)
  {
    const BeamRay& b = projector_.beams[i];
    // Parameterised by camera depth z: s = (z - o_z) / u_z (u_z > 0 is
    // guaranteed by validate()).
    const auto at_depth = [&](double z) { return b.pointAt((z - b.origin.z()) / b.direction.z()); };
    segments_[i].near_px = projectUndistorted(at_depth(config_.min_depth));
    segments_[i].far_px = projectUndistorted(at_depth(config_.max_depth));
  }
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
                                      const std::vector<char>& contested, std::vector<int>* spot_of_beam,
                                      std::vector<int>* beam_of_spot,
                                      std::vector<Eigen::Vector3d>* accepted_point) const
{
  // A dot is kept when it agrees with the surface of its accepted
  // neighbours: with the local plane through them, or with the depth of at
  // least two of them, which keeps the dots of
  // a small object in front of the rock. A spurious spot that happens to lie
  // on the segment of a beam whose dot is missing lands at a random depth
  // and fails both. Decisions use the state before this sweep.
  const double tol = config_.prediction_tolerance_px;
  const int rows = projector_.rows, cols = projector_.cols;
  std::vector<int> reject;
  for (int i = 0; i < projector_.beamCount(); ++i)
  {
    const int j = (*spot_of_beam)[i];
    if (j < 0)
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
      if ((have_plane && !confirmed) || (contested[i] && !confirmed))
        reject.push_back(i);
      continue;
    }
    Eigen::Vector2d px;
    if (predictPixel(i, support, &px) && (px - spots_px[j]).norm() <= tol)
      continue;
    const BeamRay& b = projector_.beams[i];
    int agree = 0;
    for (const Eigen::Vector3d& q : support)
    {
      const Eigen::Vector2d at_q = projectUndistorted(b.pointAt((q.z() - b.origin.z()) / b.direction.z()));
      agree += (at_q - spots_px[j]).norm() <= tol;
    }
    if (agree < 2)
      reject.push_back(i);
  }
  for (int i : reject)
  {
    (*beam_of_spot)[(*spot_of_beam)[i]] = -1;
    (*spot_of_beam)[i] = -1;
    (*accepted_point)[i] = Eigen::Vector3d::Constant(kNaN);
  }
}

std::vector<int> Triangulator::assignEpipolar(const std::vector<Eigen::Vector2d>& spots_px, int* ambiguous_out) const
{
  const int n_beams = projector_.beamCount();
  const int n_spots = static_cast<int>(spots_px.size());
  const double gate2 = config_.max_epipolar_distance_px * config_.max_epipolar_distance_px;

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
  std::vector<char> contested(n_beams, 0);
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
    const Eigen::Vector3d ray((spots_px[spot].x() - camera_.cx) / camera_.fx,
                              (spots_px[spot].y() - camera_.cy) / camera_.fy, 1.0);
    double gap = 0.0;
    return triangulateBeam(ray, projector_.beams[beam], p, &gap);
  };

  // Beams of one projector row (or column) share one epipolar line when the
  // rows are parallel to the baseline: any two of their dots can then be
  // swapped at no cost and the order-free assignment proves nothing. A
  // smooth surface keeps the dots in beam order, so the ordered reading
  // (minimum-cost order-preserving matching, by dynamic programming) is
  // accepted when every pair of it is unique by the margin among ordered
  // readings and the depths it gives are smooth along the line. A shifted
  // reading (a missing end dot) ties and is left to the surface prior.
  const auto acceptOrderedReading = [&](const std::vector<int>& comp_beams, const std::vector<int>& comp_spots,
                                        const std::vector<double>& cost, int n, int nb, int ns) -> int {
    const int cols = projector_.cols;
    if (comp_beams.size() < 2 || config_.prediction_tolerance_px <= 0.0)
      return 0;
    bool same_row = true, same_col = true;
    for (int i : comp_beams)
    {
      same_row &= i / cols == comp_beams[0] / cols;
      same_col &= i % cols == comp_beams[0] % cols;
    }
    if (!same_row && !same_col)
      return 0;
    // Local indices sorted along the grid line and along the image line.
    std::vector<int> ka(nb), la(ns);
    std::iota(ka.begin(), ka.end(), 0);
    std::iota(la.begin(), la.end(), 0);
    std::sort(ka.begin(), ka.end(), [&](int x, int y) { return comp_beams[x] < comp_beams[y]; });
    const auto mid = [&](int a) { return 0.5 * (segments_[comp_beams[a]].near_px + segments_[comp_beams[a]].far_px); };
    const Eigen::Vector2d dir = mid(ka.back()) - mid(ka.front());
    if (!(dir.norm() > 1e-6))
      return 0;
    std::sort(la.begin(), la.end(),
              [&](int x, int y) { return spots_px[comp_spots[x]].dot(dir) < spots_px[comp_spots[y]].dot(dir); });
    const int m = nb, q = ns;
    // D[k][l]: best cost of the first k beams and first l spots (in order).
    const auto solve = [&](int forbid_k, int forbid_l, std::vector<int>* match) {
      std::vector<double> D((m + 1) * (q + 1), 0.0);
      std::vector<char> how((m + 1) * (q + 1), 0);
      for (int k = 0; k <= m; ++k)
      {
        for (int l = 0; l <= q; ++l)
        {
          if (k == 0 && l == 0)
            continue;
          double best = std::numeric_limits<double>::infinity();
          char h = 0;
          if (k > 0 && D[(k - 1) * (q + 1) + l] + 1.0 < best)
          {
            best = D[(k - 1) * (q + 1) + l] + 1.0;
            h = 1;
          }
          if (l > 0 && D[k * (q + 1) + l - 1] + 1.0 < best)
          {
            best = D[k * (q + 1) + l - 1] + 1.0;
            h = 2;
          }
          if (k > 0 && l > 0 && !(k - 1 == forbid_k && l - 1 == forbid_l))
          {
            const double c = cost[ka[k - 1] * n + la[l - 1]];
            if (c < kForbidden && D[(k - 1) * (q + 1) + l - 1] + c < best)
            {
              best = D[(k - 1) * (q + 1) + l - 1] + c;
              h = 3;
            }
          }
          D[k * (q + 1) + l] = best;
          how[k * (q + 1) + l] = h;
        }
      }
      if (match)
      {
        match->assign(m, -1);
        for (int k = m, l = q; k > 0 || l > 0;)
        {
          const char h = how[k * (q + 1) + l];
          if (h == 3)
            (*match)[k - 1] = l - 1;
          k -= (h == 1 || h == 3);
          l -= (h == 2 || h == 3);
        }
      }
      return D[m * (q + 1) + q];
    };
    std::vector<int> match;
    const double best = solve(-1, -1, &match);
    int prev = -1;
    Eigen::Vector3d prev_point = Eigen::Vector3d::Zero();
    std::vector<std::pair<int, Eigen::Vector3d>> reading;
    for (int k = 0; k < m; ++k)
    {
      if (match[k] < 0)
        continue;
      if (solve(k, match[k], nullptr) - best < config_.ambiguity_margin)
        return 0;
      const int i = comp_beams[ka[k]], j = comp_spots[la[match[k]]];
      Eigen::Vector3d p;
      if (!triangulateCandidate(i, j, &p))
        return 0;
      if (prev >= 0)
      {
        // Where beam i would be at the depth of the previous dot of the line.
        const BeamRay& b = projector_.beams[i];
        const Eigen::Vector2d at_prev = projectUndistorted(b.pointAt((prev_point.z() - b.origin.z()) / b.direction.z()));
        if ((at_prev - spots_px[j]).norm() > 3.0 * config_.prediction_tolerance_px * (k - prev))
          return 0;
      }
      prev = k;
      prev_point = p;
      reading.push_back({k, p});
    }
    for (const auto& kp : reading)
    {
      const int i = comp_beams[ka[kp.first]], j = comp_spots[la[match[kp.first]]];
      spot_of_beam[i] = j;
      beam_of_spot[j] = i;
      accepted_point[i] = kp.second;
      contested[i] = 0;
    }
    return static_cast<int>(reading.size());
  };

  const int max_passes = 4 + 2 * (projector_.rows + projector_.cols);
  // Only interpolation between accepted neighbours on opposite sides is
  // used: extrapolating from one side favours whatever reading puts the spot
  // on that side's surface, which an occluding edge turns into a wrong beam
  // (measured: 6 wrong in 60 axis-aligned frames when allowed).
  bool one_sided = false;
  for (int pass = 0; pass < max_passes; ++pass)
  {
    const bool use_prior = pass > 0 && config_.prediction_tolerance_px > 0.0;
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

    int newly_accepted = 0;
    int pass_ambiguous = 0;
    for (const auto& comp : components)
    {
      const std::vector<int>& beams = comp.first;
      const std::vector<int>& spots = comp.second;
      const int nb = static_cast<int>(beams.size());
      const int ns = static_cast<int>(spots.size());
      const int n = nb + ns;
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
            const double e = (spots_px[candidates[k].spot] - prior[i]).norm() / config_.prediction_tolerance_px;
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
        if (alt_best - best >= config_.ambiguity_margin && (!use_prior || prior[beams[a]].allFinite()))
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
      if (component_ambiguous > 0 && pass == 0)
      {
        // Pairs accepted above stay; the ordered reading is tried on the
        // component only when none was (a partly accepted line is left to
        // the surface prior).
        bool untouched = true;
        for (int i : beams)
          untouched &= spot_of_beam[i] < 0;
        const int got = untouched ? acceptOrderedReading(beams, spots, cost, n, nb, ns) : 0;
        newly_accepted += got;
        if (got > 0)
          component_ambiguous = 0;
      }
      pass_ambiguous += component_ambiguous;
    }
    ambiguous = pass_ambiguous;
    if (config_.prediction_tolerance_px > 0.0)
      rejectInconsistent(spots_px, contested, &spot_of_beam, &beam_of_spot, &accepted_point);
    if (newly_accepted == 0 && (pass > 0 || config_.prediction_tolerance_px <= 0.0))
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
  if (config_.assignment == BeamAssignment::kSort)
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
    const std::vector<int> order = sortIntoRows(finite, projector_.cols);
    for (size_t k = 0; k < order.size() && static_cast<int>(k) < n_beams; ++k)
      beam_of_spot[index[order[k]]] = static_cast<int>(k);
  }
  else
  {
    beam_of_spot = assignEpipolar(undistorted, &res.ambiguous);
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
    if (!triangulateBeam(ray, projector_.beams[i], &p, &gap) || !(gap <= config_.max_ray_gap))
    {
      ++res.rejected_gap;
      continue;
    }
    if (!(p.z() >= config_.min_depth && p.z() <= config_.max_depth))
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
