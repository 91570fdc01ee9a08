// Accuracy of PoseDelta on the simulator across seeds (rock, sensor noise,
// lock instant): the cases (rough rock 0.15 m and a flat textured
// board, rig jitter 10 mm / 1 deg), per axis, with the 1-sigma the estimator
// reports next to the error it makes.
//
// Usage: evaluate_pose_delta [seeds (default 4)] [frames per seed (default 30)]
//        [point noise along the ray, m (default 0.5e-3)]
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <iostream>
#include <random>

#include "structured_light_stabilizer/pose_delta.h"
#include "structured_light_stabilizer/sim/simulator.h"

using namespace structured_light_stabilizer;

namespace
{
constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Sums
{
  Vector6d err2 = Vector6d::Zero();    // mm^2, deg^2
  Vector6d sigma2 = Vector6d::Zero();  // reported variances, same units
  double t2 = 0, r2 = 0;
  int frames = 0, valid = 0;
  void add(const Sums& o)
  {
    err2 += o.err2;
    sigma2 += o.sigma2;
    t2 += o.t2;
    r2 += o.r2;
    frames += o.frames;
    valid += o.valid;
  }
  void print(const std::string& what) const
  {
    const double n = std::max(frames, 1);
    std::cout << std::fixed << std::setprecision(3) << what << ": t " << std::sqrt(t2 / n) << " mm, r "
              << std::setprecision(4) << std::sqrt(r2 / n) << " deg, valid " << std::setprecision(1)
              << 100.0 * valid / n << " %; err/sigma tx ty tz (mm) rx ry rz (deg):" << std::setprecision(3);
    for (int a = 0; a < 6; ++a)
      std::cout << " " << std::sqrt(err2[a] / n) << "/" << std::sqrt(sigma2[a] / n);
    std::cout << "\n";
  }
};

Sums runOne(double relief, bool texture, uint32_t seed, int frames, double noise_m)
{
  SimulatorParams c;
  c.rock.relief_m = relief;
  c.rock.seed = seed;
  c.noise_seed = 42 + seed;
  c.motion.jitter_translation_m = 0.010;
  c.motion.jitter_rotation_rad = 1.0 * kDeg;
  const Simulator sim(c);
  PoseDeltaParams cfg;
  cfg.use_texture = texture;
  PoseDeltaEstimator est(cfg);
  est.setCamera(sim.camera());
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  auto input = [&](const SimFrame& f)
  {
    PoseDeltaInput in;
    in.rows = c.projector.rows;
    in.cols = c.projector.cols;
    in.points = f.points;
    for (Eigen::Vector3d& p : in.points)
      if (p.allFinite() && noise_m > 0.0)
        p += noise_m * n01(rng) * p.normalized();
    in.image = f.image;
    in.texture_channel = 2;
    return in;
  };
  // Lock at a seed-dependent instant, as the rostest does (not at rest).
  const double t_lock = 0.37 * (seed - 1);
  const SimFrame f0 = sim.render(t_lock);
  est.process(input(f0));
  Sums s;
  for (int k = 1; k <= frames; ++k)
  {
    const SimFrame f = sim.render(t_lock + 0.1 * k);
    const PoseDeltaResult r = est.process(input(f));
    const Eigen::Isometry3d truth = f.delta * f0.delta.inverse();
    const Eigen::Isometry3d E = r.transform * truth.inverse();
    const Eigen::Vector3d et = E.translation() * 1e3, er = logSO3(E.linear()) / kDeg;
    for (int a = 0; a < 3; ++a)
    {
      s.err2[a] += et[a] * et[a];
      s.err2[a + 3] += er[a] * er[a];
      s.sigma2[a] += r.covariance(a, a) * 1e6;
      s.sigma2[a + 3] += r.covariance(a + 3, a + 3) / (kDeg * kDeg);
    }
    if (!r.valid)
      std::cout << "    frame " << k << ": error " << et.transpose() << " mm " << er.transpose() << " deg; " << r.status
                << "\n";
    s.t2 += et.squaredNorm();
    s.r2 += er.squaredNorm();
    s.valid += r.valid ? 1 : 0;
  }
  s.frames = frames;
  return s;
}
}  // namespace

int main(int argc, char** argv)
{
  const int seeds = argc > 1 ? std::max(1, std::atoi(argv[1])) : 4;
  const int frames = argc > 2 ? std::max(1, std::atoi(argv[2])) : 30;
  const double noise = argc > 3 ? std::atof(argv[3]) : 0.5e-3;
  struct Case
  {
    const char* name;
    double relief;
    bool texture;
  };
  const Case cases[] = {{"rough rock", 0.15, true}, {"flat board", 0.0, true}};
  for (const Case& c : cases)
  {
    Sums all;
    for (int s = 1; s <= seeds; ++s)
    {
      const Sums one = runOne(c.relief, c.texture, static_cast<uint32_t>(s), frames, noise);
      one.print(std::string("  ") + c.name + " seed " + std::to_string(s));
      all.add(one);
    }
    all.print(std::string(c.name) + " all seeds");
  }
  return 0;
}
