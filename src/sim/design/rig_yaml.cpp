// The rig as YAML (radiometry.h): written by the design tool, read by the
// simulator (CameraDriver ~rig) and the tools. Units in the key names; every
// key optional (the study's rig); unknown keys refused with the line.
#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <yaml-cpp/yaml.h>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "sim/design/yaml_reader.h"

namespace structured_light_stabilizer
{

namespace
{

using Reader = sim::YamlReader;

void readEmitter(const Reader& r, const YAML::Node& n, EmitterParams* e)
{
  r.onlyKeys(n, "emitter",
             {"kind", "wavelength_nm", "spectral_fwhm_nm", "cw_optical_power_w", "wall_plug_efficiency",
              "peak_power_factor", "projector_efficiency", "thermal_drift_nm_per_k"});
  const int kind = r.word(n, "kind", {"led", "laser_diode"});
  if (kind >= 0)
    e->kind = kind == 0 ? EmitterKind::kLed : EmitterKind::kLaserDiode;
  r.number(n, "wavelength_nm", 1e-9, &e->wavelength_m);
  r.number(n, "spectral_fwhm_nm", 1e-9, &e->spectral_fwhm_m);
  r.number(n, "cw_optical_power_w", 1.0, &e->cw_optical_power_w);
  r.number(n, "wall_plug_efficiency", 1.0, &e->wall_plug_efficiency);
  r.number(n, "peak_power_factor", 1.0, &e->peak_power_factor);
  r.number(n, "projector_efficiency", 1.0, &e->projector_efficiency);
  r.number(n, "thermal_drift_nm_per_k", 1e-9, &e->thermal_drift_m_per_k);
}

void readFilter(const Reader& r, const YAML::Node& n, BandPassFilter* f)
{
  if (n.IsScalar() && n.Scalar() == "none")
  {
    f->enabled = false;
    return;
  }
  r.onlyKeys(n, "filter", {"centre_nm", "fwhm_nm", "transmission", "effective_index"});
  f->enabled = true;
  r.number(n, "centre_nm", 1e-9, &f->centre_m);
  r.number(n, "fwhm_nm", 1e-9, &f->fwhm_m);
  r.number(n, "transmission", 1.0, &f->transmission);
  r.number(n, "effective_index", 1.0, &f->effective_index);
}

RigParams parseRig(const SceneAnalysis& analysis, const YAML::Node& root, const Reader& r)
{
  RigParams rig = RigParams::studyDesign(analysis);
  if (root.IsNull())
    return rig;
  r.onlyKeys(root, "", {"rig"});
  const YAML::Node n = root["rig"];
  r.onlyKeys(n, "rig",
             {"name", "emitter", "beam_sigma_mrad", "drive", "electrical_budget_w", "exposure_ms", "frame_rate_hz",
              "strobe", "filter", "camera", "sun_spectrum"});
  if (n["name"])
    rig.name = n["name"].as<std::string>();
  if (n["emitter"])
    readEmitter(r, n["emitter"], &rig.emitter);
  r.number(n, "beam_sigma_mrad", 1e-3, &rig.beam_sigma_rad);
  const int drive = r.word(n, "drive", {"continuous", "pulsed"});
  if (drive >= 0)
    rig.pulsed = drive == 1;
  r.number(n, "electrical_budget_w", 1.0, &rig.electrical_budget_w);
  r.number(n, "exposure_ms", 1e-3, &rig.exposure_s);
  r.number(n, "frame_rate_hz", 1.0, &rig.frame_rate_hz);
  r.boolean(n, "strobe", &rig.strobe);
  if (n["filter"])
    readFilter(r, n["filter"], &rig.filter);
  if (const YAML::Node cam = n["camera"])
  {
    r.onlyKeys(cam, "camera", {"full_scale_e", "output_bits"});
    r.number(cam, "full_scale_e", 1.0, &rig.full_scale_e);
    r.integer(cam, "output_bits", &rig.output_bits);
  }
  const int spectrum = r.word(n, "sun_spectrum", {"blackbody", "flat_in_band"});
  if (spectrum >= 0)
    rig.sun_spectrum = spectrum == 0 ? SunSpectrum::kBlackbody : SunSpectrum::kFlatInBand;
  return rig;
}

std::string fmt(const char* format, double v)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), format, v);
  return buf;
}

}  // namespace

std::string rigToYaml(const RigParams& rig, const std::string& comment)
{
  std::ostringstream os;
  std::istringstream lines(comment);
  for (std::string line; std::getline(lines, line);)
    os << "# " << line << "\n";
  const EmitterParams& e = rig.emitter;
  os << "rig:\n"
     << "  name: " << rig.name << "\n"
     << "  emitter:\n"
     << "    kind: " << (e.kind == EmitterKind::kLed ? "led" : "laser_diode") << "\n"
     << "    wavelength_nm: " << fmt("%.6g", e.wavelength_m * 1e9) << "\n"
     << "    spectral_fwhm_nm: " << fmt("%.6g", e.spectral_fwhm_m * 1e9) << "\n"
     << "    cw_optical_power_w: " << fmt("%.6g", e.cw_optical_power_w) << "\n"
     << "    wall_plug_efficiency: " << fmt("%.6g", e.wall_plug_efficiency) << "\n"
     << "    peak_power_factor: " << fmt("%.6g", e.peak_power_factor) << "\n"
     << "    projector_efficiency: " << fmt("%.6g", e.projector_efficiency) << "\n"
     << "    thermal_drift_nm_per_k: " << fmt("%.6g", e.thermal_drift_m_per_k * 1e9) << "\n"
     << "  beam_sigma_mrad: " << fmt("%.6g", rig.beam_sigma_rad * 1e3) << "\n"
     << "  drive: " << (rig.pulsed ? "pulsed" : "continuous") << "\n"
     << "  electrical_budget_w: " << fmt("%.6g", rig.electrical_budget_w) << "\n"
     << "  exposure_ms: " << fmt("%.6g", rig.exposure_s * 1e3) << "\n"
     << "  frame_rate_hz: " << fmt("%.6g", rig.frame_rate_hz) << "\n"
     << "  strobe: " << (rig.strobe ? "true" : "false") << "\n";
  if (rig.filter.enabled)
    os << "  filter:\n"
       << "    centre_nm: " << fmt("%.6g", rig.filter.centre_m * 1e9) << "\n"
       << "    fwhm_nm: " << fmt("%.6g", rig.filter.fwhm_m * 1e9) << "\n"
       << "    transmission: " << fmt("%.6g", rig.filter.transmission) << "\n"
       << "    effective_index: " << fmt("%.6g", rig.filter.effective_index) << "\n";
  else
    os << "  filter: none\n";
  os << "  camera:\n"
     << "    full_scale_e: " << fmt("%.6g", rig.full_scale_e) << "\n"
     << "    output_bits: " << rig.output_bits << "\n"
     << "  sun_spectrum: " << (rig.sun_spectrum == SunSpectrum::kBlackbody ? "blackbody" : "flat_in_band") << "\n";
  return os.str();
}

RigParams rigFromYaml(const SceneAnalysis& analysis, const std::string& yaml_text, const std::string& source)
{
  const Reader r{"rig", source};
  RigParams rig;
  try
  {
    rig = parseRig(analysis, YAML::Load(yaml_text), r);
  }
  catch (const YAML::Exception& e)
  {
    throw std::invalid_argument("rig: " + source + ": not valid YAML: " + e.what());
  }
  try
  {
    rig.validate();
  }
  catch (const std::invalid_argument& e)
  {
    throw std::invalid_argument(std::string(e.what()) + " (in " + source + ")");
  }
  return rig;
}

RigParams loadRig(const SceneAnalysis& analysis, const std::string& path)
{
  std::ifstream file(path);
  if (!file)
    throw std::invalid_argument("rig: cannot open '" + path + "'");
  std::stringstream ss;
  ss << file.rdbuf();
  return rigFromYaml(analysis, ss.str(), path);
}

}  // namespace structured_light_stabilizer
