#include "structured_light_stabilizer/calibration/dot_grid.h"

#include <algorithm>
#include <cmath>
#include <deque>
#include <map>
#include <utility>

#include <Eigen/Dense>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

using Site = std::pair<int, int>;  // (row, col)

class GridGrower
{
public:
  GridGrower(const std::vector<Eigen::Vector2d>& pts, const DotGridParams& params) : pts_(pts), params_(params)
  {
    label_.assign(pts.size(), Site(0, 0));
    is_labelled_.assign(pts.size(), 0);
  }

  // Labels dot i as (0, 0) with steps from its neighbours; false when they
  // do not give two plausible grid steps.
  bool seedAt(int i, double pitch);
  void grow();
  // The spread of the labelled dots about their neighbours' fit sets a
  // tighter tolerance (a spurious spot at an empty site is then refused
  // unless it lies where a dot would be).
  void measureSpread();
  // Unlabels dots their labelled neighbours' affine fit contradicts; true if any.
  bool prune();
  DotGrid result() const;

private:
  bool predict(const Site& s, Eigen::Vector2d* p, double* step) const;
  int nearestFree(const Eigen::Vector2d& p, double radius) const;
  void assign(int i, const Site& s)
  {
    label_[i] = s;
    is_labelled_[i] = 1;
    at_[s] = i;
    queue_.push_back(i);
  }

  double tolerance(double step) const
  {
    const double t = params_.tolerance * step;
    return spread_px_ < 0.0 ? t : std::min(t, std::max(params_.min_tolerance_px, 6.0 * spread_px_));
  }

  const std::vector<Eigen::Vector2d>& pts_;
  DotGridParams params_;
  std::vector<Site> label_;
  std::vector<char> is_labelled_;
  std::map<Site, int> at_;
  std::deque<int> queue_;
  double spread_px_ = -1.0;  // < 0: not measured yet
  Eigen::Vector2d e_col_ = Eigen::Vector2d::Zero(), e_row_ = Eigen::Vector2d::Zero();
};

bool GridGrower::seedAt(int i, double pitch)
{
  const int n = static_cast<int>(pts_.size());
  Eigen::Vector2d ec = Eigen::Vector2d::Zero(), er = Eigen::Vector2d::Zero();
  double best_c = 0.0, best_r = 0.0;
  for (int j = 0; j < n; ++j)
  {
    const Eigen::Vector2d v = pts_[j] - pts_[i];
    const double len = v.norm();
    if (j == i || len < 0.7 * pitch || len > 1.35 * pitch)
      continue;
    // Axis of the step: along x (a column step) or along y (a row step).
    if (std::abs(v.x()) / len > best_c && std::abs(v.x()) > std::abs(v.y()))
    {
      best_c = std::abs(v.x()) / len;
      ec = v.x() > 0 ? v : Eigen::Vector2d(-v);
    }
    if (std::abs(v.y()) / len > best_r && std::abs(v.y()) > std::abs(v.x()))
    {
      best_r = std::abs(v.y()) / len;
      er = v.y() > 0 ? v : Eigen::Vector2d(-v);
    }
  }
  // Two steps of similar length, not far from perpendicular.
  if (best_c == 0.0 || best_r == 0.0 || std::abs(ec.normalized().dot(er.normalized())) > 0.5 ||
      std::max(ec.norm(), er.norm()) > 1.4 * std::min(ec.norm(), er.norm()))
    return false;
  e_col_ = ec;
  e_row_ = er;
  assign(i, Site(0, 0));
  return true;
}

// Where site s should be: an affine map (row, col) -> image fitted to the
// labelled dots within two sites of it; with fewer than three of them (not
// on one line), the seed's steps from the nearest labelled dot. *step is the
// local grid step (px).
bool GridGrower::predict(const Site& s, Eigen::Vector2d* p, double* step) const
{
  Eigen::Matrix3d N = Eigen::Matrix3d::Zero();
  Eigen::Matrix<double, 3, 2> b = Eigen::Matrix<double, 3, 2>::Zero();
  int count = 0, nearest = -1, nearest_d = 1000;
  for (int dr = -2; dr <= 2; ++dr)
    for (int dc = -2; dc <= 2; ++dc)
    {
      const auto it = at_.find(Site(s.first + dr, s.second + dc));
      if (it == at_.end() || (dr == 0 && dc == 0))
        continue;
      const Eigen::Vector3d x(s.second + dc, s.first + dr, 1.0);
      N += x * x.transpose();
      b += x * pts_[it->second].transpose();
      ++count;
      if (std::abs(dr) + std::abs(dc) < nearest_d)
      {
        nearest_d = std::abs(dr) + std::abs(dc);
        nearest = it->second;
      }
    }
  if (nearest < 0)
    return false;
  Eigen::FullPivLU<Eigen::Matrix3d> lu(N);
  if (count >= 3 && lu.rank() == 3)
  {
    const Eigen::Matrix<double, 3, 2> A = lu.solve(b);
    *p = A.transpose() * Eigen::Vector3d(s.second, s.first, 1.0);
    // Rows of A: the image step per column, per row, and the origin.
    *step = std::min(A.row(0).norm(), A.row(1).norm());
    return true;
  }
  const Site& from = label_[nearest];
  *p = pts_[nearest] + (s.second - from.second) * e_col_ + (s.first - from.first) * e_row_;
  *step = std::min(e_col_.norm(), e_row_.norm());
  return true;
}

int GridGrower::nearestFree(const Eigen::Vector2d& p, double radius) const
{
  int best = -1;
  double best_d = radius;
  for (size_t j = 0; j < pts_.size(); ++j)
  {
    const double d = (pts_[j] - p).norm();
    if (!is_labelled_[j] && d < best_d)
    {
      best_d = d;
      best = static_cast<int>(j);
    }
  }
  return best;
}

void GridGrower::grow()
{
  // Along the grid's axes first, then the diagonals (a dot whose four
  // neighbours are all missing is still reached).
  static const int dirs[8][2] = {{0, 1}, {0, -1}, {1, 0}, {-1, 0}, {1, 1}, {1, -1}, {-1, 1}, {-1, -1}};
  while (!queue_.empty())
  {
    const int i = queue_.front();
    queue_.pop_front();
    if (!is_labelled_[i])
      continue;
    for (const auto& d : dirs)
      for (int s = 1; s <= 2; ++s)
      {
        const Site site(label_[i].first + d[0] * s, label_[i].second + d[1] * s);
        if (at_.count(site))
          break;  // that way is known
        Eigen::Vector2d p;
        double step = 0.0;
        if (!predict(site, &p, &step))
          continue;
        const int j = nearestFree(p, tolerance(step));
        if (j >= 0)
        {
          assign(j, site);
          break;
        }
      }
  }
}

void GridGrower::measureSpread()
{
  std::vector<double> r;
  for (size_t i = 0; i < pts_.size(); ++i)
  {
    if (!is_labelled_[i])
      continue;
    at_.erase(label_[i]);
    Eigen::Vector2d p;
    double step = 0.0;
    if (predict(label_[i], &p, &step))
      r.push_back((p - pts_[i]).norm());
    at_[label_[i]] = static_cast<int>(i);
  }
  // Median of a 2-D distance = 1.18 sigma per axis.
  if (r.size() >= 8)
    spread_px_ = detail::median(r) / 1.18;
}

bool GridGrower::prune()
{
  bool changed = false;
  for (size_t i = 0; i < pts_.size(); ++i)
  {
    if (!is_labelled_[i])
      continue;
    at_.erase(label_[i]);  // leave-one-out
    Eigen::Vector2d p;
    double step = 0.0;
    const bool ok = predict(label_[i], &p, &step);
    if (ok && (p - pts_[i]).norm() > tolerance(step))
    {
      is_labelled_[i] = 0;
      changed = true;
      continue;
    }
    at_[label_[i]] = static_cast<int>(i);
  }
  for (size_t i = 0; i < pts_.size(); ++i)
    if (is_labelled_[i])
      queue_.push_back(static_cast<int>(i));
  return changed;
}

DotGrid GridGrower::result() const
{
  DotGrid g;
  const size_t n = pts_.size();
  g.labelled = is_labelled_;
  g.row.assign(n, 0);
  g.col.assign(n, 0);
  std::vector<double> steps;
  for (size_t i = 0; i < n; ++i)
  {
    if (!is_labelled_[i])
      continue;
    g.row[i] = label_[i].first;
    g.col[i] = label_[i].second;
    if (g.count == 0)
    {
      g.min_row = g.max_row = g.row[i];
      g.min_col = g.max_col = g.col[i];
    }
    g.min_row = std::min(g.min_row, g.row[i]);
    g.max_row = std::max(g.max_row, g.row[i]);
    g.min_col = std::min(g.min_col, g.col[i]);
    g.max_col = std::max(g.max_col, g.col[i]);
    ++g.count;
    for (const Site& s : {Site(label_[i].first, label_[i].second + 1), Site(label_[i].first + 1, label_[i].second)})
    {
      const auto it = at_.find(s);
      if (it != at_.end())
        steps.push_back((pts_[it->second] - pts_[i]).norm());
    }
  }
  g.pitch_px = detail::median(steps);
  return g;
}

}  // namespace

DotGrid labelDotGrid(const std::vector<Eigen::Vector2d>& points, const DotGridParams& params)
{
  std::vector<Eigen::Vector2d> pts;
  std::vector<int> index;  // finite points only
  for (size_t i = 0; i < points.size(); ++i)
    if (points[i].allFinite())
    {
      pts.push_back(points[i]);
      index.push_back(static_cast<int>(i));
    }
  DotGrid out;
  out.labelled.assign(points.size(), 0);
  out.row.assign(points.size(), 0);
  out.col.assign(points.size(), 0);
  if (pts.size() < 3)
    return out;
  // Seeds nearest the pattern's centre first; the labelling that reaches
  // the most dots is kept (a seed next to a spurious spot can take a wrong
  // step and stall).
  std::vector<double> nn(pts.size(), detail::kInf);
  Eigen::Vector2d centre = Eigen::Vector2d::Zero();
  for (size_t i = 0; i < pts.size(); ++i)
  {
    centre += pts[i] / static_cast<double>(pts.size());
    for (size_t j = 0; j < pts.size(); ++j)
      if (j != i)
        nn[i] = std::min(nn[i], (pts[j] - pts[i]).norm());
  }
  const double pitch = detail::median(nn);
  std::vector<int> order(pts.size());
  for (size_t i = 0; i < pts.size(); ++i)
    order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(),
            [&](int a, int b) { return (pts[a] - centre).squaredNorm() < (pts[b] - centre).squaredNorm(); });
  DotGrid g;
  int tried = 0;
  for (int i : order)
  {
    GridGrower grower(pts, params);
    if (!grower.seedAt(i, pitch))
      continue;
    grower.grow();
    grower.measureSpread();
    // A spot taken early from a poor prediction is contradicted once the
    // neighbourhood is complete; its site is then grown again.
    for (int pass = 0; pass < 3 && grower.prune(); ++pass)
      grower.grow();
    const DotGrid candidate = grower.result();
    if (candidate.count > g.count)
      g = candidate;
    if (++tried == 5 || g.count > 0.9 * pts.size())
      break;
  }
  out.min_row = g.min_row;
  out.max_row = g.max_row;
  out.min_col = g.min_col;
  out.max_col = g.max_col;
  out.count = g.count;
  out.pitch_px = g.pitch_px;
  for (size_t k = 0; k < pts.size(); ++k)
  {
    out.labelled[index[k]] = g.labelled[k];
    out.row[index[k]] = g.row[k];
    out.col[index[k]] = g.col[k];
  }
  return out;
}

}  // namespace structured_light_stabilizer
