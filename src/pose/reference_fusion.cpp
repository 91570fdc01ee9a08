#include "pose/reference_fusion.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

namespace structured_light_stabilizer
{
namespace fusion
{

namespace
{

constexpr int kMaxNodesPerSide = 120;

// Catmull-Rom weights of the stencil (-1, 0, 1, 2) at fraction s (as BeamSurface).
void catmullRom(double s, double w[4])
{
  const double s2 = s * s, s3 = s2 * s;
  w[0] = 0.5 * (-s + 2.0 * s2 - s3);
  w[1] = 0.5 * (2.0 - 5.0 * s2 + 3.0 * s3);
  w[2] = 0.5 * (s + 4.0 * s2 - 3.0 * s3);
  w[3] = 0.5 * (-s2 + s3);
}

// The grid of rays: node (r, c) on the ray (a0 + c h, b0 + r h, 1).
struct RayGrid
{
  double a0 = 0.0, b0 = 0.0, h = 1.0;
  int rows = 0, cols = 0;
  int node(int r, int c) const { return r * cols + c; }
};

}  // namespace

bool fitSurface(const std::vector<Eigen::Vector3d>& points, const SurfaceFit& fit, BeamSurface* surface)
{
  std::vector<Eigen::Vector3d> used;
  double amin = std::numeric_limits<double>::infinity(), amax = -amin, bmin = amin, bmax = -amin, depth = 0.0;
  for (const Eigen::Vector3d& p : points)
    if (isUsablePoint(p))
    {
      used.push_back(p);
      const double a = p.x() / p.z(), b = p.y() / p.z();
      amin = std::min(amin, a);
      amax = std::max(amax, a);
      bmin = std::min(bmin, b);
      bmax = std::max(bmax, b);
      depth += p.z();
    }
  if (used.size() < 16 || !(fit.spacing_m > 0.0) || fit.refine < 1)
    return false;
  depth /= static_cast<double>(used.size());
  RayGrid g;
  g.h = fit.spacing_m / depth / fit.refine;
  g.a0 = amin;
  g.b0 = bmin;
  g.cols = static_cast<int>(std::ceil((amax - amin) / g.h)) + 1;
  g.rows = static_cast<int>(std::ceil((bmax - bmin) / g.h)) + 1;
  if (g.rows < 2 || g.cols < 2 || g.rows > kMaxNodesPerSide || g.cols > kMaxNodesPerSide)
    return false;
  const int n = g.rows * g.cols;

  // Normal equations: the points' depths, then the curvature prior.
  std::vector<Eigen::Triplet<double>> terms;
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
  std::vector<int> support(n, 0);
  const double wd = 1.0 / (fit.noise_m * fit.noise_m);
  for (const Eigen::Vector3d& p : used)
  {
    const double u = (p.y() / p.z() - g.b0) / g.h, v = (p.x() / p.z() - g.a0) / g.h;
    const int r = std::min(static_cast<int>(u), g.rows - 2), c = std::min(static_cast<int>(v), g.cols - 2);
    double wr[4], wc[4];
    catmullRom(u - r, wr);
    catmullRom(v - c, wc);
    int idx[16];
    double w[16];
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j)
      {
        const int rr = std::min(std::max(r - 1 + i, 0), g.rows - 1), cc = std::min(std::max(c - 1 + j, 0), g.cols - 1);
        idx[i * 4 + j] = g.node(rr, cc);
        w[i * 4 + j] = wr[i] * wc[j];
      }
    for (int k = 0; k < 16; ++k)
    {
      rhs[idx[k]] += wd * w[k] * p.z();
      for (int l = 0; l < 16; ++l)
        terms.emplace_back(idx[k], idx[l], wd * w[k] * w[l]);
    }
    for (int rr = std::max(0, static_cast<int>(std::floor(u - 1.5))); rr <= std::min(g.rows - 1, int(u + 1.5)); ++rr)
      for (int cc = std::max(0, static_cast<int>(std::floor(v - 1.5))); cc <= std::min(g.cols - 1, int(v + 1.5)); ++cc)
        ++support[g.node(rr, cc)];
  }
  const double wc2 = 1.0 / (fit.curvature_m * fit.curvature_m);
  auto secondDifference = [&](int a, int b, int c)
  {
    const int idx[3] = {a, b, c};
    const double w[3] = {1.0, -2.0, 1.0};
    for (int k = 0; k < 3; ++k)
      for (int l = 0; l < 3; ++l)
        terms.emplace_back(idx[k], idx[l], wc2 * w[k] * w[l]);
  };
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
    {
      if (c + 2 < g.cols)
        secondDifference(g.node(r, c), g.node(r, c + 1), g.node(r, c + 2));
      if (r + 2 < g.rows)
        secondDifference(g.node(r, c), g.node(r + 1, c), g.node(r + 2, c));
    }
  // A faint pull towards the mean depth keeps nodes far from every point defined.
  for (int k = 0; k < n; ++k)
  {
    terms.emplace_back(k, k, 1e-6 * wc2);
    rhs[k] += 1e-6 * wc2 * depth;
  }
  Eigen::SparseMatrix<double> A(n, n);
  A.setFromTriplets(terms.begin(), terms.end());
  const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(A);
  if (solver.info() != Eigen::Success)
    return false;
  const Eigen::VectorXd z = solver.solve(rhs);
  if (solver.info() != Eigen::Success || !z.allFinite())
    return false;

  std::vector<Eigen::Vector3d> map(n, Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  for (int r = 0; r < g.rows; ++r)
    for (int c = 0; c < g.cols; ++c)
      if (support[g.node(r, c)] > 0 && z[g.node(r, c)] > 0.0)
        map[g.node(r, c)] = z[g.node(r, c)] * Eigen::Vector3d(g.a0 + c * g.h, g.b0 + r * g.h, 1.0);
  BeamSurface fitted;
  fitted.build(g.rows, g.cols, map, fit.max_edge_ratio);
  if (fitted.empty())
    return false;
  *surface = std::move(fitted);
  return true;
}

}  // namespace fusion
}  // namespace structured_light_stabilizer
