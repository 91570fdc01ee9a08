// InertialFusion (control/inertial_fusion.h) against the truth of the loop
// model (test/support/closed_loop_model.h) with the arm still: the simulated
// IMU (sim/render/imu_model.h) samples the disturbance, the camera estimates
// are the truth with the measured PoseDelta noise, delivered late.
//
// Asserted: a camera estimate is fused at its stamp (the posteriors do not
// depend on the latency), the fused pose beats the camera's own against the
// truth per frame and pooled, the covariance is consistent (NEES), each
// fault makes the output invalid at once and recovers, a re-lock
// re-expresses the state, bad inputs are refused with the reason.
//
// Seeds: the fusion's noise model is the simulated IMU's datasheet figures
// with a margin of 1.5 (no tuning on runs); the runs below use disturbance
// seeds 31-36 and noise seeds 331-336.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "support/closed_loop_model.h"

using namespace structured_light_stabilizer;
using namespace sls_test;

namespace
{

// The vibration-heavy arm (1-8 Hz, 3 mm and 0.3 deg RMS per axis), open loop.
RigMotionParams heavyVibration(uint32_t seed)
{
  RigMotionParams m = roverArmDisturbance();
  m.vibration_translation_rms_m = 0.003;
  m.vibration_rotation_rms_rad = 0.3 * M_PI / 180.0;
  m.vibration_min_hz = 1.0;
  m.vibration_max_hz = 8.0;
  m.seed = seed;
  return m;
}

LoopModelParams fusionRun(double rate_hz, double duration_s, uint32_t noise_seed)
{
  LoopModelParams p;
  p.rate_hz = rate_hz;
  p.latency_s = 0.025;
  p.latency_jitter_s = 0.06;
  p.duration_s = duration_s;
  p.closed = false;
  p.imu = true;
  p.noise_seed = noise_seed;
  p.imu_params.seed = noise_seed + 7;
  return p;
}

struct Errors
{
  double translation_m = 0.0, rotation_rad = 0.0;  // RMS
  double max_translation_m = 0.0, max_rotation_rad = 0.0;
  int n = 0;
};

Errors errorsOf(const std::vector<std::pair<Eigen::Isometry3d, Eigen::Isometry3d>>& pairs)
{
  Errors e;
  for (const auto& p : pairs)
  {
    const Vector6d d = offsetOf(p.first * p.second.inverse());
    e.translation_m += d.head<3>().squaredNorm();
    e.rotation_rad += d.tail<3>().squaredNorm();
    e.max_translation_m = std::max(e.max_translation_m, d.head<3>().norm());
    e.max_rotation_rad = std::max(e.max_rotation_rad, d.tail<3>().norm());
    ++e.n;
  }
  if (e.n > 0)
  {
    e.translation_m = std::sqrt(e.translation_m / e.n);
    e.rotation_rad = std::sqrt(e.rotation_rad / e.n);
  }
  return e;
}

// Frame posteriors (the stabilised image's poses) against the truth, from `from_s` on.
Errors frameErrors(const LoopRun& run, double from_s)
{
  std::vector<std::pair<Eigen::Isometry3d, Eigen::Isometry3d>> pairs;
  for (const LoopSample& s : run.samples)
    if (s.t >= from_s && s.image_valid)
      pairs.emplace_back(s.image_pose, s.truth);
  return errorsOf(pairs);
}

// IMU-rate outputs (the controller's) against the truth.
Errors fusedErrors(const LoopRun& run, double from_s)
{
  std::vector<std::pair<Eigen::Isometry3d, Eigen::Isometry3d>> pairs;
  for (const LoopFused& f : run.fused)
    if (f.t >= from_s && f.estimate.valid)
      pairs.emplace_back(f.estimate.transform, f.truth);
  return errorsOf(pairs);
}

int validCount(const LoopRun& run, double from_s, double to_s)
{
  int n = 0;
  for (const LoopFused& f : run.fused)
    n += f.t >= from_s && f.t < to_s && f.estimate.valid;
  return n;
}

// The first valid IMU-rate output at or after t (s since the lock; inf: none).
double firstValidAfter(const LoopRun& run, double t)
{
  for (const LoopFused& f : run.fused)
    if (f.t >= t && f.estimate.valid)
      return f.t;
  return INFINITY;
}

}  // namespace

TEST(InertialFusion, CameraEstimatesAreFusedAtTheirStamp)
{
  // The same run with the estimates 5 ms and 100 ms late (both after the
  // IMU sample that covers their stamp): the posterior at each frame is the
  // same (it is computed at the stamp), to round-off.
  LoopModelParams fast = fusionRun(30.0, 3.0, 331);
  fast.latency_s = 0.005;
  fast.latency_jitter_s = 0.0;
  LoopModelParams slow = fast;
  slow.latency_s = 0.1;
  const LoopRun a = runLoopFull(heavyVibration(31), StabilizationControllerParams(), ArmModelParams(), fast);
  const LoopRun b = runLoopFull(heavyVibration(31), StabilizationControllerParams(), ArmModelParams(), slow);
  ASSERT_EQ(a.samples.size(), b.samples.size());
  int compared = 0;
  double worst = 0.0;
  for (size_t i = 0; i < a.samples.size(); ++i)
  {
    if (!a.samples[i].image_valid || !b.samples[i].image_valid)
      continue;
    worst = std::max(worst, offsetOf(a.samples[i].image_pose * b.samples[i].image_pose.inverse()).norm());
    ++compared;
  }
  std::printf("[ MEASURE ] posterior 5 ms vs 100 ms late: %d frames, largest difference %.3g\n", compared, worst);
  EXPECT_GT(compared, 80);
  EXPECT_LT(worst, 1e-9);
}

TEST(InertialFusion, BeatsTheCameraAgainstTheTruth)
{
  // 120 Hz frames, 25 ms + 0-60 ms latency, heavy vibration; camera noise
  // 0.2 mm and 0.008 deg per axis (0.35 mm, 0.014 deg as a norm).
  double pooled_t = 0.0, pooled_r = 0.0, pooled_ft = 0.0;
  int runs = 0;
  for (uint32_t seed = 32; seed <= 34; ++seed)
  {
    const LoopModelParams p = fusionRun(120.0, 3.0, 300 + seed);
    const LoopRun run = runLoopFull(heavyVibration(seed), StabilizationControllerParams(), ArmModelParams(), p);
    const Errors frames = frameErrors(run, 0.5);
    const Errors fused = fusedErrors(run, 0.5);
    const double camera_t = std::sqrt(3.0) * p.noise_translation_m, camera_r = std::sqrt(3.0) * p.noise_rotation_rad;
    std::printf("[ MEASURE ] seed %u: posterior %.3f mm %.4f deg (worst %.3f mm %.4f deg), IMU-rate %.3f mm %.4f deg "
                "(worst %.3f mm), camera %.3f mm %.4f deg\n",
                seed, frames.translation_m * 1e3, frames.rotation_rad * 180 / M_PI, frames.max_translation_m * 1e3,
                frames.max_rotation_rad * 180 / M_PI, fused.translation_m * 1e3, fused.rotation_rad * 180 / M_PI,
                fused.max_translation_m * 1e3, camera_t * 1e3, camera_r * 180 / M_PI);
    EXPECT_GT(frames.n, 280);
    EXPECT_LT(frames.translation_m, 0.5 * camera_t) << seed;
    EXPECT_LT(frames.rotation_rad, 0.5 * camera_r) << seed;
    EXPECT_LT(frames.max_translation_m, 2.0 * camera_t) << seed;
    EXPECT_LT(frames.max_rotation_rad, 2.0 * camera_r) << seed;
    // The controller's estimate: IMU-propagated up to 85 ms past the last
    // correction, still within the camera's own noise.
    EXPECT_LT(fused.translation_m, camera_t) << seed;
    EXPECT_LT(fused.rotation_rad, camera_r) << seed;
    EXPECT_GE(fused.n, 950);
    pooled_t += frames.translation_m * frames.translation_m;
    pooled_r += frames.rotation_rad * frames.rotation_rad;
    pooled_ft += fused.translation_m * fused.translation_m;
    ++runs;
  }
  std::printf("[ MEASURE ] pooled: posterior %.3f mm %.4f deg, IMU-rate %.3f mm\n", std::sqrt(pooled_t / runs) * 1e3,
              std::sqrt(pooled_r / runs) * 180 / M_PI, std::sqrt(pooled_ft / runs) * 1e3);
}

TEST(InertialFusion, CovarianceIsConsistent)
{
  // Mean NEES of the posteriors over 6 degrees of freedom: 6 for a
  // consistent filter; the camera covariance is scaled by 1.5 (a margin).
  const LoopModelParams p = fusionRun(60.0, 4.0, 335);
  const LoopRun run = runLoopFull(heavyVibration(35), StabilizationControllerParams(), ArmModelParams(), p);
  double nees = 0.0;
  int n = 0;
  for (const LoopFused& f : run.fused)
    if (f.t >= 0.5 && f.estimate.valid)
    {
      const Vector6d d = offsetOf(f.truth * f.estimate.transform.inverse());
      nees += d.dot(f.estimate.covariance.ldlt().solve(d));
      ++n;
    }
  ASSERT_GT(n, 1000);
  std::printf("[ MEASURE ] mean NEES of the IMU-rate output: %.2f (6 dof)\n", nees / n);
  EXPECT_GT(nees / n, 1.5);
  EXPECT_LT(nees / n, 12.0);
}

TEST(InertialFusion, InvalidCameraMakesTheOutputInvalidAtOnce)
{
  // Estimates invalid for 2 s from 1.0 s after the lock: the first IMU
  // output after the first invalid estimate arrived is invalid, all are
  // until valid ones come back, then the output recovers.
  LoopModelParams p = fusionRun(30.0, 5.0, 336);
  p.latency_jitter_s = 0.0;
  p.invalid_from_s = 1.0;
  p.invalid_until_s = 3.0;
  const LoopRun run = runLoopFull(heavyVibration(36), StabilizationControllerParams(), ArmModelParams(), p);
  // The first invalid estimate is the frame at or after 1.0 s, delivered 25 ms later.
  const double first_invalid = std::ceil(1.0 * 30.0 - 1e-9) / 30.0 + p.latency_s;
  const double resume = std::ceil(3.0 * 30.0 - 1e-9) / 30.0 + p.latency_s;
  EXPECT_EQ(validCount(run, first_invalid + 1.0 / 400.0 + p.imu_latency_s, resume), 0);
  EXPECT_GT(validCount(run, 0.5, first_invalid - 0.01), 150);
  const double back = firstValidAfter(run, resume);
  std::printf("[ MEASURE ] camera invalid 2 s: fused valid again %.0f ms after the first valid estimate arrived\n",
              (back - resume) * 1e3);
  EXPECT_LT(back - resume, 0.2);
  EXPECT_LT(fusedErrors(run, back + 0.1).translation_m, 0.35e-3);
}

TEST(InertialFusion, SilentImuGapAndBiasStep)
{
  // The IMU silent for 0.3 s: the camera estimates during the silence
  // return an invalid estimate for the controller; after it the output is
  // invalid until recovery_updates consistent estimates.
  LoopModelParams p = fusionRun(60.0, 3.0, 337);
  const double lock_t = std::ceil(p.lock_s * p.rate_hz - 1e-9) / p.rate_hz;
  p.imu_params.silent_from_s = lock_t + 1.0;
  p.imu_params.silent_until_s = lock_t + 1.3;
  const LoopRun silent = runLoopFull(heavyVibration(37), StabilizationControllerParams(), ArmModelParams(), p);
  EXPECT_EQ(validCount(silent, 1.0, 1.3), 0);
  int silent_holds = 0;
  for (const LoopCommand& c : silent.commands)
    silent_holds += c.t > 1.0 && c.t < 1.35 && c.hold == HoldReason::kInvalid;
  EXPECT_GT(silent_holds, 10);  // the camera-rate invalid estimates reached the controller
  const double back = firstValidAfter(silent, 1.3);
  const Errors converging = fusedErrors(silent, back), settled = fusedErrors(silent, back + 0.5);
  std::printf("[ MEASURE ] IMU silent 0.3 s: fused valid again %.0f ms after it resumed; then %.3f mm RMS (worst "
              "%.3f mm), from 0.5 s later %.3f mm\n",
              (back - 1.3) * 1e3, converging.translation_m * 1e3, converging.max_translation_m * 1e3,
              settled.translation_m * 1e3);
  EXPECT_LT(back - 1.3, 0.4);
  EXPECT_LT(converging.max_translation_m, 2e-3);
  EXPECT_LT(settled.translation_m, 0.5e-3);

  // A gyro bias step of 2 deg/s and an accelerometer one of 0.3 m/s^2.
  LoopModelParams q = fusionRun(60.0, 4.0, 338);
  q.imu_params.bias_step_time_s = lock_t + 1.5;
  q.imu_params.gyro_bias_step = Eigen::Vector3d(0.035, 0.0, 0.0);
  q.imu_params.accel_bias_step = Eigen::Vector3d(0.0, 0.3, 0.0);
  const LoopRun step = runLoopFull(heavyVibration(38), StabilizationControllerParams(), ArmModelParams(), q);
  double invalid_at = INFINITY;
  for (const LoopFused& f : step.fused)
    if (f.t >= 1.5 && !f.estimate.valid)
    {
      invalid_at = f.t;
      break;
    }
  const double recovered = firstValidAfter(step, invalid_at);
  // Before it is caught the output drifts (the innovation test needs a few
  // frames to tell a bias from the camera's noise); then it converges again.
  double drift = 0.0;
  for (const LoopFused& f : step.fused)
    if (f.t >= 1.5 && f.t < invalid_at)
      drift = std::max(drift, offsetOf(f.truth * f.estimate.transform.inverse()).head<3>().norm());
  const Errors after = fusedErrors(step, recovered);
  std::printf("[ MEASURE ] bias step: output invalid %.0f ms after it (drift meanwhile up to %.2f mm), valid again "
              "%.0f ms later, then %.3f mm RMS (worst %.3f mm)\n",
              (invalid_at - 1.5) * 1e3, drift * 1e3, (recovered - invalid_at) * 1e3, after.translation_m * 1e3,
              after.max_translation_m * 1e3);
  EXPECT_LT(invalid_at - 1.5, 0.15);  // a few frames at 60 Hz + the latency
  EXPECT_LT(drift, 3e-3);
  EXPECT_LT(recovered - invalid_at, 0.5);
  EXPECT_LT(after.max_translation_m, 1.5e-3);
  EXPECT_LT(fusedErrors(step, recovered + 0.5).translation_m, 0.5e-3);
}

TEST(InertialFusion, RelockReexpressesTheState)
{
  LoopModelParams p = fusionRun(30.0, 3.0, 339);
  p.relock_s = 1.5;
  const LoopRun run = runLoopFull(heavyVibration(39), StabilizationControllerParams(), ArmModelParams(), p);
  int announced = 0;
  for (const LoopFused& f : run.fused)
    announced += f.estimate.status.find("reference locked on this frame") != std::string::npos;
  EXPECT_EQ(announced, 2);  // the first lock and the re-lock, once each
  // After the re-lock the output is relative to the new reference (the
  // truth of the loop model is too) and as accurate as before.
  const Errors after = fusedErrors(run, 1.7);
  EXPECT_LT(after.translation_m, 0.35e-3);
  EXPECT_LT(after.rotation_rad, 0.014 * M_PI / 180.0);
  EXPECT_GT(after.n, 400);
}

TEST(InertialFusion, BadInputsAreRefusedWithTheReason)
{
  InertialFusion fusion{InertialFusionParams(), ImuMount()};
  std::string why;
  FusedEstimate out;
  ImuMeasurement m;
  m.stamp = 1.0;
  m.linear_acceleration = Eigen::Vector3d(0, 0, 3.711);
  EXPECT_TRUE(fusion.addImu(m, &out, &why)) << why;
  EXPECT_FALSE(out.valid);
  EXPECT_NE(out.status.find("no reference locked"), std::string::npos) << out.status;
  m.stamp = 0.999;
  EXPECT_FALSE(fusion.addImu(m, &out, &why));
  EXPECT_NE(why.find("not after"), std::string::npos) << why;
  m.stamp = 1.0025;
  m.angular_velocity.x() = NAN;
  why.clear();
  EXPECT_FALSE(fusion.addImu(m, &out, &why));
  EXPECT_NE(why.find("NaN"), std::string::npos) << why;
  CameraMeasurement c;
  c.stamp = 1.0;
  c.valid = true;
  c.status = "ok";
  why.clear();
  EXPECT_FALSE(fusion.addCamera(c, &why).used);
  EXPECT_NE(why.find("no reference locked"), std::string::npos) << why;
  c.covariance(2, 2) = NAN;
  why.clear();
  EXPECT_FALSE(fusion.addCamera(c, &why).used);
  EXPECT_NE(why.find("NaN"), std::string::npos) << why;
  InertialFusionParams bad;
  bad.max_nis = -1.0;
  EXPECT_THROW(InertialFusion(bad, ImuMount()), std::invalid_argument);
  ImuMount skew;
  skew.rotation_camera_imu.coeffs() << 0.0, 0.0, 0.0, 2.0;
  EXPECT_THROW(InertialFusion(InertialFusionParams(), skew), std::invalid_argument);
}
