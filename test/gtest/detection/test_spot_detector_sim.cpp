// SpotDetector on the scene simulator's frames (1024 x 1024, truth from the
// renderer, with the textured-rock physics: the dot's light reflected by the
// albedo under each pixel, full well): the bounds for the fast
// method, the same figures for the study's baseline (reported, no bound: it
// is the yardstick); an approach from 1.0 to 2.0 m with up to two thirds of
// the dots clipped; fine rock texture by day with the reference channel and
// with a projector-off frame.
//
// "The study's worst SNR case" (formula 2.26, SNR 32) is full sun on albedo
// 5 % rock for the design dot (sigma ~2 px). A wider beam spreads the same
// power: at sigma 4 px the peak is 3.5 x lower, SNR ~9, worse than any case
// of the study. The bounded cases therefore scale the dot power with sigma^2
// to keep the peak SNR at the study's worst case or better; the same-power
// wide dots are measured and reported separately.
//
// Seeds: the albedo normalisation and the clipped-dot fit were tuned on rock
// seeds 900-903 and on the seeds this file used before (2-17, 50001-50036,
// 77, 99); every bound here is asserted on rock seeds from 3000 up.
//
// False spots: specks and minerals of a dot's size and of the projector's
// colour cannot be told from dots in one frame; the detector
// reports them for the Triangulator's geometry to reject, so they are
// counted and only bounded loosely here.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
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
  seed += 3000;                                  // held out (see the file's header)
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
  SpotDetectorParams praw;
  praw.fast.normalise_albedo = false;
  SpotDetector fast(pf), base(pb), raw(praw);
  Score fast_all, base_all, fast_day, fast_night, raw_day;
  double worst_recall = 1.0;
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
      (c.sun > 0 ? fast_day : fast_night).add(sf);
      if (c.sun > 0)
        raw_day.add(score(raw.detect(f.image, PixelFormat::kBgr8).spots, f));
      worst_recall = std::min(worst_recall, sf.recall());
    }
  }
  print("all (specks + olive minerals present): fast", fast_all);
  print("all (specks + olive minerals present): baseline", base_all);
  print("by day: fast", fast_day);
  print("by day: fast without the albedo normalisation", raw_day);
  print("by night (no albedo in the frame: the light's centroid): fast", fast_night);
  std::printf("[ MEASURE ] worst frame recall (fast): %.2f %%\n", 100.0 * worst_recall);
  EXPECT_GE(fast_all.recall(), 0.995);
  EXPECT_GE(worst_recall, 0.98);
  // By day the 2 cm texture of 5-45 % albedo is divided out; what is left
  // comes from the dimmest dots (peak SNR down to 9 at sigma 4) and from the
  // sun's shading of the rock's roughness (docs/spot_detector.md).
  EXPECT_LE(fast_day.rms(), 0.18);
  EXPECT_LT(fast_day.rms(), 0.6 * raw_day.rms());
  // By night the 2 cm texture of 5-45 % albedo pulls each dot's light off
  // the hit point (sigma^2 x the albedo's log-gradient; physics, not the
  // detector): reported, bounded loosely.
  EXPECT_LE(fast_night.rms(), 0.8);
  EXPECT_LT(fast_all.rms(), base_all.rms());
  EXPECT_LE(fast_all.falsePerFrame(), 5.0);
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
  const double diffraction_px =
      0.42 * sim.params().projector.wavelength_nm * 1e-9 * image_dist / sc.aperture_diameter_m / sc.pixel_size_m;
  const double var = beam_px * beam_px + defocus_px * defocus_px + diffraction_px * diffraction_px + 1.0 / 12.0;
  const double background = LightingParams::kSunFullScaleDn * 0.05 * 0.55;
  const double peak = defaults.lighting.dot_to_sun_ratio * background * beam_px * beam_px / var;
  return peak / std::sqrt(sc.read_noise_dn * sc.read_noise_dn + sc.gain_dn_per_electron * background);
}
}  // namespace

// Recall over more frames than the test above: sunlit frames only, where
// clutter (sunlit reflectance) is in view. Fast method only.
//
// Recall over every visible dot, the ones that sunlit slopes
// turned from the projector (cos of the incidence), the lens's cos^4
// vignetting towards the corners and dark rock put below the study's worst
// case included (peak SNR down to ~24, against 47 for the study's worst
// case, worstCaseSnr()): pooled, split at that SNR (dotSnr(), from the
// simulator's truth), and in every frame.
TEST(SpotDetectorSim, RecallOverManySunlitFrames)
{
  SpotDetector fast;
  Score s, in_scope, below;
  double worst_snr = 0, min_snr = 1e9, worst_frame = 1.0;
  uint32_t seed = 500;
  for (int rep = 0; rep < 2; ++rep)
    for (double beam : {0.0014, 0.002, 0.0028, 0.0038})
      for (int c = 0; c < 3; ++c)  // the sunlit conditions
      {
        SimulatorParams cfg = config(beam, kConditions[c], true, ++seed);
        cfg.keep_linear = true;
        const Simulator sim(cfg);
        worst_snr = worstCaseSnr(sim);
        const SimFrame f = sim.render(0.3 * (seed % 100));
        const Spots spots = fast.detect(f.image, PixelFormat::kBgr8).spots;
        const Score frame = score(spots, f);
        s.add(frame);
        worst_frame = std::min(worst_frame, frame.recall());
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
  print("24 sunlit frames, sigma 1.5-4 px: fast", s);
  std::printf("[ MEASURE ] recall at peak SNR >= %.1f (the issue's scope): %6.2f %% (%d/%d); below: %6.2f %% (%d/%d)\n",
              worst_snr, 100.0 * in_scope.recall(), in_scope.matched, in_scope.truth, 100.0 * below.recall(),
              below.matched, below.truth);
  EXPECT_LE(s.falsePerFrame(), 5.0);
  EXPECT_LE(s.rms(), 0.14);
  EXPECT_GT(in_scope.truth, 700);  // the scope is not emptied by a wrong reference
  EXPECT_GE(in_scope.recall(), 0.995);
  // Every visible dot, those dimmed below the study's worst case by slopes
  // and vignetting included, pooled and in every frame.
  EXPECT_GE(below.recall(), 0.98);
  EXPECT_GE(s.recall(), 0.995);
  EXPECT_GE(worst_frame, 0.98);
  std::printf("[ MEASURE ] worst frame recall: %.2f %%\n", 100.0 * worst_frame);
}

// Same projector power spread over a wider beam: below the study's worst SNR.
// Reported; bounded loosely (the centroid noise bound itself is ~0.1 px here).
TEST(SpotDetectorSim, WideDimDotsBelowTheStudysWorstSnr)
{
  SpotDetector fast;
  Score s;
  const Simulator sim(config(0.0038, kConditions[0], false, 177));
  const SimFrame f = sim.render(0.5);
  s.add(score(fast.detect(f.image, PixelFormat::kBgr8).spots, f));
  print("sigma 4 px, same power (peak SNR ~9), worst sun/albedo: fast", s);
  EXPECT_GE(s.recall(), 0.6);
  EXPECT_LE(s.rms(), 0.4);
  EXPECT_LE(s.falsePerFrame(), 10.0);
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
  SimulatorParams cfg = config(0.002, kConditions[1], true, 199);
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

namespace
{
// Visible beams' pixels, and those of the clipped ones.
std::vector<cv::Point2d> visiblePixels(const SimFrame& f, int* clipped)
{
  std::vector<cv::Point2d> truth;
  *clipped = 0;
  for (size_t t = 0; t < f.visible.size(); ++t)
    if (f.visible[t])
    {
      truth.push_back(f.pixels[t]);
      *clipped += f.clipped[t];
    }
  return truth;
}

// The rig at `distance_m` from a rock of rock seed `seed` (held out), default
// sun and dots (the study's brightness: bright rock clips the dots).
SimulatorParams rigAt(double distance_m, uint32_t seed)
{
  SimulatorParams cfg = studySimulatorParams();
  cfg.rock.distance_m = distance_m;
  cfg.rock.seed = seed;
  cfg.noise_seed = seed * 7 + 1;
  cfg.clutter.green_specks = 10;
  cfg.clutter.olive_minerals = 10;
  return cfg;
}
}  // namespace

// The rig approaches the rock to 1.0 m and recedes to 2.0 m: the dots grow
// brighter with the inverse square and clip on the brighter rock (up to two
// thirds of them at 1.0 m); every dot must be found in every frame.
TEST(SpotDetectorSim, ApproachWithClippedDots)
{
  SpotDetector fast;
  Score pooled;
  double worst = 1.0;
  int most_clipped = 0, least_clipped = 1000;
  uint32_t seed = 3100;
  for (double d : {1.0, 1.2, 1.4, 1.6, 1.8, 2.0, 1.9, 1.7, 1.5, 1.3, 1.1})
  {
    const Simulator sim(rigAt(d, ++seed));
    const SimFrame f = sim.render(0.0);
    int clipped = 0;
    const std::vector<cv::Point2d> truth = visiblePixels(f, &clipped);
    const SpotDetectionResult r = fast.detect(f.image, PixelFormat::kBgr8);
    ASSERT_TRUE(r.ok) << r.error;
    const Score s = test::score(r.spots, truth);
    pooled.add(s);
    worst = std::min(worst, s.recall());
    const int percent = static_cast<int>(std::lround(100.0 * clipped / std::max<size_t>(1, truth.size())));
    most_clipped = std::max(most_clipped, percent);
    least_clipped = std::min(least_clipped, percent);
    char label[96];
    std::snprintf(label, sizeof(label), "approach: %.1f m, %d %% of the dots clipped", d, percent);
    print(label, s);
  }
  print("approach 1.0 -> 2.0 -> 1.1 m, 11 frames", pooled);
  EXPECT_GE(most_clipped, 50);  // the premise: the near frames clip most dots
  EXPECT_LE(least_clipped, 10);
  EXPECT_GE(pooled.recall(), 0.995);
  EXPECT_GE(worst, 0.98);
  EXPECT_LE(pooled.rms(), 0.08);
}

namespace
{
// Whether clutter lies within 4 px of p in a projector-off frame (bgr8): a
// pixel whose green stands out of the rock's colour (green above 3/4 of its
// red and above its blue by 20 DN: the rock's green/red is 0.55-0.65), a
// projector-coloured speck or an olive mineral.
bool underClutter(const cv::Mat& off, const cv::Point2d& p)
{
  const int x0 = static_cast<int>(std::lround(p.x)), y0 = static_cast<int>(std::lround(p.y));
  for (int y = std::max(0, y0 - 4); y <= std::min(off.rows - 1, y0 + 4); ++y)
    for (int x = std::max(0, x0 - 4); x <= std::min(off.cols - 1, x0 + 4); ++x)
    {
      const cv::Vec3b& c = off.at<cv::Vec3b>(y, x);
      if (c[1] - std::max(0.75 * c[2], double(c[0])) > 20.0)
        return true;
    }
  return false;
}

// Fine texture of the given period (m) and +-25 %, by day; a few frames.
// reference_clear: the reference channel's spots scored against the dots
// clear of clutter only (a projector-coloured speck on a dot is one bright
// spot in a colour frame; the projector-off frame subtracts it); under: the
// dots left out.
struct TextureRun
{
  Score none, reference, reference_clear, ambient;
  int under = 0;
};

TextureRun texturedByDay(double relief_m, uint32_t seed)
{
  SpotDetectorParams off;
  off.fast.normalise_albedo = false;
  SpotDetector raw(off), normalised;
  TextureRun run;
  for (double period : {0.01, 0.02, 0.03})
    for (double sun : {0.5, 1.0})
    {
      SimulatorParams cfg = rigAt(1.5, ++seed);
      cfg.rock.fine_texture_period_m = period;
      cfg.rock.fine_texture_amplitude = 0.25;
      cfg.rock.relief_m = relief_m;
      cfg.lighting.sun_level = sun;
      const Simulator sim(cfg);
      const SimFrame f = sim.render(0.0);
      FrameRequest off_frame;
      off_frame.projector_on = false;
      const SimFrame a = sim.render(0.0, off_frame);
      int clipped = 0;
      const std::vector<cv::Point2d> truth = visiblePixels(f, &clipped);
      std::vector<cv::Point2d> clear;
      for (const cv::Point2d& t : truth)
        if (!underClutter(a.image, t))
          clear.push_back(t);
      run.under += static_cast<int>(truth.size() - clear.size());
      const Spots spots = normalised.detect(f.image, PixelFormat::kBgr8).spots;
      run.none.add(test::score(raw.detect(f.image, PixelFormat::kBgr8).spots, truth));
      run.reference.add(test::score(spots, truth));
      run.reference_clear.add(test::score(spots, clear));
      run.ambient.add(test::score(normalised.detect(f.image, a.image, PixelFormat::kBgr8).spots, truth));
    }
  return run;
}
}  // namespace

// Fine rock texture (1-3 cm, +-25 %) by day: the dot's light divided by the
// albedo under each pixel, from the rock's other colour channels or a
// projector-off frame. On the default rough rock (relief 0.15 m with a 1-2 cm
// roughness) the ambient light carries the sun's shading of the roughness and
// a dot the projector's, so the ratio keeps cos(projector incidence) /
// cos(sun incidence) across the footprint (docs/spot_detector.md); on a flat
// rock only the texture is left to remove.
TEST(SpotDetectorSim, FineTextureByDay)
{
  const TextureRun rough = texturedByDay(0.15, 3200);
  const TextureRun flat = texturedByDay(0.0, 3300);
  print("fine texture by day, rough rock: no normalisation", rough.none);
  print("fine texture by day, rough rock: colour channels", rough.reference);
  print("  the same, dots clear of clutter", rough.reference_clear);
  print("fine texture by day, rough rock: projector-off frame", rough.ambient);
  print("fine texture by day, flat rock: no normalisation", flat.none);
  print("fine texture by day, flat rock: colour channels", flat.reference);
  print("  the same, dots clear of clutter", flat.reference_clear);
  print("fine texture by day, flat rock: projector-off frame", flat.ambient);
  std::printf("[ MEASURE ] dots within 4 px of clutter: rough %d, flat %d\n", rough.under, flat.under);
  for (const TextureRun* r : {&rough, &flat})
  {
    EXPECT_GE(r->reference.recall(), 0.995);
    EXPECT_GE(r->ambient.recall(), 0.995);
    EXPECT_LT(r->reference.rms(), 0.8 * r->none.rms());
    EXPECT_LT(r->ambient.rms(), 0.6 * r->none.rms());
    EXPECT_LE(r->under, 12);  // the scope is not emptied
  }
  // Measured 0.043 / 0.073 px with the projector-off frame (0.051 / 0.078
  // while the simulator's rock lost the grain between its ray-cast samples,
  // docs/simulator.md#rock); with the colour channels 0.121 / 0.085 px
  // (flat / rough), 0.134 / 0.102 with the red channel alone (it misses the
  // texture's hue, red against blue). On the flat rock one dot of 600 lies
  // under a projector-coloured speck, 2.7 px off: without the dots near
  // clutter 0.058 px (0.086 with red alone).
  EXPECT_LE(flat.ambient.rms(), 0.05);
  EXPECT_LE(rough.ambient.rms(), 0.09);
  EXPECT_LE(flat.reference.rms(), 0.15);
  EXPECT_LE(rough.reference.rms(), 0.1);
  EXPECT_LE(flat.reference_clear.rms(), 0.065);
  EXPECT_LE(rough.reference_clear.rms(), 0.1);
}
