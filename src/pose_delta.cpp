#include "structured_light_stabilizer/pose_delta.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include <Eigen/SVD>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/detail/math.h"
#include "structured_light_stabilizer/texture_tracker.h"

namespace structured_light_stabilizer
{

namespace
{
const char* const kAxisNames[6] = {"tx", "ty", "tz", "rx", "ry", "rz"};

// Texture features tracked over the pyramid to re-predict the others, and
// the fewest of them worth a prediction.
constexpr size_t kCoarseFeatures = 48;
constexpr int kMinCoarseFeatures = 12;
constexpr int kIterationsAfterCoarseFit = 8;
// Prior of the geometry-only prediction (see process()).
constexpr double kPredictionPriorM = 0.005;
constexpr double kPredictionPriorRad = 0.005;
}  // namespace

std::string PoseDeltaParams::validate() const
{
  std::ostringstream why;
  if (min_points < 6)
    why << "min_points must be at least 6 (six unknowns); ";
  if (max_iterations < 1)
    why << "max_iterations must be positive; ";
  if (!(huber_k > 0.0))
    why << "huber_k must be positive; ";
  if (!(min_geometry_sigma_m > 0.0) || !(min_texture_sigma_px > 0.0))
    why << "noise floors must be positive; ";
  if (!(prior_sigma_translation_m > 0.0) || !(prior_sigma_rotation_rad > 0.0))
    why << "prior sigmas must be positive; ";
  if (!(max_sigma_translation_m > 0.0) || !(max_sigma_rotation_rad > 0.0) || !(max_rms_residual_m > 0.0))
    why << "validity bounds must be positive; ";
  if (!(freeze_factor >= 1.0))
    why << "freeze_factor must be at least 1; ";
  if (!(max_edge_ratio > 1.0))
    why << "max_edge_ratio must exceed 1; ";
  if (texture_window_px < 5 || texture_window_px % 2 == 0)
    why << "texture_window_px must be odd and >= 5; ";
  if (texture_refinement_window_px != 0 && (texture_refinement_window_px < 5 || texture_refinement_window_px % 2 == 0))
    why << "texture_refinement_window_px must be 0 (off) or odd and >= 5; ";
  if (texture_pyramid_levels < 0 || texture_pyramid_levels > 6)
    why << "texture_pyramid_levels must be in [0, 6]; ";
  if (!(texture_error_inflation >= 1.0))
    why << "texture_error_inflation must be at least 1; ";
  if (!(texture_depth_sigma_m >= 0.0) || !(texture_extrapolated_depth_sigma_m > 0.0))
    why << "texture depth sigmas must not be negative (the extrapolated one positive); ";
  if (texture_max_features < 0 || texture_min_features < 0)
    why << "texture feature counts must not be negative; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

// ---------------------------------------------------------------------------
// Estimator

struct PoseDeltaEstimator::Frame
{
  int rows = 0;
  int cols = 0;
  std::vector<Eigen::Vector3d> points;
  BeamSurface surface;
  std::vector<Eigen::Vector3d> features_3d;  // texture features lifted onto the surface (reference frame)
  std::vector<double> features_sigma;        // 1-sigma of each feature's depth (0 = fixed)
  bool has_image = false;
};

PoseDeltaEstimator::PoseDeltaEstimator(const PoseDeltaParams& config) : tracker_(new TextureTracker)
{
  setParams(config);
}

PoseDeltaEstimator::~PoseDeltaEstimator() = default;

void PoseDeltaEstimator::setParams(const PoseDeltaParams& config)
{
  const std::string why = config.validate();
  if (!why.empty())
    throw std::invalid_argument("PoseDelta config: " + why);
  const bool mode_changed = config.mode != config_.mode;
  config_ = config;
  if (mode_changed)
    requestLock();
}

void PoseDeltaEstimator::setCamera(const CameraModel& camera)
{
  if (!camera.validate().empty())
    return;
  const bool changed = !has_camera_ || camera.width != camera_.width || camera.height != camera_.height ||
                       camera.fx != camera_.fx || camera.fy != camera_.fy || camera.cx != camera_.cx ||
                       camera.cy != camera_.cy || camera.D != camera_.D || camera.distortion != camera_.distortion;
  camera_ = camera;
  has_camera_ = true;
  // Lifted features depend on the intrinsics; a new camera needs a new reference image.
  if (changed && reference_)
  {
    tracker_->clear();
    reference_->features_3d.clear();
    reference_->features_sigma.clear();
  }
}

void PoseDeltaEstimator::requestLock()
{
  lock_pending_ = true;
}

void PoseDeltaEstimator::reset(bool lock_on_next_frame)
{
  has_reference_ = false;
  reference_.reset();
  tracker_->clear();
  last_estimate_ = Eigen::Isometry3d::Identity();
  chained_ = Eigen::Isometry3d::Identity();
  chained_covariance_ = Matrix6d::Zero();
  lock_pending_ = lock_on_next_frame;
}

std::string PoseDeltaEstimator::checkMap(const PoseDeltaInput& frame, int* valid_points) const
{
  *valid_points = 0;
  if (frame.rows <= 0 || frame.cols <= 0 || frame.points.empty())
    return "empty cloud";
  if (static_cast<int>(frame.points.size()) != frame.rows * frame.cols)
    return "cloud has " + std::to_string(frame.points.size()) + " points but its layout is " +
           std::to_string(frame.rows) + "x" + std::to_string(frame.cols);
  if (frame.rows < 2 || frame.cols < 2)
    return "cloud layout " + std::to_string(frame.rows) + "x" + std::to_string(frame.cols) +
           " is not a 2D grid of beams (a surface needs at least 2x2)";
  for (const Eigen::Vector3d& p : frame.points)
    *valid_points += isUsablePoint(p) ? 1 : 0;
  if (*valid_points == 0)
    return "no valid point in the cloud (all NaN)";
  if (*valid_points < config_.min_points)
    return "too few points: " + std::to_string(*valid_points) + " valid, need " + std::to_string(config_.min_points);
  return "";
}

namespace
{
std::vector<cv::Point2f> projectAll(const CameraModel& camera, const std::vector<Eigen::Vector3d>& points)
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
}  // namespace

void PoseDeltaEstimator::lock(const PoseDeltaInput& frame)
{
  std::unique_ptr<Frame> ref(new Frame);
  ref->rows = frame.rows;
  ref->cols = frame.cols;
  ref->points = frame.points;
  ref->surface.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);
  tracker_->clear();
  if (config_.use_texture && has_camera_ && !frame.image.empty() && frame.image.cols == camera_.width &&
      frame.image.rows == camera_.height)
  {
    TextureTrackerParams tc;
    tc.max_features = config_.texture_max_features;
    tc.quality = config_.texture_quality;
    tc.min_distance_px = config_.texture_min_distance_px;
    tc.window_px = config_.texture_window_px;
    tc.pyramid_levels = config_.texture_pyramid_levels;
    tc.dot_clearance_px = config_.texture_dot_clearance_px;
    tc.roi_margin_px = config_.texture_roi_margin_px;
    tc.photometric_refinement = config_.texture_refinement_window_px > 0;
    tc.refinement_window_px = std::max(config_.texture_refinement_window_px, 3);
    *tracker_ = TextureTracker(tc);
    // Features where the dot map gives depth (the box of the dots) or, by
    // default, anywhere in the image: off the map their depth comes from a
    // plane through the reference points and stays an unknown of the solve.
    const std::vector<cv::Point2f> dots = projectAll(camera_, frame.points);
    if (!dots.empty())
    {
      const cv::Rect region =
          config_.texture_whole_image ? cv::Rect(0, 0, frame.image.cols, frame.image.rows) : cv::boundingRect(dots);
      tracker_->setReference(frame.image, frame.texture_channel, region, dots);
      // Least-squares plane of the reference points, and their scatter about it.
      Eigen::Vector3d centre = Eigen::Vector3d::Zero();
      int n = 0;
      for (const Eigen::Vector3d& p : frame.points)
        if (isUsablePoint(p))
        {
          centre += p;
          ++n;
        }
      centre /= std::max(n, 1);
      Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
      for (const Eigen::Vector3d& p : frame.points)
        if (isUsablePoint(p))
          scatter += (p - centre) * (p - centre).transpose();
      const Eigen::JacobiSVD<Eigen::Matrix3d> plane(scatter, Eigen::ComputeFullU);
      const Eigen::Vector3d normal = plane.matrixU().col(2);
      const double plane_rms = std::sqrt(plane.singularValues()[2] / std::max(n, 1));
      const double outside_sigma = std::max(config_.texture_extrapolated_depth_sigma_m, 3.0 * plane_rms);
      std::vector<uint8_t> keep(tracker_->features().size(), 0);
      for (size_t k = 0; k < keep.size(); ++k)
      {
        Eigen::Vector2d uv(detail::kNaN, detail::kNaN);
        Eigen::Vector3d X;
        const cv::Point2f& f = tracker_->features()[k];
        const Eigen::Vector3d ray = camera_.ray(cv::Point2d(f.x, f.y)).normalized();
        if (ref->surface.intersectRay(ray, &uv, &X))
        {
          keep[k] = 1;
          ref->features_3d.push_back(X);
          ref->features_sigma.push_back(config_.texture_depth_sigma_m);
          continue;
        }
        const double along = normal.dot(ray);
        const double depth = std::abs(along) > 0.2 ? normal.dot(centre) / along : -1.0;
        if (config_.texture_whole_image && config_.texture_depth_sigma_m > 0.0 && depth > 0.0)
        {
          keep[k] = 1;
          ref->features_3d.push_back(depth * ray);
          ref->features_sigma.push_back(outside_sigma);
        }
      }
      tracker_->retain(keep);
      ref->has_image = true;
    }
  }
  reference_ = std::move(ref);
  has_reference_ = true;
  lock_pending_ = false;
  last_estimate_ = Eigen::Isometry3d::Identity();
}

PoseDeltaResult PoseDeltaEstimator::process(const PoseDeltaInput& frame)
{
  PoseDeltaResult result;
  result.covariance = Matrix6d::Zero();
  for (int a = 0; a < 6; ++a)
    result.covariance(a, a) = a < 3 ? config_.prior_sigma_translation_m * config_.prior_sigma_translation_m
                                    : config_.prior_sigma_rotation_rad * config_.prior_sigma_rotation_rad;
  result.unobservable.fill(true);
  const bool chained = config_.mode == PoseDeltaMode::kFrameToFrame;
  result.transform = chained ? Eigen::Isometry3d(last_estimate_ * chained_) : last_estimate_;

  int valid_points = 0;
  const std::string bad = checkMap(frame, &valid_points);
  if (!bad.empty())
  {
    result.status = bad + (has_reference_ ? "" : "; no reference locked yet");
    return result;
  }

  if (!lock_pending_ && !has_reference_)
  {
    result.status = "no reference locked: call the pose_delta/lock service";
    return result;
  }
  if (lock_pending_)
  {
    BeamSurface probe;
    probe.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);
    if (probe.validCells() < 4)
    {
      result.status = "cannot lock on this map: only " + std::to_string(probe.validCells()) +
                      " surface cells between valid neighbouring dots";
      return result;
    }
    lock(frame);
    chained_ = Eigen::Isometry3d::Identity();
    chained_covariance_ = Matrix6d::Zero();
    result.locked_now = true;
    result.transform = Eigen::Isometry3d::Identity();
  }

  if (frame.rows != reference_->rows || frame.cols != reference_->cols)
  {
    result.status = "cloud layout " + std::to_string(frame.rows) + "x" + std::to_string(frame.cols) +
                    " differs from the reference's " + std::to_string(reference_->rows) + "x" +
                    std::to_string(reference_->cols) + "; lock again (pose_delta/lock)";
    return result;
  }

  BeamSurface current_surface;
  if (config_.symmetric)
    current_surface.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);

  // Texture: track the reference features into this image, starting where
  // the last estimate puts them.
  Eigen::Isometry3d initial = last_estimate_;
  std::vector<TextureConstraint> texture;
  std::string texture_note;
  bool texture_predicted = false;  // `initial` comes from the coarse texture fit
  const bool texture_wanted = config_.use_texture;
  if (texture_wanted)
  {
    if (!has_camera_)
      texture_note = "no camera_info for the texture";
    else if (!reference_->has_image)
      texture_note = "the reference has no image (lock again with images flowing)";
    else if (tracker_->empty())
      texture_note = "no trackable texture in the reference image";
    else if (frame.image.empty())
      texture_note = "no image for this cloud";
    else if (frame.image.cols != camera_.width || frame.image.rows != camera_.height)
      texture_note = "image size differs from camera_info";
    else
    {
      // Geometry first: on a rough rock it places the features to within a
      // pixel or two, on any surface it fixes distance and tilts.
      // Only a prediction: one direction, a few iterations, no second phase;
      // a firm prior keeps the axes a smooth surface leaves free near the
      // last estimate (with the weak one they wander by degrees on noise).
      PoseDeltaParams quick = config_;
      quick.max_iterations = std::min(config_.max_iterations, 6);
      quick.freeze_factor = 1e9;
      quick.prior_sigma_translation_m = std::min(config_.prior_sigma_translation_m, kPredictionPriorM);
      quick.prior_sigma_rotation_rad = std::min(config_.prior_sigma_rotation_rad, kPredictionPriorRad);
      const RegistrationOutput geo =
          registerToSurface(reference_->surface, reference_->points, nullptr, frame.points, {}, 1.0, initial, quick);
      if (geo.points_used >= config_.min_points && geo.transform.matrix().allFinite())
        initial = geo.transform;
      const std::vector<Eigen::Vector3d>& X = reference_->features_3d;
      const std::vector<double>& Xs = reference_->features_sigma;
      auto predict = [&](const Eigen::Isometry3d& T)
      {
        std::vector<cv::Point2f> px(X.size());
        for (size_t k = 0; k < X.size(); ++k)
        {
          const cv::Point2d p = camera_.project(T * X[k]);
          px[k] = cv::Point2f(static_cast<float>(p.x), static_cast<float>(p.y));
        }
        return px;
      };
      auto constraints = [&](const std::vector<cv::Point2f>& tracked, const std::vector<uint8_t>& ok)
      {
        std::vector<TextureConstraint> c;
        for (size_t k = 0; k < X.size(); ++k)
          if (ok[k])
            c.push_back({X[k], camera_.normalize(cv::Point2d(tracked[k].x, tracked[k].y)), Xs[k]});
        return c;
      };
      const std::vector<cv::Point2f> dots = projectAll(camera_, frame.points);
      std::vector<cv::Point2f> tracked;
      std::vector<uint8_t> ok;
      int n = 0;
      if (!tracker_->setFrame(frame.image, frame.texture_channel))
        texture_note = "image unusable for tracking";
      else if (config_.texture_refinement_window_px > 0)
      {
        // A few features tracked over the pyramid (wide capture range) fix
        // the in-plane axes well enough to predict every feature to a
        // fraction of a pixel; the gain-and-offset refinement from there is
        // the measurement, and costs a fraction of pyramidal tracking.
        const size_t stride = std::max<size_t>(1, X.size() / kCoarseFeatures);
        std::vector<uint8_t> coarse(X.size(), 0);
        for (size_t k = 0; k < X.size(); k += stride)
          coarse[k] = 1;
        if (tracker_->trackPyramidal(predict(initial), coarse, dots, &tracked, &ok) >= kMinCoarseFeatures)
        {
          PoseDeltaParams quick = config_;
          quick.max_iterations = std::min(config_.max_iterations, 6);
          quick.freeze_factor = 1e9;
          const RegistrationOutput coarse_fit =
              registerToSurface(reference_->surface, reference_->points, nullptr, frame.points,
                                constraints(tracked, ok), camera_.fx, initial, quick);
          if (coarse_fit.points_used >= config_.min_points && coarse_fit.transform.matrix().allFinite())
          {
            initial = coarse_fit.transform;
            texture_predicted = true;
          }
        }
        n = tracker_->refineAll(predict(initial), dots, &tracked, &ok);
      }
      else
        n = tracker_->trackPyramidal(predict(initial), {}, dots, &tracked, &ok);
      if (texture_note.empty() && n < config_.texture_min_features)
        texture_note = "only " + std::to_string(n) + " texture features tracked";
      else if (texture_note.empty())
        texture = constraints(tracked, ok);
    }
  }

  // From the texture's coarse fit the solve settles in a few iterations;
  // beyond that the robust weights of a few marginal features only flip.
  PoseDeltaParams solve = config_;
  if (texture_predicted)
    solve.max_iterations = std::min(config_.max_iterations, kIterationsAfterCoarseFit);
  const RegistrationOutput reg =
      registerToSurface(reference_->surface, reference_->points, config_.symmetric ? &current_surface : nullptr,
                        frame.points, texture, has_camera_ ? camera_.fx : 1.0, initial, solve);
  result.points_used = reg.points_used;
  result.features_used = reg.features_used;
  result.iterations = reg.iterations;
  result.sigma_geometry_m = reg.sigma_geometry_m;
  result.sigma_texture_px = texture.empty() ? 0.0 : reg.sigma_texture_px;
  result.rms_residual_m = reg.rms_geometry_m;

  Matrix6d cov = reg.covariance;
  Eigen::Isometry3d estimate = reg.transform;
  if (chained)
  {
    const Matrix6d A = adjoint(reg.transform);
    cov = reg.covariance + A * chained_covariance_ * A.transpose();
    estimate = reg.transform * chained_;
  }
  result.transform = estimate;
  result.covariance = cov;

  std::ostringstream status;
  std::string unobservable;
  for (int a = 0; a < 6; ++a)
  {
    const double sigma = std::sqrt(std::max(0.0, cov(a, a)));
    const double bound = a < 3 ? config_.max_sigma_translation_m : config_.max_sigma_rotation_rad;
    result.unobservable[a] = !(sigma <= bound);
    if (result.unobservable[a])
      unobservable += std::string(unobservable.empty() ? "" : " ") + kAxisNames[a];
  }
  const bool enough = reg.points_used >= config_.min_points;
  const bool residual_ok = reg.rms_geometry_m <= config_.max_rms_residual_m;
  result.valid = enough && residual_ok && unobservable.empty();
  if (!enough)
    status << "too few points on the reference surface: " << reg.points_used << " of " << valid_points << " (need "
           << config_.min_points << "; the rig moved off the mapped rock?)";
  else if (!residual_ok)
    status << "residual " << reg.rms_geometry_m * 1e3 << " mm exceeds " << config_.max_rms_residual_m * 1e3
           << " mm: the surface does not match the reference";
  else if (!unobservable.empty())
  {
    status << "unobservable: " << unobservable << " (";
    if (!texture_wanted)
      status << "smooth or flat surface, texture off";
    else if (!texture_note.empty())
      status << "smooth or flat surface; texture unused: " << texture_note;
    else
      status << "weak geometry and texture: " << reg.features_used << " features";
    status << ")";
  }
  else
  {
    status << "ok: " << reg.points_used << " points";
    if (texture_wanted)
    {
      if (texture_note.empty())
        status << ", " << reg.features_used << " texture features";
      else
        status << ", texture unused: " << texture_note;
    }
  }
  if (result.locked_now)
    status << "; reference locked on this frame";
  result.status = status.str();

  // The next frame starts from the last valid estimate: an invalid one may
  // carry garbage on its weak axes, and a wrong texture prediction does not
  // recover by itself.
  if (result.valid)
  {
    if (chained)
    {
      chained_ = estimate;
      chained_covariance_ = cov;
      lock(frame);
    }
    else
      last_estimate_ = reg.transform;
  }
  return result;
}

}  // namespace structured_light_stabilizer
