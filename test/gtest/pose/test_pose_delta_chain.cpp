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
// used for tuning. Bounds per scene, pooled over the frames (RMS over the
// valid ones) and per frame (every valid frame).
#include <cmath>
#include <iostream>
#include <string>

#include <gtest/gtest.h>

#include "support/pose_delta_chain.h"

using namespace sls_test;

namespace
{
constexpr uint32_t kHeldOutSeeds[] = {11, 12};
constexpr int kFrames = 20;

struct Bounds
{
  double rms_t_mm, rms_r_deg;      // pooled RMS over the valid frames
  double frame_t_mm, frame_r_deg;  // every valid frame
  double min_valid;                // fraction of frames
};

ChainTally runScene(const std::string& name, double dt = 0.1)
{
  ChainTally all;
  for (uint32_t seed : kHeldOutSeeds)
  {
    std::string log;
    const ChainTally one = runChain(chainScene(name, seed), PoseDeltaParams(), 0.37 * seed, kFrames, dt, &log);
    std::cout << log;
    all.add(one);
  }
  std::cout << "[ MEASURE ] " << name << " (seeds 11, 12, " << all.frames << " frames): translation RMS "
            << all.rmsTmm() << " mm, rotation RMS " << all.rmsRdeg() << " deg over the valid frames, worst frame "
            << all.worst_t_mm << " mm / " << all.worst_r_deg << " deg, valid " << 100.0 * all.validFraction()
            << " %, wrong beams " << all.wrong_beams << " of " << all.points << "\n";
  return all;
}

void expectWithin(const ChainTally& t, const Bounds& b)
{
  EXPECT_GE(t.validFraction(), b.min_valid);
  EXPECT_LE(t.rmsTmm(), b.rms_t_mm);
  EXPECT_LE(t.rmsRdeg(), b.rms_r_deg);
  EXPECT_LE(t.worst_t_mm, b.frame_t_mm);
  EXPECT_LE(t.worst_r_deg, b.frame_r_deg);
}

// The acceptance: 0.5 mm and 0.02 deg RMS, 95 % valid; no valid
// frame beyond three times that.
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
  const ChainTally full = runScene("bgr16");
  const ChainTally rounded = runScene("bgr16_as_bgr8");
  expectWithin(full, kAcceptance);
  EXPECT_LE(full.rmsTmm(), 1.02 * rounded.rmsTmm());
  EXPECT_LE(full.rmsRdeg(), 1.02 * rounded.rmsRdeg());
}

TEST(PoseDeltaChain, StrobedAmbientFramesAt30Hz)
{
  expectWithin(runScene("strobed", 1.0 / 30.0), kAcceptance);
}

// Not within the 0.5 mm / 0.02 deg (docs/pose_delta.md#accuracy):
// with 5-6 % albedo the texture is the relief's shading at 2 DN against
// 1.1 DN of noise, darkened to half in the corners by vignetting, and the
// error lies in the tilt / in-plane translation pair that 100 dots 5 cm
// apart pin only to about 0.02 deg. The bound is what the design reaches
// (0.6-0.73 mm, 0.024-0.029 deg on seeds 1-2 and 11-12) with a margin; the
// reported covariance covers the error (checked per axis below).
TEST(PoseDeltaChain, StudysWorstSnr)
{
  const ChainTally t = runScene("worst_snr");
  expectWithin(t, Bounds{0.9, 0.035, 2.0, 0.08, 0.95});
  for (int a = 0; a < 6; ++a)
    EXPECT_LE(std::sqrt(t.axis2[a] / t.frames), 1.5 * std::sqrt(t.sigma2[a] / t.frames)) << "axis " << a;
}

TEST(PoseDeltaChain, TexturelessFlatBoardIsNeverValid)
{
  const ChainTally t = runScene("textureless");
  EXPECT_EQ(t.valid, 0);
  EXPECT_EQ(t.in_plane_unobservable, t.frames);  // tx, ty and rz named in every frame
}
