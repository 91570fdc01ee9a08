// design_rig: the daylight design calculator (docs/daylight.md). Evaluates
// every combination of the rig's options at the worst case of the
// conditions, prints the table with the study's rig and the recommended one
// first, and writes the CSV, the plot and the recommended rig's YAML (the
// simulator reads it: CameraDriver ~rig).
//
//   design_rig [design.yaml] [--scene scene.yaml] [--rows N] [--csv FILE] [--png FILE] [--rig-yaml FILE]
//
// Exit status 0 on success (also when nothing is feasible: the table says
// why), 1 on bad inputs or an unwritable output, 2 on bad usage.
#include <cstdio>
#include <exception>
#include <fstream>
#include <iostream>
#include <string>

#include <opencv2/imgcodecs.hpp>

#include "structured_light_stabilizer/sim/design/rig_design.h"

namespace sls = structured_light_stabilizer;

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
        "  --rig-yaml FILE the recommended rig, for the simulator (~rig)\n";
}

bool writeText(const std::string& path, const std::string& text)
{
  std::ofstream f(path);
  f << text;
  f.close();
  if (!f)
  {
    std::cerr << "design_rig: cannot write '" << path << "'\n";
    return false;
  }
  return true;
}

struct Args
{
  std::string design, scene, csv, png, rig_yaml;
  size_t rows = 25;
};

// False on bad usage (said why).
bool parseArgs(int argc, char** argv, Args* a)
{
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    auto value = [&](std::string* out)
    {
      if (i + 1 >= argc)
        return false;
      *out = argv[++i];
      return true;
    };
    std::string rows;
    if (arg == "--scene"      ? !value(&a->scene)
        : arg == "--csv"      ? !value(&a->csv)
        : arg == "--png"      ? !value(&a->png)
        : arg == "--rig-yaml" ? !value(&a->rig_yaml)
        : arg == "--rows"     ? !value(&rows)
                              : false)
    {
      std::cerr << "design_rig: " << arg << " needs a value\n";
      return false;
    }
    if (!rows.empty())
      a->rows = std::stoul(rows);
    else if (arg.rfind("--", 0) == 0 && arg != "--scene" && arg != "--csv" && arg != "--png" && arg != "--rig-yaml" &&
             arg != "--rows")
    {
      std::cerr << "design_rig: unknown option " << arg << "\n";
      return false;
    }
    else if (arg.rfind("--", 0) != 0)
    {
      if (!a->design.empty())
      {
        std::cerr << "design_rig: more than one inputs file\n";
        return false;
      }
      a->design = arg;
    }
  }
  return true;
}

}  // namespace

int main(int argc, char** argv)
{
  for (int i = 1; i < argc; ++i)
    if (std::string(argv[i]) == "-h" || std::string(argv[i]) == "--help")
    {
      usage(std::cout);
      return 0;
    }
  Args args;
  try
  {
    if (!parseArgs(argc, argv, &args))
    {
      usage(std::cerr);
      return 2;
    }
  }
  catch (const std::exception&)
  {
    std::cerr << "design_rig: --rows needs a number\n";
    return 2;
  }
  sls::DesignResult result;
  try
  {
    const sls::SceneInputs scene = args.scene.empty() ? sls::SceneInputs() : sls::loadSceneInputs(args.scene);
    const sls::DesignInputs inputs =
        args.design.empty() ? sls::defaultDesignInputs() : sls::loadDesignInputs(args.design, scene);
    sls::DesignInputs with_scene = inputs;
    with_scene.scene = scene;
    result = sls::designRig(with_scene);
  }
  catch (const std::exception& e)
  {
    std::cerr << e.what() << "\n";
    return 1;
  }
  std::cout << sls::formatDesignTable(result, args.rows);
  if (result.recommended >= 0)
    std::cout << "\n"
              << sls::formatRigDetails(result) << "\nRecommended rig (YAML for the simulator):\n"
              << sls::recommendedRigYaml(result);
  else
    std::cout << "\nNo rig reaches the target: relax it or widen the options.\n";
  bool ok = true;
  if (!args.csv.empty())
    ok = writeText(args.csv, sls::designCsv(result)) && ok;
  if (!args.rig_yaml.empty() && result.recommended >= 0)
    ok = writeText(args.rig_yaml, sls::recommendedRigYaml(result)) && ok;
  if (!args.png.empty() && !cv::imwrite(args.png, sls::renderDesignPlot(result)))
  {
    std::cerr << "design_rig: cannot write '" << args.png << "'\n";
    ok = false;
  }
  return ok ? 0 : 1;
}
