#include "structured_light_stabilizer/control/stabilization_controller.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace structured_light_stabilizer
{

namespace
{

constexpr const char* kAxisNames[6] = {"tx", "ty", "tz", "rx", "ry", "rz"};
// PoseDelta's status phrases (pose_delta.cpp, describe()).
constexpr const char* kLockedPhrase = "reference locked on this frame";
constexpr const char* kUnobservablePrefix = "unobservable:";
// Commands kept for the latency compensation (s): beyond the largest useful
// timeout + arm delay.
constexpr double kHistoryS = 2.0;

bool positive(double v)
{
  return std::isfinite(v) && v > 0.0;
}
bool nonNegative(double v)
{
  return std::isfinite(v) && v >= 0.0;
}

// Shrinks a group's error vector by the dead band (continuous at its edge).
Eigen::Vector3d deadBand(const Eigen::Vector3d& e, double band)
{
  const double n = e.norm();
  if (band <= 0.0)
    return e;
  if (n <= band)
    return Eigen::Vector3d::Zero();
  return e * ((n - band) / n);
}

// Scales v so that its norm is at most max.
Eigen::Vector3d clampNorm(const Eigen::Vector3d& v, double max)
{
  const double n = v.norm();
  return n > max ? Eigen::Vector3d(v * (max / n)) : v;
}

// The error of an estimate: (t, log R) of p_cur = T p_ref.
Vector6d errorOf(const Eigen::Isometry3d& T)
{
  Vector6d e;
  e.head<3>() = T.translation();
  e.tail<3>() = logSO3(T.linear());
  return e;
}

// The axes named after "unobservable:" in a PoseDelta status.
std::array<bool, 6> namedUnobservable(const std::string& status)
{
  std::array<bool, 6> named{};
  const auto at = status.find(kUnobservablePrefix);
  if (at == std::string::npos)
    return named;
  // The names run up to the parenthesis that says why.
  const auto from = at + std::string(kUnobservablePrefix).size();
  const auto end = status.find('(', from);
  std::istringstream words(status.substr(from, end == std::string::npos ? std::string::npos : end - from));
  std::string w;
  while (words >> w)
    for (int a = 0; a < 6; ++a)
      named[a] = named[a] || w == kAxisNames[a];
  return named;
}

}  // namespace

std::string StabilizationControllerParams::validate() const
{
  std::ostringstream why;
  const double gains[] = {kp_translation, ki_translation, kd_translation, kp_rotation, ki_rotation, kd_rotation};
  if (!std::all_of(std::begin(gains), std::end(gains), nonNegative))
    why << "gains must be finite and >= 0; ";
  if (!positive(max_linear_velocity) || !positive(max_angular_velocity) ||
      !positive(max_linear_acceleration) || !positive(max_angular_acceleration))
    why << "velocity and acceleration limits must be finite and > 0; ";
  if (!nonNegative(dead_band_translation) || !nonNegative(dead_band_rotation))
    why << "dead bands must be finite and >= 0; ";
  if (!positive(timeout))
    why << "timeout must be finite and > 0; ";
  if (!nonNegative(derivative_filter_s) || !nonNegative(arm_delay) || !nonNegative(arm_lag))
    why << "derivative_filter_s, arm_delay and arm_lag must be finite and >= 0; ";
  if (!positive(max_sigma_translation) || !positive(max_sigma_rotation_deg))
    why << "max_sigma_* must be > 0; ";
  if (!positive(max_jump_translation) || !positive(max_jump_rotation_deg))
    why << "max_jump_* must be > 0; ";
  std::string s = why.str();
  if (!s.empty())
    s.resize(s.size() - 2);
  return s;
}

StabilizationControllerParams fusedLoopControllerParams()
{
  // Tuned on the loop model (benchmark_stabilization, disturbance seeds
  // 1-5): the arm's 20 ms delay and 10 Hz lag bound what any controller can
  // do; a PID with a Smith predictor of the arm's model (delay 22 ms: the
  // arm's, the IMU's sample period and the transport; its lag folded in at
  // 11 ms) comes within 10 % of that bound (docs/stabilization.md, "Gains").
  StabilizationControllerParams p;
  p.kp_translation = p.kp_rotation = 50.0;
  p.ki_translation = p.ki_rotation = 200.0;
  p.kd_translation = p.kd_rotation = 1.0;
  p.derivative_filter_s = 0.003;
  p.latency_compensation = true;
  p.arm_delay = 0.022;
  p.arm_lag = 0.011;
  // The arm's own limits (sim/arm_model.h): the controller's rate limit
  // then never lags the arm.
  p.max_linear_velocity = 0.1;
  p.max_angular_velocity = 0.5;
  p.max_linear_acceleration = 1.0;
  p.max_angular_acceleration = 5.0;
  return p;
}

const char* holdReasonName(HoldReason reason)
{
  switch (reason)
  {
    case HoldReason::kNone:
      return "commanding";
    case HoldReason::kNoEstimate:
      return "no estimate";
    case HoldReason::kInvalid:
      return "invalid estimate";
    case HoldReason::kNotFinite:
      return "NaN in the estimate";
    case HoldReason::kStale:
      return "stale estimate";
    case HoldReason::kOutOfOrder:
      return "estimate out of order";
    case HoldReason::kRelocked:
      return "reference re-locked";
    case HoldReason::kJump:
      return "estimate jumped";
    case HoldReason::kAllGated:
      return "no observable axis";
  }
  return "unknown";
}

StabilizationController::StabilizationController(const StabilizationControllerParams& params)
{
  setParams(params);
}

void StabilizationController::setParams(const StabilizationControllerParams& params)
{
  const std::string why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("stabilization controller: " + why);
  params_ = params;
}

void StabilizationController::reset()
{
  integral_.setZero();
  derivative_.setZero();
  have_error_ = have_measured_ = have_estimate_ = false;
  last_stamp_ = last_command_time_ = -1e300;
  last_command_ = StabilizationCommand();
  sent_.clear();
}

StabilizationCommand StabilizationController::hold(HoldReason reason, const std::string& why, double now)
{
  // The integrator keeps its value; the derivative and the rate limiter
  // start again from this zero, so the command resumes without a jump.
  derivative_.setZero();
  have_error_ = false;
  StabilizationCommand c;
  c.hold = reason;
  c.reason = why.empty() ? holdReasonName(reason) : std::string(holdReasonName(reason)) + ": " + why;
  remember(c.twist, now);
  last_command_ = c;
  return c;
}

HoldReason StabilizationController::screen(const StabilizationEstimate& est, double now, std::string* why) const
{
  if (!est.transform.matrix().allFinite() || !est.covariance.allFinite() || !std::isfinite(est.stamp))
    return HoldReason::kNotFinite;
  if (have_estimate_ && !(est.stamp > last_stamp_))
  {
    *why = "stamp " + std::to_string(est.stamp) + " s after " + std::to_string(last_stamp_) + " s";
    return HoldReason::kOutOfOrder;
  }
  if (now - est.stamp > params_.timeout)
  {
    std::ostringstream s;
    s << static_cast<int>(std::lround((now - est.stamp) * 1e3)) << " ms old (timeout "
      << static_cast<int>(std::lround(params_.timeout * 1e3)) << " ms)";
    *why = s.str();
    return HoldReason::kStale;
  }
  const bool partial = est.status.rfind(kUnobservablePrefix, 0) == 0;
  if (!est.valid && !(partial && params_.command_observable_axes))
  {
    *why = est.status.empty() ? "no status" : est.status;
    return HoldReason::kInvalid;
  }
  if (est.status.find(kLockedPhrase) != std::string::npos)
    return HoldReason::kRelocked;
  return HoldReason::kNone;
}

std::array<bool, 6> StabilizationController::gate(const StabilizationEstimate& est, std::string* gated) const
{
  const std::array<bool, 6> named = namedUnobservable(est.status);
  std::array<bool, 6> active{};
  for (int a = 0; a < 6; ++a)
  {
    const double sigma = std::sqrt(std::max(0.0, est.covariance(a, a)));
    const double bound = a < 3 ? params_.max_sigma_translation : params_.maxSigmaRotationRad();
    active[a] = params_.axisEnabled(a) && !named[a] && sigma <= bound;
    if (!active[a])
      *gated += std::string(gated->empty() ? "" : " ") + kAxisNames[a];
  }
  return active;
}

StabilizationCommand StabilizationController::update(const StabilizationEstimate& est, double now)
{
  std::string why;
  const HoldReason screened = screen(est, now, &why);
  if (screened == HoldReason::kNotFinite || screened == HoldReason::kOutOfOrder)
    return hold(screened, why, now);  // not remembered: the next one is judged against the last good one
  const double dt = have_estimate_ ? est.stamp - last_stamp_ : 0.0;
  have_estimate_ = true;
  last_stamp_ = est.stamp;
  if (screened == HoldReason::kRelocked)
  {
    // The jump test starts again from the new reference.
    last_measured_ = errorOf(est.transform);
    have_measured_ = true;
  }
  if (screened != HoldReason::kNone)
    return hold(screened, why, now);
  const Vector6d measured = errorOf(est.transform);
  if (jumped(measured, &why))
    return hold(HoldReason::kJump, why, now);
  std::string gated;
  const std::array<bool, 6> active = gate(est, &gated);
  if (std::none_of(active.begin(), active.end(), [](bool b) { return b; }))
    return hold(HoldReason::kAllGated, "unobservable or disabled: " + gated, now);

  StabilizationCommand c;
  c.hold = HoldReason::kNone;
  c.active = active;
  c.reason = gated.empty() ? "" : "not commanded (unobservable or disabled): " + gated;
  c.latency_s = now - est.stamp;
  Vector6d e = params_.latency_compensation ? predictedError(measured, est.stamp, now) : measured;
  e.head<3>() = deadBand(e.head<3>(), params_.dead_band_translation);
  e.tail<3>() = deadBand(e.tail<3>(), params_.dead_band_rotation);
  for (int a = 0; a < 6; ++a)
    e[a] = active[a] ? e[a] : 0.0;
  c.error = e;
  const Vector6d raw = law(e, active, dt);
  c.twist = limit(raw, active, now);
  // Anti-windup (conditional integration): an axis whose command the limits
  // cut does not keep what it just integrated in the direction of the cut.
  for (int a = 0; a < 6; ++a)
    if (std::abs(c.twist[a]) + 1e-12 < std::abs(raw[a]) && raw[a] * e[a] > 0.0 && dt < 4.0 * params_.timeout)
      integral_[a] -= e[a] * dt;
  remember(c.twist, now);
  last_command_ = c;
  return c;
}

// A change beyond max_jump_* since the last usable estimate (a re-lock that
// the status did not announce, or an outlier); the new one becomes the base.
bool StabilizationController::jumped(const Vector6d& measured, std::string* why)
{
  const Vector6d change = measured - last_measured_;
  const bool jump = have_measured_ && (change.head<3>().norm() > params_.max_jump_translation ||
                                       change.tail<3>().norm() > params_.maxJumpRotationRad());
  last_measured_ = measured;
  have_measured_ = true;
  if (jump)
  {
    std::ostringstream s;
    s.precision(3);
    s << change.head<3>().norm() * 1e3 << " mm, " << change.tail<3>().norm() * 180.0 / M_PI
      << " deg since the last estimate";
    *why = s.str();
  }
  return jump;
}

StabilizationCommand StabilizationController::tick(double now)
{
  if (!have_estimate_)
    return hold(HoldReason::kNoEstimate, "none received yet", now);
  if (now - last_stamp_ > params_.timeout)
  {
    std::ostringstream s;
    s << "the last is " << static_cast<int>(std::lround((now - last_stamp_) * 1e3)) << " ms old (timeout "
      << static_cast<int>(std::lround(params_.timeout * 1e3)) << " ms)";
    return hold(HoldReason::kNoEstimate, s.str(), now);
  }
  return last_command_;
}

// The motion commanded but not yet in the estimate (a Smith predictor with
// the arm's model): each command held over [a, b) moves the arm by u (b - a)
// in the end; by the estimate's stamp T the arm had executed u (H(T - d - a)
// - H(T - d - b)) of it, with d = arm_delay and H the integral of the unit
// step response of the arm's first-order lag (time constant arm_lag):
// H(x) = x - tau (1 - exp(-x / tau)) for x > 0, else 0. The error still to
// come is taken off the measured one (first order: the error moves by -u dt).
Vector6d StabilizationController::predictedError(const Vector6d& measured, double stamp, double now) const
{
  const double d = params_.arm_delay, tau = params_.arm_lag;
  const auto H = [tau](double x)
  {
    if (x <= 0.0)
      return 0.0;
    return tau > 0.0 ? x - tau * (1.0 - std::exp(-x / tau)) : x;
  };
  Vector6d pending = Vector6d::Zero();
  for (size_t i = 0; i < sent_.size(); ++i)
  {
    const double a = sent_[i].time;
    const double b = i + 1 < sent_.size() ? sent_[i + 1].time : now;
    if (!(b > a))
      continue;
    const double remaining = (b - a) - (H(stamp - d - a) - H(stamp - d - b));
    if (remaining > 1e-12)
      pending += sent_[i].twist * remaining;
  }
  return measured - pending;
}

// PI(D) per axis; integrates over dt (0: no integration, no derivative update).
Vector6d StabilizationController::law(const Vector6d& e, const std::array<bool, 6>& active, double dt)
{
  const bool step = dt > 0.0 && dt < 4.0 * params_.timeout;
  if (step && have_error_)
  {
    // First-order filter of the error's rate (exact discretisation).
    const double alpha = params_.derivative_filter_s > 0.0 ? 1.0 - std::exp(-dt / params_.derivative_filter_s) : 1.0;
    derivative_ += alpha * ((e - last_error_) / dt - derivative_);
  }
  Vector6d u = Vector6d::Zero();
  for (int a = 0; a < 6; ++a)
  {
    if (!active[a])
      continue;
    const bool t = a < 3;
    if (step)
      integral_[a] += e[a] * dt;
    u[a] = (t ? params_.kp_translation : params_.kp_rotation) * e[a] +
           (t ? params_.ki_translation : params_.ki_rotation) * integral_[a] +
           (t ? params_.kd_translation : params_.kd_rotation) * derivative_[a];
  }
  if (step)
  {
    last_error_ = e;
    have_error_ = true;
  }
  return u;
}

// Velocity limits, then the rate limit from the last command sent; an axis
// not commanded now is zero at once (it ramps back from zero).
Vector6d StabilizationController::limit(const Vector6d& raw, const std::array<bool, 6>& active, double now) const
{
  Vector6d u;
  u.head<3>() = clampNorm(raw.head<3>(), params_.max_linear_velocity);
  u.tail<3>() = clampNorm(raw.tail<3>(), params_.max_angular_velocity);
  const double dt = std::max(0.0, now - last_command_time_);
  Vector6d prev = last_command_.twist;
  for (int a = 0; a < 6; ++a)
    prev[a] = active[a] ? prev[a] : 0.0;
  u.head<3>() = prev.head<3>() + clampNorm(u.head<3>() - prev.head<3>(), params_.max_linear_acceleration * dt);
  u.tail<3>() = prev.tail<3>() + clampNorm(u.tail<3>() - prev.tail<3>(), params_.max_angular_acceleration * dt);
  return u;
}

void StabilizationController::remember(const Vector6d& twist, double now)
{
  last_command_time_ = now;
  if (sent_.empty() || !(sent_.back().twist == twist))
    sent_.push_back({now, twist});
  while (sent_.size() > 1 && sent_[1].time < now - kHistoryS)
    sent_.pop_front();
}

}  // namespace structured_light_stabilizer
