// PoseDelta on the simulator with the true beam hit points (SimFrame::points,
// plus 0.5 mm of noise along the camera ray to mimic triangulation) and
// SimFrame::image, compared with SimFrame::delta: the estimator alone, apart
// from the detector and the triangulator (test_pose_delta_chain runs the full
// chain on held-out seeds). Rock seed 1 was among the seeds the texture was
// developed on; seed 5 was not. Bounds: the accuracy target
// (0.5 mm, 0.02 deg RMS, 95 % valid) and its return to the reference pose
// (0.05 mm, 0.002 deg).
#include <cmath>
#include <iostream>
#include <random>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/pose/pose_delta.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

using namespace structured_light_stabilizer;

namespace
{
constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

struct Scenario
{
  const char* name;
  double relief_m;
  bool use_texture;
  double noise_m;
  int frames;
  uint32_t rock_seed = 1;
  double t_lock = 0.0;  // s; the reference is the frame at this instant
  // Stamped frames (the motion filter runs); from frame jump_frame on, the
  // rig is jump_s further on than the stamps say (a jolt the filter cannot predict).
  bool stamped = false;
  int jump_frame = 0;
  double jump_s = 0.0;
};

struct Outcome
{
  double rms_t_mm = 0, rms_r_deg = 0, valid_percent = 0;
  Vector6d axis_rms = Vector6d::Zero();  // mm, deg
  int frames = 0;
  int unobservable_in_plane = 0;  // frames whose status names tx ty rz
  std::string last_status;
  int from_motion = 0;           // frames whose texture was refined from the motion filter's prediction
  bool jump_from_motion = true;  // ... the jump's frame
  double jump_error_mm = 0.0, jump_error_deg = 0.0;
  bool jump_valid = false;
};

SimulatorParams simConfig(double relief_m, uint32_t rock_seed = 1)
{
  SimulatorParams c;
  c.rock.relief_m = relief_m;
  c.rock.seed = rock_seed;
  c.motion.jitter_translation_m = 0.010;
  c.motion.jitter_rotation_rad = 1.0 * kDeg;
  return c;
}

PoseDeltaInput inputOf(const SimFrame& f, const SimulatorParams& c, double noise_m, std::mt19937* rng)
{
  PoseDeltaInput in;
  in.rows = c.projector.rows;
  in.cols = c.projector.cols;
  in.points = f.points;
  std::normal_distribution<double> n01(0.0, 1.0);
  for (Eigen::Vector3d& p : in.points)
    if (p.allFinite() && noise_m > 0.0)
      p += noise_m * n01(*rng) * p.normalized();
  in.image = f.image;
  in.texture_channel = 2;  // bgr8: red carries the rock, not the green dots
  return in;
}

Outcome run(const Scenario& s, double dt = 0.1)
{
  const SimulatorParams c = simConfig(s.relief_m, s.rock_seed);
  const Simulator sim(c);
  PoseDeltaParams cfg;
  cfg.use_texture = s.use_texture;
  PoseDeltaEstimator est(cfg);
  est.setCamera(sim.camera());
  std::mt19937 rng(21);
  const SimFrame f0 = sim.render(s.t_lock);
  PoseDeltaInput in0 = inputOf(f0, c, s.noise_m, &rng);
  if (s.stamped)
    in0.stamp_s = s.t_lock;
  const PoseDeltaResult r0 = est.process(in0);
  std::cout << "  " << s.name << " lock: " << r0.status << "\n";
  Outcome o;
  double st2 = 0, sr2 = 0;
  int valid = 0;
  for (int k = 1; k <= s.frames; ++k)
  {
    const bool jumped = s.jump_frame > 0 && k >= s.jump_frame;
    const SimFrame f = sim.render(s.t_lock + k * dt + (jumped ? s.jump_s : 0.0));
    PoseDeltaInput in = inputOf(f, c, s.noise_m, &rng);
    if (s.stamped)
      in.stamp_s = s.t_lock + k * dt;
    const PoseDeltaResult r = est.process(in);
    // Truth relative to the reference frame.
    const Eigen::Isometry3d E = r.transform * (f.delta * f0.delta.inverse()).inverse();
    const Eigen::Vector3d et = E.translation();
    const Eigen::Vector3d er = logSO3(E.linear());
    st2 += et.squaredNorm();
    sr2 += er.squaredNorm();
    for (int a = 0; a < 3; ++a)
    {
      o.axis_rms[a] += std::pow(et[a] * 1e3, 2);
      o.axis_rms[a + 3] += std::pow(er[a] / kDeg, 2);
    }
    valid += r.valid ? 1 : 0;
    o.from_motion += r.texture_from_motion ? 1 : 0;
    if (k == s.jump_frame)
    {
      o.jump_from_motion = r.texture_from_motion;
      o.jump_valid = r.valid;
      o.jump_error_mm = 1e3 * et.norm();
      o.jump_error_deg = er.norm() / kDeg;
    }
    const bool named = r.status.find("unobservable: tx ty rz") != std::string::npos;
    o.unobservable_in_plane += named ? 1 : 0;
    if (!s.use_texture && !named)
      std::cout << "  frame " << k << ": " << r.status << "\n";
    o.last_status = r.status;
  }
  o.frames = s.frames;
  o.rms_t_mm = 1e3 * std::sqrt(st2 / s.frames);
  o.rms_r_deg = std::sqrt(sr2 / s.frames) / kDeg;
  o.valid_percent = 100.0 * valid / s.frames;
  for (int a = 0; a < 6; ++a)
    o.axis_rms[a] = std::sqrt(o.axis_rms[a] / s.frames);
  std::cout << "[ MEASURE ] sim " << s.name << ": translation RMS " << o.rms_t_mm << " mm, rotation RMS " << o.rms_r_deg
            << " deg, valid " << o.valid_percent << " % of " << o.frames << " frames (" << o.from_motion
            << " refined from the motion filter's prediction); per axis tx ty tz (mm) "
            << "rx ry rz (deg): " << o.axis_rms.transpose() << "\n"
            << "  last status: " << o.last_status << "\n";
  return o;
}
}  // namespace

TEST(PoseDeltaSim, RoughRockJitter)
{
  const Outcome o = run({"rough rock 0.15 m, jitter 10 mm / 1 deg, texture on", 0.15, true, 0.5e-3, 30});
  EXPECT_LT(o.rms_t_mm, 0.5);
  EXPECT_LT(o.rms_r_deg, 0.02);
  EXPECT_GE(o.valid_percent, 95.0);
  // The exact beam hit points, as the rostest feeds sim/ground_truth/points.
  const Outcome exact = run({"rough rock 0.15 m, exact points, texture on", 0.15, true, 0.0, 20});
  EXPECT_LT(exact.rms_t_mm, 0.5);
  EXPECT_LT(exact.rms_r_deg, 0.02);
  EXPECT_GE(exact.valid_percent, 95.0);
  // Another rock, locked while the rig is moving (as the rostest does).
  const Outcome other =
      run({"another rough rock, locked in motion, texture on", 0.15, true, 0.5e-3, 20, /*rock_seed=*/5, 1.48});
  EXPECT_LT(other.rms_t_mm, 0.5);
  EXPECT_LT(other.rms_r_deg, 0.02);
  EXPECT_GE(other.valid_percent, 95.0);
}

// At 30 Hz with stamps the motion filter predicts each frame within a
// fraction of a pixel: the texture is refined from there without the coarse
// track (texture_motion_prediction_max_px), as accurate. A jolt the filter
// cannot predict (the rig 0.6 s further on) loses
// the refinement's features and falls back to the coarse track on that
// very frame. Rock seed 5 (not used in developing the texture).
TEST(PoseDeltaSim, RefinesFromTheMotionFilterAt30HzAndFallsBackOnAJolt)
{
  Scenario s{"another rough rock, 30 Hz stamped, a jolt at frame 40", 0.15, true, 0.5e-3, 60, /*rock_seed=*/5};
  s.stamped = true;
  s.jump_frame = 40;
  s.jump_s = 0.6;
  const Outcome o = run(s, 1.0 / 30.0);
  EXPECT_LT(o.rms_t_mm, 0.5);
  EXPECT_LT(o.rms_r_deg, 0.02);
  EXPECT_GE(o.valid_percent, 95.0);
  // Every frame but the first after the lock, the jolt's and the few while
  // the filter settles again.
  EXPECT_GE(o.from_motion, 50);
  std::cout << "[ MEASURE ] the jolt's frame: " << (o.jump_from_motion ? "from the motion filter" : "coarse track")
            << ", error " << o.jump_error_mm << " mm / " << o.jump_error_deg << " deg\n";
  EXPECT_FALSE(o.jump_from_motion);
  EXPECT_TRUE(o.jump_valid);
  EXPECT_LT(o.jump_error_mm, 0.5);
  EXPECT_LT(o.jump_error_deg, 0.02);
}

TEST(PoseDeltaSim, FlatTexturedBoardJitter)
{
  const Outcome o = run({"flat board, jitter 10 mm / 1 deg, texture on", 0.0, true, 0.5e-3, 30});
  EXPECT_LT(o.rms_t_mm, 0.5);
  EXPECT_LT(o.rms_r_deg, 0.02);
  EXPECT_GE(o.valid_percent, 95.0);
}

TEST(PoseDeltaSim, FlatBoardTextureOffReportsInPlaneAxes)
{
  const Outcome o = run({"flat board, jitter 10 mm / 1 deg, texture off", 0.0, false, 0.5e-3, 30});
  EXPECT_EQ(o.unobservable_in_plane, o.frames);
  EXPECT_EQ(o.valid_percent, 0.0);
  // The observable axes: distance and the two tilts.
  EXPECT_LT(o.axis_rms[2], 1.0);
  EXPECT_LT(std::hypot(o.axis_rms[3], o.axis_rms[4]), 0.05);
}

TEST(PoseDeltaSim, ReturnsToIdentity)
{
  SimulatorParams c = simConfig(0.15);
  c.motion.return_period_s = 2.0;
  const Simulator sim(c);
  PoseDeltaEstimator est;
  est.setCamera(sim.camera());
  std::mt19937 rng(1);
  est.process(inputOf(sim.render(0.0), c, 0.0, &rng));
  double worst_t = 0, worst_r = 0;
  for (int k = 1; k <= 10; ++k)
  {
    const double t = 0.4 * k;  // every fifth frame is back at the reference pose
    const SimFrame f = sim.render(t);
    const PoseDeltaResult r = est.process(inputOf(f, c, 0.0, &rng));
    if (k % 5 != 0)
      continue;
    ASSERT_LT(f.delta.translation().norm(), 1e-12);
    const double t_mm = r.transform.translation().norm() * 1e3;
    const double r_deg = Eigen::AngleAxisd(r.transform.linear()).angle() / kDeg;
    std::cout << "[ MEASURE ] sim back at the reference pose (t = " << t << " s): " << t_mm << " mm, " << r_deg
              << " deg, " << r.status << "\n";
    EXPECT_TRUE(r.valid) << r.status;
    worst_t = std::max(worst_t, t_mm);
    worst_r = std::max(worst_r, r_deg);
  }
  EXPECT_LT(worst_t, 0.05);
  EXPECT_LT(worst_r, 0.002);
}
