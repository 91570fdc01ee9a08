// Benchmark of the whole PoseDelta stage on one core: 100 beam points (400 in the 20 x 20 cases) and a
// 1024 x 1024 bgr8 image per frame (texture tracking included), simulator
// frames rendered beforehand so that only the estimator is timed.
//
// Usage: benchmark_pose_delta [frames (default 40)] [case (0-7, default all; -1 all)]
//        [seconds between frames (default 0.1; 0.0333 for 30 Hz)]
//        [texture_motion_prediction_max_px (default the parameter's; 0 = always the coarse track)]
// Prints per case the time per frame, the valid frames, the frames whose
// texture was refined from the motion filter's prediction, and the error of
// the valid estimates against the simulator's true motion (RMS, mm and deg).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <iostream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/pose/pose_delta.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

using namespace structured_light_stabilizer;

int main(int argc, char** argv)
{
  const int frames = argc > 1 ? std::max(2, std::atoi(argv[1])) : 40;
  cv::setNumThreads(1);

  struct Case
  {
    const char* name;
    double relief_m;
    bool use_texture;
    PoseDeltaMode mode;
    int grid = 10;  // beams per row and column over the same field
  };
  const Case cases[] = {{"rough rock 0.15 m, texture on ", 0.15, true, PoseDeltaMode::kReference},
                        {"rough rock 0.15 m, texture off", 0.15, false, PoseDeltaMode::kReference},
                        {"flat board, texture on        ", 0.0, true, PoseDeltaMode::kReference},
                        // Every valid frame becomes the reference (features chosen anew).
                        {"rough rock, frame_to_frame    ", 0.15, true, PoseDeltaMode::kFrameToFrame},
                        // More relief does not let geometry alone pin the in-plane axes: the
                        // interpolation between the dots misses more (texture off 0 of 40 valid).
                        {"rougher rock 0.4 m, texture on ", 0.4, true, PoseDeltaMode::kReference},
                        {"rougher rock 0.4 m, texture off", 0.4, false, PoseDeltaMode::kReference},
                        // Denser beams do: 20 x 20 over the same field, where texture off is
                        // valid on most frames, the yardstick of the texture's cost.
                        {"rock 0.15 m, 20x20 beams, texture on ", 0.15, true, PoseDeltaMode::kReference, 20},
                        {"rock 0.15 m, 20x20 beams, texture off", 0.15, false, PoseDeltaMode::kReference, 20}};
  constexpr int kCases = sizeof(cases) / sizeof(cases[0]);
  const int only = argc > 2 ? std::atoi(argv[2]) : -1;
  const double dt = argc > 3 && std::atof(argv[3]) > 0.0 ? std::atof(argv[3]) : 0.1;
  const double motion_px = argc > 4 ? std::atof(argv[4]) : PoseDeltaParams().texture_motion_prediction_max_px;
  for (int ci = 0; ci < kCases; ++ci)
  {
    const Case& c = cases[ci];
    if (only >= 0 && ci != only)
      continue;
    SimulatorParams sc;
    sc.rock.relief_m = c.relief_m;
    sc.projector.pitch_y_rad *= (sc.projector.rows - 1.0) / (c.grid - 1.0);
    sc.projector.pitch_x_rad *= (sc.projector.cols - 1.0) / (c.grid - 1.0);
    sc.projector.rows = sc.projector.cols = c.grid;
    sc.motion.jitter_translation_m = 0.010;
    sc.motion.jitter_rotation_rad = 1.0 * 3.14159265358979323846 / 180.0;
    const Simulator sim(sc);
    std::vector<PoseDeltaInput> inputs;
    std::vector<Eigen::Isometry3d> truth;
    for (int k = 0; k <= frames; ++k)
    {
      const SimFrame f = sim.render(dt * k);
      truth.push_back(f.delta);
      PoseDeltaInput in;
      in.stamp_s = dt * k;
      in.rows = sc.projector.rows;
      in.cols = sc.projector.cols;
      in.points = f.points;
      in.image = f.image;
      inputs.push_back(in);
    }
    PoseDeltaParams cfg;
    cfg.use_texture = c.use_texture;
    cfg.mode = c.mode;
    cfg.texture_motion_prediction_max_px = motion_px;
    PoseDeltaEstimator est(cfg);
    est.setCamera(sim.camera());

    auto t0 = std::chrono::steady_clock::now();
    est.process(inputs[0]);
    const double lock_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();

    std::vector<double> ms;
    int valid = 0, features = 0, iterations = 0, from_motion = 0;
    double sq_t = 0.0, sq_r = 0.0;
    std::string why;  // the first invalid frame's status
    const std::clock_t c0 = std::clock();
    for (int k = 1; k <= frames; ++k)
    {
      t0 = std::chrono::steady_clock::now();
      const PoseDeltaResult r = est.process(inputs[k]);
      ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      valid += r.valid ? 1 : 0;
      from_motion += r.texture_from_motion ? 1 : 0;
      if (r.valid)
      {
        const Eigen::Isometry3d e = truth[static_cast<size_t>(k)].inverse() * r.transform;
        sq_t += e.translation().squaredNorm();
        const double angle = Eigen::AngleAxisd(e.rotation()).angle();
        sq_r += angle * angle;
      }
      if (!r.valid && why.empty())
        why = r.status;
      features += r.features_used;
      iterations += r.iterations;
    }
    const double cpu_ms = 1000.0 * (std::clock() - c0) / CLOCKS_PER_SEC / frames;
    std::sort(ms.begin(), ms.end());
    double sum = 0.0;
    for (double v : ms)
      sum += v;
    std::cout << c.name << ": " << sum / frames << " ms/frame mean, " << ms[ms.size() / 2] << " median, "
              << ms[ms.size() * 95 / 100] << " p95 (wall), " << cpu_ms << " ms CPU; lock " << lock_ms << " ms; "
              << valid << "/" << frames << " valid, " << features / frames << " texture features/frame, "
              << static_cast<double>(iterations) / frames << " iterations/frame, " << from_motion
              << " from the motion filter";
    if (valid > 0)
      std::cout << "; error " << 1e3 * std::sqrt(sq_t / valid) << " mm / "
                << std::sqrt(sq_r / valid) * 180.0 / 3.14159265358979323846 << " deg RMS";
    std::cout << (why.empty() ? "" : "; first invalid: " + why) << "\n";
  }
  return 0;
}
