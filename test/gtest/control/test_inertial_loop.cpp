// The fused loop on the loop model (test/support/closed_loop_model.h): the
// simulated IMU and InertialFusion in the loop, the controller with
// fusedLoopControllerParams() commanding at IMU rate.
//
// Asserted: |S| at 1 Hz, the bandwidth and the peak of the noise-free loop
// (the controller's design, docs/stabilization.md "Gains"); the Earth
// analogue in wind within 10 % of open loop and the Mars default within 6 %
// with the estimate's noise, per frame and pooled; each fault (IMU silent,
// a bias step, the camera invalid for 2 s, a re-lock) holds with a zero
// command within one frame of the invalid state, never jumps (every change
// of the command within the rate limit, or to zero), and recovers (measured).
// config/stabilize_imu.yaml equals fusedLoopControllerParams().
//
// Seeds: the gains were chosen on disturbance seeds 1-5 and noise seeds
// 101-105 (tools/benchmark_stabilization); these run seeds 41-47 / 441-447.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include "support/closed_loop_model.h"

using namespace structured_light_stabilizer;
using namespace sls_test;

namespace
{

LoopModelParams fusedLoop(double rate_hz, double duration_s, uint32_t seed)
{
  LoopModelParams p;
  p.rate_hz = rate_hz;
  p.latency_s = 0.025;
  p.latency_jitter_s = 0.06;
  p.duration_s = duration_s;
  p.imu = true;
  p.noise_seed = 400 + seed;
  p.imu_params.seed = 900 + seed;
  return p;
}

// |S| at f for a sine on every axis, noise-free (the loop's own).
double sensitivityAt(double f, uint32_t seed)
{
  RigMotionParams m;
  m.vibration_translation_rms_m = 0.00002;
  m.vibration_rotation_rms_rad = 0.00001;
  m.vibration_min_hz = m.vibration_max_hz = f;
  m.seed = seed;
  LoopModelParams p = fusedLoop(120.0, 0.0, seed);
  p.noise_translation_m = p.noise_rotation_rad = 0.0;
  p.imu_params.gyro_noise_density = p.imu_params.accel_noise_density = 0.0;
  p.imu_params.gyro_bias_random_walk = p.imu_params.accel_bias_random_walk = 0.0;
  const double settle = std::max(2.0, 2.0 / f);
  p.duration_s = settle + std::max(4.0, 5.0 / f);
  const auto samples = runLoop(m, fusedLoopControllerParams(), ArmModelParams(), p);
  return loopRms(samples, true, settle, true).translation_m / loopRms(samples, false, settle, true).translation_m;
}

// The largest change of the command between two commands (each group's
// norm, beyond the rate limit over their interval), changes to zero (holds)
// excepted; and the time of the worst.
double worstJump(const LoopRun& run, const StabilizationControllerParams& c, double* at)
{
  double worst = 0.0;
  for (size_t i = 1; i < run.commands.size(); ++i)
  {
    const LoopCommand &a = run.commands[i - 1], &b = run.commands[i];
    if (b.twist.isZero(0.0))
      continue;
    const double dt = std::max(b.t - a.t, 1e-9);
    const double lin = (b.twist - a.twist).head<3>().norm() - c.max_linear_acceleration * dt;
    const double ang = (b.twist - a.twist).tail<3>().norm() - c.max_angular_acceleration * dt;
    if (std::max(lin / c.max_linear_acceleration, ang / c.max_angular_acceleration) > worst)
    {
      worst = std::max(lin / c.max_linear_acceleration, ang / c.max_angular_acceleration);
      *at = b.t;
    }
  }
  return worst;  // seconds of acceleration beyond the limit
}

}  // namespace

TEST(FusedLoop, ShippedConfigIsFusedLoopControllerParams)
{
  const YAML::Node y = YAML::LoadFile(std::string(SLS_TEST_DATA_DIR) + "/../../config/stabilize_imu.yaml");
  StabilizationControllerParams fromFile;
  for (const auto& kv : y)
    ASSERT_TRUE(fromFile.set(kv.first.as<std::string>(), kv.second.as<std::string>())) << kv.first.as<std::string>();
  EXPECT_TRUE(fromFile == fusedLoopControllerParams());
  EXPECT_TRUE(fusedLoopControllerParams().validate().empty());
  // And config/imu.yaml is the simulated IMU's default.
  const YAML::Node imu = YAML::LoadFile(std::string(SLS_TEST_DATA_DIR) + "/../../config/imu.yaml");
  const ImuModelParams p;
  const Eigen::Quaterniond q(imu["imu_rotation"][3].as<double>(), imu["imu_rotation"][0].as<double>(),
                             imu["imu_rotation"][1].as<double>(), imu["imu_rotation"][2].as<double>());
  EXPECT_LT(q.angularDistance(p.rotation_camera_imu), 1e-8);
  EXPECT_EQ(imu["imu_rate"].as<double>(), p.rate_hz);
  for (int a = 0; a < 3; ++a)
  {
    EXPECT_EQ(imu["imu_lever_arm"][a].as<double>(), p.lever_arm_m[a]);
    EXPECT_EQ(imu["imu_gravity"][a].as<double>(), p.gravity_m_s2[a]);
    EXPECT_EQ(imu["imu_gyro_bias"][a].as<double>(), p.gyro_bias[a]);
    EXPECT_EQ(imu["imu_accel_bias"][a].as<double>(), p.accel_bias[a]);
  }
  EXPECT_EQ(imu["imu_gyro_noise_density"].as<double>(), p.gyro_noise_density);
  EXPECT_EQ(imu["imu_accel_noise_density"].as<double>(), p.accel_noise_density);
  EXPECT_EQ(imu["imu_gyro_bias_random_walk"].as<double>(), p.gyro_bias_random_walk);
  EXPECT_EQ(imu["imu_accel_bias_random_walk"].as<double>(), p.accel_bias_random_walk);
  EXPECT_EQ(imu["imu_seed"].as<uint32_t>(), p.seed);
}

TEST(FusedLoop, SensitivityOfTheDesign)
{
  // The figures for the arm's loop with IMU: |S(1 Hz)| <= 0.35,
  // bandwidth (|S| = 0.71) >= 2 Hz, peak <= 1.4.
  const double s1 = sensitivityAt(1.0, 41), s2 = sensitivityAt(2.0, 42);
  double peak = 0.0, peak_f = 0.0;
  for (double f : {5.0, 7.0, 10.0, 14.0})
  {
    const double s = sensitivityAt(f, 43);
    if (s > peak)
      peak = s, peak_f = f;
  }
  std::printf("[ MEASURE ] fused loop model: |S| %.3f at 1 Hz, %.3f at 2 Hz, peak %.2f at %.0f Hz\n", s1, s2, peak,
              peak_f);
  EXPECT_LE(s1, 0.35);
  EXPECT_LE(s2, 0.71);
  EXPECT_LE(peak, 1.4);
  EXPECT_GT(peak, 1.0);  // a loop with a delay must amplify somewhere
}

TEST(FusedLoop, EarthWindAndMarsOnHeldOutSeeds)
{
  struct Case
  {
    const char* name;
    RigMotionParams m;
    double bound;
  } cases[] = {{"Earth analogue in wind", earthWindDisturbance(), 0.10}, {"Mars default", roverArmDisturbance(), 0.06}};
  uint32_t seed = 44;
  for (Case& c : cases)
  {
    c.m.seed = seed;
    const auto samples = runLoop(c.m, fusedLoopControllerParams(), ArmModelParams(), fusedLoop(120.0, 30.0, seed));
    const LoopRms closed = loopRms(samples, true), open = loopRms(samples, false);
    double worst = 0.0;
    for (const LoopSample& s : samples)
      if (s.t >= 1.0)
        worst = std::max(worst, s.closed.head<3>().norm());
    std::printf("[ MEASURE ] %s, seed %u: open %.3f mm, closed %.3f mm (ratio %.3f, rotation %.3f), worst frame %.3f mm; "
                "image %.3f px (open loop %.2f)\n",
                c.name, seed, open.translation_m * 1e3, closed.translation_m * 1e3,
                closed.translation_m / open.translation_m, closed.rotation_rad / open.rotation_rad, worst * 1e3,
                imageResidualPx(samples, CameraModel::studyDesign().fx, true, 0.5),
                imageResidualPx(samples, CameraModel::studyDesign().fx, false, 0.5));
    EXPECT_LE(closed.translation_m / open.translation_m, c.bound) << c.name;
    EXPECT_LE(closed.rotation_rad / open.rotation_rad, c.bound) << c.name;
    EXPECT_LT(worst, 1.0e-3) << c.name;
    EXPECT_LT(imageResidualPx(samples, CameraModel::studyDesign().fx, true, 0.5), 0.2) << c.name;
    ++seed;
  }
}

// Zero from one frame after `invalid_at` (s since the lock) until `until`;
// true when every command there is zero.
bool heldFrom(const LoopRun& run, double invalid_at, double until, double frame)
{
  for (const LoopCommand& c : run.commands)
    if (c.t >= invalid_at + frame && c.t < until && !c.twist.isZero(0.0))
      return false;
  return true;
}

// The first command at or after t that commands something (s since the lock).
double firstCommandAfter(const LoopRun& run, double t)
{
  for (const LoopCommand& c : run.commands)
    if (c.t >= t && !c.twist.isZero(0.0))
      return c.t;
  return INFINITY;
}

// The first instant after t from which the residual stays below `bound` (m) for 0.5 s.
double settledAfter(const LoopRun& run, double t, double bound)
{
  double since = INFINITY;
  for (const LoopSample& s : run.samples)
  {
    if (s.t < t)
      continue;
    if (s.closed.head<3>().norm() > bound)
      since = INFINITY;
    else if (!std::isfinite(since))
      since = s.t;
    if (std::isfinite(since) && s.t - since >= 0.5)
      return since;
  }
  return INFINITY;
}

TEST(FusedLoop, FaultsHoldAtOnceWithoutJumpsAndRecover)
{
  const StabilizationControllerParams c = fusedLoopControllerParams();
  const double frame = 1.0 / 120.0;
  const double lock_t = std::ceil(1.0 * 120.0 - 1e-9) / 120.0;  // LoopModelParams::lock_s on the frame grid
  // The camera invalid for 2 s from 1 s after the lock: the controller holds
  // from the first invalid estimate's arrival on.
  LoopModelParams p = fusedLoop(120.0, 5.0, 45);
  p.latency_jitter_s = 0.0;
  p.invalid_from_s = 1.0;
  p.invalid_until_s = 3.0;
  const LoopRun invalid = runLoopFull(roverArmDisturbance(), c, ArmModelParams(), p);
  const double first_invalid = std::ceil(1.0 / frame - 1e-9) * frame + p.latency_s;
  const double back = std::ceil(3.0 / frame - 1e-9) * frame + p.latency_s;
  double at = 0.0;
  EXPECT_TRUE(heldFrom(invalid, first_invalid, back, frame));
  EXPECT_LT(worstJump(invalid, c, &at), 1e-6) << "at " << at;
  const double resumed = firstCommandAfter(invalid, back), settled = settledAfter(invalid, back, 0.5e-3);
  std::printf("[ MEASURE ] camera invalid 2 s: commands again %.0f ms after valid estimates resume, residual below "
              "0.5 mm %.0f ms after\n",
              (resumed - back) * 1e3, (settled - back) * 1e3);
  EXPECT_LT(resumed - back, 0.3);
  EXPECT_LT(settled - back, 1.5);

  // The IMU silent for 0.3 s: held once a camera estimate finds it silent.
  LoopModelParams q = fusedLoop(120.0, 3.0, 46);
  q.latency_jitter_s = 0.0;
  q.imu_params.silent_from_s = lock_t + 1.0;
  q.imu_params.silent_until_s = lock_t + 1.3;
  const LoopRun silent = runLoopFull(roverArmDisturbance(), c, ArmModelParams(), q);
  const InertialFusionParams fp;
  const double noticed = std::ceil((1.0 + fp.imu_timeout) / frame) * frame + q.latency_s;
  EXPECT_TRUE(heldFrom(silent, noticed, 1.3, frame));
  EXPECT_LT(worstJump(silent, c, &at), 1e-6) << "at " << at;
  const double silent_resumed = firstCommandAfter(silent, 1.3);
  std::printf("[ MEASURE ] IMU silent 0.3 s: held %.0f ms after it fell silent, commands again %.0f ms after it "
              "resumed\n",
              (noticed - 1.0) * 1e3, (silent_resumed - 1.3) * 1e3);
  EXPECT_LT(silent_resumed - 1.3, 0.5);

  // A gyro bias step of 2 deg/s and an accelerometer one of 0.3 m/s^2.
  LoopModelParams r = fusedLoop(120.0, 4.0, 47);
  r.imu_params.bias_step_time_s = lock_t + 1.5;
  r.imu_params.gyro_bias_step = Eigen::Vector3d(0.035, 0.0, 0.0);
  r.imu_params.accel_bias_step = Eigen::Vector3d(0.0, 0.3, 0.0);
  const LoopRun step = runLoopFull(roverArmDisturbance(), c, ArmModelParams(), r);
  double invalid_at = INFINITY;
  for (const LoopFused& f : step.fused)
    if (f.t >= 1.5 && !f.estimate.valid)
    {
      invalid_at = f.t + r.imu_latency_s;
      break;
    }
  ASSERT_TRUE(std::isfinite(invalid_at)) << "the bias step went unnoticed";
  EXPECT_TRUE(heldFrom(step, invalid_at, invalid_at + 0.02, frame));
  EXPECT_LT(worstJump(step, c, &at), 1e-6) << "at " << at;
  double drift = 0.0;
  for (const LoopSample& s : step.samples)
    if (s.t >= 1.5 && s.t < 3.0)
      drift = std::max(drift, s.closed.head<3>().norm());
  const double step_settled = settledAfter(step, invalid_at, 0.5e-3);
  std::printf("[ MEASURE ] bias step: held %.0f ms after it, worst residual meanwhile %.2f mm, residual below 0.5 mm "
              "%.0f ms after the hold\n",
              (invalid_at - 1.5) * 1e3, drift * 1e3, (step_settled - invalid_at) * 1e3);
  EXPECT_LT(invalid_at - 1.5, 0.2);
  EXPECT_LT(step_settled - invalid_at, 1.5);

  // A re-lock 1.5 s after the lock: one hold, no jump.
  LoopModelParams l = fusedLoop(120.0, 3.0, 48);
  l.relock_s = 1.5;
  const LoopRun relock = runLoopFull(roverArmDisturbance(), c, ArmModelParams(), l);
  EXPECT_LT(worstJump(relock, c, &at), 1e-6) << "at " << at;
  int relock_holds = 0;
  for (const LoopCommand& cmd : relock.commands)
    relock_holds += cmd.hold == HoldReason::kRelocked;
  EXPECT_EQ(relock_holds, 2);  // the first lock and the re-lock, each announced once
  std::printf("[ MEASURE ] re-lock: commands again %.0f ms after it\n",
              (firstCommandAfter(relock, 1.5 + l.latency_s) - 1.5) * 1e3);
}
