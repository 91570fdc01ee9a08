// evaluate_daylight: the pipeline's core (detector, triangulator, PoseDelta)
// on simulated daylight, one frame or strobed, against the simulator's
// truth (docs/daylight.md, "Measured"). Per case: recall (dots within 3 px
// of their true pixel / visible dots) pooled and its worst frame, centroid
// RMS, wrong beams, depth RMS, pose RMS and the share of valid poses.
//
//   evaluate_daylight [--rig FILE] [--ratio R] [--strobe 0|1] [--sun S] [--distance D]... [--seeds A,B]
//                     [--frames N] [--texture PERIOD_M] [--sweep R1,R2,...] [--motion M]
//                     [--full-resolution-tracking 0|1] [--output ENCODING] [--output-bits N]
//                     [--unrounded 0|1] [--true-ambient 0|1] [--focus M] [--relief M]
//                     [--noise-free 0|1]
//
// The camera: the rig's as designed (its output_bits: the recommended rig's
// 12 bits as bgr16), bgr8 without --rig; --output overrides it.
//
// Strobed: the projector fires on every second frame (30 Hz camera, 15 Hz
// dot frames); the ambient frames around each on-frame are compensated to
// its time (ambient_compensation.h) and the dots are detected on the
// difference. --ratio overrides the rig's dot/sun ratio (the 3 mm
// reference dot); --sweep runs the cases for each ratio and prints one line
// per ratio (the lowest ratio at which each stage meets its bound).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include "support/daylight_run.h"

using namespace structured_light_stabilizer;
using test::daylight::Options;
using test::daylight::runAll;

namespace
{

std::vector<double> numbers(const std::string& csv)
{
  std::vector<double> v;
  std::stringstream ss(csv);
  for (std::string item; std::getline(ss, item, ',');)
    v.push_back(std::atof(item.c_str()));
  return v;
}

}  // namespace

int main(int argc, char** argv)
{
  Options o;
  for (int i = 1; i + 1 < argc; i += 2)
  {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--rig")
      o.rig = v;
    else if (k == "--ratio")
      o.ratio = std::atof(v.c_str());
    else if (k == "--strobe")
      o.strobe = v != "0";
    else if (k == "--sun")
      o.sun = std::atof(v.c_str());
    else if (k == "--distance")
      o.distances = numbers(v);
    else if (k == "--seeds")
    {
      o.seeds.clear();
      for (double s : numbers(v))
        o.seeds.push_back(static_cast<uint32_t>(s));
    }
    else if (k == "--frames")
      o.frames = std::max(2, std::atoi(v.c_str()));
    else if (k == "--texture")
      o.texture_period = std::atof(v.c_str());
    else if (k == "--motion")
      o.motion = std::atof(v.c_str());
    else if (k == "--albedo")
      o.albedo = std::atof(v.c_str());
    else if (k == "--normalise")
      o.normalise = v != "0";
    else if (k == "--detect-threshold")
      o.detect_threshold = std::atoi(v.c_str());
    else if (k == "--min-peak")
      o.min_peak = std::atoi(v.c_str());
    else if (k == "--camera-rate")
      o.camera_rate = std::atof(v.c_str());
    else if (k == "--extrapolate")
      o.extrapolate = v != "0";
    else if (k == "--full-resolution-tracking")
      o.full_resolution_tracking = std::atoi(v.c_str()) != 0;
    else if (k == "--true-ambient")
      o.true_ambient = v != "0";
    else if (k == "--difference")
      o.difference = v != "0";
    else if (k == "--unrounded")
      o.unrounded = v != "0";
    else if (k == "--output")
      o.output = v;
    else if (k == "--albedo-floor")
      o.albedo_floor = std::atof(v.c_str());
    else if (k == "--rock-subsample")
      o.rock_subsample = std::atoi(v.c_str());
    else if (k == "--relief")
      o.relief = std::atof(v.c_str());
    else if (k == "--noise-free")
      o.noise_free = v != "0";
    else if (k == "--focus")
      o.focus_m = std::atof(v.c_str());
    else if (k == "--output-bits")
      o.output_bits = std::atoi(v.c_str());
    else if (k == "--sweep")
      o.sweep = numbers(v);
    else
    {
      std::fprintf(stderr, "evaluate_daylight: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  try
  {
    if (o.output.empty() && !o.rig.empty())
    {
      const int bits = loadRig(analyseScene(SceneInputs()), o.rig).output_bits;
      o.output = bits > 8 ? "bgr16" : "bgr8";
      o.output_bits = bits > 8 ? bits : 16;
    }
    else if (o.output.empty())
      o.output = "bgr8";
    std::printf(
        "camera output: %s%s\n", o.output.c_str(),
        o.output == "bgr16" || o.output == "rgb16" ? (", " + std::to_string(o.output_bits) + " bits").c_str() : "");
    if (o.sweep.empty())
    {
      std::printf("%s, sun %.2f, ratio %s:\n", o.strobe ? "strobed" : "one frame", o.sun,
                  o.ratio >= 0 ? std::to_string(o.ratio).c_str() : "the rig's");
      std::printf("all: %s\n", runAll(o, true).line().c_str());
      return 0;
    }
    for (double r : o.sweep)
    {
      o.ratio = r;
      std::printf("ratio %.4g %s: %s\n", r, o.strobe ? "strobed" : "one frame", runAll(o, false).line().c_str());
      std::fflush(stdout);
    }
  }
  catch (const std::exception& e)
  {
    std::fprintf(stderr, "evaluate_daylight: %s\n", e.what());
    return 1;
  }
  return 0;
}
