// the acceptance for the recommended daylight rig (config/rig_daylight.yaml,
// docs/daylight.md "Measured"): the core pipeline (SpotDetector's strobed
// mode on the compensated ambient, Triangulator, PoseDelta) on the
// simulator with corrected radiometry under the study's brightest sun, the
// rig's 12-bit camera, albedo 0.05-0.45 with the 2 cm grain, 0.15 m relief,
// wind jitter, at 1.0, 1.5 and 2.0 m; against the simulator's truth. Rock
// seeds 11 and 12: held out (nothing was tuned on them; the docs' figures
// are seeds 7-10).
#include <cmath>
#include <iostream>

#include <gtest/gtest.h>

#include "support/daylight_run.h"

using namespace structured_light_stabilizer;
using test::daylight::Options;
using test::daylight::runCase;
using test::daylight::Stats;

namespace
{

Options rigOptions()
{
  Options o;
  o.rig = std::string(SLS_TEST_DATA_DIR) + "/../../config/rig_daylight.yaml";
  o.output = "bgr16";  // the rig's camera as designed: 12 bits
  o.output_bits = 12;
  o.frames = 15;  // dot frames per case (the first is the pose reference)
  return o;
}

}  // namespace

TEST(DaylightRig, RecommendedRigMeetsTheIssueBoundsOverOneToTwoMetres)
{
  const Options o = rigOptions();
  Stats all;
  for (double distance : {1.0, 1.5, 2.0})
  {
    Stats at;
    for (uint32_t seed : {11u, 12u})
      at.add(runCase(o, distance, seed));
    std::cout << "[ MEASURE ] " << distance << " m: " << at.line() << "\n";
    // Every distance alone: recall, wrong beams and pose.
    EXPECT_GE(at.spots.recall(), 0.995) << distance << " m";
    EXPECT_GE(at.worst_frame_recall, 0.98) << distance << " m";
    EXPECT_EQ(at.wrong_beams, 0) << distance << " m";
    EXPECT_LE(std::sqrt(at.t2 / at.poses), 0.5) << distance << " m";
    EXPECT_LE(std::sqrt(at.r2 / at.poses), 0.02) << distance << " m";
    EXPECT_GE(at.valid, 0.95 * at.poses) << distance << " m";
    // The centroid, pooled and in every frame: 0.05 px at 1.0 and 1.5 m; at
    // 2.0 m the beam's 3 mm footprint on the rock's relief alone leaves
    // 0.038-0.042 px (noise-free, the next test), and the measured 0.044-0.056
    // px (seeds 7-12; frames up to 0.056) is bounded at 0.065.
    const double bound = distance < 1.9 ? 0.05 : 0.065;
    EXPECT_LE(at.spots.rms(), bound) << distance << " m";
    EXPECT_LE(at.worst_frame_rms, bound) << distance << " m";
    all.add(at);
  }
  std::cout << "[ MEASURE ] 1.0-2.0 m: " << all.line() << "\n";
  // The issue's bounds over its range 1.0-2.0 m.
  EXPECT_GE(all.spots.recall(), 0.995);
  EXPECT_LE(all.spots.rms(), 0.05);
  EXPECT_LE(std::sqrt(all.t2 / all.poses), 0.5);
  EXPECT_LE(std::sqrt(all.r2 / all.poses), 0.02);
  EXPECT_GE(all.valid, 0.95 * all.poses);
}

TEST(DaylightRig, CentroidFloorIsTheReliefUnderTheFootprint)
{
  // What holds 2.0 m above 0.05 px: with no sensor noise, the projector-off
  // frame of the on-frame's own instant and no fine grain, a flat rock gives
  // the hit point (measured 0.003-0.004 px) and the 0.15 m relief 0.038-0.042
  // px (seeds 11 and 7-8): each
  // pixel of the footprint gets the beam at its own surface point and facet.
  Options o = rigOptions();
  o.noise_free = true;
  o.true_ambient = true;
  o.texture_period = 0.0;
  o.frames = 8;
  o.relief = 0.0;
  const Stats flat = runCase(o, 2.0, 11);
  o.relief = 0.15;
  const Stats relief = runCase(o, 2.0, 11);
  std::cout << "[ MEASURE ] 2.0 m noise-free, flat: " << flat.line() << "\n";
  std::cout << "[ MEASURE ] 2.0 m noise-free, 0.15 m relief: " << relief.line() << "\n";
  EXPECT_LE(flat.spots.rms(), 0.01);
  EXPECT_GE(relief.spots.rms(), 0.03);
  EXPECT_LE(relief.spots.rms(), 0.06);
}

TEST(DaylightRig, OneColourFrameByDayTakesTheAlbedoFromBothOtherChannels)
{
  // No strobe: the albedo under each dot from the colour frame's red and
  // blue (docs/spot_detector.md, "Hue"). The simulator's historical bgr8
  // camera, a dot/sun ratio of 8 (the lowest at which one frame found every
  // dot, docs/daylight.md), 2 cm grain of its own hue, 0.15 m relief, 1.0-2.0
  // m; seeds 11 and 12 (the rock model's F threshold was chosen on
  // test_spot_detector_sim's fine-texture scenes). Measured 0.069 px pooled,
  // worst frame 0.080 px; 0.101 px and 0.116 px with red alone.
  Options o;
  o.output = "bgr8";
  o.strobe = false;
  o.ratio = 8.0;
  o.frames = 15;
  Stats all;
  for (double distance : {1.0, 1.5, 2.0})
    for (uint32_t seed : {11u, 12u})
      all.add(runCase(o, distance, seed));
  std::cout << "[ MEASURE ] one colour frame by day, 1.0-2.0 m: " << all.line() << "\n";
  EXPECT_GE(all.spots.recall(), 0.995);
  EXPECT_GE(all.worst_frame_recall, 0.98);
  EXPECT_EQ(all.wrong_beams, 0);
  EXPECT_LE(all.spots.rms(), 0.08);
  EXPECT_LE(all.worst_frame_rms, 0.095);
}
