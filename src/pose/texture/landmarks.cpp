#include "structured_light_stabilizer/pose/texture_landmarks.h"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/common/math.h"

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

// A feature lifted to 3D on its camera ray: at the reference surface between
// the dots, else on the plane of the reference points (depth left free in the
// solve with a looser prior).
struct Lifted
{
  Eigen::Vector3d point;
  Eigen::Vector3d normal;
  double depth_sigma;
};

bool lift(const cv::Point2f& f, const CameraModel& camera, const BeamSurface& surface, const Plane& plane,
          const PoseDeltaParams& config, double outside_sigma, Lifted* out)
{
  Eigen::Vector2d uv(detail::kNaN, detail::kNaN);
  const Eigen::Vector3d ray = camera.ray(cv::Point2d(f.x, f.y)).normalized();
  Eigen::Vector3d S, Su, Sv;
  if (surface.intersectRay(ray, &uv, &out->point) && surface.evaluate(uv.x(), uv.y(), &S, &Su, &Sv))
  {
    out->normal = Su.cross(Sv).normalized();
    out->depth_sigma = config.texture_depth_sigma_m;
    return true;
  }
  const double along = plane.normal.dot(ray);
  const double depth = std::abs(along) > 0.2 ? plane.normal.dot(plane.centre) / along : -1.0;
  if (!(config.texture_whole_image && config.texture_depth_sigma_m > 0.0 && depth > 0.0))
    return false;
  out->point = depth * ray;
  out->normal = plane.normal;
  out->depth_sigma = outside_sigma;
  return true;
}

// Per pixel, the brightest corner's natural vignetting over the pixel's own
// (cos^4 of the off-axis angle of its camera ray): 1 in that corner, about
// 0.45 at the centre of a 53 deg lens.
cv::Mat vignettingGain(const CameraModel& camera, const cv::Size& size)
{
  cv::Mat gain(size, CV_32F);
  double darkest = 1.0;
  for (int y = 0; y < size.height; ++y)
  {
    float* row = gain.ptr<float>(y);
    for (int x = 0; x < size.width; ++x)
    {
      const Eigen::Vector3d ray = camera.ray(cv::Point2d(x, y));
      const double q = ray.squaredNorm() / (ray.z() * ray.z());  // 1 / cos^2
      const double cos4 = 1.0 / (q * q);
      row[x] = static_cast<float>(1.0 / cos4);
      darkest = std::min(darkest, cos4);
    }
  }
  gain *= darkest;
  return gain;
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
                            const std::vector<Eigen::Vector3d>& points, const BeamSurface& surface,
                            const TextureExposure& exposure)
{
  clear();
  tracker_ = TextureTracker(trackerParams(config));
  // The reference map as the image saw it (exposed at exposure.offset).
  const bool moved = !exposure.offset.isApprox(Eigen::Isometry3d::Identity(), 1e-12);
  std::vector<Eigen::Vector3d> seen = points;
  BeamSurface moved_surface;
  if (moved)
  {
    for (Eigen::Vector3d& p : seen)
      if (isUsablePoint(p))
        p = exposure.offset * p;
    // (The surface may be built on a denser map than the beams'.)
    std::vector<Eigen::Vector3d> map = surface.points();
    for (Eigen::Vector3d& p : map)
      if (isUsablePoint(p))
        p = exposure.offset * p;
    moved_surface.build(surface.rows(), surface.cols(), map, config.max_edge_ratio);
  }
  const BeamSurface& in_image = moved ? moved_surface : surface;
  // Features where the dot map gives depth (the box of the dots) or, by
  // default, anywhere in the image: off the map their depth comes from a
  // plane through the reference points and stays an unknown of the solve.
  const std::vector<cv::Point2f> dots = projectPoints(camera, seen);
  if (dots.empty())
    return;
  const cv::Rect region = config.texture_whole_image ? cv::Rect(0, 0, image.cols, image.rows) : cv::boundingRect(dots);
  if (config.texture_flat_field)
    flat_field_gain_ = vignettingGain(camera, image.size());
  const cv::Mat tracked = trackedImage(image, &channel);
  tracker_.setReference(tracked, channel, region, exposure.dots_in_image ? dots : std::vector<cv::Point2f>());
  const Plane plane = fitPlane(seen);
  const double outside_sigma = std::max(config.texture_extrapolated_depth_sigma_m, 3.0 * plane.rms);
  std::vector<uint8_t> keep(tracker_.features().size(), 0);
  for (size_t k = 0; k < keep.size(); ++k)
  {
    Lifted l;
    if (!lift(tracker_.features()[k], camera, in_image, plane, config, outside_sigma, &l))
      continue;
    keep[k] = 1;
    // Back to the frame of the points.
    points_.push_back(exposure.offset.inverse() * l.point);
    normals_.push_back(exposure.offset.linear().transpose() * l.normal);
    depth_sigma_.push_back(l.depth_sigma);
  }
  tracker_.retain(keep);
  lifted_points_ = points_;
  lifted_sigma_ = depth_sigma_;
  lifted_at_points_ = !moved;
  has_image_ = true;
}

void TextureLandmarks::relift(const BeamSurface& surface, const PoseDeltaParams& config)
{
  if (!lifted_at_points_)
    return;
  for (size_t k = 0; k < points_.size(); ++k)
  {
    Eigen::Vector2d uv(detail::kNaN, detail::kNaN);
    Eigen::Vector3d hit, S, Su, Sv;
    if (!surface.intersectRay(points_[k], &uv, &hit) || !surface.evaluate(uv.x(), uv.y(), &S, &Su, &Sv))
      continue;
    points_[k] = lifted_points_[k] = hit;
    normals_[k] = Su.cross(Sv).normalized();
    depth_sigma_[k] = lifted_sigma_[k] = config.texture_depth_sigma_m;
  }
}

void TextureLandmarks::refineDepths(const std::vector<TextureObservations>& frames,
                                    const std::vector<Eigen::Isometry3d>& poses, double inflation)
{
  // Whitened residuals beyond this are another feature's or an outlier's.
  constexpr double kGate = 4.0;
  constexpr int kIterations = 2;
  if (!lifted_at_points_ || frames.size() != poses.size() || lifted_points_.size() != points_.size())
    return;
  // Each feature's observations: (frame, constraint).
  std::vector<std::vector<std::pair<size_t, size_t>>> seen(points_.size());
  for (size_t j = 0; j < frames.size(); ++j)
    for (size_t i = 0; i < frames[j].constraints.size(); ++i)
    {
      const int k = frames[j].constraints[i].landmark;
      if (k >= 0 && static_cast<size_t>(k) < points_.size())
        seen[k].emplace_back(j, i);
    }
  for (size_t k = 0; k < points_.size(); ++k)
  {
    const double sigma0 = lifted_sigma_[k];
    if (!(sigma0 > 0.0) || seen[k].empty())
      continue;
    const Eigen::Vector3d ray = lifted_points_[k].normalized();
    const double d0 = lifted_points_[k].norm();
    double d = d0, info = 0.0;
    for (int it = 0; it < kIterations; ++it)
    {
      info = 1.0 / (sigma0 * sigma0);
      double g = (d - d0) * info;
      for (const auto& ji : seen[k])
      {
        const TextureObservations& obs = frames[ji.first];
        const TextureConstraint& c = obs.constraints[ji.second];
        const Eigen::Matrix2d cov = c.covariance_px * inflation * inflation;
        if (!(cov.determinant() > 0.0))
          continue;
        const Eigen::Isometry3d& T = poses[ji.first];
        const Eigen::Vector3d y = obs.offset * (T * Eigen::Vector3d(d * ray));
        if (!(y.z() > 1e-6))
          continue;
        const double iz = 1.0 / y.z();
        Eigen::Matrix<double, 2, 3> dpi;
        dpi << iz, 0.0, -y.x() * iz * iz, 0.0, iz, -y.y() * iz * iz;
        const Eigen::Vector2d J = obs.focal_px * dpi * (obs.offset.linear() * T.linear() * ray);
        const Eigen::Vector2d r =
            obs.focal_px * (Eigen::Vector2d(y.x() * iz, y.y() * iz) - c.observed_normalized);
        const Eigen::Matrix2d W = cov.inverse();
        if (r.dot(W * r) > kGate * kGate)
          continue;
        info += J.dot(W * J);
        g += J.dot(W * r);
      }
      d -= g / info;
    }
    if (!(d > 0.0) || !std::isfinite(d))
      continue;
    points_[k] = d * ray;
    depth_sigma_[k] = 1.0 / std::sqrt(info);
  }
}

void TextureLandmarks::update(std::vector<TextureConstraint>* constraints) const
{
  for (TextureConstraint& c : *constraints)
    if (c.landmark >= 0 && static_cast<size_t>(c.landmark) < points_.size())
    {
      c.point_ref = points_[c.landmark];
      c.depth_sigma_m = depth_sigma_[c.landmark];
    }
}

void TextureLandmarks::clear()
{
  dropFeatures();
  flat_field_gain_.release();
  has_image_ = false;
}

cv::Mat TextureLandmarks::trackedImage(const cv::Mat& image, int* channel) const
{
  if (flat_field_gain_.empty() || image.size() != flat_field_gain_.size() || image.empty())
    return image;
  cv::Mat plane, level;
  if (image.channels() > 1)
    cv::extractChannel(image, plane, std::min(std::max(*channel, 0), image.channels() - 1));
  else
    plane = image;
  plane.convertTo(level, CV_32F, image.depth() == CV_16U ? 1.0 : 257.0);
  cv::Mat flat;
  cv::Mat(level.mul(flat_field_gain_)).convertTo(flat, CV_16U);
  *channel = 0;
  return flat;
}

void TextureLandmarks::dropFeatures()
{
  tracker_.clear();
  points_.clear();
  normals_.clear();
  depth_sigma_.clear();
  lifted_points_.clear();
  lifted_sigma_.clear();
}

bool TextureLandmarks::setFrame(const CameraModel& camera, const cv::Mat& image, int channel,
                                const std::vector<Eigen::Vector3d>& points, bool dots_in_image)
{
  camera_ = camera;
  dots_ = dots_in_image ? projectPoints(camera, points) : std::vector<cv::Point2f>();
  return tracker_.setFrame(trackedImage(image, &channel), channel);
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
    // plane, so the map is the window's average and lens distortion is in
    // it; taken around the template's own pixel (a landmark centred between
    // two ambient frames sits a little away from it).
    const cv::Point2f& f = tracker_.features()[k];
    const double reach = kWarpReachPx * static_cast<double>(1 << tracker_.levels()[k]);
    const double plane = normals_[k].dot(points_[k]);
    cv::Point2d q[3];
    bool ok = std::isfinite(p.x) && std::isfinite(p.y);
    for (int i = 0; i < 3 && ok; ++i)
    {
      const cv::Point2d from(f.x + (i == 1 ? reach : 0.0), f.y + (i == 2 ? reach : 0.0));
      const Eigen::Vector3d ray = camera_.ray(from);
      const double along = normals_[k].dot(ray);
      q[i] = camera_.project(T * Eigen::Vector3d(ray * (plane / along)));
      ok = std::abs(along) > 1e-3 && std::isfinite(q[i].x) && std::isfinite(q[i].y);
    }
    const cv::Matx22d A((q[1].x - q[0].x) / reach, (q[2].x - q[0].x) / reach, (q[1].y - q[0].y) / reach,
                        (q[2].y - q[0].y) / reach);
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
    tc.landmark = static_cast<int>(k);
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

TextureLandmarks::Refined TextureLandmarks::refine(const Eigen::Isometry3d& T) const
{
  Refined r;
  std::vector<cv::Matx22d> warps;
  const std::vector<cv::Point2f> predicted = predict(T, &warps);
  tracker_.refineAll(predicted, dots_, &r.tracked, &r.ok, &r.covariance, &warps);
  return r;
}

std::vector<TextureConstraint> TextureLandmarks::refineAll(const Eigen::Isometry3d& T) const
{
  const Refined r = refine(T);
  return constraints(r.tracked, r.ok, &r.covariance);
}

// The second exposure of a pair, predicted from the first without a
// velocity: a spread subset tracked over the pyramid from its first
// positions gives the image motion between the two (a similarity, robust to
// lost features), which carries every first position over.
TextureLandmarks::Refined TextureLandmarks::refineFrom(const Refined& first, const Eigen::Isometry3d& T)
{
  std::vector<cv::Matx22d> warps;
  std::vector<cv::Point2f> predicted = predict(T, &warps);
  const size_t stride = std::max<size_t>(1, points_.size() / kCoarseFeatures);
  std::vector<uint8_t> which(points_.size(), 0);
  for (size_t k = 0; k < points_.size(); k += stride)
    which[k] = first.ok[k];
  std::vector<cv::Point2f> coarse;
  std::vector<uint8_t> ok;
  tracker_.trackPyramidal(first.tracked, which, {}, &coarse, &ok);
  std::vector<cv::Point2f> from, to;
  for (size_t k = 0; k < points_.size(); ++k)
    if (which[k] && ok[k])
    {
      from.push_back(first.tracked[k]);
      to.push_back(coarse[k]);
    }
  const cv::Mat S = from.size() >= 3 ? cv::estimateAffinePartial2D(from, to) : cv::Mat();
  if (!S.empty())
    for (size_t k = 0; k < points_.size(); ++k)
      if (first.ok[k])
      {
        const cv::Point2f& p = first.tracked[k];
        predicted[k] =
            cv::Point2f(static_cast<float>(S.at<double>(0, 0) * p.x + S.at<double>(0, 1) * p.y + S.at<double>(0, 2)),
                        static_cast<float>(S.at<double>(1, 0) * p.x + S.at<double>(1, 1) * p.y + S.at<double>(1, 2)));
      }
  Refined r;
  tracker_.refineAll(predicted, {}, &r.tracked, &r.ok, &r.covariance, &warps);
  return r;
}

std::vector<TextureConstraint> TextureLandmarks::refineBetween(const Eigen::Isometry3d& T_first,
                                                               const Eigen::Isometry3d& T_second, const cv::Mat& first,
                                                               const cv::Mat& second, int channel, double fraction)
{
  Refined a, b;
  dots_.clear();
  int first_channel = channel, second_channel = channel;
  if (tracker_.setFrame(trackedImage(first, &first_channel), first_channel))
    a = refine(T_first);
  if (tracker_.setFrame(trackedImage(second, &second_channel), second_channel) && a.ok.size() == points_.size())
    b = refineFrom(a, T_second);
  if (a.ok.size() != points_.size() || b.ok.size() != points_.size())
    return {};
  // Between two exposures the rig moves at nearly constant velocity: the
  // interpolated position is where the feature was at the instant between.
  const float w = static_cast<float>(fraction);
  for (size_t k = 0; k < points_.size(); ++k)
  {
    a.ok[k] = a.ok[k] && b.ok[k];
    a.tracked[k] += w * (b.tracked[k] - a.tracked[k]);
    a.covariance[k] = (1.0 - fraction) * (1.0 - fraction) * a.covariance[k] + fraction * fraction * b.covariance[k];
  }
  return constraints(a.tracked, a.ok, &a.covariance);
}

void TextureLandmarks::centreBetween(const cv::Mat& second, int channel, double fraction, const CameraModel& camera,
                                     const std::vector<Eigen::Vector3d>& points, const BeamSurface& surface,
                                     const PoseDeltaParams& config)
{
  camera_ = camera;
  dots_.clear();
  if (points_.empty() || !tracker_.setFrame(trackedImage(second, &channel), channel))
    return;
  // Where each reference feature is in the second exposure: tracked over
  // the pyramid (the rig's motion over the gap is not known yet), refined.
  std::vector<cv::Point2f> coarse, tracked;
  std::vector<uint8_t> ok;
  std::vector<cv::Matx22d> covariance;
  tracker_.trackPyramidal(tracker_.features(), {}, {}, &coarse, &ok);
  for (size_t k = 0; k < coarse.size(); ++k)
    if (!ok[k])
      coarse[k] = tracker_.features()[k];
  tracker_.refineAll(coarse, {}, &tracked, &ok, &covariance);
  const Plane plane = fitPlane(points);
  const double outside_sigma = std::max(config.texture_extrapolated_depth_sigma_m, 3.0 * plane.rms);
  const float w = static_cast<float>(fraction);
  std::vector<uint8_t> keep(points_.size(), 0);
  std::vector<Eigen::Vector3d> lifted, normals;
  std::vector<double> sigmas;
  for (size_t k = 0; k < points_.size(); ++k)
  {
    Lifted l;
    const cv::Point2f at = tracker_.features()[k] + w * (tracked[k] - tracker_.features()[k]);
    if (!ok[k] || !lift(at, camera, surface, plane, config, outside_sigma, &l))
      continue;
    keep[k] = 1;
    lifted.push_back(l.point);
    normals.push_back(l.normal);
    sigmas.push_back(l.depth_sigma);
  }
  tracker_.retain(keep);
  points_.swap(lifted);
  normals_.swap(normals);
  depth_sigma_.swap(sigmas);
  lifted_points_ = points_;
  lifted_sigma_ = depth_sigma_;
  lifted_at_points_ = true;
}

}  // namespace structured_light_stabilizer
