// PoseDelta from image to pose: simulator image -> SpotDetector
// -> Triangulator (with the BeamTracker's prior) -> PoseDeltaEstimator, rig
// jitter +-10 mm / +-1 deg, on the scenes (test/support/
// pose_delta_chain.h): a weakly textured rock (albedo features of 10-25 cm),
// a rough rock with 10 % of the dots missing, 6 clutter blobs per frame and
// wider dots, the study's worst SNR (full sun on 5-6 % albedo, small dots), a
// flat textured plane, a monochrome image, a 12-bit colour camera (bgr16),
// strobed operation (texture from
// the ambient frames around each frame, 30 Hz), and a textureless flat board.
//
// Seeds: the estimator was developed and tuned on rock/noise seeds 1-4
// (tools/evaluate_pose_delta); this test runs seeds 11 and 12 only, never
// used for tuning; `evaluate_pose_delta <scene> 11 2 20` prints the same
// runs (dt=1/30 for "strobed"). Bounds per scene on each seed (RMS over
// its valid frames, its share of valid frames), and per frame (every valid
// frame).
#include <cmath>
#include <iostream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "support/pose_delta_chain.h"

using namespace sls_test;

namespace
{
constexpr uint32_t kHeldOutSeeds[] = {11, 12};
constexpr int kFrames = 20;

struct Bounds
{
  double rms_t_mm, rms_r_deg;      // RMS over the valid frames, of each seed
  double frame_t_mm, frame_r_deg;  // every valid frame
  double min_valid;                // fraction of frames, of each seed
};

struct SceneRun
{
  std::vector<ChainTally> seeds;
  ChainTally all;
};

// `true_surface`: the reference surface from the simulator's rock
// (evaluate_pose_delta --true-surface image), an experiment.
SceneRun runScene(const std::string& name, double dt = 0.1,
                  ChainScene::TrueSurface true_surface = ChainScene::TrueSurface::kNone)
{
  SceneRun run;
  for (uint32_t seed : kHeldOutSeeds)
  {
    ChainScene scene = chainScene(name, seed);
    scene.true_surface = true_surface;
    std::string log;
    const ChainTally one = runChain(scene, PoseDeltaParams(), chainLockTime(seed), kFrames, dt, &log);
    const std::string label = name + (true_surface == ChainScene::TrueSurface::kNone ? "" : " (true surface)");
    std::cout << log << "[ MEASURE ] " << label << " seed " << seed << ": translation RMS " << one.rmsTmm()
              << " mm, rotation RMS " << one.rmsRdeg() << " deg over the valid frames, worst frame " << one.worst_t_mm
              << " mm / " << one.worst_r_deg << " deg, valid " << 100.0 * one.validFraction() << " %\n";
    run.seeds.push_back(one);
    run.all.add(one);
  }
  const ChainTally& all = run.all;
  std::cout << "[ MEASURE ] " << name << (true_surface == ChainScene::TrueSurface::kNone ? "" : " (true surface)")
            << " (seeds 11, 12, " << all.frames << " frames): translation RMS " << all.rmsTmm() << " mm, rotation RMS "
            << all.rmsRdeg() << " deg over the valid frames, worst frame " << all.worst_t_mm << " mm / "
            << all.worst_r_deg << " deg, valid " << 100.0 * all.validFraction() << " %, wrong beams " << all.wrong_beams
            << " of " << all.points << "\n";
  return run;
}

void expectWithin(const SceneRun& run, const Bounds& b)
{
  for (size_t k = 0; k < run.seeds.size(); ++k)
  {
    const ChainTally& t = run.seeds[k];
    EXPECT_GE(t.validFraction(), b.min_valid) << "seed " << kHeldOutSeeds[k];
    EXPECT_LE(t.rmsTmm(), b.rms_t_mm) << "seed " << kHeldOutSeeds[k];
    EXPECT_LE(t.rmsRdeg(), b.rms_r_deg) << "seed " << kHeldOutSeeds[k];
    EXPECT_LE(t.worst_t_mm, b.frame_t_mm) << "seed " << kHeldOutSeeds[k];
    EXPECT_LE(t.worst_r_deg, b.frame_r_deg) << "seed " << kHeldOutSeeds[k];
  }
}

// The acceptance: 0.5 mm and 0.02 deg RMS, 95 % valid, on every
// seed; no valid frame beyond three times that.
const Bounds kAcceptance{0.5, 0.02, 1.5, 0.06, 0.95};
}  // namespace

TEST(PoseDeltaChain, WeaklyTexturedRock)
{
  expectWithin(runScene("weak_texture"), kAcceptance);
}

TEST(PoseDeltaChain, MissingDotsAndClutter)
{
  expectWithin(runScene("missing_dots"), kAcceptance);
}

TEST(PoseDeltaChain, FlatTexturedPlane)
{
  expectWithin(runScene("flat_textured"), kAcceptance);
}

// A monochrome camera: PoseDelta gets mono8, where the dots are
// as bright as the rock's texture in the one channel there is.
TEST(PoseDeltaChain, MonochromeImage)
{
  expectWithin(runScene("mono"), kAcceptance);
}

// A 12-bit colour camera (bgr16, the recommended daylight rig's kind):
// PoseDelta reads the 16 bits without rounding them to 8 (its nodelet
// converted them to bgr8 before). On the default rock, seeds 1-4
// (evaluate_pose_delta): 0.196 mm / 0.0069 deg against 0.210 mm / 0.0076 deg
// from the same frames as bgr8.
TEST(PoseDeltaChain, TwelveBitCameraReadAtFullDepth)
{
  const SceneRun full = runScene("bgr16");
  const SceneRun rounded = runScene("bgr16_as_bgr8");
  expectWithin(full, kAcceptance);
  EXPECT_LE(full.all.rmsTmm(), 1.02 * rounded.all.rmsTmm());
  EXPECT_LE(full.all.rmsRdeg(), 1.02 * rounded.all.rmsRdeg());
}

TEST(PoseDeltaChain, StrobedAmbientFramesAt30Hz)
{
  expectWithin(runScene("strobed", 1.0 / 30.0), kAcceptance);
}

// Not within the 0.5 mm / 0.02 deg (docs/pose_delta.md#accuracy):
// with 5-6 % albedo the texture is the relief's shading at 2 DN against
// 1.1 DN of noise, darkened to half in the corners by vignetting, and the
// texture features' depths come from the surface interpolated between dots
// 5 cm apart. Bounded per seed at what the design reaches on seeds 11 and
// 12 (0.65 / 0.68 mm, 0.025 / 0.029 deg; worst frames 1.15 / 1.20 mm,
// 0.047 / 0.046 deg) with about 10 % margin. Seeds 11-20 spread over
// 0.53-0.94 mm (docs): a bound on other seeds would have to be wider. The
// reported covariance covers the error (checked per axis below).
const Bounds kWorstSnr{0.75, 0.032, 1.35, 0.055, 0.95};

TEST(PoseDeltaChain, StudysWorstSnr)
{
  const SceneRun run = runScene("worst_snr");
  expectWithin(run, kWorstSnr);
  const ChainTally& t = run.all;
  for (int a = 0; a < 6; ++a)
    EXPECT_LE(std::sqrt(t.axis2[a] / t.frames), 1.5 * std::sqrt(t.sigma2[a] / t.frames)) << "axis " << a;
}

// The experiment that isolates the design's part: the same frames with the
// reference surface from the simulator's rock (every texture feature at its
// true depth) meet the bound on each seed (0.30 / 0.37 mm,
// 0.011 / 0.014 deg on seeds 11 / 12), the image noise unchanged: the
// interpolated reference surface is what keeps the design above it (the
// noise, removed alone, takes as much: docs/pose_delta.md#accuracy).
TEST(PoseDeltaChain, StudysWorstSnrWithTheTrueReferenceSurface)
{
  expectWithin(runScene("worst_snr", 0.1, ChainScene::TrueSurface::kImage), kAcceptance);
}

TEST(PoseDeltaChain, TexturelessFlatBoardIsNeverValid)
{
  const ChainTally t = runScene("textureless").all;
  EXPECT_EQ(t.valid, 0);
  EXPECT_EQ(t.in_plane_unobservable, t.frames);  // tx, ty and rz named in every frame
}
