#include "structured_light_stabilizer/pose/pose_delta.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "pose/reference_fusion.h"
#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/pose/texture_landmarks.h"

namespace structured_light_stabilizer
{

namespace
{

const char* const kAxisNames[6] = {"tx", "ty", "tz", "rx", "ry", "rz"};

// Pose predictions (the geometry-only one and the coarse texture fit) are
// only starting points: a few iterations, no frozen directions.
constexpr int kPredictionIterations = 6;
// Prior of the geometry-only prediction (see measureTexture()).
constexpr double kPredictionPriorM = 0.005;
constexpr double kPredictionPriorRad = 0.005;
// Coarse texture tracks needed for a texture prediction.
constexpr int kMinCoarseFeatures = 12;
// Iterations of the final solve when it starts from the coarse texture fit.
constexpr int kIterationsAfterCoarseFit = 8;

PoseDeltaParams predictionParams(const PoseDeltaParams& config, bool firm_prior)
{
  PoseDeltaParams quick = config;
  quick.max_iterations = std::min(config.max_iterations, kPredictionIterations);
  quick.freeze_factor = 1e9;
  if (firm_prior)
  {
    quick.prior_sigma_translation_m = std::min(config.prior_sigma_translation_m, kPredictionPriorM);
    quick.prior_sigma_rotation_rad = std::min(config.prior_sigma_rotation_rad, kPredictionPriorRad);
  }
  return quick;
}

}  // namespace

struct PoseDeltaEstimator::Frame
{
  int rows = 0;
  int cols = 0;
  std::vector<Eigen::Vector3d> points;
  BeamSurface surface;
  double dot_spacing_m = 0.0;   // the dots' median spacing (the surface may be built on a denser map)
  double median_depth_m = 0.0;  // the dots' median z (camera frame)
};

struct PoseDeltaEstimator::TextureMeasurement
{
  TextureObservations observations;
  std::string note;          // why the texture is not used ("" when used or not wanted)
  bool predicted = false;    // the initial guess comes from the coarse texture fit or the motion filter
  bool from_motion = false;  // ... from the motion filter (no coarse track)
};

struct PoseDeltaEstimator::FusionFrame
{
  std::vector<Eigen::Vector3d> points;
  Eigen::Isometry3d pose;  // p_cur = pose * p_ref, solved again as the surface is
  TextureObservations texture;
  double sigma_geometry_m = 0.0;
};

PoseDeltaEstimator::PoseDeltaEstimator(const PoseDeltaParams& config) : texture_(new TextureLandmarks)
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
  PoseFilterParams fp;
  fp.acceleration_noise = config.filter_acceleration_noise;
  fp.angular_acceleration_noise = config.filter_angular_acceleration_noise;
  motion_.setParams(fp);
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
    texture_->dropFeatures();
}

void PoseDeltaEstimator::requestLock()
{
  lock_pending_ = true;
}

void PoseDeltaEstimator::reset(bool lock_on_next_frame)
{
  has_reference_ = false;
  reference_.reset();
  fusion_.clear();
  fused_ = false;
  texture_->clear();
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

void PoseDeltaEstimator::lock(const PoseDeltaInput& frame)
{
  std::unique_ptr<Frame> ref(new Frame);
  ref->rows = frame.rows;
  ref->cols = frame.cols;
  ref->points = frame.points;
  const bool dense = frame.surface_rows >= 2 && frame.surface_cols >= 2 &&
                     frame.surface_points.size() == static_cast<size_t>(frame.surface_rows) * frame.surface_cols;
  if (dense)
    ref->surface.build(frame.surface_rows, frame.surface_cols, frame.surface_points, config_.max_edge_ratio);
  if (!dense || ref->surface.empty())
    ref->surface.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);
  {
    BeamSurface dots;
    dots.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);
    ref->dot_spacing_m = dots.medianSpacing();
  }
  {
    std::vector<double> z;
    for (const Eigen::Vector3d& p : frame.points)
      if (p.allFinite() && p.z() > 0.0)
        z.push_back(p.z());
    ref->median_depth_m = detail::medianInPlace(z.begin(), z.end());  // 0 without points
  }
  texture_->clear();
  // A strobed pair's ambient frame carries the texture without the dots.
  reference_ambient_ = !frame.ambient_image.empty();
  const bool lock_image = !reference_ambient_ && !frame.lock_image.empty();
  const cv::Mat& image = lock_image ? frame.lock_image : textureImage(frame);
  if (config_.use_texture && has_camera_ && !image.empty() && image.cols == camera_.width &&
      image.rows == camera_.height)
  {
    TextureExposure exposure;
    exposure.offset = exposureOffset(frame);
    exposure.dots_in_image = !reference_ambient_ && !lock_image;
    texture_->lock(config_, camera_, image, frame.texture_channel, frame.points, ref->surface, exposure);
    // Two ambient frames around the lock: each feature is lifted where it
    // was at the instant of the points, no velocity needed.
    const double fraction = bracketFraction(frame);
    if (fraction >= 0.0)
      texture_->centreBetween(frame.ambient_after_image, frame.texture_channel, fraction, camera_, frame.points,
                              ref->surface, config_);
  }
  reference_ = std::move(ref);
  last_tracked_ = 0;  // the first frame after a lock takes the coarse track
  has_reference_ = true;
  lock_pending_ = false;
  last_estimate_ = Eigen::Isometry3d::Identity();
  fusion_.clear();
  fused_ = false;
}

PoseDeltaResult PoseDeltaEstimator::process(const PoseDeltaInput& frame)
{
  // Until there is a solution: the last estimate, with the prior's
  // uncertainty on every axis.
  PoseDeltaResult result;
  result.covariance = Matrix6d::Zero();
  for (int a = 0; a < 6; ++a)
    result.covariance(a, a) = a < 3 ? config_.prior_sigma_translation_m * config_.prior_sigma_translation_m
                                    : config_.prior_sigma_rotation_rad * config_.prior_sigma_rotation_rad;
  result.unobservable.fill(true);
  const bool chained = config_.mode == PoseDeltaMode::kFrameToFrame;
  result.transform = chained ? Eigen::Isometry3d(last_estimate_ * chained_) : last_estimate_;

  int valid_points = 0;
  std::string bad = checkMap(frame, &valid_points);
  if (!bad.empty())
  {
    result.status = bad + (has_reference_ ? "" : "; no reference locked yet");
    return result;
  }
  bad = referenceFor(frame, &result);
  if (!bad.empty())
  {
    result.status = bad;
    return result;
  }

  // Texture: track the reference features into this image, starting where
  // the last estimate puts them.
  Eigen::Isometry3d initial = last_estimate_;
  TextureMeasurement texture;
  if (config_.use_texture)
    texture = measureTexture(frame, &initial);
  const RegistrationOutput reg = registerFrame(frame, texture, initial);
  report(reg, texture, valid_points, &result);
  advance(frame, result, reg);
  collectForFusion(frame, texture, reg, result);
  track(frame, &result);
  return result;
}

std::string PoseDeltaEstimator::referenceFor(const PoseDeltaInput& frame, PoseDeltaResult* result)
{
  if (!lock_pending_ && !has_reference_)
    return "no reference locked: call the pose_delta/lock service";
  if (lock_pending_)
  {
    BeamSurface probe;
    probe.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);
    if (probe.validCells() < 4)
      return "cannot lock on this map: only " + std::to_string(probe.validCells()) +
             " surface cells between valid neighbouring dots";
    // The rig's velocity stays what it was; the pose starts again here.
    // (A reference centred between two ambient frames is at the instant of
    // the points: its gap's motion is zero.)
    lock_velocity_known_ = motion_.started() || !frame.ambient_after_image.empty();
    lock_velocity_ = motion_.started() && frame.ambient_after_image.empty() ? motion_.velocity() : Vector6d::Zero();
    lock(frame);
    motion_.relock();
    chained_ = Eigen::Isometry3d::Identity();
    chained_covariance_ = Matrix6d::Zero();
    result->locked_now = true;
    result->transform = Eigen::Isometry3d::Identity();
  }
  if (frame.rows != reference_->rows || frame.cols != reference_->cols)
    return "cloud layout " + std::to_string(frame.rows) + "x" + std::to_string(frame.cols) +
           " differs from the reference's " + std::to_string(reference_->rows) + "x" +
           std::to_string(reference_->cols) + "; lock again (pose_delta/lock)";
  return "";
}

const cv::Mat& PoseDeltaEstimator::textureImage(const PoseDeltaInput& frame) const
{
  return reference_ambient_ ? frame.ambient_image : frame.image;
}

double PoseDeltaEstimator::bracketFraction(const PoseDeltaInput& frame) const
{
  if (!reference_ambient_ || frame.ambient_image.empty() || frame.ambient_after_image.empty())
    return -1.0;
  const double fraction =
      (frame.stamp_s - frame.ambient_stamp_s) / (frame.ambient_after_stamp_s - frame.ambient_stamp_s);
  return fraction >= 0.0 && fraction <= 1.0 ? fraction : -1.0;
}

// The reference texture was lifted from the lock's ambient frame as if it
// had been exposed with the points: what the texture measures is the motion
// between the two ambient exposures, the pose of the points but for the
// change of velocity since the lock, times the gap.
Eigen::Isometry3d PoseDeltaEstimator::exposureOffset(const PoseDeltaInput& frame) const
{
  const double gap = frame.ambient_stamp_s - frame.stamp_s;
  if (!reference_ambient_ || !std::isfinite(gap) || !motion_.started() || !lock_velocity_known_ ||
      bracketFraction(frame) >= 0.0)
    return Eigen::Isometry3d::Identity();
  return applyIncrement((motion_.velocity() - lock_velocity_) * gap, Eigen::Isometry3d::Identity());
}

std::string PoseDeltaEstimator::textureUnavailable(const PoseDeltaInput& frame) const
{
  if (!has_camera_)
    return "no camera_info for the texture";
  if (!texture_->hasReferenceImage())
    return "the reference has no image (lock again with images flowing)";
  if (texture_->empty())
    return "no trackable texture in the reference image";
  const cv::Mat& image = textureImage(frame);
  if (image.empty())
    return reference_ambient_ ? "no ambient image for this cloud (the reference was locked on one)"
                              : "no image for this cloud";
  if (image.cols != camera_.width || image.rows != camera_.height)
    return "image size differs from camera_info";
  return "";
}

bool PoseDeltaEstimator::refit(const PoseDeltaInput& frame, const TextureObservations& texture,
                               const PoseDeltaParams& params, Eigen::Isometry3d* pose) const
{
  const RegistrationOutput fit =
      registerToSurface(reference_->surface, reference_->points, nullptr, frame.points, texture, *pose, params);
  if (fit.points_used < config_.min_points || !fit.transform.matrix().allFinite())
    return false;
  *pose = fit.transform;
  return true;
}

PoseDeltaEstimator::TextureMeasurement PoseDeltaEstimator::measureTexture(const PoseDeltaInput& frame,
                                                                          Eigen::Isometry3d* initial)
{
  TextureMeasurement m;
  m.note = textureUnavailable(frame);
  if (!m.note.empty())
    return m;
  if (!texture_->setFrame(camera_, textureImage(frame), frame.texture_channel, frame.points, !reference_ambient_))
  {
    m.note = "image unusable for tracking";
    return m;
  }
  // The texture image was exposed at offset * T.
  const Eigen::Isometry3d offset = exposureOffset(frame);
  m.observations.focal_px = camera_.fx;
  m.observations.offset = offset;
  // Geometry alone places the features on a rough rock to within a pixel or
  // two and fixes distance and tilts on any surface: the prediction when the
  // texture cannot give one. Only a prediction: one direction, a few
  // iterations, no second phase; a firm prior keeps the axes a smooth
  // surface leaves free near the last estimate (with the weak one they
  // wander by degrees on noise).
  const PoseDeltaParams geometric = predictionParams(config_, true);
  std::vector<TextureConstraint> tracked;
  if (config_.texture_refinement_window_px > 0)
  {
    // A few features tracked over the pyramid from the last estimate (a
    // wide capture range) fix the in-plane axes well enough to predict
    // every feature to a fraction of a pixel; the gain-and-offset
    // refinement from there is the measurement, and costs a fraction of
    // pyramidal tracking.
    // Between two ambient frames: the coarse track is on the first, the rig's
    // velocity carries the prediction to each (the measurement needs none).
    const double fraction = bracketFraction(frame);
    const Vector6d v = motion_.started() ? motion_.velocity() : Vector6d::Zero();
    const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
    const Eigen::Isometry3d first =
        fraction >= 0.0 ? applyIncrement(v * (frame.ambient_stamp_s - frame.stamp_s), I) : offset;
    // A smooth motion at the frame rate: the filter predicts every feature
    // within the refinement's reach, and the coarse track is not needed.
    if (fraction < 0.0 && refineFromMotion(frame, offset, initial, &tracked))
      m.predicted = m.from_motion = true;
    else
    {
      const std::vector<TextureConstraint> coarse = texture_->trackCoarse(first * *initial);
      if (static_cast<int>(coarse.size()) >= kMinCoarseFeatures)
        m.predicted = refit(frame, {coarse, camera_.fx, first}, predictionParams(config_, false), initial);
      else
        refit(frame, TextureObservations(), geometric, initial);
      if (fraction >= 0.0)
        tracked = texture_->refineBetween(
            first * *initial, applyIncrement(v * (frame.ambient_after_stamp_s - frame.stamp_s), I) * *initial,
            frame.ambient_image, frame.ambient_after_image, frame.texture_channel, fraction);
      else
        tracked = texture_->refineAll(offset * *initial);
    }
    if (fraction < 0.0)
      last_tracked_ = tracked.size();
  }
  else
  {
    refit(frame, TextureObservations(), geometric, initial);
    tracked = texture_->trackAll(offset * *initial);
  }
  if (static_cast<int>(tracked.size()) < config_.texture_min_features)
    m.note = "only " + std::to_string(tracked.size()) + " texture features tracked";
  else
    m.observations.constraints = std::move(tracked);
  return m;
}

// The filter's prediction of this frame's pose, used when its 1-sigma in
// the image (a feature anywhere in the frame, at the rock's distance) is
// within texture_motion_prediction_max_px and the refinement from it keeps
// most of the features the last frame kept; otherwise false and *initial as
// it was.
bool PoseDeltaEstimator::refineFromMotion(const PoseDeltaInput& frame, const Eigen::Isometry3d& offset,
                                          Eigen::Isometry3d* initial, std::vector<TextureConstraint>* tracked) const
{
  if (!(config_.texture_motion_prediction_max_px > 0.0) || config_.mode != PoseDeltaMode::kReference ||
      !(reference_->median_depth_m > 0.0) || last_tracked_ == 0)
    return false;
  Eigen::Isometry3d predicted;
  Matrix6d covariance;
  if (!motion_.predict(frame.stamp_s, &predicted, &covariance) || !predicted.matrix().allFinite())
    return false;
  // A feature's predicted position in the image, 1-sigma (root sum of
  // squares over the axes) where it is most sensitive: in-plane translation
  // moves it by f / z per metre, depth by r / z (r the half diagonal in
  // pixels), tilts by f per radian, roll by r.
  const double f = camera_.fx, z = reference_->median_depth_m;
  const double r = 0.5 * std::hypot(camera_.width, camera_.height);
  const Matrix6d& C = covariance;
  const double var_px = (f / z) * (f / z) * (C(0, 0) + C(1, 1)) + (r / z) * (r / z) * C(2, 2) +
                        f * f * (C(3, 3) + C(4, 4)) + r * r * C(5, 5);
  const double sigma_px = std::sqrt(std::max(0.0, var_px));
  if (!(sigma_px <= config_.texture_motion_prediction_max_px))
    return false;
  std::vector<TextureConstraint> refined = texture_->refineAll(offset * predicted);
  // A prediction off by more than the refinement's reach loses features.
  constexpr double kKeptFraction = 0.8;
  if (static_cast<double>(refined.size()) < kKeptFraction * static_cast<double>(last_tracked_) ||
      static_cast<int>(refined.size()) < config_.texture_min_features)
    return false;
  *initial = predicted;
  *tracked = std::move(refined);
  return true;
}

RegistrationOutput PoseDeltaEstimator::registerFrame(const PoseDeltaInput& frame, const TextureMeasurement& texture,
                                                     const Eigen::Isometry3d& initial) const
{
  BeamSurface current_surface;
  if (config_.symmetric)
    current_surface.build(frame.rows, frame.cols, frame.points, config_.max_edge_ratio);
  // From the texture's coarse fit the solve settles in a few iterations;
  // beyond that the robust weights of a few marginal features only flip.
  PoseDeltaParams solve = config_;
  if (texture.predicted)
    solve.max_iterations = std::min(config_.max_iterations, kIterationsAfterCoarseFit);
  return registerToSurface(reference_->surface, reference_->points, config_.symmetric ? &current_surface : nullptr,
                           frame.points, texture.observations, initial, solve);
}

void PoseDeltaEstimator::report(const RegistrationOutput& reg, const TextureMeasurement& texture, int valid_points,
                                PoseDeltaResult* result) const
{
  result->points_used = reg.points_used;
  result->features_used = reg.features_used;
  result->iterations = reg.iterations;
  result->texture_from_motion = texture.from_motion;
  result->sigma_geometry_m = reg.sigma_geometry_m;
  result->sigma_texture_px = texture.observations.constraints.empty() ? 0.0 : reg.sigma_texture_px;
  result->rms_residual_m = reg.rms_geometry_m;
  result->transform = reg.transform;
  result->covariance = reg.covariance;
  if (config_.mode == PoseDeltaMode::kFrameToFrame)
  {
    // The chain so far is uncertain on its own (left) side.
    const Matrix6d A = adjoint(reg.transform);
    result->covariance = reg.covariance + A * chained_covariance_ * A.transpose();
    result->transform = reg.transform * chained_;
  }

  std::string unobservable;
  for (int a = 0; a < 6; ++a)
  {
    const double sigma = std::sqrt(std::max(0.0, result->covariance(a, a)));
    const double bound = a < 3 ? config_.max_sigma_translation_m : config_.maxSigmaRotationRad();
    result->unobservable[a] = !(sigma <= bound);
    if (result->unobservable[a])
      unobservable += std::string(unobservable.empty() ? "" : " ") + kAxisNames[a];
  }
  const bool enough = reg.points_used >= config_.min_points;
  const bool residual_ok = reg.rms_geometry_m <= config_.max_rms_residual_m;
  result->valid = enough && residual_ok && unobservable.empty();
  result->status = describe(*result, valid_points, enough, residual_ok, unobservable, texture.note);
}

std::string PoseDeltaEstimator::describe(const PoseDeltaResult& result, int valid_points, bool enough, bool residual_ok,
                                         const std::string& unobservable, const std::string& texture_note) const
{
  std::ostringstream status;
  if (!enough)
    status << "too few points on the reference surface: " << result.points_used << " of " << valid_points << " (need "
           << config_.min_points << "; the rig moved off the mapped rock?)";
  else if (!residual_ok)
    status << "residual " << result.rms_residual_m * 1e3 << " mm exceeds " << config_.max_rms_residual_m * 1e3
           << " mm: the surface does not match the reference";
  else if (!unobservable.empty())
  {
    status << "unobservable: " << unobservable << " (";
    if (!config_.use_texture)
      status << "smooth or flat surface, texture off";
    else if (!texture_note.empty())
      status << "smooth or flat surface; texture unused: " << texture_note;
    else
      status << "weak geometry and texture: " << result.features_used << " features";
    status << ")";
  }
  else
  {
    status << "ok: " << result.points_used << " points";
    if (config_.use_texture)
    {
      if (texture_note.empty())
        status << ", " << result.features_used << " texture features";
      else
        status << ", texture unused: " << texture_note;
    }
  }
  if (result.locked_now)
    status << "; reference locked on this frame";
  return status.str();
}

// The next frame starts from the last valid estimate: an invalid one may
// carry garbage on its weak axes, and a wrong texture prediction does not
// recover by itself.
void PoseDeltaEstimator::advance(const PoseDeltaInput& frame, const PoseDeltaResult& result,
                                 const RegistrationOutput& reg)
{
  if (!result.valid)
    return;
  if (config_.mode == PoseDeltaMode::kFrameToFrame)
  {
    chained_ = result.transform;
    chained_covariance_ = result.covariance;
    lock(frame);
  }
  else
    last_estimate_ = reg.transform;
}

}  // namespace structured_light_stabilizer

namespace structured_light_stabilizer
{

void PoseDeltaEstimator::collectForFusion(const PoseDeltaInput& frame, const TextureMeasurement& texture,
                                          const RegistrationOutput& reg, const PoseDeltaResult& result)
{
  if (fused_ || config_.reference_fusion_frames <= 0 || config_.mode != PoseDeltaMode::kReference || !result.valid)
    return;
  fusion_.push_back(FusionFrame{frame.points, reg.transform, texture.observations, reg.sigma_geometry_m});
  // Refined as the frames come (after 2, 4, 8, ... of them, so that the
  // frames of the lock period gain too), for the last time after all.
  const int n = static_cast<int>(fusion_.size());
  const bool last = n >= config_.reference_fusion_frames;
  if (last || (n >= 2 && (n & (n - 1)) == 0))
    fuseReference(last);
}

// Block coordinate descent on the lock period's poses and one surface: the
// surface fitted to the lock's dots and every kept frame's dots moved back
// by its pose, the texture features lifted on it again, each frame
// registered again against it (the lock fixes the gauge: its pose is the
// identity). A few rounds settle (the poses move by far less than the
// surface's spacing).
void PoseDeltaEstimator::fuseReference(bool last)
{
  constexpr int kRounds = 3;
  fused_ = last;
  fusion::SurfaceFit fit;
  fit.spacing_m = reference_->dot_spacing_m;
  fit.max_edge_ratio = config_.max_edge_ratio;
  std::vector<double> noise;
  for (const FusionFrame& f : fusion_)
    noise.push_back(f.sigma_geometry_m);
  fit.noise_m = std::max(config_.min_geometry_sigma_m, detail::medianInPlace(noise.begin(), noise.end()));
  for (int round = 0; round < kRounds; ++round)
  {
    std::vector<Eigen::Vector3d> all = reference_->points;
    for (const FusionFrame& f : fusion_)
    {
      const Eigen::Isometry3d back = f.pose.inverse();
      for (const Eigen::Vector3d& p : f.points)
        if (isUsablePoint(p))
          all.push_back(back * p);
    }
    BeamSurface fused;
    if (!fusion::fitSurface(all, fit, &fused))
      break;
    reference_->surface = std::move(fused);
    texture_->relift(reference_->surface, config_);
    std::vector<TextureObservations> seen;
    std::vector<Eigen::Isometry3d> poses;
    for (const FusionFrame& f : fusion_)
    {
      seen.push_back(f.texture);
      poses.push_back(f.pose);
    }
    texture_->refineDepths(seen, poses, config_.texture_error_inflation);
    for (FusionFrame& f : fusion_)
    {
      texture_->update(&f.texture.constraints);
      BeamSurface current;
      if (config_.symmetric)
        current.build(reference_->rows, reference_->cols, f.points, config_.max_edge_ratio);
      const RegistrationOutput reg =
          registerToSurface(reference_->surface, reference_->points, config_.symmetric ? &current : nullptr, f.points,
                            f.texture, f.pose, config_);
      if (reg.points_used >= config_.min_points && reg.transform.matrix().allFinite())
        f.pose = reg.transform;
    }
  }
  last_estimate_ = fusion_.back().pose;
  if (last)
    fusion_.clear();
}

void PoseDeltaEstimator::track(const PoseDeltaInput& frame, PoseDeltaResult* result)
{
  result->raw_transform = result->transform;
  result->raw_covariance = result->covariance;
  if (!has_reference_)
    return;
  // The motion is always followed (its velocity carries a strobed ambient
  // frame to the instant of the dots); the result becomes the filter's only
  // when asked.
  if (result->valid)
  {
    // Without a velocity at the lock, the first one known afterwards stands for it.
    if (motion_.update(frame.stamp_s, result->transform, result->covariance) && !lock_velocity_known_)
    {
      lock_velocity_ = motion_.velocity();
      lock_velocity_known_ = true;
    }
    if (!config_.filter)
      return;
    result->transform = motion_.pose();
    result->covariance = motion_.poseCovariance();
    result->filtered = true;
    return;
  }
  // An invalid frame: the filter's prediction, still not valid.
  Eigen::Isometry3d pose;
  Matrix6d covariance;
  if (config_.filter && motion_.predict(frame.stamp_s, &pose, &covariance))
  {
    result->transform = pose;
    result->covariance = covariance;
    result->filtered = true;
  }
}

}  // namespace structured_light_stabilizer
