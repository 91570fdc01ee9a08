// SpotDetector on the scene simulator's frames (1024 x 1024 bgr8, truth from
// the renderer): the accuracy bounds for the fast method, the same
// figures for the study's baseline (reported, no bound: it is the yardstick).
//
// "The study's worst SNR case" (formula 2.26, SNR 32) is full sun on albedo
// 5 % rock for the design dot (sigma ~2 px). A wider beam spreads the same
// power: at sigma 4 px the peak is 3.5 x lower, SNR ~9, worse than any case
// of the study. The bounded cases therefore scale the dot power with sigma^2
// to keep the peak SNR at the study's worst case or better; the same-power
// wide dots are measured and reported separately.
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/simulator.h"
#include "structured_light_stabilizer/spot_detector.h"
#include "spot_score.h"

using namespace structured_light_stabilizer;
using structured_light_stabilizer::test::Score;

namespace
{
// Scores against the pixels of the visible beams.
Score score(const Spots& spots, const SimFrame& f)
{
  std::vector<cv::Point2d> truth;
  for (size_t t = 0; t < f.visible.size(); ++t)
    if (f.visible[t])
      truth.push_back(f.pixels[t]);
  return test::score(spots, truth);
}

void print(const std::string& what, const Score& s)
{
  std::printf("[ MEASURE ] %-58s RMS %.4f px, recall %6.2f %% (%d/%d), false/frame %.2f\n", what.c_str(), s.rms(),
              100.0 * s.recall(), s.matched, s.truth, s.falsePerFrame());
}

struct Condition
{
  const char* name;
  double sun, albedo_min, albedo_max;
};

SimulatorConfig config(double beam_sigma_rad, const Condition& c, bool keep_snr, uint32_t seed)
{
  SimulatorConfig cfg;
  cfg.projector.beam_sigma_rad = beam_sigma_rad;
  cfg.lighting.sun_level = c.sun;
  cfg.rock.albedo_min = c.albedo_min;
  cfg.rock.albedo_max = c.albedo_max;
  cfg.rock.seed = seed;
  cfg.noise_seed = seed * 7 + 1;
  // Keep the peak as the 2 mrad design dot's (sigma ~2.1 px) when asked.
  if (keep_snr)
    cfg.lighting.dot_to_sun_ratio *= std::pow(beam_sigma_rad / 0.002, 2.0);
  cfg.clutter.green_specks = 20;
  cfg.clutter.olive_minerals = 20;
  cfg.motion.jitter_translation_m = 0.002;
  cfg.motion.jitter_rotation_rad = 0.002;
  return cfg;
}

const Condition kConditions[] = {
    {"worst SNR (sun 1, albedo 5-6 %)", 1.0, 0.05, 0.06},
    {"sun 0.5, albedo 5-45 %", 0.5, 0.05, 0.45},
    {"sun 1, albedo 5-45 %", 1.0, 0.05, 0.45},
    {"night, albedo 5-45 %", 0.0, 0.05, 0.45},
};
}  // namespace

TEST(SpotDetectorSim, AccuracyAgainstTruth)
{
  SpotDetectorParams pf, pb;
  pb.method = SpotMethod::kBaseline;
  SpotDetector fast(pf), base(pb);
  Score fast_all, base_all, fast_wide;
  uint32_t seed = 1;
  // beam_sigma_rad -> dot sigma in the image (defocus included) ~1.5, 2.1, 3, 4 px.
  for (double beam : {0.0014, 0.002, 0.0028, 0.0038})
  {
    for (const Condition& c : kConditions)
    {
      const Simulator sim(config(beam, c, true, ++seed));
      const SimFrame f = sim.render(0.3 * seed);
      double sigma = 0;
      int n = 0;
      for (size_t b = 0; b < f.visible.size(); ++b)
        if (f.visible[b])
        {
          sigma += f.blur_sigma_px[b];
          ++n;
        }
      ASSERT_GT(n, 50);
      const SpotDetectionResult rf = fast.detect(f.image, PixelFormat::kBgr8);
      const SpotDetectionResult rb = base.detect(f.image, PixelFormat::kBgr8);
      ASSERT_TRUE(rf.ok && rb.ok);
      const Score sf = score(rf.spots, f), sb = score(rb.spots, f);
      char label[160];
      std::snprintf(label, sizeof(label), "sigma %.1f px, %s: fast", sigma / n, c.name);
      print(label, sf);
      std::snprintf(label, sizeof(label), "sigma %.1f px, %s: baseline", sigma / n, c.name);
      print(label, sb);
      fast_all.add(sf);
      base_all.add(sb);
      if (beam > 0.0015)
        fast_wide.add(sf);
    }
  }
  print("all (specks + olive minerals present): fast", fast_all);
  print("all (specks + olive minerals present): baseline", base_all);
  print("dots of sigma 2-4 px: fast", fast_wide);
  EXPECT_LE(fast_all.rms(), 0.10);
  EXPECT_GE(fast_all.recall(), 0.995);
  EXPECT_LT(fast_all.rms(), base_all.rms());
  // With 20 green specks and 20 olive minerals in view. Specks (sigma
  // 0.6-1.4 px) are as small as sigma-1.5 dots and, on the darkest rock, as
  // green: what tells them apart is the frame-level test of size and energy
  // (a speck is off in both; see SpotDetectorParams).
  EXPECT_LE(fast_all.falsePerFrame(), 0.1);
  EXPECT_LE(fast_wide.falsePerFrame(), 0.1);
}

// The false-spot bound over more frames than the test above (16 frames can
// only show 0, 1, 2... false spots): sunlit frames only, since clutter is
// sunlit reflectance and vanishes at night, with seeds not used to set the
// detector's thresholds. Fast method only.
TEST(SpotDetectorSim, FalseSpotsOverManySunlitFrames)
{
  SpotDetector fast;
  Score s;
  uint32_t seed = 50000;
  for (int rep = 0; rep < 3; ++rep)
    for (double beam : {0.0014, 0.002, 0.0028, 0.0038})
      for (int c = 0; c < 3; ++c)  // the sunlit conditions
      {
        const Simulator sim(config(beam, kConditions[c], true, ++seed));
        const SimFrame f = sim.render(0.3 * (seed % 100));
        s.add(score(fast.detect(f.image, PixelFormat::kBgr8).spots, f));
      }
  print("36 sunlit frames, sigma 1.5-4 px, fresh seeds: fast", s);
  EXPECT_LE(s.falsePerFrame(), 0.1);
  // Sunlit frames only are the hard half of the set: this measures
  // 99.28 % (the detector before the frame-level size/energy test: 99.47 %;
  // 14 of the 26 dots missed never become candidates). The 99.5 %
  // is asserted above, over sunlit and night frames.
  EXPECT_GE(s.recall(), 0.99);
  EXPECT_LE(s.rms(), 0.10);
}

// Same projector power spread over a wider beam: below the study's worst SNR.
// Reported; bounded loosely (the centroid noise bound itself is ~0.1 px here).
TEST(SpotDetectorSim, WideDimDotsBelowTheStudysWorstSnr)
{
  SpotDetector fast;
  Score s;
  const Simulator sim(config(0.0038, kConditions[0], false, 77));
  const SimFrame f = sim.render(0.5);
  s.add(score(fast.detect(f.image, PixelFormat::kBgr8).spots, f));
  print("sigma 4 px, same power (peak SNR ~9), worst sun/albedo: fast", s);
  EXPECT_GE(s.recall(), 0.6);
  EXPECT_LE(s.rms(), 0.4);
  EXPECT_LE(s.falsePerFrame(), 1.0);
}

// Dot-sized green mineral blobs have the projector's colour in this
// simulator; on dark rock nothing in one frame tells them from dots (the
// Triangulator's epipolar gate does). Reported; dots must still be found
// (a blob right next to a dot pulls its centroid or takes its place, hence
// the looser bounds).
TEST(SpotDetectorSim, GreenMineralBlobs)
{
  SpotDetector fast;
  Score s;
  SimulatorConfig cfg = config(0.002, kConditions[1], true, 99);
  cfg.clutter.green_blobs = 10;
  const Simulator sim(cfg);
  const SimFrame f = sim.render(0.2);
  s.add(score(fast.detect(f.image, PixelFormat::kBgr8).spots, f));
  print("sun 0.5, 10 green mineral blobs (spurious dots): fast", s);
  // A blob right on a dot can take its place (or be rejected with it).
  EXPECT_GE(s.recall(), 0.98);
  EXPECT_LE(s.rms(), 0.2);
  EXPECT_LE(s.falsePerFrame(), 10.0);
}
