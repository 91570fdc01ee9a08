#include "structured_light_stabilizer/pose/beam_surface.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

// Catmull-Rom weights and their derivatives for the stencil (-1, 0, 1, 2).
void catmullRom(double s, double w[4], double dw[4])
{
  const double s2 = s * s, s3 = s2 * s;
  w[0] = 0.5 * (-s + 2.0 * s2 - s3);
  w[1] = 0.5 * (2.0 - 5.0 * s2 + 3.0 * s3);
  w[2] = 0.5 * (s + 4.0 * s2 - 3.0 * s3);
  w[3] = 0.5 * (-s2 + s3);
  dw[0] = 0.5 * (-1.0 + 4.0 * s - 3.0 * s2);
  dw[1] = 0.5 * (-10.0 * s + 9.0 * s2);
  dw[2] = 0.5 * (1.0 + 8.0 * s - 9.0 * s2);
  dw[3] = 0.5 * (-2.0 * s + 3.0 * s2);
}

// The beam map being built on, with the neighbourhood tests of the cells.
struct BeamGrid
{
  int rows;
  int cols;
  const std::vector<Eigen::Vector3d>& points;
  double max_edge = 0.0;

  bool ok(int r, int c) const { return r >= 0 && c >= 0 && r < rows && c < cols && isUsablePoint(P(r, c)); }
  const Eigen::Vector3d& P(int r, int c) const { return points[r * cols + c]; }
  // Both points present and no depth jump between them.
  bool linked(int r0, int c0, int r1, int c1) const
  {
    return ok(r0, c0) && ok(r1, c1) && (P(r0, c0) - P(r1, c1)).norm() <= max_edge;
  }

  // Lengths of the edges between neighbouring present points, row by row.
  std::vector<double> edgeLengths() const
  {
    std::vector<double> edges;
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c)
      {
        if (ok(r, c) && ok(r, c + 1))
          edges.push_back((P(r, c) - P(r, c + 1)).norm());
        if (ok(r, c) && ok(r + 1, c))
          edges.push_back((P(r, c) - P(r + 1, c)).norm());
      }
    return edges;
  }

  // The 4x4 control points of cell (r, c), false when the cell does not exist.
  bool cellStencil(int r, int c, std::array<Eigen::Vector3d, 16>* K) const;
};

bool BeamGrid::cellStencil(int r, int c, std::array<Eigen::Vector3d, 16>* K) const
{
  if (!linked(r, c, r, c + 1) || !linked(r + 1, c, r + 1, c + 1) || !linked(r, c, r + 1, c) ||
      !linked(r, c + 1, r + 1, c + 1))
    return false;
  // Stencil index (i, j) <-> grid point (r - 1 + i, c - 1 + j).
  auto at = [&](int i, int j) -> Eigen::Vector3d& { return (*K)[i * 4 + j]; };
  for (int i = 1; i <= 2; ++i)
    for (int j = 1; j <= 2; ++j)
      at(i, j) = P(r - 1 + i, c - 1 + j);
  // Edge stencil points: the real neighbour when it continues the surface,
  // otherwise a linear extrapolation of the cell.
  for (int j = 1; j <= 2; ++j)
  {
    const int cc = c - 1 + j;
    at(0, j) = linked(r - 1, cc, r, cc) ? P(r - 1, cc) : Eigen::Vector3d(2.0 * at(1, j) - at(2, j));
    at(3, j) = linked(r + 2, cc, r + 1, cc) ? P(r + 2, cc) : Eigen::Vector3d(2.0 * at(2, j) - at(1, j));
  }
  for (int i = 1; i <= 2; ++i)
  {
    const int rr = r - 1 + i;
    at(i, 0) = linked(rr, c - 1, rr, c) ? P(rr, c - 1) : Eigen::Vector3d(2.0 * at(i, 1) - at(i, 2));
    at(i, 3) = linked(rr, c + 2, rr, c + 1) ? P(rr, c + 2) : Eigen::Vector3d(2.0 * at(i, 2) - at(i, 1));
  }
  // Corners: the real point, or the bilinear extrapolation of its neighbours.
  const int ci[2] = {0, 3}, inner[2] = {1, 2};
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b)
    {
      const int i = ci[a], j = ci[b], ii = inner[a], jj = inner[b];
      const int gr = r - 1 + i, gc = c - 1 + j;
      at(i, j) =
          linked(gr, gc, r - 1 + ii, c - 1 + jj) ? P(gr, gc) : Eigen::Vector3d(at(i, jj) + at(ii, j) - at(ii, jj));
    }
  return true;
}

}  // namespace

void BeamSurface::build(int rows, int cols, const std::vector<Eigen::Vector3d>& points, double max_edge_ratio)
{
  rows_ = rows;
  cols_ = cols;
  valid_cells_ = 0;
  median_edge_ = 0.0;
  control_.clear();
  cell_ok_.clear();
  points_ = points;
  if (rows < 2 || cols < 2 || static_cast<int>(points.size()) != rows * cols)
  {
    rows_ = cols_ = 0;
    return;
  }
  BeamGrid grid{rows, cols, points};
  const std::vector<double> edges = grid.edgeLengths();
  if (edges.empty())
    return;
  median_edge_ = detail::median(edges);
  grid.max_edge = max_edge_ratio * median_edge_;

  const int cell_rows = rows - 1, cell_cols = cols - 1;
  control_.resize(static_cast<size_t>(cell_rows) * cell_cols);
  cell_ok_.assign(static_cast<size_t>(cell_rows) * cell_cols, 0);
  for (int r = 0; r < cell_rows; ++r)
    for (int c = 0; c < cell_cols; ++c)
      if (grid.cellStencil(r, c, &control_[r * cell_cols + c]))
      {
        cell_ok_[r * cell_cols + c] = 1;
        ++valid_cells_;
      }
}

bool BeamSurface::cellValid(int r, int c) const
{
  return r >= 0 && c >= 0 && r < rows_ - 1 && c < cols_ - 1 && cell_ok_[r * (cols_ - 1) + c];
}

template <typename Distance>
int BeamSurface::nearestPoint(Distance distance) const
{
  int nearest = -1;
  double best = std::numeric_limits<double>::infinity();
  for (int i = 0; i < rows_ * cols_; ++i)
  {
    if (!isUsablePoint(points_[i]))
      continue;
    const double d = distance(points_[i]);
    if (d < best)
    {
      best = d;
      nearest = i;
    }
  }
  return nearest;
}

bool BeamSurface::evaluate(double u, double v, Eigen::Vector3d* s, Eigen::Vector3d* s_u, Eigen::Vector3d* s_v) const
{
  if (valid_cells_ == 0 || !std::isfinite(u) || !std::isfinite(v))
    return false;
  const double eps = 1e-9;
  if (u < -eps || v < -eps || u > rows_ - 1 + eps || v > cols_ - 1 + eps)
    return false;
  const int r = std::min(std::max(static_cast<int>(std::floor(u)), 0), rows_ - 2);
  const int c = std::min(std::max(static_cast<int>(std::floor(v)), 0), cols_ - 2);
  if (!cellValid(r, c))
    return false;
  double wr[4], dwr[4], wc[4], dwc[4];
  catmullRom(u - r, wr, dwr);
  catmullRom(v - c, wc, dwc);
  const std::array<Eigen::Vector3d, 16>& K = control_[r * (cols_ - 1) + c];
  Eigen::Vector3d S = Eigen::Vector3d::Zero(), Su = Eigen::Vector3d::Zero(), Sv = Eigen::Vector3d::Zero();
  for (int i = 0; i < 4; ++i)
  {
    Eigen::Vector3d row = Eigen::Vector3d::Zero(), drow = Eigen::Vector3d::Zero();
    for (int j = 0; j < 4; ++j)
    {
      row += wc[j] * K[i * 4 + j];
      drow += dwc[j] * K[i * 4 + j];
    }
    S += wr[i] * row;
    Su += dwr[i] * row;
    Sv += wr[i] * drow;
  }
  *s = S;
  if (s_u)
    *s_u = Su;
  if (s_v)
    *s_v = Sv;
  return true;
}

bool BeamSurface::closestPoint(const Eigen::Vector3d& x, Eigen::Vector2d* uv, Eigen::Vector3d* foot,
                               Eigen::Vector3d* normal) const
{
  if (valid_cells_ == 0)
    return false;
  Eigen::Vector2d p = *uv;
  if (!p.allFinite())
  {
    const int i = nearestPoint([&](const Eigen::Vector3d& q) { return (q - x).squaredNorm(); });
    if (i < 0)
      return false;
    p = Eigen::Vector2d(i / cols_, i % cols_);
  }
  Eigen::Vector3d S, Su, Sv;
  bool pushed_out = false;
  for (int it = 0; it < 12; ++it)
  {
    if (!evaluate(p.x(), p.y(), &S, &Su, &Sv))
      return false;
    Eigen::Matrix<double, 3, 2> J;
    J << Su, Sv;
    const Eigen::Matrix2d A = J.transpose() * J;
    const double det = A.determinant();
    if (!(det > 1e-30))
      return false;
    Eigen::Vector2d step = A.inverse() * (J.transpose() * (x - S));
    const double len = step.norm();
    if (len > 1.0)
      step /= len;  // at most one cell per step: the surface is only locally quadratic
    Eigen::Vector2d next = p + step;
    pushed_out = false;
    if (next.x() < 0.0 || next.y() < 0.0 || next.x() > rows_ - 1 || next.y() > cols_ - 1)
    {
      next.x() = std::min(std::max(next.x(), 0.0), static_cast<double>(rows_ - 1));
      next.y() = std::min(std::max(next.y(), 0.0), static_cast<double>(cols_ - 1));
      pushed_out = true;
    }
    p = next;
    if (len < 1e-7)
      break;
  }
  // A foot clamped at the border is not a perpendicular foot: the point lies
  // beyond the mapped part of the rock.
  if (pushed_out || !evaluate(p.x(), p.y(), &S, &Su, &Sv))
    return false;
  Eigen::Vector3d n = Su.cross(Sv);
  const double nn = n.norm();
  if (!(nn > 0.0))
    return false;
  n /= nn;
  if (n.dot(S) > 0.0)
    n = -n;
  *uv = p;
  *foot = S;
  *normal = n;
  return true;
}

bool BeamSurface::intersectRay(const Eigen::Vector3d& direction, Eigen::Vector2d* uv, Eigen::Vector3d* hit) const
{
  if (valid_cells_ == 0)
    return false;
  const Eigen::Vector3d d = direction.normalized();
  const Eigen::Matrix3d Pperp = Eigen::Matrix3d::Identity() - d * d.transpose();
  Eigen::Vector2d p = *uv;
  if (!p.allFinite())
  {
    // Nearest to the ray; the search starts at the centre of a cell that has that point as a corner.
    const int i = nearestPoint([&](const Eigen::Vector3d& q) { return (Pperp * q).squaredNorm(); });
    if (i < 0)
      return false;
    p = Eigen::Vector2d(std::min(i / cols_, rows_ - 2) + 0.5, std::min(i % cols_, cols_ - 2) + 0.5);
  }
  Eigen::Vector3d S, Su, Sv;
  for (int it = 0; it < 15; ++it)
  {
    if (!evaluate(p.x(), p.y(), &S, &Su, &Sv))
      return false;
    Eigen::Matrix<double, 3, 2> J;
    J << Pperp * Su, Pperp * Sv;
    const Eigen::Matrix2d A = J.transpose() * J;
    if (!(A.determinant() > 1e-30))
      return false;
    Eigen::Vector2d step = -A.inverse() * (J.transpose() * (Pperp * S));
    const double len = step.norm();
    if (len > 1.0)
      step /= len;
    p += step;
    if (p.x() < 0.0 || p.y() < 0.0 || p.x() > rows_ - 1 || p.y() > cols_ - 1)
      return false;
    if (len < 1e-8)
      break;
  }
  if (!evaluate(p.x(), p.y(), &S))
    return false;
  // The ray must actually pass through the surface, not just near it.
  if ((Pperp * S).norm() > 1e-6 * S.norm() || S.dot(d) <= 0.0)
    return false;
  *uv = p;
  *hit = S;
  return true;
}

}  // namespace structured_light_stabilizer
