// Triangulator and board calibration on the simulator's ground truth: the
// true (distorted) pixel of every visible beam hit, plus centroid noise,
// missing dots and spurious spots, triangulated with Simulator::projector()
// (exact) or with a calibration fitted from simulated flat boards.
#include <cmath>
#include <iostream>
#include <random>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/calibration/projector_calibrator.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "support/triangulator_scene.h"

using namespace structured_light_stabilizer;

namespace
{

struct SimSpots
{
  Spots spots;  // spot.beam = true beam, -1 = spurious
  SimFrame frame;
};

// Adds `clutter` spurious spots uniformly over the image (beam -1) and
// shuffles, so that the order of the spots says nothing about the beams.
void addClutterAndShuffle(int clutter, const CameraModel& cam, std::mt19937& rng, Spots* spots)
{
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (int k = 0; k < clutter; ++k)
  {
    Spot s;
    s.x = uni(rng) * (cam.width - 1);
    s.y = uni(rng) * (cam.height - 1);
    s.beam = -1;
    spots->push_back(s);
  }
  std::shuffle(spots->begin(), spots->end(), rng);
}

SimSpots spotsFromSim(const Simulator& sim, double t, double noise_px, double drop, int clutter, uint32_t seed)
{
  SimSpots out;
  out.frame = sim.render(t);
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const CameraModel& cam = sim.camera();
  for (size_t i = 0; i < out.frame.visible.size(); ++i)
  {
    if (!out.frame.visible[i] || uni(rng) < drop)
      continue;
    Spot s;
    s.x = out.frame.pixels[i].x + noise(rng);
    s.y = out.frame.pixels[i].y + noise(rng);
    s.intensity = 100.0f;
    s.beam = static_cast<int>(i);
    out.spots.push_back(s);
  }
  addClutterAndShuffle(clutter, cam, rng, &out.spots);
  return out;
}

struct Tally
{
  int visible = 0, correct = 0, wrong = 0, points = 0;
  int identifiable = 0, identifiable_right = 0;  // see sls_test::ambiguousDots
  double sum2 = 0.0, sum2_rel = 0.0;
  void add(const SimSpots& s, const TriangulationResult& r, const Triangulator& tri)
  {
    const std::vector<char> amb = sls_test::ambiguousDots(tri, s.spots);
    for (size_t j = 0; j < s.spots.size(); ++j)
    {
      const int truth = s.spots[j].beam, got = r.beam_of_spot[j];
      visible += truth >= 0;
      identifiable += truth >= 0 && !amb[j];
      identifiable_right += truth >= 0 && !amb[j] && got == truth;
      if (got >= 0)
        (got == truth ? correct : wrong) += 1;
      if (got >= 0 && got == truth)
      {
        const double z = s.frame.points[got].z(), e = r.points[got].z() - z;
        sum2 += e * e;
        sum2_rel += e * e / (z * z);
        ++points;
      }
    }
  }
  double rmsMm() const { return std::sqrt(sum2 / std::max(1, points)) * 1e3; }
  double rmsRel() const { return std::sqrt(sum2_rel / std::max(1, points)); }
};

SimulatorParams simConfig(double distance, double roll, double relief, uint32_t seed)
{
  SimulatorParams c;
  c.rock.distance_m = distance;
  c.rock.relief_m = relief;
  c.rock.seed = seed;
  c.projector.roll_rad = roll;
  return c;
}

}  // namespace

// Exact calibration, 0.05 px noise, 10 % of the dots missing, 20 spurious
// spots: depth <= 0.1 % RMS at 1-2 m, no wrong assignment and every
// identifiable visible dot right, for the default rolled grid and an
// axis-aligned one. Visible = the simulator's flag (in view, not occluded),
// not dropped; identifiable = visible and no other spot within the gate of
// its beam's segment and within half a beam pitch of it.
TEST(TriangulatorSim, DepthAndIdentificationOnTheSimulatedRock)
{
  for (double roll : {0.087, 0.0})
  {
    for (double z : {1.0, 1.5, 2.0})
    {
      Tally tally;
      for (uint32_t k = 0; k < 4; ++k)
      {
        const Simulator sim(simConfig(z, roll, 0.15, 1 + k));
        Triangulator tri(sim.camera(), sim.projector());
        const SimSpots s = spotsFromSim(sim, 0.0, 0.05, 0.1, 20, 10 * k + 1);
        tally.add(s, tri.process(s.spots), tri);
      }
      std::cout << "[ MEASURE ] sim rock at " << z << " m, roll " << roll * 180 / M_PI << " deg: depth RMS "
                << tally.rmsMm() << " mm = " << tally.rmsRel() * 100 << " %; " << tally.correct << "/" << tally.visible
                << " dots right (identifiable " << tally.identifiable_right << "/" << tally.identifiable << "), "
                << tally.wrong << " wrong\n";
      EXPECT_LT(tally.rmsRel(), 0.001);
      EXPECT_EQ(tally.wrong, 0);
      EXPECT_EQ(tally.identifiable_right, tally.identifiable);
    }
  }
}

// A 20 cm step in the rock: the dots beyond it jump along their segments
// (and some hide behind the step). Never a wrong beam.
TEST(TriangulatorSim, StepInTheRock)
{
  SimulatorParams c = simConfig(1.4, 0.087, 0.05, 3);
  c.rock.step_height_m = 0.25;
  c.rock.step_x_m = 0.0;
  const Simulator sim(c);
  Triangulator tri(sim.camera(), sim.projector());
  const SimSpots s = spotsFromSim(sim, 0.0, 0.05, 0.0, 10, 5);
  Tally tally;
  tally.add(s, tri.process(s.spots), tri);
  std::cout << "[ MEASURE ] rock with a 25 cm step: " << tally.correct << "/" << tally.visible << " right, "
            << tally.wrong << " wrong, depth RMS " << tally.rmsMm() << " mm\n";
  EXPECT_EQ(tally.wrong, 0);
  EXPECT_GE(tally.correct, 0.95 * tally.visible);
}

// Flat boards (relief 0) at 1.0 and 2.0 m -> fitted rays -> the rock at
// 1.0 / 1.5 / 2.0 m: depth <= 0.2 % RMS.
TEST(TriangulatorSim, CalibrationFromSimulatedBoards)
{
  std::vector<BoardView> views;
  for (double d : {1.0, 2.0})
  {
    const Simulator board(simConfig(d, 0.087, 0.0, 1));
    const SimSpots s = spotsFromSim(board, 0.0, 0.05, 0.0, 0, static_cast<uint32_t>(d * 10));
    BoardView v;
    v.distance_m = d;
    v.spots = s.spots;  // ids known from the simulator
    views.push_back(v);
  }
  const Simulator ref(simConfig(1.5, 0.087, 0.15, 1));
  const BoardCalibrationResult cal = calibrateFromBoards(ref.camera(), views, BoardCalibrationParams());
  ASSERT_TRUE(cal.ok) << cal.error;
  std::cout << "[ MEASURE ] " << cal.report() << "\n";
  EXPECT_EQ(cal.poor_beams, 0);
  for (double z : {1.0, 1.5, 2.0})
  {
    Tally tally;
    for (uint32_t k = 0; k < 3; ++k)
    {
      const Simulator sim(simConfig(z, 0.087, 0.15, 7 + k));
      Triangulator tri(sim.camera(), cal.calibration);
      const SimSpots s = spotsFromSim(sim, 0.0, 0.05, 0.0, 0, 100 + k);
      tally.add(s, tri.process(s.spots), tri);
    }
    std::cout << "[ MEASURE ] fitted calibration, sim rock at " << z << " m: depth RMS " << tally.rmsMm()
              << " mm = " << tally.rmsRel() * 100 << " %; " << tally.correct << "/" << tally.visible << " right, "
              << tally.wrong << " wrong\n";
    EXPECT_LT(tally.rmsRel(), 0.002);
    EXPECT_EQ(tally.wrong, 0);
  }
}

namespace
{

// Ground truth of one frame of a sequence without rendering the image: the
// hit of every beam (camera frame at t) when it is in view and not hidden
// from the camera, as Simulator::render flags it.
struct SeqFrame
{
  Spots spots;                          // spot.beam = true beam, -1 = spurious
  std::vector<Eigen::Vector3d> points;  // per beam, NaN = not visible
};

SeqFrame sequenceFrame(const Simulator& sim, double t, double drop, int clutter,
                       const std::vector<Eigen::Vector3d>& rock_clutter, uint32_t seed)
{
  SeqFrame out;
  const CameraModel& cam = sim.camera();
  const ProjectorCalibration& proj = sim.projector();
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.05);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const Eigen::Isometry3d cam_from_rock = sim.cameraPose(t).inverse();
  const auto seen = [&](const Eigen::Vector3d& x, cv::Point2d* px)
  {
    Eigen::Vector3d h;
    if (!(x.z() > 0.0) || !sim.intersect(t, Eigen::Vector3d::Zero(), x.normalized(), &h) || h.norm() < x.norm() - 5e-4)
      return false;
    *px = cam.project(x);
    return px->x >= 0.0 && px->y >= 0.0 && px->x <= cam.width - 1 && px->y <= cam.height - 1;
  };
  out.points.assign(proj.beamCount(), Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  for (int i = 0; i < proj.beamCount(); ++i)
  {
    Eigen::Vector3d x;
    cv::Point2d px;
    if (!sim.intersect(t, proj.beams[i].origin, proj.beams[i].direction, &x) || !seen(x, &px))
      continue;
    out.points[i] = x;
    if (uni(rng) < drop)
      continue;
    Spot s;
    s.x = px.x + noise(rng);
    s.y = px.y + noise(rng);
    s.intensity = 100.0f;
    s.beam = i;
    out.spots.push_back(s);
  }
  // Green specks fixed on the rock, and spots that come and go.
  for (const Eigen::Vector3d& xr : rock_clutter)
  {
    cv::Point2d px;
    if (!seen(cam_from_rock * xr, &px))
      continue;
    Spot s;
    s.x = px.x;
    s.y = px.y;
    s.beam = -1;
    out.spots.push_back(s);
  }
  addClutterAndShuffle(clutter, cam, rng, &out.spots);
  return out;
}

}  // namespace

// Sequences at 15 Hz with the rig jittering (+-10 mm, +-1 deg per axis):
// 10 % of the dots dropped at random in every frame, 10 spurious spots that
// come and go plus 10 fixed on the rock, for the rolled and the axis-aligned
// grid, and for the axis-aligned grid with the right half of the rock 0.4 m
// nearer (an object in front). Each frame is identified alone and with the
// previous frame's result as the tracking prior: with the prior, no wrong
// assignment.
TEST(TriangulatorSim, SequenceWithTrackingPrior)
{
  struct Case
  {
    const char* name;
    double roll, step;
  };
  for (const Case& cs : {Case{"rolled grid", 0.087, 0.0}, Case{"aligned grid", 0.0, 0.0},
                         Case{"aligned grid, object 0.4 m in front", 0.0, -0.4}})
  {
    SimulatorParams c = simConfig(1.5, cs.roll, 0.15, 7);
    c.rock.step_height_m = cs.step;
    c.rock.step_x_m = 0.05;
    c.motion.jitter_translation_m = 0.01;
    c.motion.jitter_rotation_rad = 0.0175;
    const Simulator sim(c);
    const TriangulatorParams topt;
    const Triangulator tri(sim.camera(), sim.projector(), topt);
    std::mt19937 rng(99);
    std::uniform_real_distribution<double> uni(-0.5, 0.5);
    std::vector<Eigen::Vector3d> rock_clutter;
    const Eigen::Isometry3d rock_from_cam0 = sim.cameraPose(0.0);
    while (rock_clutter.size() < 10)
    {
      Eigen::Vector3d h;
      const double dy = 0.75 * uni(rng);  // sequenced draws: argument order is unspecified (docs/testing.md)
      const double dx = uni(rng);
      if (sim.intersect(0.0, Eigen::Vector3d::Zero(), Eigen::Vector3d(dx, dy, 1.0).normalized(), &h))
        rock_clutter.push_back(rock_from_cam0 * h);
    }
    const int frames = 300;
    Tally alone, tracked;
    int frames_with_prior = 0, tracked_beams = 0;
    int wrong_alone = 0, wrong_tracked = 0, look_alike_alone = 0, look_alike_tracked = 0;
    TriangulationResult previous;
    bool have_previous = false;
    for (int k = 0; k < frames; ++k)
    {
      const SeqFrame f = sequenceFrame(sim, k / 15.0, 0.1, 10, rock_clutter, 500 + k);
      SimSpots s;
      s.spots = f.spots;
      s.frame.points = f.points;
      const TriangulationResult r0 = tri.process(f.spots);
      const TriangulationResult r1 = tri.process(f.spots, have_previous ? &previous : nullptr);
      // A spurious spot within the tracking radius of where a missing dot
      // would be is that dot's look-alike: no method can tell them apart.
      std::vector<char> present(f.points.size(), 0);
      for (const Spot& sp : f.spots)
        if (sp.beam >= 0)
          present[sp.beam] = 1;
      for (size_t j = 0; j < f.spots.size(); ++j)
      {
        const int got0 = r0.beam_of_spot[j], got1 = r1.beam_of_spot[j];
        for (int got : {got0, got1})
        {
          if (got < 0 || got == f.spots[j].beam)
            continue;
          const cv::Point2d t = sim.camera().project(f.points[got]);
          const bool look_alike = f.spots[j].beam < 0 && !present[got] && f.points[got].allFinite() &&
                                  std::hypot(t.x - f.spots[j].x, t.y - f.spots[j].y) <= topt.tracking_radius_px;
          (look_alike ? (got == got1 ? look_alike_tracked : look_alike_alone)
                      : (got == got1 ? wrong_tracked : wrong_alone)) += 1;
          if (got0 == got1)
          {
            (look_alike ? look_alike_alone : wrong_alone) += 1;
            break;
          }
        }
      }
      alone.add(s, r0, tri);
      tracked.add(s, r1, tri);
      frames_with_prior += r1.tracked >= 0;
      tracked_beams += std::max(0, r1.tracked);
      previous = r1;
      have_previous = true;
    }
    std::cout << "[ MEASURE ] sequence, " << cs.name << ", " << frames << " frames: single-frame " << alone.correct
              << "/" << alone.visible << " right, " << wrong_alone << " wrong + " << look_alike_alone
              << " look-alikes taken; with the tracking prior " << tracked.correct << "/" << tracked.visible
              << " right, " << wrong_tracked << " wrong + " << look_alike_tracked
              << " look-alikes taken (prior used in " << frames_with_prior << " frames, "
              << tracked_beams / std::max(1, frames_with_prior) << " beams/frame settled by it), depth RMS "
              << tracked.rmsRel() * 100 << " %\n";
    EXPECT_EQ(wrong_tracked, 0) << cs.name;
    EXPECT_EQ(tracked.wrong, wrong_tracked + look_alike_tracked) << cs.name;
    // The prior is dropped in the frames where it and the single frame
    // disagree on many spots (the object's dots read shifted by the single
    // frame): 13 of 300 with the object.
    EXPECT_GE(frames_with_prior, frames * 9 / 10) << cs.name;
    EXPECT_GE(tracked.correct, alone.correct) << cs.name;
  }
}
