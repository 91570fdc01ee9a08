// Triangulator and board calibration on the simulator's ground truth: the
// true (distorted) pixel of every visible beam hit, plus centroid noise,
// missing dots and spurious spots, triangulated with Simulator::projector()
// (exact) or with a calibration fitted from simulated flat boards.
#include <cmath>
#include <iostream>
#include <random>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/projector_calibrator.h"
#include "structured_light_stabilizer/simulator.h"
#include "structured_light_stabilizer/triangulator.h"
#include "triangulator_scene.h"

using namespace structured_light_stabilizer;

namespace
{

struct SimSpots
{
  Spots spots;  // spot.beam = true beam, -1 = spurious
  SimFrame frame;
};

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
  for (int k = 0; k < clutter; ++k)
  {
    Spot s;
    s.x = uni(rng) * (cam.width - 1);
    s.y = uni(rng) * (cam.height - 1);
    s.beam = -1;
    out.spots.push_back(s);
  }
  std::shuffle(out.spots.begin(), out.spots.end(), rng);
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

SimulatorConfig simConfig(double distance, double roll, double relief, uint32_t seed)
{
  SimulatorConfig c;
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
  SimulatorConfig c = simConfig(1.4, 0.087, 0.05, 3);
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
  const BoardCalibrationResult cal = calibrateFromBoards(ref.camera(), views, BoardCalibrationOptions());
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
    std::cout << "[ MEASURE ] fitted calibration, sim rock at " << z << " m: depth RMS " << tally.rmsMm() << " mm = "
              << tally.rmsRel() * 100 << " %; " << tally.correct << "/" << tally.visible << " right, " << tally.wrong
              << " wrong\n";
    EXPECT_LT(tally.rmsRel(), 0.002);
    EXPECT_EQ(tally.wrong, 0);
  }
}
