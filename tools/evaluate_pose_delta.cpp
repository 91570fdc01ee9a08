// Accuracy of PoseDelta from image to pose on the simulator (the accuracy
// scenes of test/support/pose_delta_chain.h): simulator image -> SpotDetector ->
// Triangulator -> PoseDelta, rig jitter +-10 mm / +-1 deg, per seed and
// pooled, each axis's RMS error next to the 1-sigma the estimator reports.
//
// Usage: evaluate_pose_delta [scenes (comma list, default all)] [first seed (1)]
//        [seeds (4)] [frames per seed (30)] [name=value ...]
// dt=seconds sets the time between frames (default 0.1).
// name=value sets any PoseDeltaParams field (pose/pose_delta_params.def; bools 0/1, enums by name), e.g.
// use_texture=0 texture_refinement_window_px=31.
// Scenes: weak_texture, missing_dots, worst_snr, flat_textured, rough, textureless.
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "support/pose_delta_chain.h"

using namespace sls_test;

namespace
{

void print(const std::string& what, const ChainTally& s)
{
  const double n = std::max(s.frames, 1);
  std::cout << std::fixed << std::setprecision(3) << what << ": valid " << std::setprecision(1)
            << 100.0 * s.validFraction() << " %, over valid frames t " << std::setprecision(3) << s.rmsTmm()
            << " mm, r " << std::setprecision(4) << s.rmsRdeg() << " deg (worst " << std::setprecision(3)
            << s.worst_t_mm << " mm, " << std::setprecision(4) << s.worst_r_deg << " deg); all frames t "
            << std::setprecision(3) << std::sqrt(s.t2 / n) << " mm, r " << std::setprecision(4) << std::sqrt(s.r2 / n)
            << " deg; wrong beams " << s.wrong_beams << "/" << s.points
            << "; err/sigma tx ty tz (mm) rx ry rz (deg):" << std::setprecision(3);
  for (int a = 0; a < 6; ++a)
    std::cout << " " << std::sqrt(s.axis2[a] / n) << "/" << std::sqrt(s.sigma2[a] / n);
  std::cout << "; per frame: " << std::setprecision(0) << s.features / n << " features, sigma " << std::setprecision(3)
            << s.sigma_texture_px / n << " px, geometry " << s.sigma_geometry_mm / n << " mm\n";
}

std::vector<std::string> split(const std::string& list)
{
  std::vector<std::string> out;
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty())
      out.push_back(item);
  return out;
}

// name=value -> params (any field of pose/pose_delta_params.def); false
// when the name is unknown or the value does not read as its type.
bool setParam(const std::string& setting, PoseDeltaParams* p)
{
  const size_t eq = setting.find('=');
  return eq != std::string::npos && p->set(setting.substr(0, eq), setting.substr(eq + 1));
}

}  // namespace

int main(int argc, char** argv)
{
  const std::string scenes = argc > 1 ? argv[1] : "weak_texture,missing_dots,worst_snr,flat_textured,rough,textureless";
  const int first = argc > 2 ? std::max(1, std::atoi(argv[2])) : 1;
  const int seeds = argc > 3 ? std::max(1, std::atoi(argv[3])) : 4;
  const int frames = argc > 4 ? std::max(1, std::atoi(argv[4])) : 30;
  PoseDeltaParams params;
  double dt = 0.1;
  for (int a = 5; a < argc; ++a)
    if (std::string(argv[a]).rfind("dt=", 0) == 0)
      dt = std::atof(argv[a] + 3);
    else if (!setParam(argv[a], &params))
    {
      std::cerr << "unknown or bad setting: " << argv[a] << "\n";
      return 2;
    }
  for (const std::string& name : split(scenes))
  {
    ChainTally all;
    for (int s = first; s < first + seeds; ++s)
    {
      const uint32_t seed = static_cast<uint32_t>(s);
      std::string log;
      // Lock at a seed-dependent instant (not at rest), as the rostest does.
      const ChainTally one = runChain(chainScene(name, seed), params, 0.37 * (s - 1), frames, dt, &log);
      print("  " + name + " seed " + std::to_string(s), one);
      std::cout << log;
      all.add(one);
    }
    print(name + " all seeds", all);
  }
  return 0;
}
