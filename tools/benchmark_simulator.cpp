// Benchmark of the scene simulator: milliseconds per rendered 1024 x 1024
// frame for a few representative configurations, on one thread and on
// OpenCV's default thread count (the CameraDriver's case).
//
// Usage: benchmark_simulator [frames=20] [output_dir]
// With an output directory, the first frame of each case is written as PNG.
#include <chrono>
#include <ctime>
#include <cstdlib>
#include <iostream>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

using structured_light_stabilizer::SimFrame;
using structured_light_stabilizer::Simulator;
using structured_light_stabilizer::SimulatorParams;
using structured_light_stabilizer::studySimulatorParams;

int main(int argc, char** argv)
{
  const int frames = argc > 1 ? std::max(1, std::atoi(argv[1])) : 20;
  const std::string out_dir = argc > 2 ? argv[2] : "";
  const int default_threads = cv::getNumThreads();

  struct Case
  {
    std::string name;
    SimulatorParams config = studySimulatorParams();
  };
  std::vector<Case> cases;
  {
    Case c{"default", studySimulatorParams()};
    c.config.motion.jitter_translation_m = 0.003;
    c.config.motion.jitter_rotation_rad = 0.002;
    cases.push_back(c);
  }
  {
    Case c{"night_flat", studySimulatorParams()};
    c.config.lighting.sun_level = 0.0;
    c.config.rock.relief_m = 0.0;
    cases.push_back(c);
  }
  {
    Case c{"bright_relief50_distorted_clutter", studySimulatorParams()};
    c.config.lighting.sun_level = 1.0;
    c.config.rock.relief_m = 0.5;
    c.config.sensor.camera.distortion = structured_light_stabilizer::DistortionModel::kPlumbBob;
    c.config.sensor.camera.D = {-0.12, 0.05, 0.0005, -0.0003, 0.0};
    c.config.clutter.green_specks = 200;
    c.config.clutter.olive_minerals = 60;
    c.config.clutter.green_blobs = 10;
    cases.push_back(c);
  }
  {
    // The options of docs/simulator.md that cost time when on: a Bayer
    // mosaic, column blooming of bright dots, 10 ms of motion blur.
    Case c{"bayer_blooming_motion_blur", SimulatorParams()};
    c.config.sensor.output = structured_light_stabilizer::SensorOutput::kBayerRggb8;
    c.config.sensor.blooming = structured_light_stabilizer::Blooming::kColumn;
    c.config.projector.power_scale = 3.0;
    c.config.sensor.exposure_time_s = 0.010;
    c.config.motion.jitter_translation_m = 0.003;
    c.config.motion.jitter_rotation_rad = 0.002;
    c.config.motion.drift_velocity_mps = Eigen::Vector3d(0.2, 0.0, 0.5);
    cases.push_back(c);
  }
  for (int threads : {1, default_threads})
  {
    cv::setNumThreads(threads);
    for (const Case& c : cases)
    {
      const auto t_build = std::chrono::steady_clock::now();
      Simulator sim(c.config);
      const double build_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_build).count();
      int visible = 0;
      const auto t0 = std::chrono::steady_clock::now();
      const std::clock_t c0 = std::clock();
      for (int i = 0; i < frames; ++i)
      {
        const SimFrame f = sim.render(i / 30.0);
        if (i == 0)
        {
          for (uint8_t v : f.visible)
            visible += v;
          if (!out_dir.empty() && threads == 1)
            cv::imwrite(out_dir + "/sim_" + c.name + ".png", f.image);
        }
      }
      const double ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / frames;
      // CPU time as well (all threads): on a shared machine the wall clock
      // includes waiting.
      const double cpu_ms = 1000.0 * (std::clock() - c0) / CLOCKS_PER_SEC / frames;
      std::cout << c.name << " (" << threads << (threads > 1 ? " threads" : " thread") << "): construction " << build_ms
                << " ms, render " << ms << " ms/frame wall, " << cpu_ms << " ms/frame CPU (" << frames << " frames, "
                << visible << " dots visible in frame 0)\n";
    }
  }
  return 0;
}
