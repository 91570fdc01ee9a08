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
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/sim/radiometry.h"
#include "structured_light_stabilizer/sim/simulator.h"
#include "structured_light_stabilizer/spot_detector.h"
#include "support/spot_score.h"

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

SimulatorParams config(double beam_sigma_rad, const Condition& c, bool keep_snr, uint32_t seed)
{
  SimulatorParams cfg = studySimulatorParams();  // the study's SNR cases are on its brightness
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

namespace
{
// Peak SNR of each dot in the study's sense (formula 2.26: the dot's signal
// over the noise of the background it sits on), from the simulator's truth:
// the noise-free dot peak (SimFrame::peak_dn, green) over the sensor noise of
// the noise-free local background (median green of SimFrame::linear on a
// ring of radius 4 sigma + 2 px, outside the dot).
double dotSnr(const SimFrame& f, const SensorParams& sc, size_t b)
{
  const cv::Point2d p = f.pixels[b];
  const double radius = 4.0 * f.blur_sigma_px[b] + 2.0;
  std::vector<float> ring;
  for (int k = 0; k < 64; ++k)
  {
    const int x = static_cast<int>(std::lround(p.x + radius * std::cos(k * M_PI / 32)));
    const int y = static_cast<int>(std::lround(p.y + radius * std::sin(k * M_PI / 32)));
    if (x >= 0 && y >= 0 && x < f.linear.cols && y < f.linear.rows)
      ring.push_back(f.linear.at<cv::Vec3f>(y, x)[1]);
  }
  std::nth_element(ring.begin(), ring.begin() + ring.size() / 2, ring.end());
  const double background = ring.empty() ? 0.0 : ring[ring.size() / 2];
  return f.peak_dn[b] / std::sqrt(sc.read_noise_dn * sc.read_noise_dn + sc.gain_dn_per_electron * background);
}

// The same SNR for the study's worst case in this simulator: the design dot
// (2 mrad beam at 1.5 m, normal incidence, on the optical axis) at the
// study's dot/sun ratio, on rock of albedo 5 % (red; green is 0.55 of it in
// the simulator's rock) facing the full sun (sun_level 1). About 47: the
// simulator's gain puts more electrons behind a DN than the study's 2.26
// (SNR 32); the dot/sun ratio, which decides detection, is the study's.
double worstCaseSnr(const Simulator& sim)
{
  const SimulatorParams defaults = studySimulatorParams();
  const SensorParams& sc = sim.params().sensor;
  const double beam_px = LightingParams::kReferenceBeamSigmaRad * sc.camera.fx;
  const double defocus_px = sim.diameterOfConfusion(LightingParams::kReferenceDistanceM) / 4.0 / sc.pixel_size_m;
  const double image_dist = 1.0 / (1.0 / sc.focal_length_m - 1.0 / sc.focus_distance_m);
  const double diffraction_px = 0.42 * sim.params().projector.wavelength_nm * 1e-9 * image_dist /
                                sc.aperture_diameter_m / sc.pixel_size_m;
  const double var = beam_px * beam_px + defocus_px * defocus_px + diffraction_px * diffraction_px + 1.0 / 12.0;
  const double background = LightingParams::kSunFullScaleDn * 0.05 * 0.55;
  const double peak = defaults.lighting.dot_to_sun_ratio * background * beam_px * beam_px / var;
  return peak / std::sqrt(sc.read_noise_dn * sc.read_noise_dn + sc.gain_dn_per_electron * background);
}
}  // namespace

// The false-spot bound over more frames than the test above (16 frames can
// only show 0, 1, 2... false spots): sunlit frames only, since clutter is
// sunlit reflectance and vanishes at night. Fast method only.
//
// Recall: the issue's bounds hold "at the study's worst SNR case and
// better". Sunlit slopes turned from the projector (cos of the incidence),
// the lens's cos^4 vignetting towards the corners and dark rock put many
// dots of the "worst SNR" condition below that case (peak SNR 25-47, against
// 47 for the study's worst case, worstCaseSnr()), so recall is bounded at
// 99.5 % over the dots whose peak SNR (dotSnr(), from the simulator's truth)
// is at or above the study's worst case, and reported, with a loose bound,
// over all visible dots and over those below it.
TEST(SpotDetectorSim, FalseSpotsOverManySunlitFrames)
{
  SpotDetector fast;
  Score s, in_scope, below;
  double worst_snr = 0, min_snr = 1e9;
  uint32_t seed = 50000;
  for (int rep = 0; rep < 3; ++rep)
    for (double beam : {0.0014, 0.002, 0.0028, 0.0038})
      for (int c = 0; c < 3; ++c)  // the sunlit conditions
      {
        SimulatorParams cfg = config(beam, kConditions[c], true, ++seed);
        cfg.keep_linear = true;
        const Simulator sim(cfg);
        worst_snr = worstCaseSnr(sim);
        const SimFrame f = sim.render(0.3 * (seed % 100));
        const Spots spots = fast.detect(f.image, PixelFormat::kBgr8).spots;
        s.add(score(spots, f));
        // Recall split by SNR: the same matching, truth restricted.
        std::vector<cv::Point2d> hi, lo;
        for (size_t t = 0; t < f.visible.size(); ++t)
        {
          if (!f.visible[t])
            continue;
          const double snr = dotSnr(f, cfg.sensor, t);
          min_snr = std::min(min_snr, snr);
          (snr >= worst_snr ? hi : lo).push_back(f.pixels[t]);
        }
        in_scope.add(test::score(spots, hi));
        below.add(test::score(spots, lo));
      }
  std::printf("[ MEASURE ] study's worst case: peak SNR %.1f; dots in these frames: down to %.1f\n", worst_snr,
              min_snr);
  print("36 sunlit frames, sigma 1.5-4 px: fast", s);
  std::printf("[ MEASURE ] recall at peak SNR >= %.1f (the issue's scope): %6.2f %% (%d/%d); below: %6.2f %% (%d/%d)\n",
              worst_snr, 100.0 * in_scope.recall(), in_scope.matched, in_scope.truth, 100.0 * below.recall(),
              below.matched, below.truth);
  EXPECT_LE(s.falsePerFrame(), 0.1);
  EXPECT_LE(s.rms(), 0.10);
  EXPECT_GT(in_scope.truth, 1000);  // the scope is not emptied by a wrong reference
  EXPECT_GE(in_scope.recall(), 0.995);
  // Below the study's worst case: reported, bounded loosely.
  EXPECT_GE(below.recall(), 0.98);
  EXPECT_GE(s.recall(), 0.99);
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
  SimulatorParams cfg = config(0.002, kConditions[1], true, 99);
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
