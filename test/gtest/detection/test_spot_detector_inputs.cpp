// SpotDetector (fast method) on every input kind of the supported cameras: the
// simulator's frames rendered in each sensor output and projector colour
// (Bayer patterns, mono8/mono16 NIR, red and blue projectors, rgb8, white),
// the independent generator's frames in the encodings the simulator does not
// render (yuv422 UYVY and YUYV, bgra8), the SIMD row passes against their
// scalar tails, and bad input.
//
// Seeds: rock seeds 3400+ (simulator) and 6000+ (generator), not used for
// tuning (docs/testing.md). The rock is weakly textured (10 cm features):
// these tests are about reading each input; the texture's physics is in
// test_spot_detector_physics and test_spot_detector_sim.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "support/spot_score.h"
#include "support/synthetic_dots.h"
// The inputs layer's row passes (private to the core library), for the exact
// test of the matched path's score rows below.
#include "detection/inputs/pixels.h"

using namespace structured_light_stabilizer;
using structured_light_stabilizer::test::Score;

namespace
{
struct Kind
{
  const char* name;
  const char* encoding;
  ProjectorColor color;
  double sun;
  double max_rms_px;  // the 0.10 px, unless said otherwise
};

void print(const std::string& what, const Score& s, double worst)
{
  std::printf("[ MEASURE ] %-44s RMS %.4f px, recall %6.2f %% (%d/%d), worst frame %6.2f %%, false/frame %.2f\n",
              what.c_str(), s.rms(), 100.0 * s.recall(), s.matched, s.truth, 100.0 * worst, s.falsePerFrame());
}

Score simulatorKind(const Kind& k, int frames, uint32_t seed, double* worst)
{
  SpotDetectorParams p;
  p.projector_color = k.color;
  SpotDetector det(p);
  Score pooled;
  *worst = 1.0;
  for (int f = 0; f < frames; ++f)
  {
    SimulatorParams cfg = studySimulatorParams();  // the input kinds at the study's brightness
    EXPECT_TRUE(sensorOutputFromEncoding(k.encoding, &cfg.sensor.output));
    cfg.projector.color = k.color;
    cfg.projector.wavelength_nm = nominalWavelengthNm(k.color);
    cfg.lighting.sun_level = k.sun;
    cfg.rock.texture_scale_m = 0.1;
    cfg.rock.seed = seed + f;
    cfg.noise_seed = 7 * (seed + f) + 1;
    const Simulator sim(cfg);
    const SimFrame frame = sim.render(0.0);
    PixelFormat format;
    EXPECT_TRUE(pixelFormatFromEncoding(frame.encoding, &format)) << frame.encoding;
    std::vector<cv::Point2d> truth;
    for (size_t b = 0; b < frame.visible.size(); ++b)
      if (frame.visible[b])
        truth.push_back(frame.pixels[b]);
    const SpotDetectionResult r = det.detect(frame.image, format);
    EXPECT_TRUE(r.ok) << r.error;
    const Score s = test::score(r.spots, truth);
    pooled.add(s);
    *worst = std::min(*worst, s.recall());
  }
  return pooled;
}
}  // namespace

// The input kinds of the acceptance (Bayer RGGB, mono8 NIR, red
// projector on a colour camera, rgb8) and the others the package accepts,
// each on simulator frames rendered in that output: recall >= 99 %, centroid
// <= 0.10 px.
TEST(SpotDetectorInputs, SimulatorInputKinds)
{
  const Kind kinds[] = {
      {"rgb8, green", "rgb8", ProjectorColor::kGreen, 0.5, 0.10},
      {"bayer_rggb8, green", "bayer_rggb8", ProjectorColor::kGreen, 0.5, 0.10},
      {"bayer_bggr8, green", "bayer_bggr8", ProjectorColor::kGreen, 0.5, 0.10},
      {"bayer_gbrg8, green", "bayer_gbrg8", ProjectorColor::kGreen, 0.5, 0.10},
      {"bayer_grbg8, green", "bayer_grbg8", ProjectorColor::kGreen, 0.5, 0.10},
      {"bgr8, red projector", "bgr8", ProjectorColor::kRed, 0.5, 0.10},
      {"bgr8, blue projector", "bgr8", ProjectorColor::kBlue, 0.5, 0.10},
      {"mono8, NIR projector, by day", "mono8", ProjectorColor::kNir, 0.5, 0.10},
      {"mono8, NIR projector, by night", "mono8", ProjectorColor::kNir, 0.0, 0.10},
      {"mono16, NIR projector, by day", "mono16", ProjectorColor::kNir, 0.5, 0.10},
      // White light is found by intensity on a colour camera too: the sunlit
      // texture under the dot stays (no colour tells the two apart).
      {"bgr8, white projector", "bgr8", ProjectorColor::kWhite, 0.5, 0.12},
      // Red dots on red rock through the red quarter of a mosaic: the
      // reference (green) is interpolated and scaled by the rock's r/g of
      // about 1.8, which carries its noise into the centroid.
      {"bayer_rggb8, red projector", "bayer_rggb8", ProjectorColor::kRed, 0.5, 0.14},
      {"bgr16, green", "bgr16", ProjectorColor::kGreen, 0.5, 0.10},
      {"rgb16, green, full sun", "rgb16", ProjectorColor::kGreen, 1.0, 0.10},
  };
  uint32_t seed = 3400;
  for (const Kind& k : kinds)
  {
    double worst = 0;
    const Score s = simulatorKind(k, 2, seed, &worst);
    seed += 10;
    print(k.name, s, worst);
    EXPECT_GE(s.recall(), 0.99) << k.name;
    EXPECT_GE(worst, 0.98) << k.name;
    EXPECT_LE(s.rms(), k.max_rms_px) << k.name;
  }
}

// Encodings the simulator does not render, on the independent generator's
// frames: each must do as well as the bgr8 frame of the same scene (yuv422
// halves the chroma resolution).
TEST(SpotDetectorInputs, GeneratorEncodings)
{
  const synthetic_dots::Output outputs[] = {synthetic_dots::Output::kBgr8,       synthetic_dots::Output::kUyvy,
                                            synthetic_dots::Output::kYuyv,       synthetic_dots::Output::kBayerRggb8,
                                            synthetic_dots::Output::kBayerGrbg8, synthetic_dots::Output::kRgb8};
  SpotDetector det;
  for (const synthetic_dots::Output out : outputs)
  {
    Score pooled;
    double worst = 1.0;
    std::string encoding;
    for (unsigned seed = 6000; seed < 6003; ++seed)
    {
      synthetic_dots::Config cfg;
      cfg.width = cfg.height = 512;
      cfg.sun = 0.5;
      cfg.texture_px = 70.0;
      cfg.dot_to_sun_ratio = 1.5;
      cfg.output = out;
      cfg.seed = seed;
      const synthetic_dots::Frame f = synthetic_dots::render(cfg);
      encoding = f.encoding;
      PixelFormat format;
      ASSERT_TRUE(pixelFormatFromEncoding(f.encoding, &format)) << f.encoding;
      const SpotDetectionResult r = det.detect(f.image, format);
      ASSERT_TRUE(r.ok) << r.error;
      const Score s = test::score(r.spots, f.dots);
      pooled.add(s);
      worst = std::min(worst, s.recall());
    }
    print("generator, " + encoding, pooled, worst);
    EXPECT_GE(pooled.recall(), 0.99) << encoding;
    EXPECT_GE(worst, 0.98) << encoding;
    EXPECT_LE(pooled.rms(), 0.10) << encoding;
  }
}

namespace
{
// The detected spot nearest to each true dot (within 1 px), or NaN.
std::vector<cv::Point2d> nearestToTruth(const Spots& spots, const std::vector<cv::Point2d>& truth, double dx)
{
  std::vector<cv::Point2d> out;
  for (const cv::Point2d& t : truth)
  {
    cv::Point2d best(NAN, NAN);
    double d_best = 1.0;
    for (const Spot& s : spots)
    {
      const double d = std::hypot(s.x - dx - t.x, s.y - t.y);
      if (d < d_best)
      {
        d_best = d;
        best = cv::Point2d(s.x - dx, s.y);
      }
    }
    out.push_back(best);
  }
  return out;
}
}  // namespace

// The SIMD row passes handle 16 cells at a time and the rest in a scalar
// tail: the same scene shifted by 1-15 columns (2-14 on a mosaic, which keeps
// the pattern) puts every dot through both; every dot must follow the shift
// exactly (the intensity path's 16 x 16 background blocks do not shift with
// the scene, so its candidates start elsewhere: the same dot within the
// refinement's convergence; by night, as sunlit texture under a mono dot
// leaves the iterated centroid more than one fixed point).
TEST(SpotDetectorInputs, SimdPassesAgreeWithTheirTails)
{
  synthetic_dots::Config cfg;
  cfg.width = 300;
  cfg.height = 260;
  cfg.rows = cfg.cols = 5;
  cfg.seed = 6100;
  for (const synthetic_dots::Output out :
       {synthetic_dots::Output::kBgr8, synthetic_dots::Output::kBayerRggb8, synthetic_dots::Output::kMono8})
  {
    const bool mono = out == synthetic_dots::Output::kMono8;
    cfg.output = out;
    cfg.projector = mono ? synthetic_dots::Projector::kNir : synthetic_dots::Projector::kGreen;
    cfg.sun = mono ? 0.0 : 0.3;
    const synthetic_dots::Frame f = synthetic_dots::render(cfg);
    PixelFormat format;
    ASSERT_TRUE(pixelFormatFromEncoding(f.encoding, &format));
    SpotDetectorParams p;
    p.projector_color = mono ? ProjectorColor::kNir : ProjectorColor::kGreen;
    // The SIMD rows serve the fixed scores (the local scores' blocks follow
    // the frame's origin, which the shift moves).
    p.fast.local_colour = false;
    SpotDetector det(p);
    const std::vector<cv::Point2d> ref = nearestToTruth(det.detect(f.image, format).spots, f.dots, 0.0);
    const int step = isBayer(format) ? 2 : 1;
    for (int shift = step; shift < 16; shift += step)
    {
      cv::Mat wide(f.image.rows, f.image.cols + shift, f.image.type(), cv::Scalar::all(0));
      f.image.copyTo(wide(cv::Rect(shift, 0, f.image.cols, f.image.rows)));
      const std::vector<cv::Point2d> moved = nearestToTruth(det.detect(wide, format).spots, f.dots, shift);
      for (size_t i = 0; i < ref.size(); ++i)
      {
        ASSERT_TRUE(std::isfinite(ref[i].x) && std::isfinite(moved[i].x)) << f.encoding << " dot " << i;
        EXPECT_NEAR(moved[i].x, ref[i].x, mono ? 2e-3 : 1e-6) << f.encoding << " shift " << shift;
        EXPECT_NEAR(moved[i].y, ref[i].y, mono ? 2e-3 : 1e-6) << f.encoding << " shift " << shift;
      }
    }
  }
}

// The colour path's signed score rows (rows::colourScoreRow: SIMD, 8 or 16
// pixels at a time, and its scalar tail) against FramePlanes::scoreRow's
// formula written out here, d = max(0, frame - ambient) per channel (16-bit
// samples in whole DN, (v + 128) / 257), score = d_signal - max((k_ref
// d_reference) >> 8, (k_third d_third) >> 8): random frames, every
// interleaved layout (bgr16/rgb16 also without an ambient frame), widths
// 1-40 (every tail length), each projector colour's channels, weights below,
// at and above 256; what it does not serve is declined.
TEST(SpotDetectorInputs, ColourScoreRowsAreExact)
{
  namespace fd = structured_light_stabilizer::fast_detector;
  cv::RNG rng(6400);
  const PixelFormat formats[] = {PixelFormat::kBgr8,  PixelFormat::kRgb8,  PixelFormat::kBgra8,
                                 PixelFormat::kRgba8, PixelFormat::kBgr16, PixelFormat::kRgb16};
  const int channels[3][3] = {{1, 0, 2}, {0, 1, 2}, {2, 0, 1}};  // green, red, blue projectors
  for (PixelFormat format : formats)
    for (bool with_ambient : {true, false})
      for (const auto& ch : channels)
        for (int k : {0, 192, 256, 300, 1000, 32767})
          for (int width = 1; width <= 40; ++width)
          {
            const bool wide = matDepth(format) == CV_16U;
            if (!wide && !with_ambient)
              continue;  // 8-bit frames without an ambient frame: the SIMD threshold pass (colourRowRuns)
            const int type = CV_MAKETYPE(matDepth(format), channelCount(format));
            cv::Mat image(2, width, type), ambient(2, width, type);
            rng.fill(image, cv::RNG::UNIFORM, 0, wide ? 65536 : 256);
            rng.fill(ambient, cv::RNG::UNIFORM, 0, wide ? 65536 : 256);
            fd::ColourModel model;
            model.signal = ch[0];
            model.reference = ch[1];
            model.third = ch[2];
            const int k_third = 300 - k / 4 > 0 ? 300 - k / 4 : 0;
            std::vector<int16_t> out(width, -1);
            ASSERT_TRUE(fd::rows::colourScoreRow(image, with_ambient ? ambient : cv::Mat(), format, model, k, k_third,
                                                 1, out.data()));
            const fd::pixels::Interleaved L = fd::pixels::interleavedLayout(format);
            const int offset[3] = {L.r, L.g, L.b};
            const auto sample = [&](const cv::Mat& m, int x, int c)
            {
              return wide ? (m.ptr<uint16_t>(1)[L.bytes * x + offset[c]] + 128) / 257
                          : m.ptr<uint8_t>(1)[L.bytes * x + offset[c]];
            };
            for (int x = 0; x < width; ++x)
            {
              int d[3];
              for (int c = 0; c < 3; ++c)
                d[c] = std::max(0, sample(image, x, c) - (with_ambient ? sample(ambient, x, c) : 0));
              const int expect = d[ch[0]] - std::max((k * d[ch[1]]) >> 8, (k_third * d[ch[2]]) >> 8);
              ASSERT_EQ(out[x], expect) << encodingName(format) << " k " << k << " width " << width << " x " << x;
            }
          }
  std::vector<int16_t> out(8);
  const cv::Mat mono(1, 8, CV_8UC1, cv::Scalar(9)), bayer(2, 8, CV_8UC1, cv::Scalar(9));
  fd::ColourModel model;
  EXPECT_FALSE(fd::rows::colourScoreRow(mono, mono, PixelFormat::kMono8, model, 192, 256, 0, out.data()));
  EXPECT_FALSE(fd::rows::colourScoreRow(bayer, bayer, PixelFormat::kBayerRggb8, model, 192, 256, 0, out.data()));
  const cv::Mat bgr(1, 8, CV_8UC3, cv::Scalar::all(9));
  EXPECT_FALSE(fd::rows::colourScoreRow(bgr, cv::Mat(), PixelFormat::kBgr8, model, 192, 256, 0, out.data()));
  EXPECT_FALSE(fd::rows::colourScoreRow(bgr, bgr, PixelFormat::kBgr8, model, 128 * 256, 256, 0, out.data()));
}

// The threshold pass's 8-bit interleaved rows (rows::colourRowRuns: 16
// pixels at a time, with SSSE3's byte shuffle where the CPU has it, and a
// scalar tail) against the score written out here: d = max(0, frame -
// ambient) per channel, s = d_signal - max((k_ref d_reference) >> 8,
// (k_third d_third) >> 8) saturated at 255, the cells with s >= threshold as
// runs and max(0, s) added to acc: random frames, bgr8, rgb8, bgra8 and
// rgba8 with and without an ambient frame, each projector colour's channels,
// every pass mode (weights below, at and above 256), widths 1-70 (every tail
// length, several 16-pixel groups).
TEST(SpotDetectorInputs, ColourRowRunsAreExact)
{
  namespace fd = structured_light_stabilizer::fast_detector;
  cv::RNG rng(6450);
  const PixelFormat formats[] = {PixelFormat::kBgr8, PixelFormat::kRgb8, PixelFormat::kBgra8, PixelFormat::kRgba8};
  const int channels[3][3] = {{1, 0, 2}, {0, 1, 2}, {2, 0, 1}};  // green, red, blue projectors
  int hits = 0;
  for (PixelFormat format : formats)
    for (bool with_ambient : {true, false})
      for (const auto& ch : channels)
        for (const cv::Vec2i& k : {cv::Vec2i(192, 256), cv::Vec2i(0, 256), cv::Vec2i(192, 200), cv::Vec2i(256, 0),
                                   cv::Vec2i(300, 256), cv::Vec2i(1000, 40), cv::Vec2i(32767, 300)})
          for (int width = 1; width <= 70; ++width)
          {
            const int type = CV_MAKETYPE(CV_8U, channelCount(format));
            cv::Mat image(2, width, type), ambient(2, width, type);
            rng.fill(image, cv::RNG::UNIFORM, 0, 256);
            rng.fill(ambient, cv::RNG::UNIFORM, 0, 96);
            fd::ColourModel model;
            model.signal = ch[0];
            model.reference = ch[1];
            model.third = ch[2];
            const int threshold = 1 + rng.uniform(0, 120);
            std::vector<fd::Run> runs;
            std::vector<uint16_t> acc(width), expect_acc(width);
            for (int x = 0; x < width; ++x)
              acc[x] = expect_acc[x] = static_cast<uint16_t>(rng.uniform(0, 4096));
            ASSERT_TRUE(fd::rows::colourRowRuns(image, with_ambient ? ambient : cv::Mat(), format, model, k[0], k[1],
                                                threshold, 1, &runs, acc.data()));
            const fd::pixels::Interleaved L = fd::pixels::interleavedLayout(format);
            const int offset[3] = {L.r, L.g, L.b};
            std::vector<fd::Run> expect;
            for (int x = 0; x < width; ++x)
            {
              int d[3];
              for (int c = 0; c < 3; ++c)
                d[c] = std::max(0, image.ptr<uint8_t>(1)[L.bytes * x + offset[c]] -
                                       (with_ambient ? ambient.ptr<uint8_t>(1)[L.bytes * x + offset[c]] : 0));
              const int s =
                  d[ch[0]] - std::max(std::min(255, (k[0] * d[ch[1]]) >> 8), std::min(255, (k[1] * d[ch[2]]) >> 8));
              expect_acc[x] = static_cast<uint16_t>(expect_acc[x] + std::max(0, s));
              if (s >= threshold)
                fd::rows::markCell(&expect, 1, x);
            }
            const auto name = [&]
            {
              return std::string(encodingName(format)) + " k " + std::to_string(k[0]) + "/" + std::to_string(k[1]) +
                     " width " + std::to_string(width);
            };
            ASSERT_EQ(acc, expect_acc) << name();
            ASSERT_EQ(runs.size(), expect.size()) << name();
            for (size_t i = 0; i < runs.size(); ++i)
            {
              ASSERT_EQ(runs[i].y, expect[i].y) << name();
              ASSERT_EQ(runs[i].x0, expect[i].x0) << name();
              ASSERT_EQ(runs[i].x1, expect[i].x1) << name();
              hits += runs[i].x1 - runs[i].x0 + 1;
            }
          }
  EXPECT_GT(hits, 10000);  // the comparison saw hits, not only empty rows
}

// A mono16 frame is read at its full depth: the same scene as mono8 x 257
// gives the same spots.
TEST(SpotDetectorInputs, Mono16IsMono8Scaled)
{
  synthetic_dots::Config cfg;
  cfg.width = cfg.height = 300;
  cfg.rows = cfg.cols = 5;
  cfg.sun = 0.0;
  cfg.output = synthetic_dots::Output::kMono8;
  cfg.projector = synthetic_dots::Projector::kNir;
  cfg.seed = 6200;
  const synthetic_dots::Frame f = synthetic_dots::render(cfg);
  cv::Mat wide;
  f.image.convertTo(wide, CV_16U, 257.0);
  SpotDetectorParams p;
  p.projector_color = ProjectorColor::kNir;
  SpotDetector det(p);
  const Spots a = det.detect(f.image, PixelFormat::kMono8).spots;
  const Spots b = det.detect(wide, PixelFormat::kMono16).spots;
  ASSERT_EQ(a.size(), f.dots.size());
  ASSERT_EQ(b.size(), a.size());
  for (size_t i = 0; i < a.size(); ++i)
  {
    EXPECT_NEAR(a[i].x, b[i].x, 1e-6);
    EXPECT_NEAR(a[i].y, b[i].y, 1e-6);
  }
}

namespace
{
// A small sunlit frame of the independent generator with its projector-off
// frame (bgr8, 5 x 5 dots).
synthetic_dots::Frame sunlitWithAmbient(uint32_t seed)
{
  synthetic_dots::Config cfg;
  cfg.width = cfg.height = 320;
  cfg.rows = cfg.cols = 5;
  cfg.sun = 1.0;
  cfg.ambient_frame = true;
  cfg.seed = seed;
  return synthetic_dots::render(cfg);
}
}  // namespace

// An ambient estimate kept unrounded (CV_32F, AmbientCompensationParams::
// unrounded): holding the 8-bit frame's own values it gives the same spots as
// that frame; non-finite values do no harm (they read as 0); a float ambient
// of another channel count or for a 16-bit or Bayer frame is refused with a
// reason.
TEST(SpotDetectorInputs, UnroundedAmbientEstimate)
{
  const synthetic_dots::Frame f = sunlitWithAmbient(6300);
  ASSERT_EQ(f.ambient.type(), CV_8UC3);
  SpotDetector det;
  cv::Mat fine;
  f.ambient.convertTo(fine, CV_32F);
  const SpotDetectionResult a = det.detect(f.image, f.ambient, PixelFormat::kBgr8);
  const SpotDetectionResult b = det.detect(f.image, fine, PixelFormat::kBgr8);
  ASSERT_TRUE(a.ok && b.ok) << a.error << b.error;
  ASSERT_EQ(a.spots.size(), f.dots.size());
  ASSERT_EQ(b.spots.size(), a.spots.size());
  for (size_t i = 0; i < a.spots.size(); ++i)
  {
    EXPECT_NEAR(a.spots[i].x, b.spots[i].x, 1e-5);
    EXPECT_NEAR(a.spots[i].y, b.spots[i].y, 1e-5);
  }
  cv::Mat holed = fine.clone();
  holed(cv::Rect(100, 100, 60, 60)).setTo(cv::Scalar::all(std::nan("")));
  const SpotDetectionResult c = det.detect(f.image, holed, PixelFormat::kBgr8);
  ASSERT_TRUE(c.ok) << c.error;
  for (const Spot& s : c.spots)
    EXPECT_TRUE(std::isfinite(s.x) && std::isfinite(s.y));
  struct Bad
  {
    cv::Mat image, ambient;
    PixelFormat format;
  };
  const Bad bad[] = {
      {f.image, cv::Mat(f.image.size(), CV_32FC1, cv::Scalar(1)), PixelFormat::kBgr8},
      {cv::Mat(64, 64, CV_16UC1, cv::Scalar(100)), cv::Mat(64, 64, CV_32FC1, cv::Scalar(1)), PixelFormat::kMono16},
      {cv::Mat(64, 64, CV_8UC1, cv::Scalar(100)), cv::Mat(64, 64, CV_32FC1, cv::Scalar(1)), PixelFormat::kBayerRggb8},
  };
  for (const Bad& k : bad)
  {
    const SpotDetectionResult r = det.detect(k.image, k.ambient, k.format);
    EXPECT_FALSE(r.ok) << encodingName(k.format);
    EXPECT_NE(r.error.find("ambient"), std::string::npos) << r.error;
  }
}

// bgr16 and rgb16 (a colour camera of more than 8 bits) are read at their
// full depth: the same scene as bgr8 x 257 gives the same spots, with and
// without an ambient frame (simulator frames in bgr16/rgb16:
// SimulatorInputKinds).
TEST(SpotDetectorInputs, Colour16IsColour8Scaled)
{
  const synthetic_dots::Frame f = sunlitWithAmbient(6500);
  SpotDetector det;
  for (bool ambient : {false, true})
  {
    const Spots a = det.detect(f.image, ambient ? f.ambient : cv::Mat(), PixelFormat::kBgr8).spots;
    ASSERT_EQ(a.size(), f.dots.size());
    for (PixelFormat wide_format : {PixelFormat::kBgr16, PixelFormat::kRgb16})
    {
      cv::Mat wide, wide_ambient;
      f.image.convertTo(wide, CV_16U, 257.0);
      f.ambient.convertTo(wide_ambient, CV_16U, 257.0);
      if (wide_format == PixelFormat::kRgb16)
      {
        cv::cvtColor(wide, wide, cv::COLOR_BGR2RGB);
        cv::cvtColor(wide_ambient, wide_ambient, cv::COLOR_BGR2RGB);
      }
      const SpotDetectionResult b = det.detect(wide, ambient ? wide_ambient : cv::Mat(), wide_format);
      ASSERT_TRUE(b.ok) << b.error;
      ASSERT_EQ(b.spots.size(), a.size()) << encodingName(wide_format) << (ambient ? " with ambient" : "");
      for (size_t i = 0; i < a.size(); ++i)
      {
        EXPECT_NEAR(a[i].x, b.spots[i].x, 1e-5) << encodingName(wide_format);
        EXPECT_NEAR(a[i].y, b.spots[i].y, 1e-5) << encodingName(wide_format);
      }
    }
  }
}

TEST(SpotDetectorInputs, BadInputIsRefusedWithAReason)
{
  SpotDetector det;
  struct Case
  {
    cv::Mat image;
    PixelFormat format;
    const char* expect;
  };
  const Case cases[] = {
      {cv::Mat(8, 9, CV_8UC2), PixelFormat::kUyvy, "odd width"},
      {cv::Mat(1, 1, CV_8UC1), PixelFormat::kBayerRggb8, "Bayer"},
      {cv::Mat(8, 8, CV_8UC1), PixelFormat::kMono16, "16-bit"},
      {cv::Mat(8, 8, CV_16UC1), PixelFormat::kBayerGbrg8, "8-bit"},
      {cv::Mat(8, 8, CV_8UC3), PixelFormat::kYuyv, "channels"},
  };
  for (const Case& c : cases)
  {
    const SpotDetectionResult r = det.detect(c.image, c.format);
    EXPECT_FALSE(r.ok) << encodingName(c.format);
    EXPECT_NE(r.error.find(c.expect), std::string::npos) << r.error;
  }
  // Every name the nodelet may see maps to a format and back.
  for (const char* name : {"bgr8", "rgb8", "bgra8", "rgba8", "mono8", "mono16", "bayer_rggb8", "bayer_bggr8",
                           "bayer_gbrg8", "bayer_grbg8", "yuv422", "yuv422_yuy2", "bgr16", "rgb16"})
  {
    PixelFormat f;
    ASSERT_TRUE(pixelFormatFromEncoding(name, &f)) << name;
    EXPECT_EQ(std::string(encodingName(f)), name);
  }
  PixelFormat f;
  EXPECT_FALSE(pixelFormatFromEncoding("32FC1", &f));
  EXPECT_FALSE(pixelFormatFromEncoding("bayer_rggb16", &f));
  // The smallest Bayer frame, and tiny frames of every format, are read without harm.
  for (int k = 0; k <= static_cast<int>(PixelFormat::kRgb16); ++k)
  {
    const PixelFormat format = static_cast<PixelFormat>(k);
    const cv::Mat tiny(2, 2, matType(format), cv::Scalar::all(200));
    const SpotDetectionResult r = det.detect(tiny, tiny, format);
    EXPECT_TRUE(r.ok) << encodingName(format) << ": " << r.error;
    EXPECT_EQ(toBgr(tiny, format).size(), tiny.size()) << encodingName(format);
  }
}

// A frame of noise is never refused. With the local scores (a noise model
// and a significance test) it gives no dots, whatever its encoding. The
// fixed greenness (the default) finds a third of it above its threshold, more
// than a pattern of dots covers: the frame is scored against its local
// colour, and says so (before, 368-593 spots: the candidate budget). A frame
// with more significant candidates than the pattern can hold (dots among a
// thousand and more bright specks of the projector's colour) keeps the most
// significant, says so, and finds every dot.
TEST(SpotDetectorInputs, NoiseFramesAndTheCandidateBudget)
{
  SpotDetectorParams local;
  local.fast.local_colour = true;
  SpotDetector det_local(local), det_fixed;
  cv::RNG rng(7);
  for (const auto& k : {std::make_pair(PixelFormat::kBgr8, CV_8UC3), std::make_pair(PixelFormat::kUyvy, CV_8UC2),
                        std::make_pair(PixelFormat::kBayerRggb8, CV_8UC1)})
  {
    cv::Mat noise(1024, 1024, k.second);
    rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
    const SpotDetectionResult r = det_local.detect(noise, k.first);
    EXPECT_TRUE(r.ok) << encodingName(k.first) << ": " << r.error;
    // yuv422's pixel pairs share their chroma: its noise is not Gaussian, and
    // a few pairs stand out of it as dot-like colour.
    EXPECT_LE(r.spots.size(), k.first == PixelFormat::kUyvy ? 100u : 5u) << encodingName(k.first);
    const SpotDetectionResult f = det_fixed.detect(noise, k.first);
    EXPECT_TRUE(f.ok) << encodingName(k.first) << ": " << f.error;
    EXPECT_LE(f.spots.size(), 1000u) << encodingName(k.first);  // the budget: 10 x the 100 beams
    EXPECT_NE(f.note.find("scored against the local colour"), std::string::npos) << f.note;
    std::cout << "[ MEASURE ] noise frame, " << encodingName(k.first) << ": " << r.spots.size()
              << " spots with the local scores, " << f.spots.size() << " with the fixed greenness"
              << (f.note.empty() ? "" : " (" + f.note + ")") << "\n";
  }
  synthetic_dots::Config cfg;
  cfg.seed = 6300;
  cfg.green_specks = cfg.olive_minerals = cfg.green_blobs = 10;
  const synthetic_dots::Frame f = synthetic_dots::render(cfg);
  const SpotDetectionResult good = det_fixed.detect(f.image, PixelFormat::kBgr8);
  ASSERT_TRUE(good.ok) << good.error;
  EXPECT_TRUE(good.note.empty()) << good.note;
  EXPECT_EQ(test::score(good.spots, f.dots).recall(), 1.0);

  // The same frame with 1500 faint specks of the projector's colour, a
  // quarter of the dots' amplitude, scattered away from the dots.
  cv::Mat crowded = f.image.clone();
  int added = 0;
  for (int tries = 0; added < 1500 && tries < 100000; ++tries)
  {
    const double cy = rng.uniform(8.0, crowded.rows - 8.0),
                 cx = rng.uniform(8.0, crowded.cols - 8.0);  // sequenced draws (docs/testing.md)
    const cv::Point2d c(cx, cy);
    bool near = false;
    for (const cv::Point2d& d : f.dots)
      near = near || std::hypot(d.x - c.x, d.y - c.y) < 12.0;
    if (near)
      continue;
    cv::circle(crowded, cv::Point(cvRound(c.x), cvRound(c.y)), 1, cv::Scalar(0, 40, 0), cv::FILLED);
    ++added;
  }
  SpotDetectorParams small;
  small.fast.max_candidates = 200;  // the budget: max(200, 10 x the beams)
  small.projector_rows = small.projector_cols = 4;
  SpotDetector few(small);
  const SpotDetectionResult r = few.detect(crowded, PixelFormat::kBgr8);
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_NE(r.note.find("most significant"), std::string::npos) << r.note;
  EXPECT_EQ(test::score(r.spots, f.dots).recall(), 1.0);
}
