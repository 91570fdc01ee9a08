#include "cli/design_rig_cli.h"

#include <cstdio>
#include <exception>
#include <fstream>
#include <iostream>
#include <string>

#include <opencv2/imgcodecs.hpp>

#include "structured_light_stabilizer/sim/design/rig_design.h"

namespace structured_light_stabilizer
{

namespace
{

void usage(std::ostream& os)
{
  os << "usage: design_rig [design.yaml] [--scene scene.yaml] [--rows N] [--csv FILE] [--png FILE] "
        "[--rig-yaml FILE]\n"
        "  design.yaml     conditions, target, options, emitters (default: config/rig_design.yaml's values)\n"
        "  --scene FILE    the camera, sun and target of the scene analysis (default: the study's)\n"
        "  --rows N        table rows to print (default 25, 0 = all)\n"
        "  --csv FILE      every rig evaluated, as CSV\n"
        "  --png FILE      worst-case SNR and dot/sun ratio versus exposure\n"
        "  --rig-yaml FILE the recommended rig, for the simulator (~rig)\n"
        "  --beams 0|1     the beam x focus table with each design's relief floor (default 1; renders)\n";
}

bool writeText(const std::string& path, const std::string& text, std::ostream& err)
{
  std::ofstream f(path);
  f << text;
  f.close();
  if (!f)
  {
    err << "design_rig: cannot write '" << path << "'\n";
    return false;
  }
  return true;
}

struct Args
{
  std::string design, scene, csv, png, rig_yaml;
  size_t rows = 25;
  bool beams = true;
};

// False on bad usage (said why).
bool parseArgs(const std::vector<std::string>& args, Args* a, std::ostream& err)
{
  for (size_t i = 0; i < args.size(); ++i)
  {
    const std::string& arg = args[i];
    auto value = [&](std::string* out)
    {
      if (i + 1 >= args.size())
        return false;
      *out = args[++i];
      return true;
    };
    std::string rows, beams;
    const bool known = arg == "--scene" || arg == "--csv" || arg == "--png" || arg == "--rig-yaml" ||
                       arg == "--rows" || arg == "--beams";
    if (arg == "--scene"      ? !value(&a->scene)
        : arg == "--csv"      ? !value(&a->csv)
        : arg == "--png"      ? !value(&a->png)
        : arg == "--rig-yaml" ? !value(&a->rig_yaml)
        : arg == "--rows"     ? !value(&rows)
        : arg == "--beams"    ? !value(&beams)
                              : false)
    {
      err << "design_rig: " << arg << " needs a value\n";
      return false;
    }
    if (!rows.empty())
      a->rows = std::stoul(rows);
    else if (!beams.empty() && beams != "0" && beams != "1")
    {
      err << "design_rig: --beams takes 0 or 1\n";
      return false;
    }
    else if (!beams.empty())
      a->beams = beams == "1";
    else if (arg.rfind("--", 0) == 0 && !known)
    {
      err << "design_rig: unknown option " << arg << "\n";
      return false;
    }
    else if (arg.rfind("--", 0) != 0)
    {
      if (!a->design.empty())
      {
        err << "design_rig: more than one inputs file\n";
        return false;
      }
      a->design = arg;
    }
  }
  return true;
}

}  // namespace

int designRigMain(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err)
{
  for (const std::string& a : argv)
    if (a == "-h" || a == "--help")
    {
      usage(out);
      return 0;
    }
  Args args;
  try
  {
    if (!parseArgs(argv, &args, err))
    {
      usage(err);
      return 2;
    }
  }
  catch (const std::exception&)
  {
    err << "design_rig: --rows needs a number\n";
    return 2;
  }
  DesignResult result;
  std::vector<BeamDesign> beams;
  try
  {
    const SceneInputs scene = args.scene.empty() ? SceneInputs() : loadSceneInputs(args.scene);
    const DesignInputs inputs =
        args.design.empty() ? defaultDesignInputs() : loadDesignInputs(args.design, scene);
    DesignInputs with_scene = inputs;
    with_scene.scene = scene;
    result = designRig(with_scene);
    if (args.beams)
      beams = designBeams(with_scene);
  }
  catch (const std::exception& e)
  {
    err << e.what() << "\n";
    return 1;
  }
  out << formatDesignTable(result, args.rows);
  if (result.recommended >= 0)
    out << "\n"
              << formatRigDetails(result) << "\nRecommended rig (YAML for the simulator):\n"
              << recommendedRigYaml(result);
  else
    out << "\nNo rig reaches the target: relax it or widen the options.\n";
  if (args.beams)
    out << "\n" << formatBeamDesigns(beams, result.inputs);
  bool ok = true;
  if (!args.csv.empty())
    ok = writeText(args.csv, designCsv(result), err) && ok;
  if (!args.rig_yaml.empty() && result.recommended >= 0)
    ok = writeText(args.rig_yaml, recommendedRigYaml(result), err) && ok;
  if (!args.png.empty() && !cv::imwrite(args.png, renderDesignPlot(result)))
  {
    err << "design_rig: cannot write '" << args.png << "'\n";
    ok = false;
  }
  return ok ? 0 : 1;
}

}  // namespace structured_light_stabilizer
