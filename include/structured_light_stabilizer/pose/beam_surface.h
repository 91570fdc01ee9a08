// A smooth surface through an organised beam map, ROS-free: the model of the
// reference rock that PoseDelta registers against (docs/pose_delta.md).
//
// Contract: points are rows x cols (beam = r * cols + c), camera optical
// frame, metres; a missing beam is NaN (any non-finite point, or one not in
// front of the camera, counts as missing). Surface coordinates (u, v) are
// continuous beam-grid coordinates: u = row, v = column, the beam (r, c) at
// (r, c). Not thread-safe for concurrent build(); the const queries are.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace structured_light_stabilizer
{

// True for a beam-map point that is present: finite and in front of the camera.
inline bool isUsablePoint(const Eigen::Vector3d& p)
{
  return p.allFinite() && p.z() > 0.0;
}

// Catmull-Rom bicubic interpolation of the 3D points over the beam grid.
// Because the beams fan out smoothly, S(u, v) is a smooth parametrisation of
// the rock between the dots; the interpolant passes through every valid
// point and reproduces any quadratic surface exactly. A cell [r, r+1] x
// [c, c+1] exists when its four corners are valid and none of its edges
// jumps (occlusion); missing outer stencil points are linearly extrapolated.
class BeamSurface
{
public:
  // `points` has rows * cols entries (NaN = missing). `max_edge_ratio`: a cell
  // whose longest edge exceeds this multiple of the median edge is treated as
  // a depth discontinuity and dropped.
  void build(int rows, int cols, const std::vector<Eigen::Vector3d>& points, double max_edge_ratio = 3.0);

  int rows() const { return rows_; }
  int cols() const { return cols_; }
  int validCells() const { return valid_cells_; }
  bool empty() const { return valid_cells_ == 0; }
  // Median distance between neighbouring beam points (metres).
  double medianSpacing() const { return median_edge_; }
  // The map it was built on (rows * cols points).
  const std::vector<Eigen::Vector3d>& points() const { return points_; }

  // S(u, v) and its partial derivatives. False outside the valid cells.
  bool evaluate(double u, double v, Eigen::Vector3d* s, Eigen::Vector3d* s_u = nullptr,
                Eigen::Vector3d* s_v = nullptr) const;

  // Foot of the perpendicular from x onto the surface, by Gauss-Newton on
  // (u, v) starting at *uv (at the grid point nearest to x when *uv is NaN).
  // On success *uv, the foot point and the unit normal (pointing towards the
  // camera, -z side) are filled. Fails when the foot leaves the valid cells
  // or the iteration does not settle.
  bool closestPoint(const Eigen::Vector3d& x, Eigen::Vector2d* uv, Eigen::Vector3d* foot,
                    Eigen::Vector3d* normal) const;

  // Intersection of the camera ray through the origin along `direction` with
  // the surface. *uv is filled (the search starts at the nearest grid point
  // in the image when *uv is NaN).
  bool intersectRay(const Eigen::Vector3d& direction, Eigen::Vector2d* uv, Eigen::Vector3d* hit) const;

private:
  bool cellValid(int r, int c) const;
  // Index of the usable point with the smallest distance(point), -1 if none.
  template <typename Distance>
  int nearestPoint(Distance distance) const;

  int rows_ = 0;
  int cols_ = 0;
  int valid_cells_ = 0;
  double median_edge_ = 0.0;
  std::vector<Eigen::Vector3d> points_;
  // Per cell (rows-1) x (cols-1): the 4x4 Catmull-Rom control points, or
  // empty when the cell is invalid.
  std::vector<std::array<Eigen::Vector3d, 16>> control_;
  std::vector<uint8_t> cell_ok_;
};

}  // namespace structured_light_stabilizer
