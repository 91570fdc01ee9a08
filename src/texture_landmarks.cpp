#include "structured_light_stabilizer/texture_landmarks.h"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/detail/math.h"

namespace structured_light_stabilizer
{

namespace
{

// Reach of the finite differences of a window's warp, in pixels of its level.
constexpr double kWarpReachPx = 8.0;

TextureTrackerParams trackerParams(const PoseDeltaParams& config)
{
  TextureTrackerParams tc;
  tc.max_features = config.texture_max_features;
  tc.quality = config.texture_quality;
  tc.min_distance_px = config.texture_min_distance_px;
  tc.window_px = config.texture_window_px;
  tc.pyramid_levels = config.texture_pyramid_levels;
  tc.dot_clearance_px = config.texture_dot_clearance_px;
  tc.roi_margin_px = config.texture_roi_margin_px;
  tc.photometric_refinement = config.texture_refinement_window_px > 0;
  tc.refinement_window_px = std::max(config.texture_refinement_window_px, 3);
  tc.min_level = config.texture_min_level;
  tc.max_level = config.texture_max_level;
  tc.min_snr = config.texture_min_snr;
  tc.max_sigma_px = config.texture_max_sigma_px;
  return tc;
}

// Least-squares plane of the usable points, and their RMS distance from it.
struct Plane
{
  Eigen::Vector3d centre;
  Eigen::Vector3d normal;
  double rms;
};

Plane fitPlane(const std::vector<Eigen::Vector3d>& points)
{
  Plane plane;
  plane.centre = Eigen::Vector3d::Zero();
  int n = 0;
  for (const Eigen::Vector3d& p : points)
    if (isUsablePoint(p))
    {
      plane.centre += p;
      ++n;
    }
  plane.centre /= std::max(n, 1);
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : points)
    if (isUsablePoint(p))
      scatter += (p - plane.centre) * (p - plane.centre).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(scatter, Eigen::ComputeFullU);
  plane.normal = svd.matrixU().col(2);
  // (A copy: reading the member in place trips GCC's -Wmaybe-uninitialized here.)
  const Eigen::Vector3d singular_values = svd.singularValues();
  plane.rms = std::sqrt(singular_values[2] / std::max(n, 1));
  return plane;
}

}  // namespace

std::vector<cv::Point2f> projectPoints(const CameraModel& camera, const std::vector<Eigen::Vector3d>& points)
{
  std::vector<cv::Point2f> px;
  px.reserve(points.size());
  for (const Eigen::Vector3d& p : points)
  {
    if (!isUsablePoint(p))
      continue;
    const cv::Point2d q = camera.project(p);
    if (std::isfinite(q.x) && std::isfinite(q.y))
      px.emplace_back(static_cast<float>(q.x), static_cast<float>(q.y));
  }
  return px;
}

void TextureLandmarks::lock(const PoseDeltaParams& config, const CameraModel& camera, const cv::Mat& image, int channel,
                            const std::vector<Eigen::Vector3d>& points, const BeamSurface& surface)
{
  clear();
  tracker_ = TextureTracker(trackerParams(config));
  // Features where the dot map gives depth (the box of the dots) or, by
  // default, anywhere in the image: off the map their depth comes from a
  // plane through the reference points and stays an unknown of the solve.
  const std::vector<cv::Point2f> dots = projectPoints(camera, points);
  if (dots.empty())
    return;
  const cv::Rect region = config.texture_whole_image ? cv::Rect(0, 0, image.cols, image.rows) : cv::boundingRect(dots);
  tracker_.setReference(image, channel, region, dots);
  const Plane plane = fitPlane(points);
  const double outside_sigma = std::max(config.texture_extrapolated_depth_sigma_m, 3.0 * plane.rms);
  std::vector<uint8_t> keep(tracker_.features().size(), 0);
  for (size_t k = 0; k < keep.size(); ++k)
  {
    Eigen::Vector2d uv(detail::kNaN, detail::kNaN);
    Eigen::Vector3d X;
    const cv::Point2f& f = tracker_.features()[k];
    const Eigen::Vector3d ray = camera.ray(cv::Point2d(f.x, f.y)).normalized();
    Eigen::Vector3d S, Su, Sv;
    if (surface.intersectRay(ray, &uv, &X) && surface.evaluate(uv.x(), uv.y(), &S, &Su, &Sv))
    {
      keep[k] = 1;
      points_.push_back(X);
      normals_.push_back(Su.cross(Sv).normalized());
      depth_sigma_.push_back(config.texture_depth_sigma_m);
      continue;
    }
    const double along = plane.normal.dot(ray);
    const double depth = std::abs(along) > 0.2 ? plane.normal.dot(plane.centre) / along : -1.0;
    if (config.texture_whole_image && config.texture_depth_sigma_m > 0.0 && depth > 0.0)
    {
      keep[k] = 1;
      points_.push_back(depth * ray);
      normals_.push_back(plane.normal);
      depth_sigma_.push_back(outside_sigma);
    }
  }
  tracker_.retain(keep);
  has_image_ = true;
}

void TextureLandmarks::clear()
{
  dropFeatures();
  has_image_ = false;
}

void TextureLandmarks::dropFeatures()
{
  tracker_.clear();
  points_.clear();
  normals_.clear();
  depth_sigma_.clear();
}

bool TextureLandmarks::setFrame(const CameraModel& camera, const cv::Mat& image, int channel,
                                const std::vector<Eigen::Vector3d>& points)
{
  camera_ = camera;
  dots_ = projectPoints(camera, points);
  return tracker_.setFrame(image, channel);
}

std::vector<cv::Point2f> TextureLandmarks::predict(const Eigen::Isometry3d& T, std::vector<cv::Matx22d>* warps) const
{
  std::vector<cv::Point2f> px(points_.size());
  if (warps)
    warps->assign(points_.size(), cv::Matx22d::eye());
  for (size_t k = 0; k < points_.size(); ++k)
  {
    const cv::Point2d p = camera_.project(T * points_[k]);
    px[k] = cv::Point2f(static_cast<float>(p.x), static_cast<float>(p.y));
    if (!warps)
      continue;
    // Finite differences over the window's reach on the rock's tangent
    // plane, so the map is the window's average and lens distortion is in it.
    const cv::Point2f& f = tracker_.features()[k];
    const double reach = kWarpReachPx * static_cast<double>(1 << tracker_.levels()[k]);
    const double plane = normals_[k].dot(points_[k]);
    cv::Matx22d A;
    bool ok = std::isfinite(p.x) && std::isfinite(p.y);
    for (int axis = 0; axis < 2 && ok; ++axis)
    {
      const cv::Point2d from(f.x + (axis == 0 ? reach : 0.0), f.y + (axis == 1 ? reach : 0.0));
      const Eigen::Vector3d ray = camera_.ray(from);
      const double along = normals_[k].dot(ray);
      const cv::Point2d q = camera_.project(T * Eigen::Vector3d(ray * (plane / along)));
      A(0, axis) = (q.x - p.x) / reach;
      A(1, axis) = (q.y - p.y) / reach;
      ok = std::abs(along) > 1e-3 && std::isfinite(q.x) && std::isfinite(q.y);
    }
    if (ok)
      (*warps)[k] = A;
  }
  return px;
}

std::vector<TextureConstraint> TextureLandmarks::constraints(const std::vector<cv::Point2f>& tracked,
                                                             const std::vector<uint8_t>& ok,
                                                             const std::vector<cv::Matx22d>* covariance) const
{
  std::vector<TextureConstraint> c;
  for (size_t k = 0; k < points_.size(); ++k)
  {
    if (!ok[k])
      continue;
    TextureConstraint tc;
    tc.point_ref = points_[k];
    tc.observed_normalized = camera_.normalize(cv::Point2d(tracked[k].x, tracked[k].y));
    tc.depth_sigma_m = depth_sigma_[k];
    if (covariance)
    {
      const cv::Matx22d& m = (*covariance)[k];
      tc.covariance_px << m(0, 0), m(0, 1), m(1, 0), m(1, 1);
    }
    c.push_back(tc);
  }
  return c;
}

std::vector<TextureConstraint> TextureLandmarks::trackPyramidal(const Eigen::Isometry3d& T,
                                                                const std::vector<uint8_t>& which)
{
  std::vector<cv::Point2f> tracked;
  std::vector<uint8_t> ok;
  tracker_.trackPyramidal(predict(T), which, dots_, &tracked, &ok);
  return constraints(tracked, ok);
}

std::vector<TextureConstraint> TextureLandmarks::trackCoarse(const Eigen::Isometry3d& T)
{
  const size_t stride = std::max<size_t>(1, points_.size() / kCoarseFeatures);
  std::vector<uint8_t> coarse(points_.size(), 0);
  for (size_t k = 0; k < points_.size(); k += stride)
    coarse[k] = 1;
  return trackPyramidal(T, coarse);
}

std::vector<TextureConstraint> TextureLandmarks::trackAll(const Eigen::Isometry3d& T)
{
  return trackPyramidal(T, {});
}

std::vector<TextureConstraint> TextureLandmarks::refineAll(const Eigen::Isometry3d& T) const
{
  std::vector<cv::Point2f> tracked;
  std::vector<uint8_t> ok;
  std::vector<cv::Matx22d> covariance, warps;
  const std::vector<cv::Point2f> predicted = predict(T, &warps);
  tracker_.refineAll(predicted, dots_, &tracked, &ok, &covariance, &warps);
  return constraints(tracked, ok, &covariance);
}

}  // namespace structured_light_stabilizer
