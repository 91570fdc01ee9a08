// scene_analysis: prints the study's optical and radiometric design (docs/study.md §2.1)
// computed from a YAML of inputs, next to the values the study states, and
// writes the aperture sweep of its figure 2.2 as CSV and PNG.
//
//   scene_analysis [inputs.yaml] [--sweep-csv FILE] [--sweep-png FILE]
//
// Without an inputs file the study's values are used
// (config/scene_analysis.yaml documents them). Exit status 0 on success,
// 1 on bad inputs or an unwritable output, 2 on bad usage.
#include <cmath>
#include <cstdio>
#include <exception>
#include <fstream>
#include <iostream>
#include <string>

#include <opencv2/imgcodecs.hpp>

#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace sls = structured_light_stabilizer;

namespace
{

void usage(std::ostream& os)
{
  os << "usage: scene_analysis [inputs.yaml] [--sweep-csv FILE] [--sweep-png FILE]\n"
        "  Prints the design table of the study's §2.1 (computed vs stated).\n"
        "  inputs.yaml      inputs (default: the study's values, see config/scene_analysis.yaml)\n"
        "  --sweep-csv FILE diameter of confusion and diffraction spots vs aperture (fig. 2.2) as CSV\n"
        "  --sweep-png FILE the same as a plot\n";
}

void printSimulatorRecipe(const sls::SceneAnalysis& a)
{
  const sls::SceneInputs& in = a.inputs;
  const double kDeg = sls::detail::kPi / 180.0;
  const double stated = sls::dotToSunRatio(a, sls::RadiometryModel::kStudyAsStated);
  const double weakest = a.irradiance_latitude.min * std::cos(in.sun_incidence_max_deg * kDeg) /
                         (a.irradiance_latitude.max * std::cos(in.sun_incidence_min_deg * kDeg));
  std::printf("\nSimulator brightness (LightingParams; sun_level 1 = F50 %.1f W/m^2 on the rock at %.0f deg)\n",
              a.irradiance_latitude.max, in.sun_incidence_min_deg);
  std::printf("  dot_to_sun_ratio = dot peak / sunlit rock, photo-electrons, at sun_level 1 (any albedo):\n");
  std::printf("    study as stated (= its 'SNR 32')       : %.4g\n", stated);
  for (double sigma : {1e-3, 2e-3, 3e-3})
    std::printf("    corrected, dot sigma %.0f mm on the rock : %.4g\n", sigma * 1e3,
                sls::dotToSunRatio(a, sls::RadiometryModel::kCorrected, sigma));
  std::printf(
      "  sun_level: study's worst case 1.0 (F50 max, %.0f deg); weakest sun %.3f (F50 min, %.0f deg); night 0\n",
      in.sun_incidence_min_deg, weakest, in.sun_incidence_max_deg);
  std::printf("  study's noise model (noise = sun electrons): SNR = ratio / sun_level: %.0f at 1.0, %.0f at %.3f\n",
              stated, stated / weakest, weakest);
  const double t = a.saturating_exposure_s;
  const sls::DotSunElectrons worst =
      sls::dotAndSunElectrons(a, in.albedo_min, 1.0, sls::RadiometryModel::kCorrected, sls::Brdf::kLambertian, t);
  const sls::DotSunElectrons best = sls::dotAndSunElectrons(a, in.albedo_max, weakest, sls::RadiometryModel::kCorrected,
                                                            sls::Brdf::kLambertianGlossy, t);
  std::printf("  corrected, exposure %.2f ms (brightest pixel at the full well):\n", t * 1e3);
  std::printf("    worst (albedo %.2f, sun_level 1)       : sun %.0f e-, dot %.0f e-, SNR %.1f\n", in.albedo_min,
              worst.sun_e, worst.dot_e, worst.snr());
  std::printf("    weakest sun (albedo %.2f, level %.3f) : sun %.0f e-, dot %.0f e-, SNR %.1f\n", in.albedo_max,
              weakest, best.sun_e, best.dot_e, best.snr());
  std::printf("  image SNR of a dot of ratio r over B e- of sunlit rock: r B / sqrt((1 + r) B + read^2)\n");
  for (double b : {2e3, 2e4})
    std::printf("    B = %.0f e-, read 100 e-: ratio for SNR 32 = %.3g, for SNR 348 = %.3g\n", b,
                sls::ratioForSnr(32, b, 100), sls::ratioForSnr(348, b, 100));
}

}  // namespace

int main(int argc, char** argv)
{
  std::string inputs_path, csv_path, png_path;
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    if (arg == "-h" || arg == "--help")
    {
      usage(std::cout);
      return 0;
    }
    if (arg == "--sweep-csv" || arg == "--sweep-png")
    {
      if (i + 1 >= argc)
      {
        std::cerr << "scene_analysis: " << arg << " needs a file name\n";
        usage(std::cerr);
        return 2;
      }
      (arg == "--sweep-csv" ? csv_path : png_path) = argv[++i];
      continue;
    }
    if (!arg.empty() && arg[0] == '-')
    {
      std::cerr << "scene_analysis: unknown option '" << arg << "'\n";
      usage(std::cerr);
      return 2;
    }
    if (!inputs_path.empty())
    {
      std::cerr << "scene_analysis: more than one inputs file\n";
      usage(std::cerr);
      return 2;
    }
    inputs_path = arg;
  }

  try
  {
    const sls::SceneInputs in = inputs_path.empty() ? sls::SceneInputs() : sls::loadSceneInputs(inputs_path);
    const sls::SceneAnalysis a = sls::analyseScene(in);
    std::printf("Scene analysis (study §2.1), inputs: %s\n\n",
                inputs_path.empty() ? "the study's defaults" : inputs_path.c_str());
    std::fputs(sls::formatDesignTable(a).c_str(), stdout);
    printSimulatorRecipe(a);

    if (!csv_path.empty() || !png_path.empty())
    {
      const sls::ApertureSweep sweep = sls::apertureSweep(in);
      if (!csv_path.empty())
      {
        std::ofstream f(csv_path);
        f << sls::apertureSweepCsv(sweep);
        if (!f)
        {
          std::cerr << "scene_analysis: cannot write '" << csv_path << "'\n";
          return 1;
        }
        std::printf("\nwrote %s (%zu apertures)\n", csv_path.c_str(), sweep.rows.size());
      }
      if (!png_path.empty())
      {
        const cv::Mat img = sls::renderApertureSweep(in, sweep);
        bool ok = false;
        try
        {
          ok = cv::imwrite(png_path, img);
        }
        catch (const cv::Exception& e)
        {
          std::cerr << "scene_analysis: " << e.what() << "\n";
        }
        if (!ok)
        {
          std::cerr << "scene_analysis: cannot write '" << png_path << "'\n";
          return 1;
        }
        std::printf("wrote %s\n", png_path.c_str());
      }
    }
  }
  catch (const std::exception& e)
  {
    std::cerr << e.what() << "\n";
    return 1;
  }
  return 0;
}
