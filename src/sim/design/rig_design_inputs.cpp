// The design calculator's inputs: the default option grid (documented in
// config/rig_design.yaml) and its YAML reader.
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <yaml-cpp/yaml.h>

#include "structured_light_stabilizer/sim/design/rig_design.h"
#include "sim/design/yaml_reader.h"

namespace structured_light_stabilizer
{

namespace
{

// Emitters of the default grid. Figures are typical of current parts (why
// each is what it is: docs/daylight.md#emitters); a designer puts the
// datasheet's in config/rig_design.yaml.
std::vector<NamedEmitter> defaultEmitters(const SceneAnalysis& a)
{
  NamedEmitter study{"study_led", EmitterParams::studyLed(a)};
  study.emitter.peak_power_factor = 3.0;  // a small LED takes ~5x its current in short pulses; droop
  NamedEmitter led{"green_led_1w", EmitterParams()};
  led.emitter.kind = EmitterKind::kLed;
  led.emitter.wavelength_m = 525e-9;
  led.emitter.spectral_fwhm_m = 30e-9;
  led.emitter.cw_optical_power_w = 0.25;  // a 1 mm^2 green die at ~1 A
  led.emitter.wall_plug_efficiency = 0.2;
  led.emitter.peak_power_factor = 3.0;
  led.emitter.projector_efficiency = 0.15;  // the study's lens and grid
  led.emitter.thermal_drift_m_per_k = 0.04e-9;
  NamedEmitter green{"green_ld_1w", EmitterParams()};
  green.emitter.kind = EmitterKind::kLaserDiode;
  green.emitter.wavelength_m = 520e-9;
  green.emitter.spectral_fwhm_m = 1.5e-9;  // multimode InGaN diode
  green.emitter.cw_optical_power_w = 1.0;
  green.emitter.wall_plug_efficiency = 0.12;
  green.emitter.peak_power_factor = 1.0;     // facet damage limits pulses to about the CW rating
  green.emitter.projector_efficiency = 0.7;  // diffractive 10 x 10 splitter
  green.emitter.thermal_drift_m_per_k = 0.06e-9;
  NamedEmitter red = green;
  red.name = "red_ld_700mw";
  red.emitter.wavelength_m = 638e-9;
  red.emitter.spectral_fwhm_m = 1.0e-9;
  red.emitter.cw_optical_power_w = 0.7;
  red.emitter.wall_plug_efficiency = 0.3;
  red.emitter.thermal_drift_m_per_k = 0.2e-9;
  return {study, led, green, red};
}

using Reader = sim::YamlReader;

void readConditions(const Reader& r, const YAML::Node& n, DesignConditions* c)
{
  r.onlyKeys(n, "conditions",
             {"sun_level", "albedo_min", "albedo_max", "distance_min_m", "distance_max_m", "texture_contrast",
              "texture_period_m", "roughness_m", "ambient_misalignment_px", "ambient_noise_scale",
              "albedo_reference_residual", "temperature_range_k"});
  r.number(n, "sun_level", 1.0, &c->sun_level);
  r.number(n, "albedo_min", 1.0, &c->albedo_min);
  r.number(n, "albedo_max", 1.0, &c->albedo_max);
  r.number(n, "distance_min_m", 1.0, &c->distance_min_m);
  r.number(n, "distance_max_m", 1.0, &c->distance_max_m);
  r.number(n, "texture_contrast", 1.0, &c->texture.contrast);
  r.number(n, "texture_period_m", 1.0, &c->texture.period_m);
  r.number(n, "roughness_m", 1.0, &c->texture.roughness_m);
  r.number(n, "ambient_misalignment_px", 1.0, &c->texture.ambient_misalignment_px);
  r.number(n, "ambient_noise_scale", 1.0, &c->texture.ambient_noise_scale);
  r.number(n, "albedo_reference_residual", 1.0, &c->texture.albedo_reference_residual);
  r.number(n, "temperature_range_k", 1.0, &c->temperature_range_k);
}

void readTarget(const Reader& r, const YAML::Node& n, DesignTarget* t)
{
  r.onlyKeys(n, "target", {"snr", "centroid_px", "min_dot_sigma_px", "ambient_fill"});
  r.number(n, "snr", 1.0, &t->snr);
  r.number(n, "centroid_px", 1.0, &t->centroid_px);
  r.number(n, "min_dot_sigma_px", 1.0, &t->min_dot_sigma_px);
  r.number(n, "ambient_fill", 1.0, &t->ambient_fill);
}

void readOptions(const Reader& r, const YAML::Node& n, DesignOptions* o)
{
  r.onlyKeys(n, "options",
             {"beam_sigma_mrad", "pulsed", "exposure_ms", "filter_fwhm_nm", "strobe", "filter_transmission",
              "filter_effective_index", "electrical_budget_w", "frame_rate_hz", "output_bits"});
  r.numbers(n, "beam_sigma_mrad", 1e-3, &o->beam_sigma_rad);
  r.booleans(n, "pulsed", &o->pulsed);
  r.numbers(n, "exposure_ms", 1e-3, &o->exposure_s);
  r.numbers(n, "filter_fwhm_nm", 1e-9, &o->filter_fwhm_m);
  r.booleans(n, "strobe", &o->strobe);
  r.number(n, "filter_transmission", 1.0, &o->filter_transmission);
  r.number(n, "filter_effective_index", 1.0, &o->filter_effective_index);
  r.number(n, "electrical_budget_w", 1.0, &o->electrical_budget_w);
  r.number(n, "frame_rate_hz", 1.0, &o->frame_rate_hz);
  double bits = o->output_bits;
  r.number(n, "output_bits", 1.0, &bits);
  if (bits != std::floor(bits) || bits < 8 || bits > 16)
    r.refuse(n["output_bits"], "output_bits must be an integer in [8, 16]");
  o->output_bits = static_cast<int>(bits);
}

void readBeams(const Reader& r, const YAML::Node& n, BeamDesignOptions* b)
{
  r.onlyKeys(n, "beams", {"beam_sigma_mrad", "focus_distance_m", "relief_m", "seeds", "frames"});
  r.numbers(n, "beam_sigma_mrad", 1e-3, &b->beam_sigma_rad);
  r.numbers(n, "focus_distance_m", 1.0, &b->focus_distance_m);
  r.number(n, "relief_m", 1.0, &b->relief_m);
  r.integer(n, "seeds", &b->seeds);
  r.integer(n, "frames", &b->frames);
}

// emitters: a list of {name, + the keys of a rig's emitter}.
void readEmitters(const Reader& r, const SceneAnalysis& a, const YAML::Node& n, std::vector<NamedEmitter>* out)
{
  if (!n.IsSequence() || n.size() == 0)
    r.refuse(n, "emitters must be a non-empty list");
  out->clear();
  for (const auto& item : n)
  {
    if (!item.IsMap() || !item["name"])
      r.refuse(item, "each emitter needs a name");
    YAML::Node emitter = YAML::Clone(item);
    emitter.remove("name");
    YAML::Node doc;
    doc["rig"]["emitter"] = emitter;
    std::stringstream text;
    text << doc;
    NamedEmitter e{item["name"].as<std::string>(), EmitterParams()};
    try
    {
      e.emitter = rigFromYaml(a, text.str(), r.source + " (emitter " + e.name + ")").emitter;
    }
    catch (const std::invalid_argument& ex)
    {
      r.refuse(item, ex.what());
    }
    out->push_back(e);
  }
}

}  // namespace

DesignInputs defaultDesignInputs()
{
  DesignInputs in;
  const SceneAnalysis a = analyseScene(in.scene);
  DesignOptions& o = in.options;
  o.emitters = defaultEmitters(a);
  o.beam_sigma_rad = {1e-3, 1.5e-3, 2e-3, 3e-3};
  o.pulsed = {false, true};
  o.exposure_s = {0.25e-3, 0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3, 33e-3};
  o.filter_fwhm_m = {0.0, 10e-9, 20e-9, 30e-9, 40e-9, 60e-9};
  o.strobe = {false, true};
  return in;
}

DesignInputs designInputsFromYaml(const std::string& yaml_text, const std::string& source, const SceneInputs& scene)
{
  DesignInputs in = defaultDesignInputs();
  in.scene = scene;
  const Reader r{"rig_design", source};
  try
  {
    const YAML::Node root = YAML::Load(yaml_text);
    if (root.IsNull())
      return in;
    r.onlyKeys(root, "", {"conditions", "target", "options", "beams", "emitters"});
    if (root["conditions"])
      readConditions(r, root["conditions"], &in.conditions);
    if (root["target"])
      readTarget(r, root["target"], &in.target);
    if (root["options"])
      readOptions(r, root["options"], &in.options);
    if (root["beams"])
      readBeams(r, root["beams"], &in.beams);
    if (root["emitters"])
      readEmitters(r, analyseScene(scene), root["emitters"], &in.options.emitters);
  }
  catch (const YAML::Exception& e)
  {
    throw std::invalid_argument("rig_design: " + source + ": not valid YAML: " + e.what());
  }
  return in;
}

DesignInputs loadDesignInputs(const std::string& path, const SceneInputs& scene)
{
  std::ifstream file(path);
  if (!file)
    throw std::invalid_argument("rig_design: cannot open '" + path + "'");
  std::stringstream ss;
  ss << file.rdbuf();
  return designInputsFromYaml(ss.str(), path, scene);
}

}  // namespace structured_light_stabilizer
