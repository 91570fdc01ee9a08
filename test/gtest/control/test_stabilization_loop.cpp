// The closed loop's simulated parts and the loop itself, without rendering:
// the arm model against closed-form responses (screw motion, first-order lag,
// delay, limits, timeout), the disturbance against its parameters (RMS and
// band of the vibration by a DFT, ramped steps, rotation about the pivot),
// the shipped config/stabilize.yaml against roverArmDisturbance(), and the
// loop model (test/support/closed_loop_model.h): the physics of a sampled,
// delayed loop (slow motion rejected, vibration not) and the acceptance
// ratio on held-out seeds.
//
// Seeds: the controller's default gains were chosen with the loop model on
// disturbance seeds 1-5 and noise seeds 101-105 (tools/benchmark_stabilization);
// the ratio test below runs held-out seeds 11-18 / 211-218.
#include <algorithm>
#include <cmath>
#include <complex>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>

#include "support/closed_loop_model.h"

using namespace structured_light_stabilizer;
using namespace sls_test;

namespace
{

Vector6d twist(double vx, double vy, double vz, double wx, double wy, double wz)
{
  Vector6d v;
  v << vx, vy, vz, wx, wy, wz;
  return v;
}

// Camera pose relative to the disturbed pose: C = correction^-1.
Eigen::Isometry3d cameraMotion(const ArmModel& arm)
{
  return arm.correction().inverse();
}

// Amplitude of the DFT of x (sampled at rate) at frequency f.
double amplitudeAt(const std::vector<double>& x, double rate, double f)
{
  std::complex<double> s = 0.0;
  for (size_t i = 0; i < x.size(); ++i)
    s += x[i] * std::exp(std::complex<double>(0.0, -2.0 * M_PI * f * i / rate));
  return 2.0 * std::abs(s) / x.size();
}

}  // namespace

TEST(ArmModel, ConstantTwistIsAnExactScrewMotion)
{
  ArmModelParams p;
  p.delay_s = 0.0;
  p.bandwidth_hz = 1e4;  // follows at once
  p.max_linear_acceleration_mps2 = p.max_angular_acceleration_radps2 = 1e6;
  ArmModel arm(p);
  const Vector6d xi = twist(0.02, -0.01, 0.005, 0.1, 0.05, -0.2);
  arm.command(0.0, xi);
  arm.advance(0.2);  // command_timeout 0.25 s: still in force
  // Closed form: C(t) = Exp(xi t) for a body twist (the lag's first 0.1 ms aside).
  const double t = 0.2;
  const Eigen::Vector3d w = xi.tail<3>() * t, v = xi.head<3>() * t;
  const double th = w.norm();
  const Eigen::Matrix3d K = skew(w);
  const Eigen::Matrix3d V =
      Eigen::Matrix3d::Identity() + (1 - std::cos(th)) / (th * th) * K + (th - std::sin(th)) / (th * th * th) * K * K;
  const Eigen::Isometry3d C = cameraMotion(arm);
  EXPECT_LT((C.translation() - V * v).norm(), 2e-6);
  EXPECT_LT(logSO3(C.linear().transpose() * expSO3(w)).norm(), 2e-5);
}

TEST(ArmModel, FirstOrderLagDelayLimitsAndTimeout)
{
  ArmModelParams p;  // 10 Hz, 20 ms delay, 1 m/s^2
  p.max_linear_acceleration_mps2 = 100.0;
  ArmModel arm(p);
  arm.command(1.0, twist(0.01, 0, 0, 0, 0, 0));
  arm.advance(1.0 + p.delay_s - 0.001);
  EXPECT_EQ(arm.velocity().norm(), 0.0);  // not before the delay
  // One time constant after the delay: 1 - 1/e of the command.
  const double tau = 1.0 / (2.0 * M_PI * p.bandwidth_hz);
  arm.advance(1.0 + p.delay_s + tau);
  EXPECT_NEAR(arm.velocity()[0], 0.01 * (1.0 - std::exp(-1.0)), 2e-4);

  // Acceleration limit: a 0.1 m/s step with 1 m/s^2 takes 0.1 s at least.
  ArmModelParams q;
  q.delay_s = 0.0;
  q.bandwidth_hz = 1e4;
  ArmModel limited(q);
  limited.command(0.0, twist(0.1, 0, 0, 0, 0, 0));
  limited.advance(0.05);
  EXPECT_NEAR(limited.velocity()[0], 0.05, 1e-3);
  // Velocity limit (0.1 m/s) on a command of 1 m/s, the direction kept.
  ArmModel fast(q);
  fast.command(0.0, twist(0.6, 0.8, 0, 0, 0, 0));
  fast.advance(0.2);
  EXPECT_NEAR(fast.velocity().head<3>().norm(), q.max_linear_velocity_mps, 1e-9);
  EXPECT_NEAR(fast.velocity()[1] / fast.velocity()[0], 0.8 / 0.6, 1e-9);
  // No newer command for command_timeout_s: the arm stops.
  fast.advance(0.2 + q.command_timeout_s + 0.2);
  EXPECT_LT(fast.velocity().norm(), 1e-9);
  // A NaN command stops it too.
  ArmModel nan(q);
  nan.command(0.0, twist(0.01, 0, 0, 0, 0, 0));
  nan.advance(0.1);
  nan.command(0.1, twist(NAN, 0, 0, 0, 0, 0));
  nan.advance(0.3);
  EXPECT_LT(nan.velocity().norm(), 1e-9);
  EXPECT_TRUE(nan.correction().matrix().allFinite());
}

TEST(Disturbance, VibrationHasItsRmsAndStaysInItsBand)
{
  RigMotionParams m;
  m.vibration_translation_rms_m = 0.001;
  m.vibration_rotation_rms_rad = 0.0;
  m.vibration_min_hz = 2.0;
  m.vibration_max_hz = 8.0;
  m.seed = 3;
  const double rate = 100.0;
  std::vector<double> x;
  double sq = 0.0;
  for (int i = 0; i < 20000; ++i)  // 200 s
  {
    const double v = disturbanceMotion(m, i / rate).inverse().translation().x();
    x.push_back(v);
    sq += v * v;
  }
  // RMS about the mean (the value at t = 0 is taken off, a constant).
  double mean = 0.0;
  for (double v : x)
    mean += v / x.size();
  EXPECT_NEAR(std::sqrt(sq / x.size() - mean * mean), 0.001, 0.0001);
  // Independent check of the band: DFT amplitudes inside and outside.
  double in = 0.0, out = 0.0;
  for (double f = 0.2; f < 12.0; f += 0.05)
  {
    const double a = amplitudeAt(x, rate, f);
    (f > 1.9 && f < 8.1 ? in : out) += a * a;
  }
  EXPECT_LT(out, 0.02 * in);
  // A tone: min = max, RMS kept.
  m.vibration_min_hz = m.vibration_max_hz = 3.0;
  x.clear();
  for (int i = 0; i < 1000; ++i)
    x.push_back(disturbanceMotion(m, i / rate).inverse().translation().x());
  EXPECT_NEAR(amplitudeAt(x, rate, 3.0), 0.001 * std::sqrt(2.0), 2e-5);
}

TEST(Disturbance, StepsRampInAndRotateAboutThePivot)
{
  RigMotionParams m;
  m.step_period_s = 2.0;
  m.step_rise_s = 0.2;
  m.step_translation_m = Eigen::Vector3d(0, 0.001, 0);
  m.step_rotation_rad = Eigen::Vector3d(0.002, 0, 0);
  m.pivot_m = Eigen::Vector3d(0.3, 0.8, -1.2);
  EXPECT_TRUE(disturbanceMotion(m, 1.99).isApprox(Eigen::Isometry3d::Identity()));
  // Half-way up the first step: half the rotation (raised cosine).
  const Eigen::Isometry3d half = disturbanceMotion(m, 2.1).inverse();  // pose of the camera in the reference
  EXPECT_NEAR(logSO3(half.linear()).x(), 0.001, 1e-12);
  // After two whole steps: twice the step, the rotation about the pivot.
  const Eigen::Isometry3d two = disturbanceMotion(m, 4.25).inverse();
  const Eigen::Matrix3d R = expSO3(Eigen::Vector3d(0.004, 0, 0));
  EXPECT_LT((two.linear() - R).norm(), 1e-12);
  const Eigen::Vector3d expected = Eigen::Vector3d(0, 0.002, 0) + m.pivot_m - R * m.pivot_m;
  EXPECT_LT((two.translation() - expected).norm(), 1e-12);
  // The pivot itself only moves by the steps' translation.
  EXPECT_LT((two * m.pivot_m - m.pivot_m - Eigen::Vector3d(0, 0.002, 0)).norm(), 1e-12);
  // A rise longer than the period is refused.
  SimulatorParams bad;
  bad.motion = m;
  bad.motion.step_rise_s = 3.0;
  EXPECT_NE(bad.validate().find("step_rise_s"), std::string::npos) << bad.validate();
  bad.motion = m;
  bad.motion.vibration_translation_rms_m = 0.001;
  bad.motion.vibration_min_hz = 0.0;
  EXPECT_NE(bad.validate().find("vibration band"), std::string::npos) << bad.validate();
}

TEST(Disturbance, ShippedConfigIsTheDefault)
{
  const YAML::Node y = YAML::LoadFile(std::string(SLS_TEST_DATA_DIR) + "/../../config/stabilize.yaml");
  const RigMotionParams m = roverArmDisturbance();
  const auto vec = [&](const char* key)
  { return Eigen::Vector3d(y[key][0].as<double>(), y[key][1].as<double>(), y[key][2].as<double>()); };
  EXPECT_EQ(y["jitter_translation"].as<double>(), m.jitter_translation_m);
  EXPECT_EQ(y["jitter_rotation"].as<double>(), m.jitter_rotation_rad);
  EXPECT_EQ(y["jitter_frequency"].as<double>(), m.jitter_frequency_hz);
  EXPECT_EQ(y["vibration_translation_rms"].as<double>(), m.vibration_translation_rms_m);
  EXPECT_EQ(y["vibration_rotation_rms"].as<double>(), m.vibration_rotation_rms_rad);
  EXPECT_EQ(y["vibration_min_frequency"].as<double>(), m.vibration_min_hz);
  EXPECT_EQ(y["vibration_max_frequency"].as<double>(), m.vibration_max_hz);
  EXPECT_EQ(y["vibration_spectrum_slope"].as<double>(), m.vibration_spectrum_slope);
  EXPECT_EQ(vec("drift_velocity"), m.drift_velocity_mps);
  EXPECT_EQ(vec("drift_angular_velocity"), m.drift_angular_velocity_radps);
  EXPECT_EQ(y["step_period"].as<double>(), m.step_period_s);
  EXPECT_EQ(vec("step_translation"), m.step_translation_m);
  EXPECT_EQ(vec("step_rotation"), m.step_rotation_rad);
  EXPECT_EQ(y["step_rise"].as<double>(), m.step_rise_s);
  EXPECT_EQ(vec("motion_pivot"), m.pivot_m);
  EXPECT_EQ(y["motion_seed"].as<uint32_t>(), m.seed);
  const ArmModelParams a;
  EXPECT_EQ(y["arm_bandwidth"].as<double>(), a.bandwidth_hz);
  EXPECT_EQ(y["arm_delay"].as<double>(), a.delay_s);
  EXPECT_EQ(y["arm_max_linear_velocity"].as<double>(), a.max_linear_velocity_mps);
  EXPECT_EQ(y["arm_max_angular_velocity"].as<double>(), a.max_angular_velocity_radps);
  EXPECT_EQ(y["arm_max_linear_acceleration"].as<double>(), a.max_linear_acceleration_mps2);
  EXPECT_EQ(y["arm_max_angular_acceleration"].as<double>(), a.max_angular_acceleration_radps2);
  EXPECT_EQ(y["arm_command_timeout"].as<double>(), a.command_timeout_s);
  EXPECT_TRUE(SimulatorParams().validate().empty());
}

namespace
{

// The loop as stabilize.launch measured it (docs/stabilization.md): exposure
// to command 25 ms median, 77 ms at the 95th percentile: 25 ms + up to 60 ms.
LoopModelParams measuredLoop()
{
  LoopModelParams p;
  p.latency_s = 0.025;
  p.latency_jitter_s = 0.06;
  return p;
}

// |S| at f: residual over disturbance RMS (centred) for a sine on every axis.
double sensitivityAt(double f, uint32_t seed)
{
  RigMotionParams m;
  m.vibration_translation_rms_m = 0.001;
  m.vibration_rotation_rms_rad = 0.0005;
  m.vibration_min_hz = m.vibration_max_hz = f;
  m.seed = seed;
  LoopModelParams p = measuredLoop();
  p.noise_translation_m = p.noise_rotation_rad = 0.0;
  p.duration_s = 3.0 + std::max(10.0, 5.0 / f);
  const auto samples = runLoop(m, StabilizationControllerParams(), ArmModelParams(), p);
  return loopRms(samples, true, 3.0, true).translation_m / loopRms(samples, false, 3.0, true).translation_m;
}

}  // namespace

TEST(ClosedLoop, RejectsSlowMotionButNotVibration)
{
  // The physics of a loop sampled at 30 Hz with tens of ms of latency: slow
  // motion is rejected, the loop amplifies near its crossover, and the
  // vibration band passes through.
  EXPECT_LT(sensitivityAt(0.05, 21), 0.05);
  EXPECT_LT(sensitivityAt(0.2, 22), 0.35);
  const double peak = std::max({sensitivityAt(1.5, 23), sensitivityAt(2.0, 24), sensitivityAt(2.5, 25)});
  EXPECT_GT(peak, 1.2);
  EXPECT_LT(peak, 2.0);  // but stays stable with margin
  EXPECT_GT(sensitivityAt(5.0, 26), 0.8);
}

TEST(ClosedLoop, OpenLoopIsTheDisturbance)
{
  LoopModelParams p = measuredLoop();
  p.closed = false;
  p.duration_s = 10.0;
  const auto samples = runLoop(roverArmDisturbance(), StabilizationControllerParams(), ArmModelParams(), p);
  ASSERT_EQ(samples.size(), 301u);
  for (const LoopSample& s : samples)
    EXPECT_LT((s.closed - s.open).norm(), 1e-12);
}

TEST(ClosedLoop, DefaultDisturbanceRejectedTenfoldOnHeldOutSeeds)
{
  // Held-out seeds (tuning used 1-5 / 101-105). Per seed: the acceptance
  // ratio (closed-loop RMS <= 10 % of open-loop, translation and rotation)
  // and a per-frame bound after the first second (the largest residual of
  // any frame: a step's transient, the estimate noise, the vibration).
  double worst_t = 0.0, worst_r = 0.0, pooled_c = 0.0, pooled_o = 0.0;
  for (uint32_t seed = 11; seed <= 18; ++seed)
  {
    RigMotionParams m = roverArmDisturbance();
    m.seed = seed;
    LoopModelParams p = measuredLoop();
    p.noise_seed = 200 + seed;
    const auto samples = runLoop(m, StabilizationControllerParams(), ArmModelParams(), p);
    const LoopRms c = loopRms(samples, true), o = loopRms(samples, false);
    worst_t = std::max(worst_t, c.translation_m / o.translation_m);
    worst_r = std::max(worst_r, c.rotation_rad / o.rotation_rad);
    pooled_c += c.translation_m * c.translation_m;
    pooled_o += o.translation_m * o.translation_m;
    double max_t = 0.0, max_r = 0.0;
    for (const LoopSample& s : samples)
      if (s.t >= 1.0)
      {
        max_t = std::max(max_t, s.closed.head<3>().norm());
        max_r = std::max(max_r, s.closed.tail<3>().norm());
      }
    EXPECT_LT(max_t, 0.8e-3) << "seed " << seed;
    EXPECT_LT(max_r, 0.05 * M_PI / 180.0) << "seed " << seed;
    std::printf("[ MEASURE ] seed %u: open %.3f mm %.4f deg, closed %.3f mm %.4f deg, worst frame %.3f mm %.4f deg\n",
                seed, o.translation_m * 1e3, o.rotation_rad * 180 / M_PI, c.translation_m * 1e3,
                c.rotation_rad * 180 / M_PI, max_t * 1e3, max_r * 180 / M_PI);
  }
  EXPECT_LE(worst_t, 0.10);
  EXPECT_LE(worst_r, 0.10);
  EXPECT_LE(std::sqrt(pooled_c / pooled_o), 0.09);
}
