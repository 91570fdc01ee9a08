// Splitting a strobed stream (strobe_demux.h) on simulator frames with the
// truth of which frames had the projector on: by parity with the phase
// found from the images (also after a dropped frame and with the dots at
// 30 % of the sunlit rock), with lost frames counted from the stamps' gaps, and by the projector's pulse times (pulses
// before or after the frames, a frame without pulse information dropped).
#include <algorithm>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/strobe_demux.h"

using namespace structured_light_stabilizer;

namespace
{

struct Stream
{
  std::vector<cv::Mat> images;
  std::vector<double> stamps;
  std::vector<bool> on;
};

// `n` frames at 30 Hz, the projector on in the frames where index % 2 ==
// on_parity, the rig moving; the frames in `lost` lost in transit; each
// stamp off its exposure by up to +-jitter frame periods (uniform; a
// software stamp taken on arrival).
Stream strobedStream(int n, int on_parity, const std::vector<int>& lost, double dot_to_sun, double jitter = 0.0)
{
  cv::RNG rng(5);
  SimulatorParams p;
  applySimRadiometry(studySimRadiometry(), &p);  // the historical camera; the ratio below
  p.rock.seed = 21;
  p.lighting.sun_level = 1.0;
  p.lighting.dot_to_sun_ratio = dot_to_sun;
  p.motion.jitter_translation_m = 0.002;
  p.motion.jitter_rotation_rad = 0.001;
  p.motion.drift_velocity_mps = Eigen::Vector3d(0.02, 0.0, 0.0);
  const Simulator sim(p);
  Stream s;
  for (int i = 0; i < n; ++i)
  {
    if (std::find(lost.begin(), lost.end(), i) != lost.end())
      continue;
    FrameRequest r;
    r.projector_on = i % 2 == on_parity;
    s.images.push_back(sim.render(i / 30.0, r).image);
    s.stamps.push_back((i + rng.uniform(-jitter, jitter)) / 30.0);
    s.on.push_back(r.projector_on);
  }
  return s;
}

// Parity: each frame of the stream through the demux, true where it was
// routed to the wrong topic.
std::vector<bool> misrouted(StrobeDemux* demux, const Stream& s)
{
  std::vector<bool> wrong;
  for (size_t i = 0; i < s.images.size(); ++i)
  {
    const std::vector<StrobedFrame> out = demux->push(s.images[i], s.stamps[i]);
    EXPECT_EQ(out.size(), 1u);
    wrong.push_back(out.empty() || out[0].projector_on != s.on[i]);
  }
  return wrong;
}

}  // namespace

TEST(StrobeDemux, ParityFindsThePhaseAndRecoversAfterADroppedFrame)
{
  // Started on the wrong phase (the first frame is ambient), and frame 20
  // lost; the stamps not read (the vote alone recovers).
  const Stream s = strobedStream(44, 1, {20}, 0.3);
  StrobeDemuxParams p;
  p.phase = 0;
  p.stamp_gaps = false;
  StrobeDemux demux(p);
  const std::vector<bool> mistaken = misrouted(&demux, s);
  int wrong_after_settling = 0, wrong = 0;
  for (size_t i = 0; i < mistaken.size(); ++i)
  {
    wrong += mistaken[i];
    // Settling: the vote needs a majority of its window after the start and after the loss.
    if ((i >= 10 && i < 20) || i >= 30)
      wrong_after_settling += mistaken[i];
  }
  std::cout << "[ MEASURE ] parity: " << wrong << " of " << s.images.size()
            << " frames misrouted while the vote settled, last pair score " << demux.lastScore() << "\n";
  EXPECT_EQ(wrong_after_settling, 0);
  EXPECT_LE(wrong, 20);
}

TEST(StrobeDemux, FixedPhaseWithoutVoting)
{
  const Stream s = strobedStream(6, 0, {}, 0.3);
  StrobeDemuxParams p;
  p.auto_phase = false;
  StrobeDemux demux(p);
  for (size_t i = 0; i < s.images.size(); ++i)
    EXPECT_EQ(demux.push(s.images[i], s.stamps[i])[0].projector_on, s.on[i]);
}

// Frames lost one, two and three in a row (an odd and an even number), the
// stamps jittered by +-0.2 of a period: the gaps in the stamps keep the
// alternation, so after the vote found the phase at the start no frame is
// misrouted, and with the phase given no frame at all.
TEST(StrobeDemux, ParityCountsTheFramesLostFromTheStamps)
{
  const std::vector<int> lost{14, 21, 22, 31, 32, 33, 40};
  const Stream s = strobedStream(52, 1, lost, 0.3, 0.2);
  for (const bool auto_phase : {true, false})
  {
    StrobeDemuxParams p;
    p.phase = auto_phase ? 0 : 1;  // auto: started on the wrong phase
    p.auto_phase = auto_phase;
    StrobeDemux demux(p);
    const std::vector<bool> mistaken = misrouted(&demux, s);
    const int wrong_at_start = static_cast<int>(std::count(mistaken.begin(), mistaken.begin() + 10, true));
    const int wrong = static_cast<int>(std::count(mistaken.begin() + 10, mistaken.end(), true));
    std::cout << "[ MEASURE ] parity from stamps (auto_phase " << auto_phase << "): " << wrong_at_start
              << " misrouted in the first 10 frames, " << wrong << " after, " << demux.missedExposures()
              << " exposures counted as lost (truth " << lost.size() << ")\n";
    EXPECT_EQ(demux.missedExposures(), static_cast<long>(lost.size()));
    EXPECT_EQ(wrong, 0);
    if (!auto_phase)
    {
      EXPECT_EQ(wrong_at_start, 0);
    }
  }
}

// Jittered stamps (+-0.24 of a period) with no frame lost count no loss; a
// stamp that goes back (a bag replayed in a loop) counts none either.
TEST(StrobeDemux, JitterAndStampsGoingBackAreNotLosses)
{
  StrobeDemux demux;
  const cv::Mat img(8, 8, CV_8UC1, cv::Scalar(1));
  cv::RNG rng(7);
  for (int i = 0; i < 300; ++i)
    demux.push(img, (i + rng.uniform(-0.24, 0.24)) / 30.0);
  EXPECT_EQ(demux.missedExposures(), 0);
  for (int i = 0; i < 10; ++i)
    demux.push(img, i / 30.0);
  EXPECT_EQ(demux.missedExposures(), 0);
  // A pause of two seconds is left to the vote (more than 30 frames).
  demux.push(img, 12.0);
  EXPECT_EQ(demux.missedExposures(), 0);
}

TEST(StrobeDemux, PulseTimesBeforeOrAfterTheFrames)
{
  StrobeDemuxParams p;
  p.mode = StrobeMode::kTrigger;
  p.tolerance_s = 0.004;
  p.wait_s = 0.2;
  StrobeDemux demux(p);
  const cv::Mat img(8, 8, CV_8UC1, cv::Scalar(1));
  // The pulse of frame 0 arrives before it; frame 1 (ambient) waits until
  // the pulse of frame 2 shows that none came for it.
  EXPECT_TRUE(demux.addPulse(0.001).empty());
  std::vector<StrobedFrame> out = demux.push(img, 0.0);
  ASSERT_EQ(out.size(), 1u);
  EXPECT_TRUE(out[0].projector_on);
  EXPECT_TRUE(demux.push(img, 1 / 30.0).empty());
  EXPECT_TRUE(demux.push(img, 2 / 30.0).empty());
  out = demux.addPulse(2 / 30.0 + 0.002);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_FALSE(out[0].projector_on);
  EXPECT_TRUE(out[1].projector_on);
  EXPECT_EQ(out[1].index, 2);
  // No pulse information at all for 0.2 s: the frame is given up.
  std::vector<StrobedFrame> dropped;
  EXPECT_TRUE(demux.push(img, 3 / 30.0, &dropped).empty());
  out = demux.push(img, 3 / 30.0 + 0.25, &dropped);
  EXPECT_EQ(dropped.size(), 1u);
  EXPECT_TRUE(out.empty());  // the newer one still waits
}

TEST(StrobeDemux, BadParams)
{
  StrobeDemuxParams p;
  p.votes = 4;
  EXPECT_FALSE(p.validate().empty());
  p.votes = 9;
  p.phase = 2;
  EXPECT_FALSE(p.validate().empty());
  p.phase = 0;
  p.tolerance_s = 0.0;
  EXPECT_FALSE(p.validate().empty());
  // Frames of another size score 0 (no vote) instead of failing.
  EXPECT_EQ(strobePairScore(cv::Mat(4, 4, CV_8UC1), cv::Mat(5, 4, CV_8UC1)), 0.0);
}
