// A model of the closed loop without rendering, for the gtests and
// benchmark_stabilization: the disturbance (sim/arm_model.h,
// disturbanceMotion) and the arm model move the camera; each frame's
// estimate is the true offset from the locked pose with white noise of the
// measured per-axis size, delivered to the controller a fixed latency (plus
// a uniform jitter) after its exposure; the controller's command goes to the
// arm at that moment. The full chain (rendering, detector, triangulator,
// PoseDelta, ROS transport) is stabilize.launch; this model has its latency
// and noise as inputs (docs/stabilization.md, "Measured").
#pragma once

#include <cmath>
#include <deque>
#include <random>
#include <vector>

#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/sim/render/arm_model.h"
#include "structured_light_stabilizer/control/stabilization_controller.h"

namespace sls_test
{

using structured_light_stabilizer::Vector6d;

struct LoopModelParams
{
  double rate_hz = 30.0;
  double latency_s = 0.06;              // exposure to command (the pipeline + transport)
  double latency_jitter_s = 0.0;        // + uniform [0, jitter]
  double noise_translation_m = 0.0002;  // 1-sigma per axis of the estimate
  double noise_rotation_rad = 0.00014;
  uint32_t noise_seed = 1;
  double lock_s = 1.0;       // the reference is locked on the first frame at or after this
  double duration_s = 30.0;  // simulated time after the lock
  bool closed = true;        // false: the arm never moves (open loop)
};

struct LoopSample
{
  double t;          // s since the lock
  Vector6d closed;   // true offset from the locked pose (t, rotation vector), arm on
  Vector6d open;     // the disturbance's offset (the arm still)
  Vector6d command;  // the last command sent
};

// The offset (t, log R) of T.
inline Vector6d offsetOf(const Eigen::Isometry3d& T)
{
  Vector6d v;
  v << T.translation(), structured_light_stabilizer::logSO3(T.linear());
  return v;
}

inline std::vector<LoopSample> runLoop(const structured_light_stabilizer::RigMotionParams& disturbance,
                                       const structured_light_stabilizer::StabilizationControllerParams& control,
                                       const structured_light_stabilizer::ArmModelParams& arm_params,
                                       const LoopModelParams& p)
{
  using namespace structured_light_stabilizer;
  StabilizationController controller(control);
  ArmModel arm(arm_params);
  std::mt19937 rng(p.noise_seed);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> jitter(0.0, p.latency_jitter_s);
  struct Delivery
  {
    double at;
    StabilizationEstimate estimate;
  };
  std::deque<Delivery> queue;
  std::vector<LoopSample> samples;
  Eigen::Isometry3d lock_truth, lock_disturbance;
  Vector6d command = Vector6d::Zero();
  const int lock_frame = static_cast<int>(std::ceil(p.lock_s * p.rate_hz - 1e-9));
  const int frames = lock_frame + static_cast<int>(std::lround(p.duration_s * p.rate_hz));
  for (int k = 0; k <= frames; ++k)
  {
    const double t = k / p.rate_hz;
    while (!queue.empty() && queue.front().at <= t)
    {
      arm.advance(queue.front().at);
      command = controller.update(queue.front().estimate, queue.front().at).twist;
      if (p.closed)
        arm.command(queue.front().at, command);
      queue.pop_front();
    }
    arm.advance(t);
    const Eigen::Isometry3d D = disturbanceMotion(disturbance, t);
    const Eigen::Isometry3d truth = arm.correction() * D;
    if (k < lock_frame)
      continue;
    if (k == lock_frame)
    {
      lock_truth = truth;
      lock_disturbance = D;
    }
    const Eigen::Isometry3d offset = truth * lock_truth.inverse();
    samples.push_back(
        {t - lock_frame / p.rate_hz, offsetOf(offset), offsetOf(D * lock_disturbance.inverse()), command});
    // The estimate: the offset with white noise on the current-frame side.
    Vector6d n;
    for (int a = 0; a < 6; ++a)
      n[a] = gauss(rng) * (a < 3 ? p.noise_translation_m : p.noise_rotation_rad);
    StabilizationEstimate e;
    e.stamp = t;
    e.transform = applyIncrement(n, offset);
    e.covariance = Matrix6d::Zero();
    for (int a = 0; a < 6; ++a)
      e.covariance(a, a) = std::pow(a < 3 ? p.noise_translation_m : p.noise_rotation_rad, 2);
    e.valid = true;
    e.status = k == lock_frame ? "ok: model; reference locked on this frame" : "ok: model";
    const double at = t + p.latency_s + (p.latency_jitter_s > 0.0 ? jitter(rng) : 0.0);
    queue.push_back({std::max(at, queue.empty() ? at : queue.back().at), e});
  }
  return samples;
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

}  // namespace sls_test
