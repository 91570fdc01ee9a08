// evaluate_validation: the core pipeline (SpotDetector with the nodelet's
// defaults, the Triangulator, PoseDelta locked on each sequence's first
// frame) on the path-traced validation set (test/data/validation/README.md,
// docs/validation.md), against its truth: one line per frame and noise seed,
// a pooled line per case.
//
//   evaluate_validation [--data DIR] [--case NAME[,NAME...]] [--half tuning|heldout|all]
//                       [--seeds A,B,...] [--encoding bgr8|bayer_rggb8|bgr16] [--strobe 0|1]
//                       [--param name=value]... [--projector FILE] [--match-px PX] [--noise 0|1]
//                       [--dump FILE.csv]
//
// --half: the cases of that half (default all; tune only on `tuning`).
// --strobe: overrides the cases' own (1: the detector gets the projector-off
// frames around each frame, motion-compensated, as its ambient). --param: any
// SpotDetectorParams field (e.g. fast.detect_threshold is `detect_threshold`),
// repeatable. --encoding bgr16: a 12-bit converter, MSB-aligned. --noise 0:
// no shot nor read noise (quantisation stays). --dump: every matched spot
// with its light centroid and hit pixel (full-frame px), and every false
// spot (beam -1), as CSV.
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "support/validation_run.h"

using namespace structured_light_stabilizer;
using namespace structured_light_stabilizer::test::validation;

namespace
{

std::vector<std::string> split(const std::string& csv)
{
  std::vector<std::string> v;
  std::stringstream ss(csv);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty())
      v.push_back(item);
  return v;
}

int usage(const std::string& why)
{
  std::fprintf(stderr, "evaluate_validation: %s\n", why.c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv)
{
  std::string data = std::string(SLS_SOURCE_DIR) + "/test/data/validation";
  std::string half = "all";
  std::vector<std::string> names;
  RunOptions o;
  o.projector_file = std::string(SLS_SOURCE_DIR) + "/config/projector_sim.yaml";
  for (int i = 1; i < argc; i += 2)
  {
    const std::string k = argv[i];
    if (i + 1 >= argc)
      return usage(k + " needs a value");
    const std::string v = argv[i + 1];
    if (k == "--data")
      data = v;
    else if (k == "--case")
      names = split(v);
    else if (k == "--half")
      half = v;
    else if (k == "--seeds")
    {
      o.seeds.clear();
      for (const std::string& s : split(v))
        o.seeds.push_back(std::strtoull(s.c_str(), nullptr, 10));
    }
    else if (k == "--encoding")
    {
      if (v != "bgr8" && v != "bayer_rggb8" && v != "bgr16")
        return usage("--encoding: bgr8, bayer_rggb8 or bgr16");
      pixelFormatFromEncoding(v, &o.output);
    }
    else if (k == "--strobe")
      o.strobe = v != "0";
    else if (k == "--param")
    {
      const size_t eq = v.find('=');
      if (eq == std::string::npos || !o.detector.set(v.substr(0, eq), v.substr(eq + 1)))
        return usage("--param " + v + ": not a SpotDetectorParams field=value");
    }
    else if (k == "--projector")
      o.projector_file = v;
    else if (k == "--match-px")
      o.match_px = std::atof(v.c_str());
    else if (k == "--noise")
      o.noise = v != "0";
    else if (k == "--dump")
    {
      o.dump = std::fopen(v.c_str(), "w");
      if (!o.dump)
        return usage("--dump: cannot write " + v);
      std::fprintf(o.dump, "case,seed,frame,beam,spot_x,spot_y,light_x,light_y,hit_x,hit_y\n");
    }
    else
      return usage("unknown option " + k);
  }
  if (half != "all" && half != "tuning" && half != "heldout")
    return usage("--half: tuning, heldout or all");
  for (const std::string& line : o.detector.sanitize())
    std::printf("detector params: %s\n", line.c_str());
  try
  {
    const ValidationSet set = loadValidationSet(data);
    int run = 0;
    for (const CaseSpec& c : set.cases)
    {
      if (half != "all" && c.half != half)
        continue;
      if (!names.empty() && std::find(names.begin(), names.end(), c.name) == names.end())
        continue;
      const bool strobe = o.strobe < 0 ? c.strobe : o.strobe != 0;
      std::printf("case %s (scene %s, %s, %s%s, %s half, %s):\n", c.name.c_str(), c.scene.c_str(), c.lighting.c_str(),
                  strobe ? "strobed" : "single frame",
                  c.min_dot_to_sun > 0
                      ? (", dots >= " + std::to_string(c.min_dot_to_sun).substr(0, 4) + " x the rock").c_str()
                      : "",
                  c.half.c_str(), encodingName(o.output));
      const CaseResult r = runCase(set, c, o, true);
      std::printf("  pooled: %s\n", r.pooled.line().c_str());
      std::fflush(stdout);
      ++run;
    }
    if (run == 0)
      return usage("no case matches");
  }
  catch (const std::exception& e)
  {
    std::fprintf(stderr, "evaluate_validation: %s\n", e.what());
    return 1;
  }
  return 0;
}
