// A model of the closed loop without rendering, for the gtests and
// benchmark_stabilization: the disturbance (sim/arm_model.h,
// disturbanceMotion) and the arm model move the camera; each frame's
// estimate is the true offset from the locked pose with white noise of the
// measured per-axis size, delivered a fixed latency (plus a uniform jitter)
// after its exposure. Without the IMU the controller commands at each
// estimate; with it (LoopModelParams::imu) the simulated IMU
// (sim/render/imu_model.h) samples the true motion, InertialFusion fuses it
// with the estimates at their stamps and the controller commands at each
// fused sample, imu_latency_s after it. The full chain (rendering, detector,
// triangulator, PoseDelta, ROS transport) is stabilize.launch; this model has
// its latency and noise as inputs (docs/stabilization.md, "Measured").
#pragma once

#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <vector>

#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/control/inertial_fusion.h"
#include "structured_light_stabilizer/control/stabilization_controller.h"
#include "structured_light_stabilizer/sim/render/arm_model.h"
#include "structured_light_stabilizer/sim/render/imu_model.h"

namespace sls_test
{

using structured_light_stabilizer::Vector6d;

struct LoopModelParams
{
  double rate_hz = 30.0;
  double latency_s = 0.06;              // exposure to delivery of an estimate (the pipeline + transport)
  double latency_jitter_s = 0.0;        // + uniform [0, jitter]
  double noise_translation_m = 0.0002;  // 1-sigma per axis of the estimate
  double noise_rotation_rad = 0.00014;
  // PoseDelta's own ambiguity on top (1-sigma, rad): a rotation about x or
  // y paired with the translation that moves the rock's image alike (at
  // ambiguity_depth_m), errors that correlate at -0.9998 (tx, ry) and
  // +0.9998 (ty, rx) in a lockstep run (docs/stabilization.md).
  double noise_ambiguity_rad = 0.0;
  double ambiguity_depth_m = 1.5;
  uint32_t noise_seed = 1;
  double lock_s = 1.0;       // the reference is locked on the first frame at or after this
  double duration_s = 30.0;  // simulated time after the lock
  bool closed = true;        // false: the arm never moves (open loop)
  // The inertial path.
  bool imu = false;
  structured_light_stabilizer::ImuModelParams imu_params;
  structured_light_stabilizer::InertialFusionParams fusion;
  bool mount_from_truth = true;  // the fusion's mount = the simulated IMU's (else `mount`)
  structured_light_stabilizer::ImuMount mount;
  double imu_latency_s = 0.001;  // IMU sample to command
  // Faults, in s after the lock: the estimates invalid over
  // [invalid_from_s, invalid_until_s); a re-lock on the first frame at or
  // after relock_s.
  double invalid_from_s = std::numeric_limits<double>::infinity();
  double invalid_until_s = std::numeric_limits<double>::infinity();
  double relock_s = std::numeric_limits<double>::infinity();
};

struct LoopSample
{
  double t;          // s since the lock
  Vector6d closed;   // true offset from the locked pose (t, rotation vector), arm on
  Vector6d open;     // the disturbance's offset (the arm still)
  Vector6d command;  // the last command sent
  // The pose a stabilised image of this frame is warped with (the fused
  // posterior at its stamp with the IMU, else the estimate itself) and the
  // truth it should equal, both p_cur = T p_lock; valid: it was warped.
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d image_pose = Eigen::Isometry3d::Identity();
  bool image_valid = false;
  // From the estimates' reference (the last lock) to the first lock's.
  Eigen::Isometry3d reference = Eigen::Isometry3d::Identity();
};

struct LoopCommand
{
  double t;  // s since the lock
  Vector6d twist;
  structured_light_stabilizer::HoldReason hold;
  bool fused_valid;  // the estimate it answered was valid
};

// A fused estimate (IMU path) and the truth it estimates: both p_cur = T
// p_ref with ref the last lock's camera.
struct LoopFused
{
  double t;  // s since the (first) lock
  Eigen::Isometry3d truth;
  structured_light_stabilizer::FusedEstimate estimate;
};

struct LoopRun
{
  std::vector<LoopSample> samples;
  std::vector<LoopCommand> commands;
  std::vector<LoopFused> fused;  // every IMU-rate output after the lock
};

// The offset (t, log R) of T.
inline Vector6d offsetOf(const Eigen::Isometry3d& T)
{
  Vector6d v;
  v << T.translation(), structured_light_stabilizer::logSO3(T.linear());
  return v;
}

namespace detail
{

// The loop as a sequence of timed events.
class LoopSimulation
{
public:
  LoopSimulation(const structured_light_stabilizer::RigMotionParams& disturbance,
                 const structured_light_stabilizer::StabilizationControllerParams& control,
                 const structured_light_stabilizer::ArmModelParams& arm_params, const LoopModelParams& p)
    : disturbance_(disturbance)
    , p_(p)
    , controller_(control)
    , arm_(arm_params)
    , imu_(p.imu_params)
    , fusion_(p.fusion, mountOf(p))
    , rng_(p.noise_seed)
    , jitter_(0.0, p.latency_jitter_s)
  {
  }

  LoopRun run()
  {
    lock_frame_ = static_cast<int>(std::ceil(p_.lock_s * p_.rate_hz - 1e-9));
    const int frames = lock_frame_ + static_cast<int>(std::lround(p_.duration_s * p_.rate_hz));
    const double end = frames / p_.rate_hz;
    for (int k = 0; k <= frames; ++k)
      events_.emplace(k / p_.rate_hz, Event{kFrame, k, {}, {}, 0.0});
    if (p_.imu)
      for (int i = 0; i / p_.imu_params.rate_hz <= end; ++i)
        events_.emplace(i / p_.imu_params.rate_hz, Event{kImuSample, i, {}, {}, 0.0});
    while (!events_.empty())
    {
      const auto it = events_.begin();
      const double t = it->first;
      const Event e = it->second;
      events_.erase(it);
      if (t > end + 1e-9)
        break;
      arm_.advance(t);
      if (e.kind == kFrame)
        frame(e.index, t);
      else if (e.kind == kDelivery)
        deliver(e, t);
      else if (e.kind == kImuSample)
        sampleImu(t);
      else
        deliverImu(e, t);
    }
    return std::move(out_);
  }

private:
  enum Kind
  {
    kFrame,
    kDelivery,
    kImuSample,
    kImuDelivery
  };
  struct Event
  {
    Kind kind;
    int index;
    structured_light_stabilizer::StabilizationEstimate estimate;
    structured_light_stabilizer::ImuMeasurement imu;
    double sample_t;  // kImuDelivery: the true time of the sample
  };

  static structured_light_stabilizer::ImuMount mountOf(const LoopModelParams& p)
  {
    if (!p.mount_from_truth)
      return p.mount;
    structured_light_stabilizer::ImuMount m;
    m.rotation_camera_imu = p.imu_params.rotation_camera_imu;
    m.lever_arm_m = p.imu_params.lever_arm_m;
    m.time_offset_s = p.imu_params.time_offset_s;
    return m;
  }

  void frame(int k, double t)
  {
    using namespace structured_light_stabilizer;
    const Eigen::Isometry3d D = disturbanceMotion(disturbance_, t);
    const Eigen::Isometry3d truth = arm_.correction() * D;
    if (k < lock_frame_)
      return;
    const double since = t - lock_frame_ / p_.rate_hz;
    bool relock = k == lock_frame_;
    if (!relocked_ && since >= p_.relock_s)
      relock = relocked_ = true;
    if (k == lock_frame_)
    {
      lock_truth_ = lock_estimate_ = truth;
      lock_disturbance_ = D;
    }
    if (relock)
      lock_estimate_ = truth;
    const Eigen::Isometry3d offset = truth * lock_truth_.inverse();
    LoopSample s{since, offsetOf(offset), offsetOf(D * lock_disturbance_.inverse()), command_, offset,
                 Eigen::Isometry3d::Identity(), false, lock_estimate_ * lock_truth_.inverse()};
    frame_index_[t] = out_.samples.size();
    out_.samples.push_back(s);
    // The estimate: the offset from the (last) lock with white noise on the
    // current-frame side, and PoseDelta's ambiguity.
    Vector6d n;
    for (int a = 0; a < 6; ++a)
      n[a] = gauss_(rng_) * (a < 3 ? p_.noise_translation_m : p_.noise_rotation_rad);
    Vector6d v1, v2;  // (tx, ry) and (ty, rx) pairs, per radian
    v1 << -p_.ambiguity_depth_m, 0, 0, 0, 1, 0;
    v2 << 0, p_.ambiguity_depth_m, 0, 1, 0, 0;
    if (p_.noise_ambiguity_rad > 0.0)
    {
      const double a2 = gauss_(rng_), a1 = gauss_(rng_);  // sequenced draws (docs/testing.md)
      n += p_.noise_ambiguity_rad * (a1 * v1 + a2 * v2);
    }
    StabilizationEstimate e;
    e.stamp = t;
    e.transform = applyIncrement(n, truth * lock_estimate_.inverse());
    for (int a = 0; a < 6; ++a)
      e.covariance(a, a) = std::pow(a < 3 ? p_.noise_translation_m : p_.noise_rotation_rad, 2);
    e.covariance += std::pow(p_.noise_ambiguity_rad, 2) * (v1 * v1.transpose() + v2 * v2.transpose());
    e.valid = !(since >= p_.invalid_from_s && since < p_.invalid_until_s);
    e.status = e.valid ? "ok: model" : "fault: model estimate invalid";
    if (relock)
      e.status += "; reference locked on this frame";
    if (!p_.imu)
    {
      out_.samples.back().image_pose = e.transform * out_.samples.back().reference;
      out_.samples.back().image_valid = e.valid;
    }
    double at = t + p_.latency_s + (p_.latency_jitter_s > 0.0 ? jitter_(rng_) : 0.0);
    at = std::max(at, last_delivery_);
    last_delivery_ = at;
    events_.emplace(at, Event{kDelivery, k, e, {}, 0.0});
  }

  void deliver(const Event& e, double at)
  {
    using namespace structured_light_stabilizer;
    if (!p_.imu)
    {
      command(e.estimate, at);
      return;
    }
    CameraMeasurement c;
    c.stamp = e.estimate.stamp;
    c.transform = e.estimate.transform;
    c.covariance = e.estimate.covariance;
    c.valid = e.estimate.valid;
    c.status = e.estimate.status;
    std::string why;
    const CameraUpdate u = fusion_.addCamera(c, &why);
    const auto f = frame_index_.find(c.stamp);
    if (f != frame_index_.end() && u.used)
    {
      LoopSample& s = out_.samples[f->second];
      s.image_pose = u.frame.transform * s.reference;
      s.image_valid = u.frame.valid;
    }
    if (u.silent_imu)
      command(estimateOf(u.fused), at);
  }

  void sampleImu(double t)
  {
    using namespace structured_light_stabilizer;
    ImuSample s;
    if (!imu_.sample(cameraKinematics(disturbance_, &arm_, t), &s))
      return;
    ImuMeasurement m;
    m.stamp = s.stamp;
    m.angular_velocity = s.angular_velocity;
    m.linear_acceleration = s.linear_acceleration;
    imu_truth_[s.t] = arm_.correction() * disturbanceMotion(disturbance_, t) * lock_estimate_.inverse();
    events_.emplace(t + p_.imu_latency_s, Event{kImuDelivery, 0, {}, m, s.t});
  }

  void deliverImu(const Event& e, double at)
  {
    structured_light_stabilizer::FusedEstimate f;
    std::string why;
    if (!fusion_.addImu(e.imu, &f, &why))
      return;
    command(estimateOf(f), at);
    const double lock_t = lock_frame_ / p_.rate_hz;
    const auto truth = imu_truth_.find(e.sample_t);
    if (e.sample_t >= lock_t && truth != imu_truth_.end())
      out_.fused.push_back({e.sample_t - lock_t, truth->second, f});
    imu_truth_.erase(imu_truth_.begin(), truth);
  }

  static structured_light_stabilizer::StabilizationEstimate estimateOf(
      const structured_light_stabilizer::FusedEstimate& f)
  {
    structured_light_stabilizer::StabilizationEstimate e;
    e.stamp = f.stamp;
    e.transform = f.transform;
    e.covariance = f.covariance;
    e.valid = f.valid;
    e.status = f.status;
    return e;
  }

  void command(const structured_light_stabilizer::StabilizationEstimate& e, double at)
  {
    const structured_light_stabilizer::StabilizationCommand c = controller_.update(e, at);
    command_ = c.twist;
    if (p_.closed)
      arm_.command(at, c.twist);
    if (at >= lock_frame_ / p_.rate_hz)
      out_.commands.push_back({at - lock_frame_ / p_.rate_hz, c.twist, c.hold, e.valid});
  }

  structured_light_stabilizer::RigMotionParams disturbance_;
  LoopModelParams p_;
  structured_light_stabilizer::StabilizationController controller_;
  structured_light_stabilizer::ArmModel arm_;
  structured_light_stabilizer::ImuModel imu_;
  structured_light_stabilizer::InertialFusion fusion_;
  std::mt19937 rng_;
  std::normal_distribution<double> gauss_{0.0, 1.0};
  std::uniform_real_distribution<double> jitter_;
  std::multimap<double, Event> events_;  // equal times keep their order of insertion
  std::map<double, size_t> frame_index_;
  std::map<double, Eigen::Isometry3d> imu_truth_;  // by sample time, until delivered
  LoopRun out_;
  Vector6d command_ = Vector6d::Zero();
  int lock_frame_ = 0;
  bool relocked_ = false;
  double last_delivery_ = -1e300;
  Eigen::Isometry3d lock_truth_ = Eigen::Isometry3d::Identity();     // the first lock's true pose
  Eigen::Isometry3d lock_estimate_ = Eigen::Isometry3d::Identity();  // the last lock's (the estimates' reference)
  Eigen::Isometry3d lock_disturbance_ = Eigen::Isometry3d::Identity();
};

}  // namespace detail

inline LoopRun runLoopFull(const structured_light_stabilizer::RigMotionParams& disturbance,
                           const structured_light_stabilizer::StabilizationControllerParams& control,
                           const structured_light_stabilizer::ArmModelParams& arm_params, const LoopModelParams& p)
{
  return detail::LoopSimulation(disturbance, control, arm_params, p).run();
}

inline std::vector<LoopSample> runLoop(const structured_light_stabilizer::RigMotionParams& disturbance,
                                       const structured_light_stabilizer::StabilizationControllerParams& control,
                                       const structured_light_stabilizer::ArmModelParams& arm_params,
                                       const LoopModelParams& p)
{
  return runLoopFull(disturbance, control, arm_params, p).samples;
}

// RMS of the translation norm (m) and of the rotation angle (rad) of the
// samples from `from_s` on: closed loop (arm on) or open loop. centred: about
// the mean of each axis (for a sine, whose offset from the locked pose has a
// constant part that depends on the phase at the lock).
struct LoopRms
{
  double translation_m = 0.0;
  double rotation_rad = 0.0;
};

inline LoopRms loopRms(const std::vector<LoopSample>& samples, bool closed, double from_s = 0.0, bool centred = false)
{
  Vector6d mean = Vector6d::Zero();
  int n = 0;
  for (const LoopSample& s : samples)
    if (s.t >= from_s)
    {
      mean += closed ? s.closed : s.open;
      ++n;
    }
  LoopRms r;
  if (n == 0)
    return r;
  mean = centred ? Vector6d(mean / n) : Vector6d::Zero();
  for (const LoopSample& s : samples)
  {
    if (s.t < from_s)
      continue;
    const Vector6d v = (closed ? s.closed : s.open) - mean;
    r.translation_m += v.head<3>().squaredNorm();
    r.rotation_rad += v.tail<3>().squaredNorm();
  }
  r.translation_m = std::sqrt(r.translation_m / n);
  r.rotation_rad = std::sqrt(r.rotation_rad / n);
  return r;
}

// The rock points the dots hit at the lock, in the locked camera frame: the
// default projector's 10 x 10 fan (35 mrad pitch) on a rock 1.5 m away with
// a few cm of relief, for image-space figures without rendering.
inline std::vector<Eigen::Vector3d> modelDotPoints()
{
  std::vector<Eigen::Vector3d> points;
  for (int r = 0; r < 10; ++r)
    for (int c = 0; c < 10; ++c)
    {
      const double ax = 0.035 * (c - 4.5), ay = 0.035 * (r - 4.5);
      const double z = 1.5 + 0.05 * std::sin(1.3 * c + 0.7 * r);
      points.emplace_back(std::tan(ax) * z, std::tan(ay) * z, z);
    }
  return points;
}

// Image motion at the dots (px RMS over dots and frames from `from_s` on),
// a pinhole of focal length f_px: the stabilised image (where the truth puts
// each rock point against where the image's pose puts it, frames warped
// only) or the raw image of the open loop (the disturbance's motion).
inline double imageResidualPx(const std::vector<LoopSample>& samples, double f_px, bool stabilised, double from_s = 0.0)
{
  const std::vector<Eigen::Vector3d> dots = modelDotPoints();
  const auto project = [&](const Eigen::Vector3d& p) { return Eigen::Vector2d(f_px * p.x() / p.z(), f_px * p.y() / p.z()); };
  double sq = 0.0;
  int n = 0;
  for (const LoopSample& s : samples)
  {
    if (s.t < from_s || (stabilised && !s.image_valid))
      continue;
    Eigen::Isometry3d open = Eigen::Isometry3d::Identity();
    open.linear() = structured_light_stabilizer::expSO3(s.open.tail<3>());
    open.translation() = s.open.head<3>();
    for (const Eigen::Vector3d& X : dots)
    {
      const Eigen::Vector2d e =
          stabilised ? Eigen::Vector2d(project(s.truth * X) - project(s.image_pose * X)) : Eigen::Vector2d(project(open * X) - project(X));
      sq += e.squaredNorm();
      ++n;
    }
  }
  return n > 0 ? std::sqrt(sq / n) : std::numeric_limits<double>::quiet_NaN();
}

}  // namespace sls_test
