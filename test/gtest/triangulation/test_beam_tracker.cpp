// BeamTracker: when the previous frame's result is handed to the
// Triangulator as the tracking prior, and when it is forgotten (stamp gap,
// stamps going backwards, a new Triangulator object, tracking off, reset).
#include <memory>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "support/triangulator_scene.h"

using namespace structured_light_stabilizer;

namespace
{

class BeamTrackerTest : public ::testing::Test
{
protected:
  BeamTrackerTest()
  {
    const CameraModel cam = CameraModel::studyDesign();
    const ProjectorCalibration proj = sls_test::simLikeProjector(0.087);
    tri_ = std::make_shared<const Triangulator>(cam, proj);
    other_ = std::make_shared<const Triangulator>(cam, proj);
    sls_test::Scene scene;
    scene.distance = 1.4;
    scene.relief = 0.1;
    sls_test::FrameOptions fo;
    fo.noise_px = 0.04;
    fo.drop_fraction = 0.1;
    fo.clutter = 5;
    spots_ = sls_test::makeFrame(cam, proj, scene, fo).spots;
  }

  // The results agree on what the tracker could have changed.
  static void expectSame(const TriangulationResult& a, const TriangulationResult& b)
  {
    EXPECT_EQ(a.beam_of_spot, b.beam_of_spot);
    EXPECT_EQ(a.tracked, b.tracked);
    EXPECT_EQ(a.ambiguous, b.ambiguous);
    EXPECT_EQ(a.valid_points, b.valid_points);
  }

  std::shared_ptr<const Triangulator> tri_, other_;
  Spots spots_;
};

}  // namespace

TEST_F(BeamTrackerTest, FirstFrameStandsAlone)
{
  BeamTracker tracker;
  EXPECT_EQ(tracker.priorFor(tri_, 10.0), nullptr);
  const TriangulationResult r = tracker.process(tri_, spots_, 10.0);
  EXPECT_EQ(r.tracked, -1);
  expectSame(r, tri_->process(spots_));
}

TEST_F(BeamTrackerTest, NextFrameUsesThePreviousResult)
{
  BeamTracker tracker;
  const TriangulationResult r0 = tracker.process(tri_, spots_, 10.0);
  ASSERT_NE(tracker.priorFor(tri_, 10.25), nullptr);
  const TriangulationResult r1 = tracker.process(tri_, spots_, 10.25);
  EXPECT_GE(r1.tracked, 50);
  expectSame(r1, tri_->process(spots_, &r0));
  // A gap of exactly tracking_reset_gap (0.5 s, exact in binary) still counts as consecutive.
  const TriangulationResult r2 = tracker.process(tri_, spots_, 10.75);
  EXPECT_GE(r2.tracked, 50);
  expectSame(r2, tri_->process(spots_, &r1));
}

TEST_F(BeamTrackerTest, StampGapOrStampGoingBackwardsForgets)
{
  BeamTracker tracker(BeamTrackerParams{true, 0.2});
  tracker.process(tri_, spots_, 10.0);
  EXPECT_EQ(tracker.priorFor(tri_, 10.3), nullptr);  // too far apart
  EXPECT_EQ(tracker.priorFor(tri_, 10.0), nullptr);  // the same stamp again
  EXPECT_EQ(tracker.priorFor(tri_, 9.9), nullptr);   // a bag looping
  EXPECT_NE(tracker.priorFor(tri_, 10.2), nullptr);
  EXPECT_EQ(tracker.process(tri_, spots_, 10.3).tracked, -1);
  // The frame after the gap is the new prior.
  EXPECT_GE(tracker.process(tri_, spots_, 10.4).tracked, 50);
}

TEST_F(BeamTrackerTest, NewTriangulatorObjectForgets)
{
  BeamTracker tracker;
  tracker.process(tri_, spots_, 10.0);
  EXPECT_EQ(tracker.priorFor(other_, 10.1), nullptr);
  EXPECT_EQ(tracker.process(other_, spots_, 10.1).tracked, -1);
  EXPECT_GE(tracker.process(other_, spots_, 10.2).tracked, 50);
  EXPECT_EQ(tracker.priorFor(tri_, 10.3), nullptr);
}

TEST_F(BeamTrackerTest, TrackingOffOrResetForgets)
{
  BeamTracker tracker;
  tracker.process(tri_, spots_, 10.0);
  tracker.setParams(BeamTrackerParams{false, 0.5});
  EXPECT_EQ(tracker.priorFor(tri_, 10.1), nullptr);
  EXPECT_EQ(tracker.process(tri_, spots_, 10.1).tracked, -1);
  // Turned on again: the frames processed while off left nothing behind.
  tracker.setParams(BeamTrackerParams());
  EXPECT_EQ(tracker.priorFor(tri_, 10.2), nullptr);
  tracker.process(tri_, spots_, 10.2);
  EXPECT_NE(tracker.priorFor(tri_, 10.3), nullptr);
  tracker.reset();
  EXPECT_EQ(tracker.priorFor(tri_, 10.3), nullptr);
}
