#include "cli/evaluate_daylight_cli.h"

#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "support/daylight_run.h"

namespace structured_light_stabilizer
{

namespace
{

using test::daylight::Options;

std::vector<double> numbers(const std::string& csv)
{
  std::vector<double> v;
  std::stringstream ss(csv);
  for (std::string item; std::getline(ss, item, ',');)
    v.push_back(std::atof(item.c_str()));
  return v;
}

std::string format(const char* f, double a)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), f, a);
  return buf;
}

// `flag value` into the options: "" when read, else why not.
std::string readOption(const std::string& k, const std::string& v, Options* o)
{
  const std::string scene = o->ablations.parse(k, v);
  if (scene != "?")
    return scene;
  const bool on = v != "0";
  if (k == "--rig")
    o->rig = v;
  else if (k == "--ratio")
    o->ratio = std::atof(v.c_str());
  else if (k == "--strobe")
    o->strobe = on;
  else if (k == "--sun")
    o->sun = std::atof(v.c_str());
  else if (k == "--distance")
    o->distances = numbers(v);
  else if (k == "--seeds")
  {
    o->seeds.clear();
    for (double s : numbers(v))
      o->seeds.push_back(static_cast<uint32_t>(s));
  }
  else if (k == "--frames")
    o->frames = std::max(2, std::atoi(v.c_str()));
  else if (k == "--texture")
    o->texture_period = std::atof(v.c_str());
  else if (k == "--motion")
    o->motion = std::atof(v.c_str());
  else if (k == "--albedo")
    o->albedo = std::atof(v.c_str());
  else if (k == "--normalise")
    o->normalise = on;
  else if (k == "--camera-rate")
    o->camera_rate = std::atof(v.c_str());
  else if (k == "--extrapolate")
    o->extrapolate = on;
  else if (k == "--full-resolution-tracking")
    o->full_resolution_tracking = on;
  else if (k == "--true-ambient")
    o->true_ambient = on;
  else if (k == "--difference")
    o->difference = on;
  else if (k == "--unrounded")
    o->unrounded = on;
  else if (k == "--output")
    o->output = v;
  else if (k == "--rock-subsample")
    o->rock_subsample = std::atoi(v.c_str());
  else if (k == "--focus")
    o->focus_m = std::atof(v.c_str());
  else if (k == "--output-bits")
    o->output_bits = std::atoi(v.c_str());
  else if (k == "--sweep")
    o->sweep = numbers(v);
  else if (k == "--param")
  {
    const std::string bad = o->settings.set(v);
    return bad.empty() ? "" : "--param " + v + ": " + bad;
  }
  else
    return "unknown option " + k;
  return "";
}

}  // namespace

int evaluateDaylightMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err)
{
  Options o;
  for (size_t i = 0; i < args.size(); i += 2)
  {
    if (i + 1 >= args.size())
    {
      err << "evaluate_daylight: " << args[i] << " needs a value\n";
      return 2;
    }
    const std::string bad = readOption(args[i], args[i + 1], &o);
    if (!bad.empty())
    {
      err << "evaluate_daylight: " << bad << "\n";
      return 2;
    }
  }
  const std::string unusable = o.settings.validate();
  if (!unusable.empty())
  {
    err << "evaluate_daylight: " << unusable << "\n";
    return 2;
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
    const bool deep = o.output == "bgr16" || o.output == "rgb16";
    out << "camera output: " << o.output << (deep ? ", " + std::to_string(o.output_bits) + " bits" : "") << "\n";
    if (!o.ablations.describe().empty())
      out << "scene changes:" << o.ablations.describe() << "\n";
    if (o.sweep.empty())
    {
      out << (o.strobe ? "strobed" : "one frame") << format(", sun %.2f", o.sun) << ", ratio "
          << (o.ratio >= 0 ? std::to_string(o.ratio) : "the rig's") << ":\n";
      test::daylight::Stats all;
      for (double d : o.distances)
        for (uint32_t s : o.seeds)
        {
          const test::daylight::Stats one = test::daylight::runCase(o, d, s);
          out << format("  %.1f m", d) << " seed " << s << ": " << one.line() << "\n";
          all.add(one);
        }
      out << "all: " << all.line() << "\n";
      return 0;
    }
    for (double r : o.sweep)
    {
      o.ratio = r;
      out << format("ratio %.4g ", r) << (o.strobe ? "strobed" : "one frame") << ": "
          << test::daylight::runAll(o, false).line() << "\n"
          << std::flush;
    }
  }
  catch (const std::exception& e)
  {
    err << "evaluate_daylight: " << e.what() << "\n";
    return 1;
  }
  return 0;
}

}  // namespace structured_light_stabilizer
