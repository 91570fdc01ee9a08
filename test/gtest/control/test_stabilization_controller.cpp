// The stabilisation controller's law and safety rules on hand-made
// estimates (no simulator): signs and units of the command, the holds
// (invalid, NaN, stale, out of order, re-lock, jump, no estimate) within one
// estimate and without a jump on resuming, axis gating by the covariance and
// by the status, limits, dead band, anti-windup and the latency compensation.
#include <cmath>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/control/stabilization_controller.h"

using namespace structured_light_stabilizer;

namespace
{

constexpr double kFrame = 1.0 / 30.0;

// A valid estimate: the reference seen from the current camera at (t, w),
// small and equal covariances.
StabilizationEstimate estimate(double stamp, const Eigen::Vector3d& t,
                               const Eigen::Vector3d& w = Eigen::Vector3d::Zero())
{
  StabilizationEstimate e;
  e.stamp = stamp;
  e.transform = Eigen::Isometry3d::Identity();
  e.transform.linear() = expSO3(w);
  e.transform.translation() = t;
  e.covariance = Matrix6d::Identity() * 1e-8;  // 0.1 mm / 0.1 mrad
  e.valid = true;
  e.status = "ok: 100 points, 80 texture features";
  return e;
}

StabilizationControllerParams plainParams()
{
  StabilizationControllerParams p;
  p.kp_translation = p.kp_rotation = 5.0;
  p.ki_translation = p.ki_rotation = 0.0;
  p.max_linear_acceleration = p.max_angular_acceleration = 1e6;  // no rate limit
  return p;
}

// Feeds estimates of a constant error every frame; returns the last command.
StabilizationCommand feed(StabilizationController* c, double* t, int frames, const Eigen::Vector3d& e,
                          const Eigen::Vector3d& w = Eigen::Vector3d::Zero())
{
  StabilizationCommand cmd;
  for (int i = 0; i < frames; ++i)
  {
    *t += kFrame;
    cmd = c->update(estimate(*t, e, w), *t + 0.05);
  }
  return cmd;
}

}  // namespace

TEST(StabilizationController, ProportionalCommandHasTheSignThatClosesTheError)
{
  StabilizationController c(plainParams());
  // The reference is 2 mm to the right and rotated 0.01 rad about y as seen
  // from the camera: move right, turn about +y.
  const StabilizationCommand cmd =
      c.update(estimate(10.0, Eigen::Vector3d(0.002, 0, 0), Eigen::Vector3d(0, 0.01, 0)), 10.05);
  EXPECT_EQ(cmd.hold, HoldReason::kNone);
  EXPECT_NEAR(cmd.twist[0], 5.0 * 0.002, 1e-12);  // kp 5/s
  EXPECT_NEAR(cmd.twist[4], 5.0 * 0.01, 1e-9);
  EXPECT_NEAR(cmd.twist[1], 0.0, 1e-15);
  EXPECT_NEAR(cmd.latency_s, 0.05, 1e-12);
  for (bool a : cmd.active)
    EXPECT_TRUE(a);
}

TEST(StabilizationController, IntegratorRemovesARampError)
{
  // A constant error integrates: after 1 s at 1 mm, ki * 1 mm * 1 s on top.
  StabilizationControllerParams p = plainParams();
  p.kp_translation = 0.0;
  p.ki_translation = 2.0;
  StabilizationController c(p);
  double t = 0.0;
  const StabilizationCommand cmd = feed(&c, &t, 31, Eigen::Vector3d(0.001, 0, 0));
  EXPECT_NEAR(c.integrator()[0], 0.001 * 30 * kFrame, 1e-9);
  EXPECT_NEAR(cmd.twist[0], 2.0 * 0.001 * 30 * kFrame, 1e-9);
}

TEST(StabilizationController, HoldsWithinOneEstimateOfAnInvalidOneAndResumesWithoutJump)
{
  StabilizationControllerParams p;  // defaults: PI + rate limits
  StabilizationController c(p);
  double t = 0.0;
  StabilizationCommand cmd = feed(&c, &t, 60, Eigen::Vector3d(0.003, -0.002, 0.001), Eigen::Vector3d(0.002, 0, 0));
  ASSERT_GT(cmd.twist.norm(), 1e-3);
  const Vector6d frozen = c.integrator();

  t += kFrame;
  StabilizationEstimate bad = estimate(t, Eigen::Vector3d(0.003, -0.002, 0.001));
  bad.valid = false;
  bad.status = "too few points on the reference surface: 3 of 5 (need 12; the rig moved off the mapped rock?)";
  cmd = c.update(bad, t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kInvalid);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
  EXPECT_NE(cmd.reason.find("too few points"), std::string::npos) << cmd.reason;
  EXPECT_EQ(c.integrator(), frozen);

  // Resuming: the command starts from zero and grows at most at the rate limits.
  t += kFrame;
  const double now = t + 0.05;
  cmd = c.update(estimate(t, Eigen::Vector3d(0.003, -0.002, 0.001), Eigen::Vector3d(0.002, 0, 0)), now);
  EXPECT_EQ(cmd.hold, HoldReason::kNone);
  EXPECT_LE(cmd.twist.head<3>().norm(), p.max_linear_acceleration * kFrame + 1e-12);
  EXPECT_LE(cmd.twist.tail<3>().norm(), p.max_angular_acceleration * kFrame + 1e-12);
  EXPECT_GT(cmd.twist.head<3>().norm(), 0.0);
}

TEST(StabilizationController, HoldsOnNaNStaleOutOfOrderAndMissingEstimates)
{
  StabilizationControllerParams p = plainParams();
  StabilizationController c(p);
  double t = 0.0;
  feed(&c, &t, 10, Eigen::Vector3d(0.002, 0, 0));
  const Vector6d frozen = c.integrator();

  StabilizationEstimate nan = estimate(t + kFrame, Eigen::Vector3d(NAN, 0, 0));
  StabilizationCommand cmd = c.update(nan, t + kFrame + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kNotFinite);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
  StabilizationEstimate nan_cov = estimate(t + kFrame, Eigen::Vector3d(0.002, 0, 0));
  nan_cov.covariance(2, 2) = NAN;
  EXPECT_EQ(c.update(nan_cov, t + kFrame + 0.05).hold, HoldReason::kNotFinite);

  // Stale: exposed 0.3 s before it arrived (timeout 0.2 s).
  t += kFrame;
  cmd = c.update(estimate(t, Eigen::Vector3d(0.002, 0, 0)), t + 0.3);
  EXPECT_EQ(cmd.hold, HoldReason::kStale);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
  EXPECT_NE(cmd.reason.find("300 ms old"), std::string::npos) << cmd.reason;

  // Out of order: an older stamp than the last one.
  cmd = c.update(estimate(t - 0.01, Eigen::Vector3d(0.002, 0, 0)), t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kOutOfOrder);
  EXPECT_EQ(c.integrator(), frozen);

  // No estimate for longer than the timeout: the watchdog's tick holds.
  t += kFrame;
  cmd = c.update(estimate(t, Eigen::Vector3d(0.002, 0, 0)), t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kNone);
  EXPECT_EQ(c.tick(t + 0.1).hold, HoldReason::kNone);  // still fresh
  cmd = c.tick(t + 0.25);
  EXPECT_EQ(cmd.hold, HoldReason::kNoEstimate);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
}

TEST(StabilizationController, NeverCommandsAnAxisReportedUnobservable)
{
  StabilizationController c(plainParams());
  // Flat board without texture: tx, ty, rz unobservable (large sigma, named in the status).
  StabilizationEstimate e = estimate(1.0, Eigen::Vector3d(0.003, 0.003, 0.003), Eigen::Vector3d(0.005, 0.005, 0.005));
  e.valid = false;
  e.status = "unobservable: tx ty rz (smooth or flat surface, texture off)";
  e.covariance(0, 0) = e.covariance(1, 1) = 0.05 * 0.05;
  e.covariance(5, 5) = 0.05 * 0.05;
  StabilizationCommand cmd = c.update(e, 1.05);
  EXPECT_EQ(cmd.hold, HoldReason::kNone);
  EXPECT_EQ(cmd.twist[0], 0.0);
  EXPECT_EQ(cmd.twist[1], 0.0);
  EXPECT_EQ(cmd.twist[5], 0.0);
  EXPECT_GT(cmd.twist[2], 0.0);
  EXPECT_GT(cmd.twist[3], 0.0);
  EXPECT_GT(cmd.twist[4], 0.0);
  EXPECT_FALSE(cmd.active[0]);
  EXPECT_NE(cmd.reason.find("tx ty rz"), std::string::npos) << cmd.reason;

  // Named in the status alone (covariance small): still not commanded.
  e.stamp = 1.0 + kFrame;
  e.covariance = Matrix6d::Identity() * 1e-8;
  cmd = c.update(e, e.stamp + 0.05);
  EXPECT_EQ(cmd.twist[0], 0.0);
  EXPECT_EQ(cmd.twist[5], 0.0);

  // Only the names before the parenthesis count (the reason may contain anything).
  e.stamp += kFrame;
  e.status = "unobservable: rz (texture unused: tx ty)";
  cmd = c.update(e, e.stamp + 0.05);
  EXPECT_GT(cmd.twist[0], 0.0);
  EXPECT_GT(cmd.twist[1], 0.0);
  EXPECT_EQ(cmd.twist[5], 0.0);

  // Large sigma alone on a valid estimate: not commanded either.
  StabilizationEstimate v = estimate(1.0 + 3 * kFrame, Eigen::Vector3d(0.003, 0.003, 0.003));
  v.covariance(1, 1) = 0.01 * 0.01;
  cmd = c.update(v, v.stamp + 0.05);
  EXPECT_EQ(cmd.twist[1], 0.0);
  EXPECT_GT(cmd.twist[0], 0.0);

  // With the rate limits in force, an axis that becomes unobservable is zero
  // at once, not ramped down.
  StabilizationController ramped{StabilizationControllerParams()};
  double t = 10.0;
  StabilizationCommand before = feed(&ramped, &t, 30, Eigen::Vector3d(0.003, 0.003, 0.003));
  ASSERT_GT(before.twist[0], 0.0);
  e.stamp = t + kFrame;
  e.status = "unobservable: tx ty rz (smooth or flat surface, texture off)";
  e.covariance(0, 0) = 0.05 * 0.05;
  cmd = ramped.update(e, e.stamp + 0.05);
  EXPECT_EQ(cmd.twist[0], 0.0);
  EXPECT_EQ(cmd.twist[1], 0.0);
  EXPECT_EQ(cmd.twist[5], 0.0);
  EXPECT_GT(cmd.twist[2], 0.0);

  // And with command_observable_axes off, an unobservable estimate holds all.
  StabilizationControllerParams strict = plainParams();
  strict.command_observable_axes = false;
  StabilizationController s(strict);
  e.stamp = 5.0;
  cmd = s.update(e, 5.05);
  EXPECT_EQ(cmd.hold, HoldReason::kInvalid);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
}

TEST(StabilizationController, ReLockAndJumpsHoldOneEstimateThenResume)
{
  StabilizationControllerParams p;
  StabilizationController c(p);
  double t = 0.0;
  feed(&c, &t, 30, Eigen::Vector3d(0.004, 0, 0));
  // The reference is re-locked during motion: the estimate jumps to identity.
  t += kFrame;
  StabilizationEstimate relock = estimate(t, Eigen::Vector3d::Zero());
  relock.status = "ok: 100 points, 80 texture features; reference locked on this frame";
  StabilizationCommand cmd = c.update(relock, t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kRelocked);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
  t += kFrame;
  cmd = c.update(estimate(t, Eigen::Vector3d(0.0001, 0, 0)), t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kNone);
  EXPECT_LE(cmd.twist.head<3>().norm(), p.max_linear_acceleration * kFrame + 1e-12);

  // An unannounced jump of 5 cm (a re-lock whose status was lost, an outlier).
  t += kFrame;
  cmd = c.update(estimate(t, Eigen::Vector3d(0.05, 0, 0)), t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kJump);
  EXPECT_EQ(cmd.twist, Vector6d::Zero());
  // The next one, consistent with it, is used.
  t += kFrame;
  cmd = c.update(estimate(t, Eigen::Vector3d(0.0501, 0, 0)), t + 0.05);
  EXPECT_EQ(cmd.hold, HoldReason::kNone);
  EXPECT_GT(cmd.twist[0], 0.0);
}

TEST(StabilizationController, LimitsKeepTheDirectionAndTheIntegratorDoesNotWindUp)
{
  StabilizationControllerParams p;
  p.max_linear_acceleration = 1e6;
  StabilizationController c(p);
  double t = 0.0;
  // 3 cm error for 10 s: kp alone asks 0.15 m/s, three times the limit.
  StabilizationCommand cmd;
  for (int i = 0; i < 300; ++i)
  {
    t += kFrame;
    cmd = c.update(estimate(t, Eigen::Vector3d(0.024, 0.018, 0.0)), t + 0.05);
  }
  EXPECT_NEAR(cmd.twist.head<3>().norm(), p.max_linear_velocity, 1e-9);
  EXPECT_NEAR(cmd.twist[1] / cmd.twist[0], 0.75, 1e-9);
  // Saturated from the first estimate: nothing integrated.
  EXPECT_LT(c.integrator().head<3>().norm(), 1e-9);
}

TEST(StabilizationController, DeadBandIsContinuous)
{
  StabilizationControllerParams p = plainParams();
  p.dead_band_translation = 0.001;
  StabilizationController c(p);
  StabilizationCommand cmd = c.update(estimate(1.0, Eigen::Vector3d(0.0009, 0, 0)), 1.05);
  EXPECT_EQ(cmd.twist[0], 0.0);
  cmd = c.update(estimate(1.0 + kFrame, Eigen::Vector3d(0.0011, 0, 0)), 1.05 + kFrame);
  EXPECT_NEAR(cmd.twist[0], 5.0 * 0.0001, 1e-12);
}

TEST(StabilizationController, LatencyCompensationSubtractsTheMotionInFlight)
{
  StabilizationControllerParams p = plainParams();
  p.latency_compensation = true;
  p.arm_delay = 0.0;
  StabilizationController c(p);
  // First command at t = 1.05: 5 mm/s (1 mm error, kp 5).
  StabilizationCommand cmd = c.update(estimate(1.0, Eigen::Vector3d(0.001, 0, 0)), 1.05);
  ASSERT_NEAR(cmd.twist[0], 0.005, 1e-12);
  // The next estimate was exposed at 1.04, before that command went out at
  // 1.05: the command's motion from 1.05 to now = 1.1 (0.05 s * 5 mm/s =
  // 0.25 mm) is not in it yet and is taken off the measured 1 mm.
  const double stamp = 1.04;
  cmd = c.update(estimate(stamp, Eigen::Vector3d(0.001, 0, 0)), 1.1);
  EXPECT_NEAR(cmd.error[0], 0.001 - 0.005 * 0.05, 1e-12);
}

TEST(StabilizationController, RejectsUnusableParams)
{
  StabilizationControllerParams p;
  p.kp_translation = -1.0;
  EXPECT_THROW(StabilizationController{p}, std::invalid_argument);
  p = StabilizationControllerParams();
  p.timeout = 0.0;
  EXPECT_NE(p.validate().find("timeout"), std::string::npos);
  p = StabilizationControllerParams();
  p.max_linear_velocity = NAN;
  EXPECT_FALSE(p.validate().empty());
  EXPECT_TRUE(StabilizationControllerParams().validate().empty());
}
