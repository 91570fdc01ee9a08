#include "structured_light_stabilizer/control/image_stabilizer.h"

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <Eigen/SVD>
#include <opencv2/imgproc.hpp>

namespace structured_light_stabilizer
{

namespace
{

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Node positions along one image axis: every `step` pixels and the last pixel.
std::vector<int> nodePositions(int size, int step)
{
  std::vector<int> at;
  for (int x = 0; x < size - 1; x += step)
    at.push_back(x);
  at.push_back(size - 1);
  return at;
}

// For each pixel of an axis: the cell (between nodes i and i + 1) and the
// weight of node i + 1.
void cellsOf(const std::vector<int>& nodes, int size, std::vector<int>* cell, std::vector<float>* weight)
{
  cell->resize(size);
  weight->resize(size);
  size_t i = 0;
  for (int x = 0; x < size; ++x)
  {
    while (i + 2 < nodes.size() && x > nodes[i + 1])
      ++i;
    (*cell)[x] = static_cast<int>(i);
    const int span = std::max(1, nodes[i + 1] - nodes[i]);
    (*weight)[x] = static_cast<float>(x - nodes[i]) / static_cast<float>(span);
  }
}

}  // namespace

std::string ImageStabilizerParams::validate() const
{
  if (grid_step_px < 2 || grid_step_px > 64)
    return "grid_step_px must be in [2, 64]";
  return "";
}

bool ReferenceSurface::build(int rows, int cols, const std::vector<Eigen::Vector3d>& points, StabilizerSurface model,
                             std::string* why)
{
  built_ = false;
  model_ = model;
  if (rows <= 0 || cols <= 0 || static_cast<int>(points.size()) != rows * cols)
  {
    *why = "the map is not an organised rows x cols cloud";
    return false;
  }
  std::vector<Eigen::Vector3d> usable;
  for (const Eigen::Vector3d& p : points)
    if (isUsablePoint(p))
      usable.push_back(p);
  if (usable.size() < 3)
  {
    *why = "fewer than 3 points in the locked map";
    return false;
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : usable)
    mean += p / static_cast<double>(usable.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : usable)
    scatter += (p - mean) * (p - mean).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(scatter, Eigen::ComputeFullU);
  const Eigen::Vector3d s = svd.singularValues();
  if (!(s[1] > 1e-6 * s[0]))
  {
    *why = "the locked map's points lie on a line: no plane";
    return false;
  }
  normal_ = svd.matrixU().col(2);
  if (normal_.dot(mean) > 0.0)
    normal_ = -normal_;  // towards the camera
  offset_ = normal_.dot(mean);
  if (model == StabilizerSurface::kSurface)
    surface_.build(rows, cols, points);
  built_ = true;
  return true;
}

bool ReferenceSurface::intersect(const Eigen::Vector3d& direction, Eigen::Vector2d* uv, Eigen::Vector3d* point) const
{
  if (!built_)
    return false;
  if (model_ == StabilizerSurface::kSurface && !surface_.empty())
  {
    Eigen::Vector2d trial = *uv;
    Eigen::Vector3d hit;
    if (surface_.intersectRay(direction, &trial, &hit))
    {
      *uv = trial;
      *point = hit;
      return true;
    }
  }
  // The plane, where the surface has no cell (beyond the dots).
  const double along = normal_.dot(direction);
  if (!(std::abs(along) > 1e-12))
    return false;
  const double s = offset_ / along;
  if (!(s > 0.0))
    return false;
  *point = direction * s;
  return true;
}

ImageStabilizer::ImageStabilizer(const ImageStabilizerParams& params) : params_(params)
{
  const std::string why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("image stabilizer: " + why);
}

bool ImageStabilizer::setReference(const CameraModel& camera, const ReferenceSurface& surface, std::string* why)
{
  nodes_.clear();
  const std::string bad = camera.validate();
  if (!bad.empty())
  {
    *why = "camera: " + bad;
    return false;
  }
  if (surface.empty())
  {
    *why = "no reference surface";
    return false;
  }
  camera_ = camera;
  surface_ = surface;
  node_x_ = nodePositions(camera.width, params_.grid_step_px);
  node_y_ = nodePositions(camera.height, params_.grid_step_px);
  grid_cols_ = static_cast<int>(node_x_.size());
  grid_rows_ = static_cast<int>(node_y_.size());
  std::vector<Eigen::Vector3d> nodes(grid_cols_ * grid_rows_, Eigen::Vector3d::Constant(kNaN));
  int hits = 0;
  for (int j = 0; j < grid_rows_; ++j)
  {
    // The surface's parameters carry from node to node along a row (a near start).
    Eigen::Vector2d uv(kNaN, kNaN);
    for (int i = 0; i < grid_cols_; ++i)
    {
      const Eigen::Vector3d ray = camera.ray(cv::Point2d(node_x_[i], node_y_[j]));
      Eigen::Vector3d X;
      if (ray.allFinite() && surface.intersect(ray, &uv, &X))
      {
        nodes[j * grid_cols_ + i] = X;
        ++hits;
      }
    }
  }
  if (hits == 0)
  {
    *why = "no pixel's ray meets the locked surface";
    return false;
  }
  nodes_ = std::move(nodes);
  return true;
}

bool ImageStabilizer::sourcePixel(const cv::Point2d& u, const Eigen::Isometry3d& T, cv::Point2d* source) const
{
  if (!hasReference())
    return false;
  Eigen::Vector2d uv(kNaN, kNaN);
  Eigen::Vector3d X;
  if (!surface_.intersect(camera_.ray(u), &uv, &X))
    return false;
  *source = camera_.project(T * X);
  return std::isfinite(source->x) && std::isfinite(source->y);
}

bool ImageStabilizer::warp(const cv::Mat& image, const Eigen::Isometry3d& T, cv::Mat* out, std::string* why) const
{
  if (!hasReference())
  {
    *why = "no reference (no lock yet)";
    return false;
  }
  if (image.cols != camera_.width || image.rows != camera_.height)
  {
    std::ostringstream s;
    s << "image " << image.cols << "x" << image.rows << " but the reference camera is " << camera_.width << "x"
      << camera_.height;
    *why = s.str();
    return false;
  }
  if (!T.matrix().allFinite())
  {
    *why = "pose not finite";
    return false;
  }
  // The exact source of every node, then bilinear in each cell.
  std::vector<cv::Point2f> source(nodes_.size(), cv::Point2f(-1.0f, -1.0f));
  std::vector<uint8_t> ok(nodes_.size(), 0);
  for (size_t n = 0; n < nodes_.size(); ++n)
  {
    if (!nodes_[n].allFinite())
      continue;
    const cv::Point2d p = camera_.project(T * nodes_[n]);
    if (std::isfinite(p.x) && std::isfinite(p.y))
    {
      source[n] = cv::Point2f(static_cast<float>(p.x), static_cast<float>(p.y));
      ok[n] = 1;
    }
  }
  std::vector<int> cell_x, cell_y;
  std::vector<float> wx, wy;
  cellsOf(node_x_, camera_.width, &cell_x, &wx);
  cellsOf(node_y_, camera_.height, &cell_y, &wy);
  cv::Mat map(camera_.height, camera_.width, CV_32FC2);
  for (int y = 0; y < camera_.height; ++y)
  {
    const int j = cell_y[y];
    const float b = wy[y];
    cv::Point2f* row = map.ptr<cv::Point2f>(y);
    for (int x = 0; x < camera_.width; ++x)
    {
      const int i = cell_x[x];
      const size_t n00 = static_cast<size_t>(j * grid_cols_ + i), n01 = n00 + 1;
      const size_t n10 = n00 + static_cast<size_t>(grid_cols_), n11 = n10 + 1;
      if (!(ok[n00] && ok[n01] && ok[n10] && ok[n11]))
      {
        row[x] = cv::Point2f(-1.0f, -1.0f);
        continue;
      }
      const float a = wx[x];
      row[x] = (source[n00] * (1.0f - a) + source[n01] * a) * (1.0f - b) +
               (source[n10] * (1.0f - a) + source[n11] * a) * b;
    }
  }
  cv::remap(image, *out, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return true;
}

}  // namespace structured_light_stabilizer
