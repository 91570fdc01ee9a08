// SceneInputs: the study's values as defaults, validation, and loading from
// YAML (every key optional, unknown keys refused).
#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <yaml-cpp/yaml.h>

#include "sim/design/scene_model.h"

namespace structured_light_stabilizer
{

using namespace scene;

namespace
{

void requirePositive(double v, const char* field)
{
  if (!std::isfinite(v) || v <= 0.0)
    fail(field, "must be a positive number, got " + num(v));
}

void requireFraction(double v, const char* field)
{
  if (!std::isfinite(v) || v < 0.0 || v > 1.0)
    fail(field, "must be in [0, 1], got " + num(v));
}

void requireAngle(double v, double lo, double hi, const char* field)
{
  if (!std::isfinite(v) || v < lo || v > hi)
    fail(field, "must be in [" + num(lo) + ", " + num(hi) + "] deg, got " + num(v));
}

void validateScene(const SceneInputs& in)
{
  requirePositive(in.target_height_m, "target_height_m");
  requirePositive(in.distance_min_m, "distance_min_m");
  requirePositive(in.distance_max_m, "distance_max_m");
  if (in.distance_min_m > in.distance_max_m)
    fail("distance_min_m",
         "larger than distance_max_m (" + num(in.distance_min_m) + " > " + num(in.distance_max_m) + ")");
}

void validateOptics(const SceneInputs& in)
{
  if (in.pixels_x <= 0 || in.pixels_y <= 0)
    fail("pixels", "must be positive, got " + std::to_string(in.pixels_x) + " x " + std::to_string(in.pixels_y));
  requirePositive(in.pixel_size_m, "pixel_size_m");
  requirePositive(in.sensor_height_m, "sensor_height_m");
  if (in.sensor_height_m > in.pixels_y * in.pixel_size_m * (1.0 + 1e-9))
    fail("sensor_height_m", "larger than pixels_y * pixel_size_m = " + num(in.pixels_y * in.pixel_size_m) + " m");
  requirePositive(in.focus_distance_m, "focus_distance_m");
  requirePositive(in.aperture_diameter_m, "aperture_diameter_m");
  const double efl = eflOf(in);
  if (in.focus_distance_m <= efl)
    fail("focus_distance_m", "must exceed the effective focal length " + num(efl) + " m");
  // f/1 is the practical limit of a lens (and of the paraxial camera
  // equation (2.9)): the entrance pupil cannot exceed the EFL.
  if (in.aperture_diameter_m > efl)
    fail("aperture_diameter_m",
         num(in.aperture_diameter_m) + " m is larger than the lens allows: at most the EFL " + num(efl) + " m (f/1)");
  requirePositive(in.wavelength_min_m, "wavelength_min_m");
  requirePositive(in.wavelength_max_m, "wavelength_max_m");
  if (in.wavelength_min_m >= in.wavelength_max_m)
    fail("wavelength_min_m", "wavelength range reversed or empty (" + num(in.wavelength_min_m * 1e9) +
                                 " nm >= " + num(in.wavelength_max_m * 1e9) + " nm)");
  requirePositive(in.exposure_s, "exposure_s");
  requireAngle(in.camera_axis_angle_deg, 0.0, 89.0, "camera_axis_angle_deg");
  requireFraction(in.lens_transmission, "lens_transmission");
}

void validateQuantumEfficiency(const SceneInputs& in)
{
  const auto& qe = in.quantum_efficiency;
  if (qe.size() < 2)
    fail("quantum_efficiency", "needs at least 2 (wavelength, QE) points");
  for (size_t i = 0; i < qe.size(); ++i)
  {
    const auto& p = qe[i];
    if (!std::isfinite(p.first) || p.first <= 0.0)
      fail("quantum_efficiency", "wavelength of point " + std::to_string(i) + " must be positive");
    if (!std::isfinite(p.second) || p.second < 0.0 || p.second > 1.0)
      fail("quantum_efficiency", "QE of point " + std::to_string(i) + " must be in [0, 1], got " + num(p.second));
    if (i > 0 && p.first <= qe[i - 1].first)
      fail("quantum_efficiency", "wavelengths must increase (point " + std::to_string(i) + ")");
  }
  if (qe.front().first > in.wavelength_min_m * (1 + 1e-9) || qe.back().first < in.wavelength_max_m * (1 - 1e-9))
    fail("quantum_efficiency", "table must cover the wavelength range [" + num(in.wavelength_min_m * 1e9) + ", " +
                                   num(in.wavelength_max_m * 1e9) + "] nm");
}

void validateSensorNoise(const SceneInputs& in)
{
  if (!std::isfinite(in.read_noise_e) || in.read_noise_e < 0.0)
    fail("read_noise_e", "must be >= 0, got " + num(in.read_noise_e));
  if (!std::isfinite(in.dark_current_a_m2) || in.dark_current_a_m2 < 0.0)
    fail("dark_current", "must be >= 0, got " + num(in.dark_current_a_m2));
  requirePositive(in.dark_reference_temperature_k, "dark_reference_temperature_k");
  requirePositive(in.temperature_k, "temperature_k");
  requirePositive(in.full_well_e, "full_well_e");
}

void validateSun(const SceneInputs& in)
{
  requirePositive(in.sun_surface_flux_w_m2, "sun_surface_flux_w_m2");
  requirePositive(in.sun_radius_m, "sun_radius_m");
  requirePositive(in.mars_perihelion_m, "mars_perihelion_m");
  requirePositive(in.mars_aphelion_m, "mars_aphelion_m");
  requirePositive(in.mars_semi_major_axis_m, "mars_semi_major_axis_m");
  if (in.mars_perihelion_m > in.mars_semi_major_axis_m || in.mars_semi_major_axis_m > in.mars_aphelion_m)
    fail("mars_semi_major_axis_m", "need perihelion <= semi-major axis <= aphelion");
  if (in.mars_perihelion_m <= in.sun_radius_m)
    fail("mars_perihelion_m", "must exceed the sun's radius");
  if (!std::isfinite(in.atmosphere_loss) || in.atmosphere_loss < 0.0 || in.atmosphere_loss >= 1.0)
    fail("atmosphere_loss", "must be in [0, 1), got " + num(in.atmosphere_loss));
  requireAngle(in.latitude_deg, 0.0, 89.0, "latitude_deg");
  requireAngle(in.sun_elevation_min_deg, 0.1, 90.0, "sun_elevation_min_deg");
  if (in.sun_elevation_min_deg > 90.0 - in.latitude_deg)
    fail("sun_elevation_min_deg",
         num(in.sun_elevation_min_deg) +
             " deg is above the highest elevation 90 - latitude = " + num(90.0 - in.latitude_deg) + " deg");
}

void validateTarget(const SceneInputs& in)
{
  requireFraction(in.albedo_min, "albedo_min");
  requireFraction(in.albedo_max, "albedo_max");
  if (in.albedo_min > in.albedo_max)
    fail("albedo_min", "larger than albedo_max (" + num(in.albedo_min) + " > " + num(in.albedo_max) + ")");
  requireAngle(in.sun_incidence_min_deg, 0.0, 89.9, "sun_incidence_min_deg");
  requireAngle(in.sun_incidence_max_deg, 0.0, 89.9, "sun_incidence_max_deg");
  if (in.sun_incidence_min_deg > in.sun_incidence_max_deg)
    fail("sun_incidence_min_deg", "larger than sun_incidence_max_deg");
  requireFraction(in.glossy_fraction, "glossy_fraction");
}

void validateLed(const SceneInputs& in)
{
  requirePositive(in.led_luminous_intensity_cd, "led_luminous_intensity_cd");
  if (!std::isfinite(in.led_beam_angle_deg) || in.led_beam_angle_deg <= 0.0 || in.led_beam_angle_deg >= 180.0)
    fail("led_beam_angle_deg", "must be in (0, 180) deg, got " + num(in.led_beam_angle_deg));
  requirePositive(in.led_luminous_efficacy_lm_w, "led_luminous_efficacy_lm_w");
  if (in.led_luminous_efficacy_lm_w > kMaxLuminousEfficacy)
    fail("led_luminous_efficacy_lm_w", "above the physical maximum of 683 lm/W");
  if (!std::isfinite(in.led_wavelength_m) || in.led_wavelength_m < 380e-9 || in.led_wavelength_m > 780e-9)
    fail("led_wavelength_m",
         "must be a visible wavelength in [380, 780] nm, got " + num(in.led_wavelength_m * 1e9) + " nm");
  if (in.led_wavelength_m < in.quantum_efficiency.front().first ||
      in.led_wavelength_m > in.quantum_efficiency.back().first)
    fail("led_wavelength_m", "outside the quantum efficiency table");
  requireFraction(in.led_lens_transmission, "led_lens_transmission");
  requireFraction(in.led_grid_transmission, "led_grid_transmission");
  if (in.dot_rows <= 0 || in.dot_cols <= 0)
    fail("dots", "rows and cols must be positive");
  requirePositive(in.dot_area_m2, "dot_area_m2");
  requireAngle(in.led_incidence_deg, 0.0, 89.9, "led_incidence_deg");
}

void validateSweep(const SceneInputs& in)
{
  requirePositive(in.sweep_aperture_min_m, "sweep_aperture_min_m");
  if (in.sweep_aperture_max_m <= in.sweep_aperture_min_m)
    fail("sweep_aperture_max_m", "must exceed sweep_aperture_min_m");
  const double efl = eflOf(in);
  if (in.sweep_aperture_max_m > efl)
    fail("sweep_aperture_max_m", "larger than the EFL " + num(efl) + " m (f/1)");
}

}  // namespace

std::vector<std::pair<double, double>> SceneInputs::defaultQuantumEfficiency()
{
  // Shape of a front-illuminated frame-transfer CCD peaking at 510 nm (study
  // fig. 2.3, which the text version of the study does not reproduce). Its
  // level is chosen so that with lens_transmission = 0.8 it gives the
  // efficiencies the study's own numbers imply: band mean of QE x lens = 0.157
  // ((2.22) / (2.21)) and 0.274 at 520 nm (LED case, once its x100 slip is
  // removed).
  static const double table[][2] = {
      {400, 0.100}, {425, 0.160}, {450, 0.230}, {475, 0.290}, {500, 0.335}, {510, 0.343}, {525, 0.340},
      {550, 0.315}, {575, 0.280}, {600, 0.240}, {650, 0.170}, {700, 0.115}, {750, 0.080}, {800, 0.050},
  };
  std::vector<std::pair<double, double>> qe;
  for (const auto& row : table)
    qe.emplace_back(row[0] * 1e-9, row[1]);
  return qe;
}

// In the order of the study's sections; the first failure throws.
void SceneInputs::validate() const
{
  validateScene(*this);
  validateOptics(*this);
  validateQuantumEfficiency(*this);
  validateSensorNoise(*this);
  validateSun(*this);
  validateTarget(*this);
  validateLed(*this);
  validateSweep(*this);
}

// ---------------------------------------------------------------------------
// YAML

namespace
{

// A numeric key of a section: where it goes and its file unit -> SI factor.
struct YamlField
{
  const char* key;
  double* value;
  double scale;
};

std::string where(const std::string& source, const YAML::Node& node)
{
  const YAML::Mark m = node.Mark();
  if (m.line < 0)
    return source;
  return source + ":" + std::to_string(m.line + 1);
}

[[noreturn]] void refuse(const std::string& source, const YAML::Node& node, const std::string& reason)
{
  throw std::invalid_argument("scene_analysis: " + where(source, node) + ": " + reason);
}

double readNumber(const YAML::Node& node, const std::string& what, const std::string& source)
{
  if (!node.IsScalar())
    refuse(source, node, what + " must be a number");
  double v = 0.0;
  try
  {
    v = node.as<double>();
  }
  catch (const YAML::Exception&)
  {
    refuse(source, node, what + " is not a number ('" + node.Scalar() + "')");
  }
  if (!std::isfinite(v))
    refuse(source, node, what + " is not finite");
  return v;
}

int readInt(const YAML::Node& node, const std::string& what, const std::string& source)
{
  const double v = readNumber(node, what, source);
  if (v != std::floor(v) || std::fabs(v) > 1e6)
    refuse(source, node, what + " must be an integer");
  return static_cast<int>(v);
}

// Reads the numeric fields of one section; extra_keys are read elsewhere,
// any other key is refused with the list of known ones.
void readSection(const YAML::Node& root, const char* section, const std::vector<YamlField>& fields,
                 const std::vector<std::string>& extra_keys, const std::string& source)
{
  const YAML::Node node = root[section];
  if (!node)
    return;
  if (!node.IsMap())
    refuse(source, node, std::string("section '") + section + "' must be a mapping");
  for (const auto& kv : node)
  {
    const std::string key = kv.first.as<std::string>();
    bool known = std::find(extra_keys.begin(), extra_keys.end(), key) != extra_keys.end();
    for (const auto& f : fields)
    {
      if (key == f.key)
      {
        *f.value = readNumber(kv.second, std::string(section) + "." + key, source) * f.scale;
        known = true;
      }
    }
    if (known)
      continue;
    std::string list;
    for (const auto& f : fields)
      list += std::string(list.empty() ? "" : ", ") + f.key;
    for (const auto& k : extra_keys)
      list += ", " + k;
    refuse(source, kv.first, "unknown key '" + std::string(section) + "." + key + "' (known: " + list + ")");
  }
}

void checkSections(const YAML::Node& root, const std::string& source)
{
  const std::vector<std::string> sections = {"scene", "camera", "sun", "target", "led", "sweep"};
  for (const auto& kv : root)
  {
    const std::string key = kv.first.as<std::string>();
    if (std::find(sections.begin(), sections.end(), key) == sections.end())
      refuse(source, kv.first, "unknown section '" + key + "' (known: scene, camera, sun, target, led, sweep)");
  }
}

// The numeric keys of every section, in file units (the key names say which).
void readNumericSections(const YAML::Node& root, const std::string& source, SceneInputs* in)
{
  readSection(root, "scene",
              {{"target_height_m", &in->target_height_m, 1.0},
               {"distance_min_m", &in->distance_min_m, 1.0},
               {"distance_max_m", &in->distance_max_m, 1.0}},
              {}, source);
  readSection(root, "camera",
              {{"pixel_size_um", &in->pixel_size_m, 1e-6},
               {"sensor_height_mm", &in->sensor_height_m, 1e-3},
               {"focus_distance_m", &in->focus_distance_m, 1.0},
               {"aperture_diameter_mm", &in->aperture_diameter_m, 1e-3},
               {"wavelength_min_nm", &in->wavelength_min_m, 1e-9},
               {"wavelength_max_nm", &in->wavelength_max_m, 1e-9},
               {"exposure_s", &in->exposure_s, 1.0},
               {"camera_axis_angle_deg", &in->camera_axis_angle_deg, 1.0},
               {"lens_transmission", &in->lens_transmission, 1.0},
               {"read_noise_e", &in->read_noise_e, 1.0},
               {"dark_current_pa_cm2", &in->dark_current_a_m2, 1e-12 / 1e-4},
               {"dark_reference_temperature_k", &in->dark_reference_temperature_k, 1.0},
               {"temperature_k", &in->temperature_k, 1.0},
               {"full_well_e", &in->full_well_e, 1.0}},
              {"pixels_x", "pixels_y", "quantum_efficiency"}, source);
  readSection(root, "sun",
              {{"surface_flux_w_m2", &in->sun_surface_flux_w_m2, 1.0},
               {"radius_m", &in->sun_radius_m, 1.0},
               {"mars_perihelion_m", &in->mars_perihelion_m, 1.0},
               {"mars_aphelion_m", &in->mars_aphelion_m, 1.0},
               {"mars_semi_major_axis_m", &in->mars_semi_major_axis_m, 1.0},
               {"atmosphere_loss", &in->atmosphere_loss, 1.0},
               {"latitude_deg", &in->latitude_deg, 1.0},
               {"elevation_min_deg", &in->sun_elevation_min_deg, 1.0}},
              {}, source);
  readSection(root, "target",
              {{"albedo_min", &in->albedo_min, 1.0},
               {"albedo_max", &in->albedo_max, 1.0},
               {"sun_incidence_min_deg", &in->sun_incidence_min_deg, 1.0},
               {"sun_incidence_max_deg", &in->sun_incidence_max_deg, 1.0},
               {"glossy_fraction", &in->glossy_fraction, 1.0}},
              {}, source);
  readSection(root, "led",
              {{"luminous_intensity_cd", &in->led_luminous_intensity_cd, 1.0},
               {"beam_angle_deg", &in->led_beam_angle_deg, 1.0},
               {"luminous_efficacy_lm_w", &in->led_luminous_efficacy_lm_w, 1.0},
               {"wavelength_nm", &in->led_wavelength_m, 1e-9},
               {"lens_transmission", &in->led_lens_transmission, 1.0},
               {"grid_transmission", &in->led_grid_transmission, 1.0},
               {"dot_area_mm2", &in->dot_area_m2, 1e-6},
               {"incidence_deg", &in->led_incidence_deg, 1.0}},
              {"dot_rows", "dot_cols"}, source);
  readSection(
      root, "sweep",
      {{"aperture_min_mm", &in->sweep_aperture_min_m, 1e-3}, {"aperture_max_mm", &in->sweep_aperture_max_m, 1e-3}}, {},
      source);
}

// camera.quantum_efficiency: a list of [wavelength_nm, qe] pairs.
void readQuantumEfficiency(const YAML::Node& qe, const std::string& source, SceneInputs* in)
{
  if (!qe.IsSequence())
    refuse(source, qe, "camera.quantum_efficiency must be a list of [wavelength_nm, qe] pairs");
  in->quantum_efficiency.clear();
  for (size_t i = 0; i < qe.size(); ++i)
  {
    const YAML::Node p = qe[i];
    if (!p.IsSequence() || p.size() != 2)
      refuse(source, p, "camera.quantum_efficiency[" + std::to_string(i) + "] must be a pair [wavelength_nm, qe]");
    in->quantum_efficiency.emplace_back(readNumber(p[0], "quantum_efficiency wavelength", source) * 1e-9,
                                        readNumber(p[1], "quantum_efficiency value", source));
  }
}

// The integer and list keys (the extra keys of readSection).
void readOtherKeys(const YAML::Node& root, const std::string& source, SceneInputs* in)
{
  const YAML::Node cam = root["camera"];
  if (cam)
  {
    if (cam["pixels_x"])
      in->pixels_x = readInt(cam["pixels_x"], "camera.pixels_x", source);
    if (cam["pixels_y"])
      in->pixels_y = readInt(cam["pixels_y"], "camera.pixels_y", source);
    if (cam["quantum_efficiency"])
      readQuantumEfficiency(cam["quantum_efficiency"], source, in);
  }
  const YAML::Node led = root["led"];
  if (led)
  {
    if (led["dot_rows"])
      in->dot_rows = readInt(led["dot_rows"], "led.dot_rows", source);
    if (led["dot_cols"])
      in->dot_cols = readInt(led["dot_cols"], "led.dot_cols", source);
  }
}

SceneInputs parseSceneInputs(const std::string& yaml_text, const std::string& source)
{
  YAML::Node root;
  try
  {
    root = YAML::Load(yaml_text);
  }
  catch (const YAML::Exception& e)
  {
    throw std::invalid_argument("scene_analysis: " + source + ": not valid YAML: " + e.what());
  }
  SceneInputs in;
  if (root.IsNull())
    return in;  // an empty file means "the study's defaults"
  if (!root.IsMap())
    throw std::invalid_argument("scene_analysis: " + source + ": top level must be a mapping of sections");
  checkSections(root, source);
  readNumericSections(root, source, &in);
  readOtherKeys(root, source, &in);
  try
  {
    in.validate();
  }
  catch (const std::invalid_argument& e)
  {
    throw std::invalid_argument(std::string(e.what()) + " (in " + source + ")");
  }
  return in;
}

}  // namespace

SceneInputs sceneInputsFromYaml(const std::string& yaml_text, const std::string& source)
{
  try
  {
    return parseSceneInputs(yaml_text, source);
  }
  catch (const YAML::Exception& e)
  {
    // e.g. a key that is itself a list or a mapping.
    throw std::invalid_argument("scene_analysis: " + source + ": unexpected YAML structure: " + e.what());
  }
}

SceneInputs loadSceneInputs(const std::string& path)
{
  std::ifstream file(path);
  if (!file)
    throw std::invalid_argument("scene_analysis: cannot open '" + path + "'");
  std::stringstream ss;
  ss << file.rdbuf();
  return sceneInputsFromYaml(ss.str(), path);
}

}  // namespace structured_light_stabilizer
