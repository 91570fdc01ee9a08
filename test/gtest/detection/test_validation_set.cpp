// The package judged on the held-out half of the path-traced validation set
// (test/data/validation/README.md: scenes *_b; the *_a scenes are the tuning
// half and are not read here): rendered with Blender's Cycles, independent of
// the simulator, with the light's own centroid and the hit point as truth.
// The bounds are today's, per frame, with the detector's defaults (noise
// seeds 1 and 2, bgr8), a little below the figures measured (in the comment
// above each test): they keep what holds from slipping. The goals the detection
// work aims at (recall >= 99 % per frame in every lighting, 0 wrong beams,
// centroids within 0.05 px of the light and 0.2 px of the hit point) are
// not met by day in single frames nor for the centroids anywhere;
// tools/evaluate_validation prints every figure (docs/validation.md).

#include <gtest/gtest.h>

#include "support/validation_run.h"

using namespace structured_light_stabilizer;
using namespace structured_light_stabilizer::test::validation;

namespace
{

const std::string kData = std::string(SLS_TEST_DATA_DIR) + "/validation";
const std::string kProjector = std::string(SLS_TEST_DATA_DIR) + "/../../config/projector_sim.yaml";

const ValidationSet& validationSet()
{
  static const ValidationSet set = loadValidationSet(kData);
  return set;
}

RunOptions options()
{
  RunOptions o;
  o.seeds = {1, 2};
  o.projector_file = kProjector;
  return o;
}

struct Bounds
{
  double min_recall;        // per frame
  int max_wrong;            // wrong beams per frame
  double max_light_rms;     // px, per frame, to the light's own centroid
  double max_hit_rms;       // px, per frame, to the hit point's pixel
  double min_valid;         // share of the poses valid, pooled (0: not asserted)
  int max_false = 1 << 30;  // false spots per frame (not on a dot, occluded or not)
};

// Runs every held-out rock case of one lighting, strobe setting and dot
// selection, asserts the bounds per frame (no frame refused), returns the
// pooled tally.
Tally heldOutRock(const std::string& lighting, bool strobe, double min_dot_to_sun, const Bounds& b)
{
  Tally all;
  int cases = 0;
  for (const CaseSpec& c : validationSet().cases)
  {
    if (c.half != "heldout" || c.lighting != lighting || c.strobe != strobe || c.min_dot_to_sun != min_dot_to_sun ||
        validationSet().scene(c.scene).kind != "rock")
      continue;
    ++cases;
    const CaseResult r = runCase(validationSet(), c, options(), false);
    std::cout << "[ MEASURE ] " << c.name << ": " << r.pooled.line() << "\n";
    for (const FrameScore& f : r.frames)
    {
      const Tally& t = f.tally;
      const std::string where = c.name + " frame " + std::to_string(f.frame) + " seed " + std::to_string(f.seed);
      EXPECT_EQ(t.refused, 0) << where << ": " << t.line();
      EXPECT_GE(t.recall(), b.min_recall) << where << ": " << t.line();
      EXPECT_LE(t.wrong, b.max_wrong) << where << ": " << t.line();
      EXPECT_LE(t.false_spots, b.max_false) << where << ": " << t.line();
      EXPECT_LE(t.lightRms(), b.max_light_rms) << where << ": " << t.line();
      EXPECT_LE(t.hitRms(), b.max_hit_rms) << where << ": " << t.line();
    }
    all.add(r.pooled);
  }
  EXPECT_GT(cases, 0) << "no held-out rock case lit by " << lighting;
  if (b.min_valid > 0)
  {
    EXPECT_GE(all.valid, b.min_valid * all.poses) << lighting << (strobe ? " strobed" : "") << ": " << all.line();
  }
  return all;
}

}  // namespace

// The truth is what it says: every pass loads at the scene's size, visible
// dots have their light, each light centroid lies near its hit point (within
// the dot) and, on the rocks, on average on it (a slip of the pixel
// convention between Blender and OpenCV would show as a mean offset),
// projector frames see most dots.
TEST(ValidationSet, TruthIsConsistent)
{
  const ValidationSet& set = validationSet();
  ASSERT_FALSE(set.cases.empty());
  for (const auto& kv : set.scenes)
  {
    const SceneTruth& s = kv.second;
    for (const FrameTruth& f : s.frames)
    {
      const Passes p = loadPasses(s, f);
      EXPECT_EQ(p.proj.empty(), !f.projector) << s.name << " frame " << f.index;
      int visible = 0;
      double d2 = 0;
      cv::Point2d mean(0, 0);
      for (const BeamTruth& b : f.beams)
        if (b.visible && b.has_light && !b.window_cut)
        {
          ++visible;
          d2 += std::pow(b.light_centroid.x - b.pixel.x, 2) + std::pow(b.light_centroid.y - b.pixel.y, 2);
          mean += b.light_centroid - b.pixel;
          EXPECT_LT(std::hypot(b.light_centroid.x - b.pixel.x, b.light_centroid.y - b.pixel.y), 2.0)
              << s.name << " frame " << f.index << " beam " << b.beam;
        }
      if (f.projector)
      {
        EXPECT_GE(visible, 80) << s.name << " frame " << f.index;
        mean /= std::max(visible, 1);
        if (s.kind == "rock")  // on a print, the squares' edges pull each dot's light towards the white
        {
          EXPECT_LT(std::hypot(mean.x, mean.y), 0.03) << s.name << " frame " << f.index << ": mean offset " << mean;
        }
        std::cout << "[ MEASURE ] " << s.name << " frame " << f.index << ": " << visible
                  << " visible dots, light centroid to hit point " << std::sqrt(d2 / std::max(visible, 1))
                  << " px RMS\n";
      }
    }
  }
}

// Dusk (dots 8 x the rock): measured recall >= 0.990 per frame, 1 wrong
// beam in 598, 0.239 / 0.186 px worst frame.
TEST(ValidationSet, HeldOutRockAtDusk)
{
  heldOutRock("dusk", false, 0.0, {0.98, 1, 0.30, 0.25, 0.0});
}

// By day in single frames, the dots at least 0.5 x the sunlit rock: the
// frame is not refused and no beam is wrong, but recall is 0.26-0.51 per
// frame (the dots on the sunlit facets are missed). The grey rock scores
// above the fixed greenness over 30 % of each frame, which is therefore
// scored against the rock's local colour: 1 false spot in 6 frames (5 per
// frame with the fixed greenness).
TEST(ValidationSet, HeldOutRockByDaySingleFrame)
{
  heldOutRock("day", false, 0.5, {0.2, 0, 0.55, 0.55, 0.0, 2});
}

// By day, strobed (projector-off frames around each, motion-compensated):
// measured recall >= 0.970 per frame, at most 1 wrong beam per frame,
// 0.366 / 0.322 px worst frame, 4 of 4 poses valid.
TEST(ValidationSet, HeldOutRockByDayStrobed)
{
  heldOutRock("day", true, 0.0, {0.96, 1, 0.42, 0.38, 0.95});
}

// Night: measured recall >= 0.990 per frame, 1 wrong beam in 100 in two
// frames, 0.216 / 0.196 px worst frame.
TEST(ValidationSet, HeldOutRockAtNight)
{
  heldOutRock("night", false, 0.0, {0.98, 1, 0.26, 0.24, 0.0});
}
