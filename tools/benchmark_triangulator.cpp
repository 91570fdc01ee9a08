// Benchmark: milliseconds per frame of the Triangulator (identification +
// triangulation) on synthetic frames of the study's camera and the
// simulator's 10 x 10 projector: 10 % of the dots missing, 20 spurious
// spots, 0.04 px noise; rolled (5 deg) and axis-aligned grids, and the
// study's sort for comparison; the epipolar method also with a tracking
// prior (the frame's own single-frame result); then sequences through
// BeamTracker (test_triangulator_sequence's scene: 1 -> 2 m, jitter, 10 %
// missing, 20 spurious spots per frame) with their wrong beams. Usage:
// benchmark_triangulator [frames]
#include <chrono>
#include <algorithm>
#include <cstdlib>
#include <vector>
#include <iostream>
#include <memory>

#include "support/triangulator_scene.h"
#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

using namespace structured_light_stabilizer;

namespace
{

// A moving rig through BeamTracker: ms per frame and identification.
void benchmarkSequences(int frames)
{
  const CameraModel cam = CameraModel::studyDesign();
  for (double roll : {0.087, 0.0})
  {
    const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
    sls_test::SequenceOptions o;
    o.seed = 9;
    const auto rock = sls_test::rockClutterPoints(cam, o, o.rock_clutter);
    std::vector<sls_test::Frame> input;
    for (int k = 0; k < frames; ++k)
      input.push_back(sls_test::sequenceFrame(cam, proj, o, k, rock));
    const auto tri = std::make_shared<const Triangulator>(cam, proj);
    BeamTracker tracker;
    std::vector<TriangulationResult> results;
    const auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < frames; ++k)
      results.push_back(tracker.process(tri, input[k].spots, k / 15.0));
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    long visible = 0, right = 0, wrong = 0;
    for (int k = 0; k < frames; ++k)
      for (size_t j = 0; j < input[k].spots.size(); ++j)
      {
        const int truth = input[k].spots[j].beam, got = results[k].beam_of_spot[j];
        visible += truth >= 0;
        right += got >= 0 && got == truth;
        wrong += got >= 0 && got != truth;
      }
    std::cout << "roll " << roll * 180.0 / M_PI << " deg, sequence with BeamTracker: " << ms / frames << " ms/frame, "
              << right << "/" << visible << " dots right (" << 100.0 * right / std::max(1L, visible) << " %), " << wrong
              << " wrong (look-alikes included)\n";
  }
}

}  // namespace

int main(int argc, char** argv)
{
  const int frames = argc > 1 ? std::atoi(argv[1]) : 200;
  const CameraModel cam = CameraModel::studyDesign();
  for (double roll : {0.087, 0.0})
  {
    const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
    std::vector<sls_test::Frame> input;
    for (int k = 0; k < frames; ++k)
    {
      sls_test::Scene scene;
      scene.distance = 1.0 + 0.1 * (k % 11);
      scene.relief = 0.15;
      scene.phase = 0.37 * k;
      sls_test::FrameOptions fo;
      fo.noise_px = 0.04;
      fo.drop_fraction = 0.1;
      fo.clutter = 20;
      fo.seed = 1 + k;
      input.push_back(sls_test::makeFrame(cam, proj, scene, fo));
    }
    for (BeamAssignment method : {BeamAssignment::kEpipolar, BeamAssignment::kSort})
    {
      TriangulatorParams o;
      o.assignment = method;
      const Triangulator tri(cam, proj, o);
      long points = 0;
      std::vector<TriangulationResult> results;
      results.reserve(input.size());
      auto t0 = std::chrono::steady_clock::now();
      for (const auto& f : input)
      {
        results.push_back(tri.process(f.spots));
        points += results.back().valid_points;
      }
      const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (method == BeamAssignment::kEpipolar)
      {
        // With the tracking prior in its steady state: the previous result
        // put every dot where it is now (no motion), so the prior settles the
        // beams first and the rest is solved around them.
        long tracked = 0;
        t0 = std::chrono::steady_clock::now();
        for (size_t k = 0; k < input.size(); ++k)
          tracked += std::max(0, tri.process(input[k].spots, &results[k]).tracked);
        const double ms_tracked =
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        std::cout << "roll " << roll * 180.0 / M_PI << " deg, epipolar + tracking prior: " << ms_tracked / frames
                  << " ms/frame, " << static_cast<double>(tracked) / frames << " beams/frame settled by the prior\n";
      }
      // Identification against the truth (spot.beam), outside the timing.
      long visible = 0, right = 0, wrong = 0;
      for (size_t k = 0; k < input.size(); ++k)
        for (size_t j = 0; j < input[k].spots.size(); ++j)
        {
          const int truth = input[k].spots[j].beam, got = results[k].beam_of_spot[j];
          visible += truth >= 0;
          right += got >= 0 && got == truth;
          wrong += got >= 0 && got != truth;
        }
      std::cout << "roll " << roll * 180.0 / M_PI << " deg, "
                << (method == BeamAssignment::kSort ? "sort    " : "epipolar") << ": " << ms / frames << " ms/frame, "
                << static_cast<double>(points) / frames << " points/frame, " << right << "/" << visible
                << " dots right (" << 100.0 * right / std::max(1L, visible) << " %), " << wrong << " wrong\n";
    }
  }
  benchmarkSequences(frames);
  return 0;
}
