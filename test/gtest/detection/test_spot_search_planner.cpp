// Detection in windows around the tracked dots (SpotSearchPlanner +
// SpotDetector::detectIn) against the truth of the simulator and
// against a full search of the same frames: the same dots found, the same
// centroid error, on sequences not used for choosing the planner's defaults
// (those were chosen on the benchmark's scene, rock seed 1100; here rock
// seeds 3100-3102, a mono8 NIR sequence on 3300, a strobed bgr8 sequence on
// 3400 and a Bayer frame on 3200).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/detection/spot_search_planner.h"
#include "support/spot_score.h"

using namespace structured_light_stabilizer;
using structured_light_stabilizer::test::Score;

namespace
{
std::vector<cv::Point2d> truthOf(const SimFrame& f)
{
  std::vector<cv::Point2d> truth;
  for (size_t b = 0; b < f.visible.size(); ++b)
    if (f.visible[b])
      truth.push_back(f.pixels[b]);
  return truth;
}

SimulatorParams sequenceScene(int seed, const char* output = "bgr8")
{
  SimulatorParams cfg = studySimulatorParams();
  sensorOutputFromEncoding(output, &cfg.sensor.output);
  cfg.lighting.sun_level = 0.5;
  cfg.clutter.green_specks = 20;
  cfg.clutter.olive_minerals = 20;
  cfg.rock.seed = seed;
  cfg.motion.jitter_translation_m = 0.002;
  return cfg;
}

double pixelsOf(const std::vector<cv::Rect>& regions)
{
  double n = 0;
  for (const cv::Rect& r : regions)
    n += r.area();
  return n;
}
}  // namespace

TEST(SpotSearchRegions, ClippedEvenAndMergedOnlyWhenCheap)
{
  const cv::Size frame(100, 80);
  // Clipped to the frame, widened to multiples of 8 px (or the frame's edge).
  std::vector<cv::Rect> out = mergeSearchRegions({cv::Rect(-5, 3, 20, 10)}, frame);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0], cv::Rect(0, 0, 16, 16));
  out = mergeSearchRegions({cv::Rect(95, 75, 20, 20)}, frame);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0], cv::Rect(88, 72, 12, 8));
  // Two nearly identical boxes become one; two far apart stay two; a box
  // outside the frame vanishes.
  out = mergeSearchRegions(
      {cv::Rect(10, 10, 20, 20), cv::Rect(12, 12, 20, 20), cv::Rect(60, 40, 10, 10), cv::Rect(200, 200, 5, 5)}, frame);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_EQ(out[0], cv::Rect(8, 8, 24, 24));
  EXPECT_EQ(out[1], cv::Rect(56, 40, 16, 16));
  // Diagonal neighbours: one box would waste half its pixels.
  out = mergeSearchRegions({cv::Rect(0, 0, 20, 20), cv::Rect(16, 16, 20, 20)}, frame);
  EXPECT_EQ(out.size(), 2u);
}

// The merging's definition, written the slow way: the first pair (in the
// list's order) whose bounding box wastes at most a quarter of the pixels the
// two cover is merged, and the search starts over, until no pair is left.
// mergeSearchRegions must give the same boxes (it does not start over).
std::vector<cv::Rect> mergeByDefinition(std::vector<cv::Rect> in, const cv::Size& frame)
{
  std::vector<cv::Rect> out;
  for (const cv::Rect& r : in)
  {
    const int x0 = std::max(0, r.x) / 8 * 8, y0 = std::max(0, r.y) / 8 * 8;
    const int x1 = std::min(frame.width, (r.x + r.width + 7) / 8 * 8);
    const int y1 = std::min(frame.height, (r.y + r.height + 7) / 8 * 8);
    if (x1 > x0 && y1 > y0)
      out.emplace_back(x0, y0, x1 - x0, y1 - y0);
  }
  const auto worth = [](const cv::Rect& a, const cv::Rect& b)
  { return (a | b).area() <= 1.25 * (double(a.area()) + b.area() - (a & b).area()); };
  for (bool merged = true; merged;)
  {
    merged = false;
    for (size_t i = 0; i < out.size() && !merged; ++i)
      for (size_t j = i + 1; j < out.size() && !merged; ++j)
        if ((merged = worth(out[i], out[j])))
        {
          out[i] |= out[j];
          out.erase(out.begin() + static_cast<std::ptrdiff_t>(j));
        }
  }
  std::sort(out.begin(), out.end(),
            [](const cv::Rect& a, const cv::Rect& b) { return a.y != b.y ? a.y < b.y : a.x < b.x; });
  return out;
}

TEST(SpotSearchRegions, MergedAsByTheDefinition)
{
  // Random windows of dots and bands (chains of overlapping boxes, boxes
  // inside bands, boxes off the frame), 2000 sets: the same boxes.
  const cv::Size frame(640, 480);
  cv::RNG rng(20261204);
  int merges = 0;
  for (int trial = 0; trial < 2000; ++trial)
  {
    std::vector<cv::Rect> in;
    const int n = rng.uniform(1, 60);
    for (int k = 0; k < n; ++k)
    {
      if (rng.uniform(0, 20) == 0)
      {
        const int bh = rng.uniform(10, 120), by = rng.uniform(-40, 480);  // sequenced draws (docs/testing.md)
        in.emplace_back(0, by, 640, bh);  // a band
      }
      else
      {
        const int h = rng.uniform(4, 40);
        // Sequenced draws (docs/testing.md).
        const int height = rng.uniform(std::max(4, h - 8), h + 8), y = rng.uniform(-30, 500),
                  x = rng.uniform(-30, 650);
        in.emplace_back(x, y, h, height);
      }
    }
    const std::vector<cv::Rect> expected = mergeByDefinition(in, frame);
    ASSERT_EQ(mergeSearchRegions(in, frame), expected) << "trial " << trial;
    merges += static_cast<int>(in.size() - expected.size());
  }
  EXPECT_GT(merges, 2000);  // the sets did exercise the merging
}

TEST(SpotSearchRegions, ParametersOutOfRangeAreReplacedWithAWarning)
{
  SpotSearchParams p;
  EXPECT_TRUE(p.validate().empty());
  p.track_margin_px = NAN;
  p.track_band_rows = -3;
  p.full_search_every = -1;
  EXPECT_FALSE(p.validate().empty());
  SpotSearchPlanner planner;
  EXPECT_EQ(planner.setParams(p).size(), 3u);
  EXPECT_EQ(planner.params().track_margin_px, 8.0);
  EXPECT_EQ(planner.params().track_band_rows, 0);
  EXPECT_EQ(planner.params().full_search_every, 0);
}

// A dot cut by a region's inner edge is left out; inside a region searched
// afresh it comes out where the full search puts it, and refined from where
// the last frame had it (FastParams::tracked_seeds) within 0.02 px of that
// (measured 0.011 px: the background's ring is the border of the first
// window filled, which depends on where the refinement starts).
TEST(SpotSearchRegions, DotCutByARegionEdgeIsLeftOut)
{
  const SimFrame f = Simulator(sequenceScene(3100)).render(0.0);
  SpotDetector det;
  const SpotDetectionResult full = det.detect(f.image, PixelFormat::kBgr8);
  ASSERT_TRUE(full.ok);
  ASSERT_GT(full.spots.size(), 50u);
  const Spot& s = full.spots[full.spots.size() / 2];
  const int x = static_cast<int>(s.x), y = static_cast<int>(s.y);
  const auto nearest = [&](const Spots& spots)
  {
    double d = 1e9;
    for (const Spot& t : spots)
      d = std::min(d, std::hypot(t.x - s.x, t.y - s.y));
    return d;
  };
  // Whole, in a region of a detector with no last frame: searched, the same centroid.
  SpotDetector fresh;
  SpotDetectionResult in = fresh.detectIn(f.image, cv::Mat(), PixelFormat::kBgr8, {cv::Rect(x - 20, y - 20, 40, 40)});
  ASSERT_TRUE(in.ok);
  EXPECT_LT(nearest(in.spots), 1e-6) << "dot at " << s.x << ", " << s.y << " not found at the same place in its window";
  // The same region after the full search: the dot refined from its last position.
  in = det.detectIn(f.image, cv::Mat(), PixelFormat::kBgr8, {cv::Rect(x - 20, y - 20, 40, 40)});
  ASSERT_TRUE(in.ok);
  EXPECT_LT(nearest(in.spots), 0.02) << "dot at " << s.x << ", " << s.y << " moved when refined from there";
  // The region ends one pixel right of the centroid: cut.
  in = det.detectIn(f.image, cv::Mat(), PixelFormat::kBgr8, {cv::Rect(x - 30, y - 20, 32, 40)});
  ASSERT_TRUE(in.ok);
  for (const Spot& t : in.spots)
    EXPECT_GT(std::hypot(t.x - s.x, t.y - s.y), 2.0) << "a cut dot was reported";
}

// The same dots, a centroid error no worse than a full search's on every frame,
// with a fraction of the pixels searched: bgr8 by day; mono8 with a NIR
// projector by day with its projector-off frame (strobed), found by intensity
// over block-wise local backgrounds; bgr8 strobed with dim dots (0.3 x the
// study's brightness), whose matched filter thresholds against the noise of
// the last whole frame (renewed by a full search every 30 frames).
TEST(SpotSearchPlanner, TrackedDetectionMatchesFullSearchAgainstTruth)
{
  for (int seed : {3100, 3101, 3102, 3300, 3400})
  {
    const bool mono = seed == 3300, strobed = mono || seed == 3400;
    SimulatorParams cfg = sequenceScene(seed, mono ? "mono8" : "bgr8");
    if (mono)
    {
      cfg.projector.color = ProjectorColor::kNir;
      cfg.projector.wavelength_nm = nominalWavelengthNm(ProjectorColor::kNir);
    }
    if (seed == 3400)
      cfg.lighting.dot_to_sun_ratio *= 0.3;
    const PixelFormat format = mono ? PixelFormat::kMono8 : PixelFormat::kBgr8;
    const Simulator sim(cfg);
    SpotDetectorParams p;
    p.projector_color = cfg.projector.color;
    SpotDetector full(p), tracked(p);
    SpotSearchPlanner planner;
    Score pooled_full, pooled_tracked;
    double tracked_pixels = 0;
    int tracked_frames = 0, seeded = 0, tracked_spots = 0;
    for (int i = 0; i < 40; ++i)
    {
      const SimFrame f = sim.render(i / 30.0);
      FrameRequest off;
      off.projector_on = false;
      const cv::Mat ambient = strobed ? sim.render(i / 30.0, off).image : cv::Mat();
      const std::vector<cv::Point2d> truth = truthOf(f);
      const SpotDetectionResult a = full.detect(f.image, ambient, format);
      std::string why;
      if (!tracked.hasRegionStatistics(!ambient.empty(), format, f.image.size(), &why))
        planner.requestFullSearch(why);
      const std::vector<cv::Rect> regions = planner.plan(f.image.size());
      SpotDetectorDebug debug;
      const SpotDetectionResult b = tracked.detectIn(f.image, ambient, format, regions, &debug);
      planner.update(b);
      ASSERT_TRUE(a.ok && b.ok);
      const Score sa = test::score(a.spots, truth, 2.0), sb = test::score(b.spots, truth, 2.0);
      // Per frame: every dot the full search finds, and no more false spots.
      EXPECT_GE(sb.matched, sa.matched) << "seed " << seed << " frame " << i;
      EXPECT_LE(sb.false_spots, sa.false_spots + 1) << "seed " << seed << " frame " << i;
      // No worse centroids (refined from the last frame's dots, tracking can
      // do better: it starts from a window centred on the dot).
      EXPECT_LE(sb.rms(), sa.rms() + 0.01) << "seed " << seed << " frame " << i;
      pooled_full.add(sa);
      pooled_tracked.add(sb);
      if (!regions.empty())
      {
        tracked_pixels += pixelsOf(regions) / f.image.total();
        ++tracked_frames;
        seeded += debug.seeded;
        tracked_spots += static_cast<int>(b.spots.size());
      }
    }
    std::printf(
        "[ MEASURE ] %s seed %d: full search recall %.4f RMS %.4f px; tracked recall %.4f RMS %.4f px; %ld full "
        "searches in 40 frames; %.1f %% of the pixels searched when tracking, %.1f %% of the tracked dots seeded\n",
        mono      ? "mono8 NIR strobed"
        : strobed ? "bgr8 strobed"
                  : "bgr8",
        seed, pooled_full.recall(), pooled_full.rms(), pooled_tracked.recall(), pooled_tracked.rms(),
        planner.fullSearches(), 100.0 * tracked_pixels / std::max(1, tracked_frames),
        100.0 * seeded / std::max(1, tracked_spots));
    // Colour frames without an ambient frame refine most tracked dots from
    // their last positions (the others lie in the swept band, or in a
    // region that needed a search); the rest search every region.
    if (!strobed)
      EXPECT_GT(seeded, tracked_spots / 2) << "seed " << seed;
    else
      EXPECT_EQ(seeded, 0) << "seed " << seed;
    // bgr8 strobed: the start and the noise statistics renewed after 30 frames.
    EXPECT_EQ(planner.fullSearches(), seed == 3400 ? 2 : 1) << "seed " << seed << ": " << planner.lastFullReason();
    EXPECT_LE(pooled_tracked.rms(), pooled_full.rms() + 0.003);
    EXPECT_GE(pooled_tracked.recall(), pooled_full.recall());
    EXPECT_LT(tracked_pixels / tracked_frames, 0.35);
  }
}

// A jump larger than the margin (the image shifted by half the dot spacing
// along both axes: the arm jerked) loses the dots for one frame; the next is
// a full search and finds them all.
TEST(SpotSearchPlanner, LossTriggersAFullSearch)
{
  const Simulator sim(sequenceScene(3101));
  SpotDetector full, tracked;
  SpotSearchPlanner planner;
  for (int i = 0; i < 3; ++i)
  {
    const SimFrame f = sim.render(i / 30.0);
    planner.update(tracked.detectIn(f.image, cv::Mat(), PixelFormat::kBgr8, planner.plan(f.image.size())));
  }
  ASSERT_EQ(planner.fullSearches(), 1);
  const SimFrame f = sim.render(3 / 30.0);
  const SpotDetectionResult before = full.detect(f.image, PixelFormat::kBgr8);
  std::vector<double> spacing;
  for (const Spot& a : before.spots)
  {
    double d = 1e9;
    for (const Spot& b : before.spots)
      if (&a != &b)
        d = std::min(d, std::hypot(a.x - b.x, a.y - b.y));
    spacing.push_back(d);
  }
  std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
  const double half = 0.5 * spacing[spacing.size() / 2];
  std::printf("[ MEASURE ] dot spacing %.1f px: image shifted by %.1f px along both axes\n", 2 * half, half);
  cv::Mat shifted;
  const cv::Matx23d m(1, 0, half, 0, 1, half);
  cv::warpAffine(f.image, shifted, m, f.image.size(), cv::INTER_NEAREST, cv::BORDER_REPLICATE);
  const SpotDetectionResult lost =
      tracked.detectIn(shifted, cv::Mat(), PixelFormat::kBgr8, planner.plan(shifted.size()));
  planner.update(lost);
  EXPECT_EQ(planner.fullSearches(), 1);
  const std::vector<cv::Rect> next = planner.plan(shifted.size());
  EXPECT_TRUE(next.empty()) << "no full search after the jump (" << planner.lastFullReason() << ")";
  EXPECT_EQ(planner.fullSearches(), 2);
  const SpotDetectionResult again = tracked.detectIn(shifted, cv::Mat(), PixelFormat::kBgr8, next);
  const SpotDetectionResult reference = full.detect(shifted, PixelFormat::kBgr8);
  EXPECT_EQ(again.spots.size(), reference.spots.size());
}

// Dots that come into view (an occluder over the lower half leaves) are found
// by the band swept down the frame within one sweep, without a full search.
TEST(SpotSearchPlanner, DotsComingIntoViewAreFoundByTheSweep)
{
  const Simulator sim(sequenceScene(3102));
  SpotDetector tracked;
  SpotSearchPlanner planner;
  const SimFrame first = sim.render(0.0);
  cv::Mat occluded = first.image.clone();
  occluded.rowRange(first.image.rows / 2, first.image.rows).setTo(cv::Scalar(20, 20, 20));
  planner.update(tracked.detectIn(occluded, cv::Mat(), PixelFormat::kBgr8, planner.plan(occluded.size())));
  const std::vector<cv::Point2d> lower = [&]
  {
    std::vector<cv::Point2d> t;
    for (const cv::Point2d& p : truthOf(first))
      if (p.y > first.image.rows / 2 + 10)
        t.push_back(p);
    return t;
  }();
  ASSERT_GT(lower.size(), 30u);
  const int sweep = (first.image.rows + planner.params().track_band_rows - 1) / planner.params().track_band_rows;
  Score last;
  for (int i = 1; i <= sweep + 1; ++i)
  {
    const SimFrame f = sim.render(i / 30.0);
    const SpotDetectionResult r =
        tracked.detectIn(f.image, cv::Mat(), PixelFormat::kBgr8, planner.plan(f.image.size()));
    planner.update(r);
    std::vector<cv::Point2d> now;
    for (const cv::Point2d& p : truthOf(f))
      if (p.y > f.image.rows / 2 + 10)
        now.push_back(p);
    last = test::score(r.spots, now, 2.0);
  }
  EXPECT_EQ(planner.fullSearches(), 1) << planner.lastFullReason();
  EXPECT_EQ(last.matched, last.truth) << "of the dots that came into view, after one sweep of " << sweep << " frames";
}

// Regions at odd coordinates on a Bayer frame: widened to even ones, the
// colour sites stay where they were; the spots are those of a full search.
TEST(SpotSearchRegions, BayerRegionsKeepThePattern)
{
  const SimFrame f = Simulator(sequenceScene(3200, "bayer_rggb8")).render(0.0);
  SpotDetector det;
  const SpotDetectionResult full = det.detect(f.image, PixelFormat::kBayerRggb8);
  ASSERT_TRUE(full.ok);
  ASSERT_GT(full.spots.size(), 50u);
  std::vector<cv::Rect> regions;
  for (const Spot& s : full.spots)
    regions.emplace_back(static_cast<int>(s.x) - 21, static_cast<int>(s.y) - 19, 41, 39);
  const SpotDetectionResult in = det.detectIn(f.image, cv::Mat(), PixelFormat::kBayerRggb8, regions);
  ASSERT_TRUE(in.ok);
  const Score a = test::score(full.spots, truthOf(f), 2.0), b = test::score(in.spots, truthOf(f), 2.0);
  std::printf("[ MEASURE ] bayer_rggb8: full search %d/%d RMS %.4f px; in odd windows %d/%d RMS %.4f px\n", a.matched,
              a.truth, a.rms(), b.matched, b.truth, b.rms());
  EXPECT_GE(b.matched, a.matched);
  EXPECT_LE(b.rms(), a.rms() + 0.003);
}
