// Benchmark: milliseconds per frame of the Triangulator (identification +
// triangulation) on synthetic frames of the study's camera and the
// simulator's 10 x 10 projector: 10 % of the dots missing, 20 spurious
// spots, 0.04 px noise; rolled (5 deg) and axis-aligned grids, and the
// study's sort for comparison. Usage: bench_triangulator [frames]
#include <chrono>
#include <cstdlib>
#include <iostream>

#include "../test/gtest/triangulator_scene.h"
#include "structured_light_stabilizer/triangulator.h"

using namespace structured_light_stabilizer;

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
      TriangulatorOptions o;
      o.assignment = method;
      const Triangulator tri(cam, proj, o);
      long points = 0;
      const auto t0 = std::chrono::steady_clock::now();
      for (const auto& f : input)
        points += tri.process(f.spots).valid_points;
      const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      std::cout << "roll " << roll * 180.0 / M_PI << " deg, " << (method == BeamAssignment::kSort ? "sort    " : "epipolar")
                << ": " << ms / frames << " ms/frame, " << static_cast<double>(points) / frames
                << " points/frame\n";
    }
  }
  return 0;
}
