// "0 wrong beams" over long sequences: 2000 frames at 15 Hz of a
// rig approaching a rock from 2 m to 1 m and back while jittering (+-10 mm,
// +-1 deg per axis), 10 % of the dots missing at random in every frame and
// 20 projector-coloured spurious spots per frame (10 fixed on the rock, 10
// anywhere, new every frame), through BeamTracker with the tracking prior,
// for the rolled (5 deg) and the axis-aligned grid. Clutter is refused by
// geometry: the epipolar gate, the tracking prior (each dot predicted from
// its previous position, the pattern's affine motion and its neighbours'
// local flow, within 5 sigma of the measured spread, at least 0.6 px; a dot
// missing for up to 3 frames keeps its predicted position as its prior) and
// the neighbour check.
//
// A spurious spot within tracking_radius_px (1.5 px) of where a missing dot
// would be, inside its epipolar gate, is that dot's look-alike: it is where
// the dot is predicted to within the dots' own frame-to-frame motion, and
// for clutter of the projector's colour and size no detector tells them
// apart either. With ~9 missing dots and 20 spots per frame over a
// 1024 x 1024 image, an acceptance region of about 2 px^2 per missing dot
// (the radius the spread allows, 0.6-1.2 px, inside the 1 px gate) gives
// 9 * 20 * 2 / 1e6 = 4e-4 per frame, about 0.7 per sequence (measured 0-4,
// mean 1, over seeds 1-8 on both grids); they are
// counted apart and bounded. Anything else given to a beam is a wrong beam.
//
// Sequence seeds 1-2 were used to choose the radius (min 0.6 px, 5 sigma);
// seeds 3-4 are held out.
#include <cmath>
#include <iostream>
#include <memory>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "support/triangulator_scene.h"

using namespace structured_light_stabilizer;

namespace
{

struct SequenceTally
{
  long visible = 0, right = 0, wrong = 0, look_alikes = 0, close_look_alikes = 0;  // close: within 0.6 px
  int worst_frame_right_pct = 100;
};

SequenceTally runSequence(double roll, uint32_t seed, int frames)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
  sls_test::SequenceOptions o;
  o.seed = seed;
  const std::vector<Eigen::Vector3d> rock_points = sls_test::rockClutterPoints(cam, o, o.rock_clutter);
  const auto tri = std::make_shared<const Triangulator>(cam, proj);
  BeamTracker tracker;
  SequenceTally t;
  const double look_alike_px = tri->params().tracking_radius_px;
  for (int k = 0; k < frames; ++k)
  {
    const sls_test::Frame f = sls_test::sequenceFrame(cam, proj, o, k, rock_points);
    const TriangulationResult r = tracker.process(tri, f.spots, k / 15.0);
    std::vector<char> present(proj.beamCount(), 0);
    int frame_visible = 0, frame_right = 0;
    for (const Spot& s : f.spots)
      if (s.beam >= 0)
        present[s.beam] = 1;
    for (size_t j = 0; j < f.spots.size(); ++j)
    {
      const int truth = f.spots[j].beam, got = r.beam_of_spot[j];
      frame_visible += truth >= 0;
      frame_right += got >= 0 && got == truth;
      if (got < 0 || got == truth)
        continue;
      const double d = std::hypot(f.pixels[got].x - f.spots[j].x, f.pixels[got].y - f.spots[j].y);
      const bool look_alike = truth < 0 && !present[got] && d <= look_alike_px;
      (look_alike ? t.look_alikes : t.wrong) += 1;
      t.close_look_alikes += look_alike && d <= 0.6;
    }
    t.visible += frame_visible;
    t.right += frame_right;
    if (frame_visible > 0)
      t.worst_frame_right_pct = std::min(t.worst_frame_right_pct, 100 * frame_right / frame_visible);
  }
  return t;
}

}  // namespace

TEST(TriangulatorSequence, NoWrongBeamOver2000FramesWithClutterAndMissingDots)
{
  for (double roll : {0.087, 0.0})
    for (uint32_t seed : {3u, 4u})  // held out
    {
      const SequenceTally t = runSequence(roll, seed, 2000);
      std::cout << "[ MEASURE ] " << (roll > 0.0 ? "rolled" : "axis-aligned") << " grid, seed " << seed
                << ", 2000 frames, 10 % missing, 20 spurious spots per frame: " << t.right << " / " << t.visible
                << " dots right (" << 100.0 * t.right / t.visible << " %, worst frame " << t.worst_frame_right_pct
                << " %), " << t.wrong << " wrong, " << t.look_alikes << " look-alike(s) taken (" << t.close_look_alikes
                << " within 0.6 px)\n";
      EXPECT_EQ(t.wrong, 0);
      EXPECT_LE(t.look_alikes, 5);  // measured 0-4 per sequence over seeds 1-8 (mean ~1): P(> 5) < 0.1 %
      EXPECT_GE(t.right, 0.998 * t.visible);
      EXPECT_GE(t.worst_frame_right_pct, 90);
    }
}
