#include "structured_light_stabilizer/control/inertial_fusion.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace structured_light_stabilizer
{

namespace
{

// PoseDelta's status phrases (pose_delta.cpp, describe()).
constexpr const char* kLockedPhrase = "reference locked on this frame";
constexpr const char* kUnobservablePrefix = "unobservable:";
// The reference is the locked camera pose by definition: its offset from
// itself is known to this (rad, m), not exactly 0 (a singular covariance).
constexpr double kLockSigma = 1e-6;
// What is released when the IMU and the camera disagree, or the IMU was
// silent, so that the next camera estimates set the state afresh (rad, m, m/s).
constexpr double kReleaseRotation = 0.01, kReleasePosition = 0.01, kReleaseVelocity = 1.0;
constexpr double kReleaseGyroBias = 0.05, kReleaseAccelBias = 0.5;  // rad/s, m/s^2
// Fewest IMU samples that make a gravity estimate at the lock.
constexpr int kGravitySamples = 8;

using Matrix15d = InertialFusion::Matrix15d;
using State = InertialFusion::State;

bool finitePositive(double v)
{
  return std::isfinite(v) && v > 0.0;
}

std::string ms(double s)
{
  return std::to_string(static_cast<long>(std::lround(s * 1e3))) + " ms";
}

bool isPartial(const CameraMeasurement& c)
{
  return !c.valid && c.status.rfind(kUnobservablePrefix, 0) == 0;
}

// Adds sigma^2 to the diagonal of the 3x3 block at `at`.
void release(Matrix15d* P, int at, double sigma)
{
  P->block<3, 3>(at, at) += Eigen::Matrix3d::Identity() * sigma * sigma;
}

}  // namespace

std::string InertialFusionParams::validate() const
{
  std::ostringstream why;
  const double positive[] = {gyro_noise_density,      gyro_bias_random_walk,   accel_noise_density,
                             accel_bias_random_walk,  initial_gyro_bias_sigma, initial_accel_bias_sigma,
                             initial_velocity_sigma,  gravity_window,          camera_covariance_scale,
                             min_sigma_translation,   min_sigma_rotation,      max_nis,
                             imu_timeout,             camera_timeout,          history,
                             valid_sigma_translation, valid_sigma_rotation};
  if (!std::all_of(std::begin(positive), std::end(positive), finitePositive))
    why << "noise densities, sigmas, windows, timeouts and max_nis must be finite and > 0; ";
  if (inconsistent_updates < 1 || recovery_updates < 1 || nis_window < 1)
    why << "inconsistent_updates, recovery_updates and nis_window must be >= 1; ";
  if (!finitePositive(max_mean_nis))
    why << "max_mean_nis must be finite and > 0; ";
  std::string s = why.str();
  if (!s.empty())
    s.resize(s.size() - 2);
  return s;
}

std::string ImuMount::validate() const
{
  if (!rotation_camera_imu.coeffs().allFinite() || std::abs(rotation_camera_imu.norm() - 1.0) > 1e-3)
    return "the IMU rotation must be a unit quaternion (x y z w)";
  if (!lever_arm_m.allFinite() || !std::isfinite(time_offset_s))
    return "the lever arm and the time offset must be finite";
  return "";
}

InertialFusion::InertialFusion(const InertialFusionParams& params, const ImuMount& mount) : mount_(mount)
{
  const std::string why = mount.validate();
  if (!why.empty())
    throw std::invalid_argument("inertial fusion: " + why);
  R_ci_ = mount.rotation_camera_imu.normalized().toRotationMatrix();
  setParams(params);
}

void InertialFusion::setParams(const InertialFusionParams& params)
{
  const std::string why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("inertial fusion: " + why);
  params_ = params;
}

void InertialFusion::reset()
{
  events_.clear();
  initialized_ = false;
  last_imu_t_ = last_lock_t_ = last_good_camera_t_ = -1e300;
  camera_problem_.clear();
  partial_status_.clear();
  rejected_in_row_ = recovering_ = 0;
  recent_nis_.clear();
  last_nis_ = 0.0;
}

Eigen::Vector3d InertialFusion::gyroBias() const
{
  return events_.empty() ? Eigen::Vector3d::Zero() : events_.back().state.bg;
}

Eigen::Vector3d InertialFusion::accelBias() const
{
  return events_.empty() ? Eigen::Vector3d::Zero() : events_.back().state.ba;
}

// ---------------------------------------------------------------------------
// Inputs

// Inserts by time and returns the index; at equal times the IMU samples
// come first (whatever the order of arrival: the same state either way).
size_t InertialFusion::insert(Event e)
{
  auto at = events_.end();
  const auto after = [&](const Event& x)
  { return x.t > e.t || (x.t == e.t && e.kind == EventKind::kImu && x.kind != EventKind::kImu); };
  while (at != events_.begin() && after(*std::prev(at)))
    --at;
  const size_t index = static_cast<size_t>(at - events_.begin());
  events_.insert(at, std::move(e));
  return index;
}

bool InertialFusion::addImu(const ImuMeasurement& m, FusedEstimate* out, std::string* why)
{
  if (!std::isfinite(m.stamp) || !m.angular_velocity.allFinite() || !m.linear_acceleration.allFinite())
  {
    *why = "NaN or infinite values in the IMU sample";
    return false;
  }
  const double t = m.stamp + mount_.time_offset_s;
  if (!(t > last_imu_t_))
  {
    *why = "IMU stamp " + std::to_string(m.stamp) + " s is not after the last sample's";
    return false;
  }
  Event e;
  e.kind = EventKind::kImu;
  e.t = t;
  e.imu = m;
  e.gap = initialized_ && t - last_imu_t_ > params_.imu_timeout;
  if (e.gap)
  {
    recovering_ = params_.recovery_updates;
    recovery_reason_ = "IMU resumed after a " + ms(t - last_imu_t_) + " gap";
  }
  last_imu_t_ = t;
  const size_t index = insert(std::move(e));
  // Camera events just before it used extrapolated rates: replayed with these.
  size_t from = index;
  while (from > 0 && events_[from - 1].kind != EventKind::kImu)
    --from;
  process(from);
  tryPendingLock();
  prune();
  const auto done = std::find_if(events_.rbegin(), events_.rend(), [t](const Event& x) { return x.t <= t; });
  if (done == events_.rend() || !done->has_state)
  {
    *out = FusedEstimate();
    out->stamp = t;
    out->status = "no reference locked yet (waiting for PoseDelta's lock)";
    return true;
  }
  *out = output(done->state, invalidReason(done->state));
  if (out->valid && announce_lock_)
  {
    // The controller restarts its jump test from the new reference.
    out->status += std::string("; ") + kLockedPhrase;
    announce_lock_ = false;
  }
  return true;
}

CameraUpdate InertialFusion::addCamera(const CameraMeasurement& c, std::string* why)
{
  CameraUpdate u;
  u.frame.stamp = c.stamp;
  if (!std::isfinite(c.stamp) || !c.transform.matrix().allFinite() || !c.covariance.allFinite())
  {
    *why = u.frame.status = "NaN or infinite values in the camera estimate";
    return u;
  }
  if (initialized_ && c.stamp - last_imu_t_ > params_.imu_timeout)
  {
    // The controller hears nothing from a silent IMU: this is its estimate.
    u.silent_imu = true;
    u.fused.stamp = c.stamp;
    u.fused.status = "IMU silent for " + ms(c.stamp - last_imu_t_);
  }
  if (c.valid && c.status.find(kLockedPhrase) != std::string::npos)
    return addLock(c, u, why);
  if (!initialized_)
    *why = "no reference locked yet";
  else if (u.silent_imu || inImuGap(c.stamp))
    *why = "no IMU data around the estimate's stamp: not fused";
  else if (c.stamp <= last_lock_t_)
    *why = "estimate from before the last lock";
  else if (c.stamp < events_.front().t)
    *why = "estimate " + ms(last_imu_t_ - c.stamp) + " old, beyond the fusion's history (~history)";
  else if (!c.valid && !isPartial(c))
  {
    // Not fused; the output is invalid at once.
    camera_problem_ = "camera estimate invalid: " + (c.status.empty() ? std::string("no status") : c.status);
    *why = camera_problem_;
  }
  if (!why->empty())
  {
    u.frame.status = *why;
    return u;
  }
  Event e;
  e.kind = EventKind::kCamera;
  e.t = c.stamp;
  e.camera = c;
  const size_t index = insert(std::move(e));
  process(index);
  const Event& done = events_[index];
  u.used = done.decision != Decision::kReject;
  if (!u.used)
    *why = "innovation test failed (NIS " + std::to_string(done.nis) + " > " + std::to_string(params_.max_nis) +
           "): estimate rejected as an outlier";
  u.frame = output(done.state, u.used ? invalidReason(done.state) : *why);
  prune();
  return u;
}

CameraUpdate InertialFusion::addLock(const CameraMeasurement& c, CameraUpdate u, std::string* why)
{
  if (c.stamp <= last_lock_t_ || (initialized_ && c.stamp < events_.front().t))
  {
    *why = u.frame.status = "a lock older than the last one, or than the history: ignored";
    return u;
  }
  last_lock_t_ = c.stamp;
  Event e;
  e.kind = EventKind::kLock;
  e.t = c.stamp;
  e.camera = c;
  const size_t index = insert(std::move(e));
  camera_problem_.clear();
  partial_status_.clear();
  rejected_in_row_ = 0;
  last_good_camera_t_ = c.stamp;
  announce_lock_ = true;
  if (!initialized_)
  {
    pending_lock_ = true;
    tryPendingLock();  // processes from the lock when it starts the filter
  }
  else
    process(index);
  const auto lock = std::find_if(events_.begin(), events_.end(),
                                 [&](const Event& x) { return x.kind == EventKind::kLock && x.t == c.stamp; });
  if (!initialized_ || lock == events_.end() || !lock->has_state)
  {
    *why = u.frame.status = "locked; waiting for IMU data around the lock (gravity)";
    return u;
  }
  u.used = true;
  u.frame = output(lock->state, invalidReason(lock->state));
  u.frame.status += std::string("; ") + kLockedPhrase;
  return u;
}

// The first lock starts the filter once the IMU has spoken around it: gravity
// is the mean specific force over gravity_window before the lock (and a
// little after it when the IMU is late); the velocity is not known yet.
void InertialFusion::tryPendingLock()
{
  if (!pending_lock_)
    return;
  size_t lock_index = events_.size();
  for (size_t i = 0; i < events_.size(); ++i)
    if (events_[i].kind == EventKind::kLock && events_[i].t == last_lock_t_)
      lock_index = i;
  if (lock_index == events_.size())
  {
    pending_lock_ = false;  // pruned: the next lock starts it
    return;
  }
  // The samples before the lock within the window (once one at or after it
  // came: all of them are in), or the first ones after it when the IMU
  // started later. Chosen by stamp, not by arrival: the same gravity
  // whatever the latencies.
  if (last_imu_t_ < last_lock_t_)
    return;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  int n = 0;
  for (const Event& e : events_)
    if (e.kind == EventKind::kImu && e.t >= last_lock_t_ - params_.gravity_window && e.t < last_lock_t_)
    {
      sum += e.imu.linear_acceleration;
      ++n;
    }
  if (n < kGravitySamples)
  {
    sum.setZero();
    n = 0;
    for (const Event& e : events_)
      if (e.kind == EventKind::kImu && e.t >= last_lock_t_ && n < kGravitySamples)
      {
        sum += e.imu.linear_acceleration;
        ++n;
      }
    if (n < kGravitySamples)
      return;
  }
  gravity_ = -(R_ci_ * (sum / n));
  pending_lock_ = false;
  initialized_ = true;
  recovering_ = params_.recovery_updates;
  recovery_reason_ = "started at the lock, the velocity not yet known";
  process(lock_index);
}

// ---------------------------------------------------------------------------
// The history: events by time, each with the state after it

// True when t falls in a silence of the IMU that a later sample ended.
bool InertialFusion::inImuGap(double t) const
{
  double previous = -1e300;
  for (const Event& e : events_)
    if (e.kind == EventKind::kImu)
    {
      if (e.t >= t)
        return e.gap && previous < t;
      previous = e.t;
    }
  return false;
}

void InertialFusion::process(size_t from)
{
  for (size_t j = from; j < events_.size(); ++j)
  {
    Event& e = events_[j];
    const Event* before = nullptr;
    for (size_t i = j; i-- > 0;)
      if (events_[i].has_state)
      {
        before = &events_[i];
        break;
      }
    e.has_state = false;
    if (!before)
    {
      // The first lock starts the filter; nothing before it has a state.
      if (e.kind == EventKind::kLock && initialized_)
      {
        e.state = initialState(e.t);
        e.has_state = true;
      }
      continue;
    }
    State s = before->state;
    if (const ImuMeasurement* rates = ratesFor(j))
      propagate(*rates, e.t, &s);
    s.t = e.t;
    if (e.kind == EventKind::kImu && e.gap)
    {
      release(&s.P, 0, kReleaseRotation);
      release(&s.P, 3, kReleasePosition);
      release(&s.P, 6, kReleaseVelocity);
    }
    else if (e.kind == EventKind::kLock)
      relock(&s);
    else if (e.kind == EventKind::kCamera)
      decideAndUpdate(&e, &s);
    e.state = s;
    e.has_state = true;
  }
}

// A camera event: decided once (when it comes), replayed as decided.
void InertialFusion::decideAndUpdate(Event* e, State* s)
{
  if (e->decision == Decision::kPending)
  {
    State trial = *s;
    double nis = 0.0;
    update(e->camera, &trial, &nis);
    e->nis = last_nis_ = nis;
    const bool outage = e->t - last_good_camera_t_ > params_.camera_timeout;
    if (outage)
    {
      e->decision = Decision::kReleaseApply;
      recovering_ = std::max(recovering_, params_.recovery_updates);
      recovery_reason_ = "camera corrections resumed after " + ms(e->t - last_good_camera_t_);
      rejected_in_row_ = 0;
    }
    else if (nis > params_.max_nis)
    {
      if (++rejected_in_row_ >= params_.inconsistent_updates)
      {
        e->decision = Decision::kReleaseApply;
        recovering_ = params_.recovery_updates;
        std::ostringstream why;
        why.precision(3);
        why << "IMU and camera disagree (NIS " << nis << " in " << rejected_in_row_
            << " estimates in a row: an IMU bias step?); re-converging";
        recovery_reason_ = why.str();
        rejected_in_row_ = 0;
        recent_nis_.clear();
      }
      else
        e->decision = Decision::kReject;
    }
    else
    {
      e->decision = Decision::kApply;
      rejected_in_row_ = 0;
      if (recovering_ > 0)
        --recovering_;
      // A slow drift passes each test; its mean over a window does not.
      recent_nis_.push_back(nis);
      while (static_cast<int>(recent_nis_.size()) > params_.nis_window)
        recent_nis_.pop_front();
      double mean = 0.0;
      for (double x : recent_nis_)
        mean += x / static_cast<double>(recent_nis_.size());
      if (static_cast<int>(recent_nis_.size()) == params_.nis_window && mean > params_.max_mean_nis)
      {
        e->decision = Decision::kReleaseApply;
        recovering_ = params_.recovery_updates;
        std::ostringstream why;
        why.precision(3);
        why << "IMU and camera disagree (mean NIS " << mean << " over " << params_.nis_window
            << " estimates: an IMU bias step?); re-converging";
        recovery_reason_ = why.str();
        recent_nis_.clear();
      }
    }
    if (e->decision != Decision::kReject)
    {
      camera_problem_.clear();
      partial_status_ = isPartial(e->camera) ? e->camera.status : std::string();
      last_good_camera_t_ = std::max(last_good_camera_t_, e->t);
    }
  }
  if (e->decision == Decision::kReject)
    return;
  if (e->decision == Decision::kReleaseApply)
  {
    release(&s->P, 0, kReleaseRotation);
    release(&s->P, 3, kReleasePosition);
    release(&s->P, 6, kReleaseVelocity);
    release(&s->P, 9, kReleaseGyroBias);
    release(&s->P, 12, kReleaseAccelBias);
  }
  double nis = 0.0;
  update(e->camera, s, &nis);
}

// The rates in force over the interval that ends at events_[index]: those of
// the first IMU sample at or after it (a sample is the mean over the period
// ending at its stamp), else the last one before it (extrapolated).
const ImuMeasurement* InertialFusion::ratesFor(size_t index) const
{
  for (size_t i = index; i < events_.size(); ++i)
    if (events_[i].kind == EventKind::kImu)
      return &events_[i].imu;
  for (size_t i = index; i-- > 0;)
    if (events_[i].kind == EventKind::kImu)
      return &events_[i].imu;
  return nullptr;
}

void InertialFusion::prune()
{
  if (events_.empty())
    return;
  // Before the filter starts: the gravity window before a lock up to
  // `history` late.
  const double keep_from =
      events_.back().t - (initialized_ ? params_.history : params_.history + params_.gravity_window);
  while (events_.size() > 2)
  {
    if (initialized_ && !pending_lock_ && !events_[0].has_state && events_[1].t <= last_lock_t_)
      events_.pop_front();  // before the lock: of no use once the filter runs
    else if (events_[1].t < keep_from && (events_[1].has_state || !initialized_))
      events_.pop_front();  // one state before the window stays, the base of a replay
    else
      break;
  }
}

// ---------------------------------------------------------------------------
// The filter

State InertialFusion::initialState(double t) const
{
  State s;
  s.t = t;
  s.R.setIdentity();
  s.p = mount_.lever_arm_m;  // the camera at the origin
  s.v.setZero();
  s.gravity = gravity_;
  s.P.setZero();
  s.P.block<3, 3>(0, 0).diagonal().setConstant(kLockSigma * kLockSigma);
  s.P.block<3, 3>(3, 3).diagonal().setConstant(kLockSigma * kLockSigma);
  s.P.block<3, 3>(6, 6).diagonal().setConstant(std::pow(params_.initial_velocity_sigma, 2));
  s.P.block<3, 3>(9, 9).diagonal().setConstant(std::pow(params_.initial_gyro_bias_sigma, 2));
  s.P.block<3, 3>(12, 12).diagonal().setConstant(std::pow(params_.initial_accel_bias_sigma, 2));
  return s;
}

// Strapdown mechanisation over [s.t, to] with the sample's mean rates, and
// the error state's covariance (first order in dt).
void InertialFusion::propagate(const ImuMeasurement& rates, double to, State* s) const
{
  const double dt = to - s->t;
  if (!(dt > 0.0))
    return;
  const Eigen::Vector3d w = R_ci_ * (rates.angular_velocity - s->bg);  // camera frame
  const Eigen::Vector3d f = R_ci_ * (rates.linear_acceleration - s->ba);
  const Eigen::Matrix3d dR = expSO3(w * dt);
  const Eigen::Matrix3d R_mid = s->R * expSO3(0.5 * w * dt);
  const Eigen::Vector3d a = R_mid * f + s->gravity;
  Matrix15d F = Matrix15d::Identity();
  F.block<3, 3>(0, 0) = dR.transpose();
  F.block<3, 3>(0, 9) = -R_ci_ * dt;
  F.block<3, 3>(3, 6) = Eigen::Matrix3d::Identity() * dt;
  F.block<3, 3>(6, 0) = -R_mid * skew(f) * dt;
  F.block<3, 3>(6, 12) = -R_mid * R_ci_ * dt;
  s->p += s->v * dt + 0.5 * a * dt * dt;
  s->v += a * dt;
  s->R = s->R * dR;
  const Eigen::Quaterniond q(s->R);
  s->R = q.normalized().toRotationMatrix();
  Matrix15d P = F * s->P * F.transpose();
  const double gn = params_.gyro_noise_density, an = params_.accel_noise_density;
  P.block<3, 3>(0, 0).diagonal().array() += gn * gn * dt;
  P.block<3, 3>(3, 3).diagonal().array() += an * an * dt * dt * dt / 3.0;
  P.block<3, 3>(6, 6).diagonal().array() += an * an * dt;
  P.block<3, 3>(9, 9).diagonal().array() += std::pow(params_.gyro_bias_random_walk, 2) * dt;
  P.block<3, 3>(12, 12).diagonal().array() += std::pow(params_.accel_bias_random_walk, 2) * dt;
  s->P = 0.5 * (P + P.transpose());
  s->t = to;
}

// A camera estimate as a measurement of the camera's rotation and position
// in the reference frame; *nis its normalised innovation squared.
bool InertialFusion::update(const CameraMeasurement& c, State* s, double* nis) const
{
  const Eigen::Matrix3d R_meas = c.transform.linear().transpose();
  const Eigen::Vector3d p_meas = -(R_meas * c.transform.translation());
  const Eigen::Vector3d p_cam = s->p - s->R * mount_.lever_arm_m;
  Vector6d r;
  r.head<3>() = p_meas - p_cam;
  r.tail<3>() = logSO3(s->R.transpose() * R_meas);
  Eigen::Matrix<double, 6, 15> H = Eigen::Matrix<double, 6, 15>::Zero();
  H.block<3, 3>(0, 0) = s->R * skew(mount_.lever_arm_m);
  H.block<3, 3>(0, 3).setIdentity();
  H.block<3, 3>(3, 0).setIdentity();
  // PoseDelta's covariance is of a left increment (v, w) of T_cur_ref: the
  // camera position then errs by R v, the rotation by w.
  // The floor is added, not a minimum of the diagonal: PoseDelta's
  // covariance is nearly singular along the image's own constraints (tx
  // and ry move the rock's image alike: their errors correlate at -0.9998
  // in a simulated run), and the small errors of the model there (a depth
  // bias of a few hundredths of a mm) must not read as inconsistencies.
  Matrix6d C = c.covariance * params_.camera_covariance_scale;
  for (int a = 0; a < 6; ++a)
  {
    const double floor = a < 3 ? params_.min_sigma_translation : params_.min_sigma_rotation;
    C(a, a) += floor * floor;
  }
  Matrix6d M = Matrix6d::Identity();
  M.topLeftCorner<3, 3>() = R_meas;
  const Matrix6d Rm = M * C * M.transpose();
  const Matrix6d S = H * s->P * H.transpose() + Rm;
  const Eigen::LDLT<Matrix6d> ldlt(S);
  if (ldlt.info() != Eigen::Success)
    return false;
  *nis = r.dot(ldlt.solve(r));
  const Eigen::Matrix<double, 15, 6> K = s->P * H.transpose() * ldlt.solve(Matrix6d::Identity());
  const Eigen::Matrix<double, 15, 1> dx = K * r;
  const Matrix15d I_KH = Matrix15d::Identity() - K * H;
  s->P = I_KH * s->P * I_KH.transpose() + K * Rm * K.transpose();
  s->P = 0.5 * (s->P + s->P.transpose());
  s->R = s->R * expSO3(dx.segment<3>(0));
  s->p += dx.segment<3>(3);
  s->v += dx.segment<3>(6);
  s->bg += dx.segment<3>(9);
  s->ba += dx.segment<3>(12);
  return true;
}

// A re-lock: the state re-expressed in the new reference, the camera pose
// at this instant (rotation and position exactly known again).
void InertialFusion::relock(State* s) const
{
  const Eigen::Matrix3d Rt = s->R.transpose();
  const Eigen::Vector3d p_cam = s->p - s->R * mount_.lever_arm_m;
  s->p = Rt * (s->p - p_cam);
  s->v = Rt * s->v;
  s->gravity = Rt * s->gravity;
  s->R.setIdentity();
  Matrix15d T = Matrix15d::Identity();
  T.block<3, 3>(6, 6) = Rt;
  Matrix15d P = T * s->P * T.transpose();
  P.block<6, 15>(0, 0).setZero();
  P.block<15, 6>(0, 0).setZero();
  P.block<6, 6>(0, 0).diagonal().setConstant(kLockSigma * kLockSigma);
  s->P = P;
}

// ---------------------------------------------------------------------------
// The output

std::string InertialFusion::invalidReason(const State& s) const
{
  const double t = s.t;
  if (!initialized_)
    return "no reference locked yet (waiting for PoseDelta's lock)";
  if (!camera_problem_.empty())
    return camera_problem_;
  if (t - last_good_camera_t_ > params_.camera_timeout)
    return "no camera correction for " + ms(t - last_good_camera_t_) + " (IMU alone drifts)";
  if (recovering_ > 0)
    return recovery_reason_ + " (" + std::to_string(recovering_) + " more consistent camera estimates needed)";
  // The filter's own uncertainty: after a release it is honest about not
  // knowing the velocity yet, while the innovation tests already pass.
  const Matrix6d C = output(s, "").covariance;
  const double st = std::sqrt(C.topLeftCorner<3, 3>().diagonal().maxCoeff());
  const double sr = std::sqrt(C.bottomRightCorner<3, 3>().diagonal().maxCoeff());
  if (st > params_.valid_sigma_translation || sr > params_.valid_sigma_rotation)
  {
    std::ostringstream why;
    why.precision(3);
    why << "converging: 1-sigma " << st * 1e3 << " mm, " << sr * 180.0 / 3.14159265358979323846 << " deg";
    return why.str();
  }
  return "";
}

FusedEstimate InertialFusion::output(const State& s, const std::string& problem) const
{
  FusedEstimate out;
  out.stamp = s.t;
  const Eigen::Vector3d p_cam = s.p - s.R * mount_.lever_arm_m;
  out.transform.linear() = s.R.transpose();
  out.transform.translation() = -(s.R.transpose() * p_cam);
  // (v, w) of the left increment of T = T_cur_ref from (dtheta, dp):
  // v = -[r]x dtheta - R^T dp, w = -dtheta.
  Matrix6d M = Matrix6d::Zero();
  M.block<3, 3>(0, 0) = -skew(mount_.lever_arm_m);
  M.block<3, 3>(0, 3) = -s.R.transpose();
  M.block<3, 3>(3, 0) = -Eigen::Matrix3d::Identity();
  out.covariance = M * s.P.topLeftCorner<6, 6>() * M.transpose();
  if (!problem.empty())
    out.status = problem;
  else if (!partial_status_.empty())
    out.status = partial_status_ + "; fused";  // the controller reads the axes named
  else
  {
    out.valid = true;
    out.status = "ok: fused (IMU + camera)";
  }
  return out;
}

}  // namespace structured_light_stabilizer
