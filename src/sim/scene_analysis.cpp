#include "structured_light_stabilizer/sim/scene_analysis.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgproc.hpp>
#include <yaml-cpp/yaml.h>

namespace structured_light_stabilizer
{

namespace
{

constexpr double kPi = 3.14159265358979323846;
constexpr double kPlanck = 6.62607015e-34;      // J s
constexpr double kLightSpeed = 299792458.0;     // m/s
constexpr double kBoltzmannEv = 8.617333262e-5;  // eV/K
constexpr double kBoltzmann = 1.380649e-23;     // J/K
constexpr double kStefanBoltzmann = 5.670374419e-8;  // W/(m^2 K^4)
constexpr double kElementaryCharge = 1.602176634e-19;  // C
constexpr double kMaxLuminousEfficacy = 683.0;  // lm/W at 555 nm
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

double deg2rad(double d) { return d * kPi / 180.0; }
double rad2deg(double r) { return r * 180.0 / kPi; }

[[noreturn]] void fail(const std::string& field, const std::string& reason)
{
  throw std::invalid_argument("scene_analysis: " + field + ": " + reason);
}

std::string num(double v)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6g", v);
  return buf;
}

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

// Silicon band gap (eV) versus temperature (Varshni form used by Janesick).
double siliconBandGapEv(double t_k)
{
  return 1.1557 - 7.021e-4 * t_k * t_k / (1108.0 + t_k);
}

// Spectral radiant exitance of a blackbody, W/(m^2 m).
double planckExitance(double wavelength_m, double t_k)
{
  const double a = 2.0 * kPi * kPlanck * kLightSpeed * kLightSpeed / std::pow(wavelength_m, 5);
  const double x = kPlanck * kLightSpeed / (wavelength_m * kBoltzmann * t_k);
  return a / std::expm1(x);
}

// Simpson's rule on [a, b] with n (even) intervals.
double integrate(const std::function<double(double)>& f, double a, double b, int n = 2000)
{
  const double h = (b - a) / n;
  double s = f(a) + f(b);
  for (int i = 1; i < n; ++i)
    s += f(a + i * h) * ((i % 2) ? 4.0 : 2.0);
  return s * h / 3.0;
}

// Camera equation factor: sensor irradiance = radiance * this (study (2.9)).
double cameraFactor(const SceneInputs& in, double efl)
{
  const double c = std::cos(deg2rad(in.camera_axis_angle_deg));
  const double r = in.aperture_diameter_m / efl;
  return kPi / 4.0 * r * r * c * c * c * c;
}

double eflOf(const SceneInputs& in)
{
  const double half = std::atan(0.5 * in.target_height_m / in.distance_max_m);
  return 0.5 * in.sensor_height_m / std::tan(half);
}

double focalOf(const SceneInputs& in, double efl)
{
  return 1.0 / (1.0 / in.focus_distance_m + 1.0 / efl);
}

double photonEnergy(double wavelength_m) { return kPlanck * kLightSpeed / wavelength_m; }

// CIE 1931 2-degree photopic V(lambda), 380-780 nm in 10 nm steps.
const double kPhotopic[] = {
  0.000039, 0.000120, 0.000396, 0.001210, 0.004000, 0.011600, 0.023000, 0.038000, 0.060000,
  0.090980, 0.139020, 0.208020, 0.323000, 0.503000, 0.710000, 0.862000, 0.954000, 0.994950,
  0.995000, 0.952000, 0.870000, 0.757000, 0.631000, 0.503000, 0.381000, 0.265000, 0.175000,
  0.107000, 0.061000, 0.032000, 0.017000, 0.008210, 0.004102, 0.002091, 0.001047, 0.000520,
  0.000249, 0.000120, 0.000060, 0.000030, 0.000015,
};

}  // namespace

// ---------------------------------------------------------------------------
// Inputs

std::vector<std::pair<double, double>> SceneInputs::defaultQuantumEfficiency()
{
  // Shape of a front-illuminated frame-transfer CCD peaking at 510 nm (study
  // fig. 2.3, which the text version of the study does not reproduce). Its
  // level is chosen so that with lens_transmission = 0.8 it gives the
  // efficiencies the study's own numbers imply: band mean of QE x lens = 0.157
  // ((2.22) / (2.21)) and 0.274 at 520 nm (LED case, once its x100 slip is
  // removed).
  static const double table[][2] = {
    { 400, 0.100 }, { 425, 0.160 }, { 450, 0.230 }, { 475, 0.290 }, { 500, 0.335 },
    { 510, 0.343 }, { 525, 0.340 }, { 550, 0.315 }, { 575, 0.280 }, { 600, 0.240 },
    { 650, 0.170 }, { 700, 0.115 }, { 750, 0.080 }, { 800, 0.050 },
  };
  std::vector<std::pair<double, double>> qe;
  for (const auto& row : table)
    qe.emplace_back(row[0] * 1e-9, row[1]);
  return qe;
}

void SceneInputs::validate() const
{
  requirePositive(target_height_m, "target_height_m");
  requirePositive(distance_min_m, "distance_min_m");
  requirePositive(distance_max_m, "distance_max_m");
  if (distance_min_m > distance_max_m)
    fail("distance_min_m", "larger than distance_max_m (" + num(distance_min_m) + " > " + num(distance_max_m) + ")");
  if (pixels_x <= 0 || pixels_y <= 0)
    fail("pixels", "must be positive, got " + std::to_string(pixels_x) + " x " + std::to_string(pixels_y));
  requirePositive(pixel_size_m, "pixel_size_m");
  requirePositive(sensor_height_m, "sensor_height_m");
  if (sensor_height_m > pixels_y * pixel_size_m * (1.0 + 1e-9))
    fail("sensor_height_m", "larger than pixels_y * pixel_size_m = " + num(pixels_y * pixel_size_m) + " m");
  requirePositive(focus_distance_m, "focus_distance_m");
  requirePositive(aperture_diameter_m, "aperture_diameter_m");
  const double efl = eflOf(*this);
  if (focus_distance_m <= efl)
    fail("focus_distance_m", "must exceed the effective focal length " + num(efl) + " m");
  // f/1 is the practical limit of a lens (and of the paraxial camera
  // equation (2.9)): the entrance pupil cannot exceed the EFL.
  if (aperture_diameter_m > efl)
    fail("aperture_diameter_m", num(aperture_diameter_m) + " m is larger than the lens allows: at most the EFL " +
                                    num(efl) + " m (f/1)");
  requirePositive(wavelength_min_m, "wavelength_min_m");
  requirePositive(wavelength_max_m, "wavelength_max_m");
  if (wavelength_min_m >= wavelength_max_m)
    fail("wavelength_min_m", "wavelength range reversed or empty (" + num(wavelength_min_m * 1e9) + " nm >= " +
                                 num(wavelength_max_m * 1e9) + " nm)");
  requirePositive(exposure_s, "exposure_s");
  requireAngle(camera_axis_angle_deg, 0.0, 89.0, "camera_axis_angle_deg");
  requireFraction(lens_transmission, "lens_transmission");
  if (quantum_efficiency.size() < 2)
    fail("quantum_efficiency", "needs at least 2 (wavelength, QE) points");
  for (size_t i = 0; i < quantum_efficiency.size(); ++i)
  {
    const auto& p = quantum_efficiency[i];
    if (!std::isfinite(p.first) || p.first <= 0.0)
      fail("quantum_efficiency", "wavelength of point " + std::to_string(i) + " must be positive");
    if (!std::isfinite(p.second) || p.second < 0.0 || p.second > 1.0)
      fail("quantum_efficiency", "QE of point " + std::to_string(i) + " must be in [0, 1], got " + num(p.second));
    if (i > 0 && p.first <= quantum_efficiency[i - 1].first)
      fail("quantum_efficiency", "wavelengths must increase (point " + std::to_string(i) + ")");
  }
  if (quantum_efficiency.front().first > wavelength_min_m * (1 + 1e-9) ||
      quantum_efficiency.back().first < wavelength_max_m * (1 - 1e-9))
    fail("quantum_efficiency", "table must cover the wavelength range [" + num(wavelength_min_m * 1e9) + ", " +
                                   num(wavelength_max_m * 1e9) + "] nm");
  if (!std::isfinite(read_noise_e) || read_noise_e < 0.0)
    fail("read_noise_e", "must be >= 0, got " + num(read_noise_e));
  if (!std::isfinite(dark_current_a_m2) || dark_current_a_m2 < 0.0)
    fail("dark_current", "must be >= 0, got " + num(dark_current_a_m2));
  requirePositive(dark_reference_temperature_k, "dark_reference_temperature_k");
  requirePositive(temperature_k, "temperature_k");
  requirePositive(full_well_e, "full_well_e");

  requirePositive(sun_surface_flux_w_m2, "sun_surface_flux_w_m2");
  requirePositive(sun_radius_m, "sun_radius_m");
  requirePositive(mars_perihelion_m, "mars_perihelion_m");
  requirePositive(mars_aphelion_m, "mars_aphelion_m");
  requirePositive(mars_semi_major_axis_m, "mars_semi_major_axis_m");
  if (mars_perihelion_m > mars_semi_major_axis_m || mars_semi_major_axis_m > mars_aphelion_m)
    fail("mars_semi_major_axis_m", "need perihelion <= semi-major axis <= aphelion");
  if (mars_perihelion_m <= sun_radius_m)
    fail("mars_perihelion_m", "must exceed the sun's radius");
  if (!std::isfinite(atmosphere_loss) || atmosphere_loss < 0.0 || atmosphere_loss >= 1.0)
    fail("atmosphere_loss", "must be in [0, 1), got " + num(atmosphere_loss));
  requireAngle(latitude_deg, 0.0, 89.0, "latitude_deg");
  requireAngle(sun_elevation_min_deg, 0.1, 90.0, "sun_elevation_min_deg");
  if (sun_elevation_min_deg > 90.0 - latitude_deg)
    fail("sun_elevation_min_deg", num(sun_elevation_min_deg) + " deg is above the highest elevation 90 - latitude = " +
                                      num(90.0 - latitude_deg) + " deg");

  requireFraction(albedo_min, "albedo_min");
  requireFraction(albedo_max, "albedo_max");
  if (albedo_min > albedo_max)
    fail("albedo_min", "larger than albedo_max (" + num(albedo_min) + " > " + num(albedo_max) + ")");
  requireAngle(sun_incidence_min_deg, 0.0, 89.9, "sun_incidence_min_deg");
  requireAngle(sun_incidence_max_deg, 0.0, 89.9, "sun_incidence_max_deg");
  if (sun_incidence_min_deg > sun_incidence_max_deg)
    fail("sun_incidence_min_deg", "larger than sun_incidence_max_deg");
  requireFraction(glossy_fraction, "glossy_fraction");

  requirePositive(led_luminous_intensity_cd, "led_luminous_intensity_cd");
  if (!std::isfinite(led_beam_angle_deg) || led_beam_angle_deg <= 0.0 || led_beam_angle_deg >= 180.0)
    fail("led_beam_angle_deg", "must be in (0, 180) deg, got " + num(led_beam_angle_deg));
  requirePositive(led_luminous_efficacy_lm_w, "led_luminous_efficacy_lm_w");
  if (led_luminous_efficacy_lm_w > kMaxLuminousEfficacy)
    fail("led_luminous_efficacy_lm_w", "above the physical maximum of 683 lm/W");
  if (!std::isfinite(led_wavelength_m) || led_wavelength_m < 380e-9 || led_wavelength_m > 780e-9)
    fail("led_wavelength_m", "must be a visible wavelength in [380, 780] nm, got " + num(led_wavelength_m * 1e9) +
                                 " nm");
  if (led_wavelength_m < quantum_efficiency.front().first || led_wavelength_m > quantum_efficiency.back().first)
    fail("led_wavelength_m", "outside the quantum efficiency table");
  requireFraction(led_lens_transmission, "led_lens_transmission");
  requireFraction(led_grid_transmission, "led_grid_transmission");
  if (dot_rows <= 0 || dot_cols <= 0)
    fail("dots", "rows and cols must be positive");
  requirePositive(dot_area_m2, "dot_area_m2");
  requireAngle(led_incidence_deg, 0.0, 89.9, "led_incidence_deg");

  requirePositive(sweep_aperture_min_m, "sweep_aperture_min_m");
  if (sweep_aperture_max_m <= sweep_aperture_min_m)
    fail("sweep_aperture_max_m", "must exceed sweep_aperture_min_m");
  if (sweep_aperture_max_m > efl)
    fail("sweep_aperture_max_m", "larger than the EFL " + num(efl) + " m (f/1)");
}

// ---------------------------------------------------------------------------
// YAML

namespace
{

struct YamlField
{
  const char* key;
  double* value;
  double scale;  // file unit -> SI
};

std::string where(const std::string& source, const YAML::Node& node)
{
  const YAML::Mark m = node.Mark();
  if (m.line < 0)
    return source;
  return source + ":" + std::to_string(m.line + 1);
}

double readNumber(const YAML::Node& node, const std::string& what, const std::string& source)
{
  if (!node.IsScalar())
    throw std::invalid_argument("scene_analysis: " + where(source, node) + ": " + what + " must be a number");
  double v = 0.0;
  try
  {
    v = node.as<double>();
  }
  catch (const YAML::Exception&)
  {
    throw std::invalid_argument("scene_analysis: " + where(source, node) + ": " + what + " is not a number ('" +
                                node.Scalar() + "')");
  }
  if (!std::isfinite(v))
    throw std::invalid_argument("scene_analysis: " + where(source, node) + ": " + what + " is not finite");
  return v;
}

void readSection(const YAML::Node& root, const char* section, const std::vector<YamlField>& fields,
                 const std::vector<std::string>& extra_keys, const std::string& source)
{
  const YAML::Node node = root[section];
  if (!node)
    return;
  if (!node.IsMap())
    throw std::invalid_argument("scene_analysis: " + where(source, node) + ": section '" + section +
                                "' must be a mapping");
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
    if (!known)
    {
      std::string list;
      for (const auto& f : fields)
        list += std::string(list.empty() ? "" : ", ") + f.key;
      for (const auto& k : extra_keys)
        list += ", " + k;
      throw std::invalid_argument("scene_analysis: " + where(source, kv.first) + ": unknown key '" + section + "." +
                                  key + "' (known: " + list + ")");
    }
  }
}

int readInt(const YAML::Node& node, const std::string& what, const std::string& source)
{
  const double v = readNumber(node, what, source);
  if (v != std::floor(v) || std::fabs(v) > 1e6)
    throw std::invalid_argument("scene_analysis: " + where(source, node) + ": " + what + " must be an integer");
  return static_cast<int>(v);
}

}  // namespace

namespace
{
SceneInputs parseSceneInputs(const std::string& yaml_text, const std::string& source);
}

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

namespace
{
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

  const std::vector<std::string> sections = { "scene", "camera", "sun", "target", "led", "sweep" };
  for (const auto& kv : root)
  {
    const std::string key = kv.first.as<std::string>();
    if (std::find(sections.begin(), sections.end(), key) == sections.end())
      throw std::invalid_argument("scene_analysis: " + where(source, kv.first) + ": unknown section '" + key +
                                  "' (known: scene, camera, sun, target, led, sweep)");
  }

  readSection(root, "scene",
              { { "target_height_m", &in.target_height_m, 1.0 },
                { "distance_min_m", &in.distance_min_m, 1.0 },
                { "distance_max_m", &in.distance_max_m, 1.0 } },
              {}, source);
  readSection(root, "camera",
              { { "pixel_size_um", &in.pixel_size_m, 1e-6 },
                { "sensor_height_mm", &in.sensor_height_m, 1e-3 },
                { "focus_distance_m", &in.focus_distance_m, 1.0 },
                { "aperture_diameter_mm", &in.aperture_diameter_m, 1e-3 },
                { "wavelength_min_nm", &in.wavelength_min_m, 1e-9 },
                { "wavelength_max_nm", &in.wavelength_max_m, 1e-9 },
                { "exposure_s", &in.exposure_s, 1.0 },
                { "camera_axis_angle_deg", &in.camera_axis_angle_deg, 1.0 },
                { "lens_transmission", &in.lens_transmission, 1.0 },
                { "read_noise_e", &in.read_noise_e, 1.0 },
                { "dark_current_pa_cm2", &in.dark_current_a_m2, 1e-12 / 1e-4 },
                { "dark_reference_temperature_k", &in.dark_reference_temperature_k, 1.0 },
                { "temperature_k", &in.temperature_k, 1.0 },
                { "full_well_e", &in.full_well_e, 1.0 } },
              { "pixels_x", "pixels_y", "quantum_efficiency" }, source);
  readSection(root, "sun",
              { { "surface_flux_w_m2", &in.sun_surface_flux_w_m2, 1.0 },
                { "radius_m", &in.sun_radius_m, 1.0 },
                { "mars_perihelion_m", &in.mars_perihelion_m, 1.0 },
                { "mars_aphelion_m", &in.mars_aphelion_m, 1.0 },
                { "mars_semi_major_axis_m", &in.mars_semi_major_axis_m, 1.0 },
                { "atmosphere_loss", &in.atmosphere_loss, 1.0 },
                { "latitude_deg", &in.latitude_deg, 1.0 },
                { "elevation_min_deg", &in.sun_elevation_min_deg, 1.0 } },
              {}, source);
  readSection(root, "target",
              { { "albedo_min", &in.albedo_min, 1.0 },
                { "albedo_max", &in.albedo_max, 1.0 },
                { "sun_incidence_min_deg", &in.sun_incidence_min_deg, 1.0 },
                { "sun_incidence_max_deg", &in.sun_incidence_max_deg, 1.0 },
                { "glossy_fraction", &in.glossy_fraction, 1.0 } },
              {}, source);
  readSection(root, "led",
              { { "luminous_intensity_cd", &in.led_luminous_intensity_cd, 1.0 },
                { "beam_angle_deg", &in.led_beam_angle_deg, 1.0 },
                { "luminous_efficacy_lm_w", &in.led_luminous_efficacy_lm_w, 1.0 },
                { "wavelength_nm", &in.led_wavelength_m, 1e-9 },
                { "lens_transmission", &in.led_lens_transmission, 1.0 },
                { "grid_transmission", &in.led_grid_transmission, 1.0 },
                { "dot_area_mm2", &in.dot_area_m2, 1e-6 },
                { "incidence_deg", &in.led_incidence_deg, 1.0 } },
              { "dot_rows", "dot_cols" }, source);
  readSection(root, "sweep",
              { { "aperture_min_mm", &in.sweep_aperture_min_m, 1e-3 },
                { "aperture_max_mm", &in.sweep_aperture_max_m, 1e-3 } },
              {}, source);

  const YAML::Node cam = root["camera"];
  if (cam)
  {
    if (cam["pixels_x"])
      in.pixels_x = readInt(cam["pixels_x"], "camera.pixels_x", source);
    if (cam["pixels_y"])
      in.pixels_y = readInt(cam["pixels_y"], "camera.pixels_y", source);
    const YAML::Node qe = cam["quantum_efficiency"];
    if (qe)
    {
      if (!qe.IsSequence())
        throw std::invalid_argument("scene_analysis: " + where(source, qe) +
                                    ": camera.quantum_efficiency must be a list of [wavelength_nm, qe] pairs");
      in.quantum_efficiency.clear();
      for (size_t i = 0; i < qe.size(); ++i)
      {
        const YAML::Node p = qe[i];
        if (!p.IsSequence() || p.size() != 2)
          throw std::invalid_argument("scene_analysis: " + where(source, p) + ": camera.quantum_efficiency[" +
                                      std::to_string(i) + "] must be a pair [wavelength_nm, qe]");
        in.quantum_efficiency.emplace_back(readNumber(p[0], "quantum_efficiency wavelength", source) * 1e-9,
                                           readNumber(p[1], "quantum_efficiency value", source));
      }
    }
  }
  const YAML::Node led = root["led"];
  if (led)
  {
    if (led["dot_rows"])
      in.dot_rows = readInt(led["dot_rows"], "led.dot_rows", source);
    if (led["dot_cols"])
      in.dot_cols = readInt(led["dot_cols"], "led.dot_cols", source);
  }
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

SceneInputs loadSceneInputs(const std::string& path)
{
  std::ifstream file(path);
  if (!file)
    throw std::invalid_argument("scene_analysis: cannot open '" + path + "'");
  std::stringstream ss;
  ss << file.rdbuf();
  return sceneInputsFromYaml(ss.str(), path);
}

// ---------------------------------------------------------------------------
// Building blocks

double diameterOfConfusion(const SceneInputs& in, double aperture_m, double distance_m)
{
  const double efl = eflOf(in);
  const double f = focalOf(in, efl);
  const double rf = in.focus_distance_m;
  return aperture_m * std::fabs(distance_m - rf) / distance_m * f / (rf - f);
}

double diffractionSpot(const SceneInputs& in, double aperture_m, double wavelength_m)
{
  return 2.0 * eflOf(in) * std::tan(1.22 * wavelength_m / aperture_m);
}

double quantumEfficiency(const SceneInputs& in, double wavelength_m)
{
  const auto& t = in.quantum_efficiency;
  if (t.empty())
    return 0.0;
  if (wavelength_m <= t.front().first)
    return t.front().second;
  if (wavelength_m >= t.back().first)
    return t.back().second;
  auto hi = std::lower_bound(t.begin(), t.end(), wavelength_m,
                             [](const std::pair<double, double>& p, double w) { return p.first < w; });
  auto lo = hi - 1;
  const double u = (wavelength_m - lo->first) / (hi->first - lo->first);
  return lo->second + u * (hi->second - lo->second);
}

double photopicEfficiency(double wavelength_m)
{
  const double nm = wavelength_m * 1e9;
  if (nm < 380.0 || nm > 780.0)
    return 0.0;
  const double x = (nm - 380.0) / 10.0;
  const int i = std::min(static_cast<int>(x), 39);
  const double u = x - i;
  return kPhotopic[i] + u * (kPhotopic[i + 1] - kPhotopic[i]);
}

double targetRadiance(const SceneInputs& in, double irradiance, double albedo, double incidence_deg, Brdf brdf)
{
  const double c = std::cos(deg2rad(incidence_deg));
  if (brdf == Brdf::kLambertian)
    return irradiance * albedo / kPi * c;
  // The study's "optimal" surface: (1-g) Lambertian plus a glossy lobe of
  // constant BRDF g*albedo (sr^-1), applied to the irradiance without cos.
  return irradiance * albedo * ((1.0 - in.glossy_fraction) / kPi * c + in.glossy_fraction);
}

// ---------------------------------------------------------------------------
// Analysis

namespace
{

struct Ctx
{
  const SceneInputs& in;
  double efl;
  double cam;          // camera equation factor
  double pixel_area;
  double band_mean_wl;
  double sun_eff;      // photon-weighted QE * lens over the band
  double led_eff;      // QE * lens at the LED wavelength
};

double sunElectrons(const Ctx& c, double radiance, double exposure)
{
  const double w = radiance * c.cam * c.pixel_area;
  return w * exposure * c.band_mean_wl / (kPlanck * kLightSpeed) * c.sun_eff;
}

double ledElectrons(const Ctx& c, double radiance, double exposure)
{
  const double w = radiance * c.cam * c.pixel_area;
  return w * exposure / photonEnergy(c.in.led_wavelength_m) * c.led_eff;
}

double dotIrradiance(const Ctx& c, double led_power)
{
  const int n = c.in.dot_rows * c.in.dot_cols;
  return c.in.led_lens_transmission * c.in.led_grid_transmission * led_power / n / c.in.dot_area_m2;
}

Ctx makeCtx(const SceneInputs& in)
{
  Ctx c{ in, 0, 0, 0, 0, 0, 0 };
  c.efl = eflOf(in);
  c.cam = cameraFactor(in, c.efl);
  c.pixel_area = in.pixel_size_m * in.pixel_size_m;
  const double l0 = in.wavelength_min_m, l1 = in.wavelength_max_m;
  c.band_mean_wl = 0.5 * (l0 + l1);
  // A flat spectral power over the band: photons at lambda are weighted by lambda.
  c.sun_eff = integrate([&](double l) { return l * quantumEfficiency(in, l); }, l0, l1) /
              integrate([](double l) { return l; }, l0, l1) * in.lens_transmission;
  c.led_eff = quantumEfficiency(in, in.led_wavelength_m) * in.lens_transmission;
  return c;
}

// Decimal places of a number printed as text ("26.6" -> 1).
int decimalsOf(const std::string& s)
{
  const auto dot = s.find('.');
  if (dot == std::string::npos)
    return 0;
  size_t end = dot + 1;
  while (end < s.size() && std::isdigit(static_cast<unsigned char>(s[end])))
    ++end;
  return static_cast<int>(end - dot - 1);
}

class TableBuilder
{
public:
  explicit TableBuilder(std::vector<Quantity>* t) : t_(t) {}

  // value in SI, scale to the display unit; study as printed (display unit),
  // empty when the study gives no number; "lo|hi" for ranges.
  Quantity& add(const std::string& key, const std::string& name, const std::string& ref, double value_si,
                double scale, const std::string& unit, const std::string& study, const std::string& note = "")
  {
    Quantity q;
    q.key = key;
    q.name = name;
    q.ref = ref;
    q.value = value_si * scale;
    q.value_max = kNaN;
    q.unit = unit;
    q.note = note;
    setStudy(&q, study);
    if (q.has_study)
      q.agrees = within(q.value, q.study, study);
    t_->push_back(q);
    return t_->back();
  }

  Quantity& addRange(const std::string& key, const std::string& name, const std::string& ref, Range r_si,
                     double scale, const std::string& unit, const std::string& study_lo = "",
                     const std::string& study_hi = "", const std::string& note = "")
  {
    Quantity q;
    q.key = key;
    q.name = name;
    q.ref = ref;
    q.is_range = true;
    q.value = r_si.min * scale;
    q.value_max = r_si.max * scale;
    q.unit = unit;
    q.note = note;
    setStudy(&q, study_lo);
    if (!study_hi.empty())
      q.study_max = std::stod(study_hi);
    if (q.has_study)
      q.agrees = within(q.value, q.study, study_lo) && within(q.value_max, q.study_max, study_hi);
    t_->push_back(q);
    return t_->back();
  }

private:
  static void setStudy(Quantity* q, const std::string& s)
  {
    q->study = kNaN;
    q->study_max = kNaN;
    if (s.empty())
      return;
    q->has_study = true;
    q->study = std::stod(s);
  }
  // Agreement to the precision the study prints: half a unit in its last digit.
  static bool within(double v, double study, const std::string& text)
  {
    const double tol = 0.5 * std::pow(10.0, -decimalsOf(text)) * (1.0 + 1e-9);
    return std::fabs(v - study) <= tol;
  }

  std::vector<Quantity>* t_;
};

}  // namespace

SceneAnalysis analyseScene(const SceneInputs& inputs)
{
  inputs.validate();
  SceneAnalysis a;
  a.inputs = inputs;
  const SceneInputs& in = a.inputs;

  // --- Camera geometry (§2.1.1) ---
  const double half = std::atan(0.5 * in.target_height_m / in.distance_max_m);
  a.fov_half_deg = rad2deg(half);
  a.fov_full_deg = 2.0 * a.fov_half_deg;
  a.efl_m = eflOf(in);
  a.focal_length_m = focalOf(in, a.efl_m);
  a.f_number = a.focal_length_m / in.aperture_diameter_m;
  a.doc_far_m = diameterOfConfusion(in, in.aperture_diameter_m, in.distance_max_m);
  a.doc_near_m = diameterOfConfusion(in, in.aperture_diameter_m, in.distance_min_m);
  a.diffraction_min_m = diffractionSpot(in, in.aperture_diameter_m, in.wavelength_min_m);
  a.diffraction_max_m = diffractionSpot(in, in.aperture_diameter_m, in.wavelength_max_m);
  {
    // DoC grows with the aperture, the diffraction spot shrinks: bisect the crossing.
    double lo = 1e-6, hi = a.efl_m;
    for (int i = 0; i < 200; ++i)
    {
      const double m = 0.5 * (lo + hi);
      if (diameterOfConfusion(in, m, in.distance_max_m) < diffractionSpot(in, m, in.wavelength_max_m))
        lo = m;
      else
        hi = m;
    }
    a.balanced_aperture_m = 0.5 * (lo + hi);
  }
  {
    const double m = a.efl_m / in.focus_distance_m;
    const double c = a.doc_far_m;
    const double den = m * m - (c / in.aperture_diameter_m) * (c / in.aperture_diameter_m);
    a.dof_formula_m = den > 0 ? 2.0 * a.f_number * c * (m + 1.0) / den : kInf;
    // Distances whose DoC equals the far-end DoC: the sharp zone of the design.
    const double rf = in.focus_distance_m;
    const double k = c * (rf - a.focal_length_m) / (in.aperture_diameter_m * a.focal_length_m);
    a.dof_near_m = rf / (1.0 + k);
    a.dof_far_m = k < 1.0 ? rf / (1.0 - k) : kInf;
  }

  // --- Sun (§2.1.3.1) ---
  a.sun_temperature_k = std::pow(in.sun_surface_flux_w_m2 / kStefanBoltzmann, 0.25);
  a.solar_fraction_in_band =
      integrate([&](double l) { return planckExitance(l, a.sun_temperature_k); }, in.wavelength_min_m,
                in.wavelength_max_m) /
      (kStefanBoltzmann * std::pow(a.sun_temperature_k, 4));
  auto flux = [&](double r) { return in.sun_surface_flux_w_m2 * std::pow(in.sun_radius_m / r, 2); };
  a.irradiance_perihelion = flux(in.mars_perihelion_m);
  a.irradiance_aphelion = flux(in.mars_aphelion_m);
  a.irradiance_semi_major = flux(in.mars_semi_major_axis_m);
  a.irradiance_surface = (1.0 - in.atmosphere_loss) * a.irradiance_semi_major;
  const double elev_max = 90.0 - in.latitude_deg;
  a.irradiance_latitude = { a.irradiance_surface * std::sin(deg2rad(in.sun_elevation_min_deg)),
                            a.irradiance_surface * std::sin(deg2rad(elev_max)) };

  // --- LED (§2.1.2, §2.1.3.4) ---
  const double alpha = deg2rad(0.5 * in.led_beam_angle_deg);
  a.led_solid_angle_sr = 2.0 * kPi * (1.0 - std::cos(alpha));
  a.led_luminous_flux_lm = in.led_luminous_intensity_cd * a.led_solid_angle_sr;
  a.led_power_study_w = a.led_luminous_flux_lm / in.led_luminous_efficacy_lm_w;
  a.led_luminous_efficacy_radiation_lm_w = kMaxLuminousEfficacy * photopicEfficiency(in.led_wavelength_m);
  a.led_optical_power_w = a.led_luminous_flux_lm / a.led_luminous_efficacy_radiation_lm_w;
  a.led_lens_diameter_ratio = 2.0 * std::tan(alpha);

  const Ctx c = makeCtx(in);
  a.dot_power_w = in.led_lens_transmission * in.led_grid_transmission * a.led_optical_power_w /
                  (in.dot_rows * in.dot_cols);
  a.dot_irradiance = dotIrradiance(c, a.led_optical_power_w);
  a.sun_band_efficiency = c.sun_eff;
  a.led_efficiency = c.led_eff;

  // --- Sunlit target and sensor (§2.1.3.2-3) ---
  const double f50s[2] = { a.irradiance_latitude.min, a.irradiance_latitude.max };
  const double albedos[2] = { in.albedo_min, in.albedo_max };
  const double thetas[2] = { in.sun_incidence_min_deg, in.sun_incidence_max_deg };
  const Brdf brdfs[2] = { Brdf::kLambertian, Brdf::kLambertianGlossy };
  Range rad{ kInf, -kInf };
  for (double f : f50s)
    for (double al : albedos)
      for (double th : thetas)
        for (Brdf b : brdfs)
        {
          const double r = targetRadiance(in, f, al, th, b);
          rad.min = std::min(rad.min, r);
          rad.max = std::max(rad.max, r);
        }
  a.radiance_target = rad;
  a.irradiance_sensor = { rad.min * c.cam, rad.max * c.cam };
  a.power_per_pixel = { a.irradiance_sensor.min * c.pixel_area, a.irradiance_sensor.max * c.pixel_area };
  const double photons_per_joule = c.band_mean_wl / (kPlanck * kLightSpeed);
  a.photons_per_pixel = { a.power_per_pixel.min * in.exposure_s * photons_per_joule,
                          a.power_per_pixel.max * in.exposure_s * photons_per_joule };
  a.sun_electrons = { sunElectrons(c, rad.min, in.exposure_s), sunElectrons(c, rad.max, in.exposure_s) };

  // --- LED dot seen by the camera ---
  const double led_rad_min = targetRadiance(in, a.dot_irradiance, in.albedo_min, in.led_incidence_deg, Brdf::kLambertian);
  const double led_rad_max =
      targetRadiance(in, a.dot_irradiance, in.albedo_max, in.led_incidence_deg, Brdf::kLambertianGlossy);
  a.led_power_per_pixel = { led_rad_min * c.cam * c.pixel_area, led_rad_max * c.cam * c.pixel_area };
  a.led_electrons = { ledElectrons(c, led_rad_min, in.exposure_s), ledElectrons(c, led_rad_max, in.exposure_s) };

  // --- Noise (§2.1.3.5) ---
  a.read_noise_e = in.read_noise_e;
  {
    // Janesick's dark current law, scaled from the datasheet's reference
    // point: D(T) = D(Tref) (T/Tref)^1.5 exp(Eg(Tref)/2kTref - Eg(T)/2kT).
    const double t = in.temperature_k, tr = in.dark_reference_temperature_k;
    const double ref_e_s = in.dark_current_a_m2 * c.pixel_area / kElementaryCharge;
    a.dark_current_e_s = ref_e_s * std::pow(t / tr, 1.5) *
                         std::exp(siliconBandGapEv(tr) / (2 * kBoltzmannEv * tr) -
                                  siliconBandGapEv(t) / (2 * kBoltzmannEv * t));
  }
  const double dark_e = a.dark_current_e_s * in.exposure_s;
  a.dark_noise_e = std::sqrt(dark_e);
  a.noise_floor_e = std::sqrt(in.read_noise_e * in.read_noise_e + dark_e);
  const double r2 = in.read_noise_e * in.read_noise_e;
  auto snr = [&](double s, double b, double scale) {
    return s * scale / std::sqrt((s + b) * scale + dark_e * scale + r2);
  };
  a.snr_sun = { snr(a.sun_electrons.min, 0, 1), snr(a.sun_electrons.max, 0, 1) };
  a.snr_led_night = { snr(a.led_electrons.min, 0, 1), snr(a.led_electrons.max, 0, 1) };

  // Case 3: the same surface (albedo, BRDF) reflects both lights; the sun's
  // strength and incidence vary independently of it.
  Range day{ kInf, -kInf };
  double brightest = 0.0;
  struct Corner { double s, b; };
  std::vector<Corner> corners;
  for (double al : albedos)
    for (Brdf br : brdfs)
    {
      const double s = ledElectrons(c, targetRadiance(in, a.dot_irradiance, al, in.led_incidence_deg, br), in.exposure_s);
      for (double f : f50s)
        for (double th : thetas)
        {
          const double b = sunElectrons(c, targetRadiance(in, f, al, th, br), in.exposure_s);
          const double v = snr(s, b, 1);
          day.min = std::min(day.min, v);
          day.max = std::max(day.max, v);
          brightest = std::max(brightest, s + b);
          corners.push_back({ s, b });
        }
    }
  a.snr_led_day = day;
  a.saturating_exposure_s = in.exposure_s * in.full_well_e / brightest;
  {
    const double scale = std::min(1.0, in.full_well_e / brightest);
    double worst = kInf;
    for (const auto& k : corners)
      worst = std::min(worst, snr(k.s, k.b, scale));
    a.snr_led_day_worst_unsaturated = worst;
  }

  // --- The design table ---
  TableBuilder t(&a.table);
  const double study_scale_ratio = a.led_power_study_w / a.led_optical_power_w;
  t.add("fov_half", "Field of view, half angle", "§2.1.1.2", a.fov_half_deg, 1, "deg", "26.6",
        "the study's \"FoV = 26.6 x 26.6 deg\" is this half angle");
  t.add("fov_full", "Field of view, full angle", "§2.1.1.2, table 2.1", a.fov_full_deg, 1, "deg", "26.6",
        "tan(FoV/2) = H/(2D) gives FoV = " + num(std::round(a.fov_full_deg * 10) / 10) +
            " deg; the study reports the half angle as the FoV (and compares it with Navcam's full 45 deg)");
  t.add("efl", "Effective focal length EFL", "§2.1.1.3", a.efl_m, 1e3, "mm", "12.29");
  t.add("focal_length", "Focal length f (focus at rf)", "§2.1.1.3", a.focal_length_m, 1e3, "mm", "12.14");
  t.add("f_number", "f-number f/Dsr", "table 2.1", a.f_number, 1, "", "");
  t.add("doc_far", "Diameter of confusion at distance_max", "§2.1.1.4", a.doc_far_m, 1e3, "mm", "0.0117");
  t.add("doc_near", "Diameter of confusion at distance_min", "§2.1.1.4", a.doc_near_m, 1e6, "um", "");
  t.add("diffraction_min", "Diffraction spot at wavelength_min", "§2.1.1.4", a.diffraction_min_m, 1e6, "um", "");
  t.add("diffraction_max", "Diffraction spot at wavelength_max", "§2.1.1.4", a.diffraction_max_m, 1e6, "um", "",
        a.diffraction_max_m > in.pixel_size_m
            ? "larger than the " + num(in.pixel_size_m * 1e6) + " um pixel: at " +
                  num(in.aperture_diameter_m * 1e3) + " mm not \"all the curves\" of fig. 2.2 are under the pixel"
            : "");
  t.add("balanced_aperture", "Aperture where DoC(far) = diffraction(wl_max)", "fig. 2.2", a.balanced_aperture_m, 1e3,
        "mm", "1.9",
        "the study's choice 1.9 mm keeps the DoC under the pixel (up to " +
            num(in.pixel_size_m / (a.doc_far_m / in.aperture_diameter_m) * 1e3) +
            " mm); no aperture keeps both curves under 12 um at 800 nm; they cross at " +
            num(diffractionSpot(in, a.balanced_aperture_m, in.wavelength_max_m) * 1e6) + " um")
      .agrees = true;
  t.add("dof", "Depth of field (study's formula)", "§2.1.1.4", a.dof_formula_m, 1, "m", "1.33");
  t.addRange("dof_limits", "Sharp zone (DoC <= DoC(far))", "table 2.1", { a.dof_near_m, a.dof_far_m }, 1, "m", "0.67",
             "2");
  t.add("max_relief", "Largest relief DoF/2", "§2.1.1.4", a.dof_formula_m / 2, 1e2, "cm", "66.5",
        "the study halves the rounded 1.33 m");

  t.add("sun_temperature", "Sun temperature implied by F_sun", "(2.2)", a.sun_temperature_k, 1, "K", "",
        "the sun's effective temperature is 5772 K (F_sun = 6.29e7 W/m^2); the stated 6.45e7 is 2.5% high");
  t.add("irradiance_perihelion", "Solar irradiance at perihelion", "(2.3)", a.irradiance_perihelion, 1, "W/m^2",
        "730", "the study truncates " + num(a.irradiance_perihelion) + " to 730");
  t.add("irradiance_aphelion", "Solar irradiance at aphelion", "(2.3)", a.irradiance_aphelion, 1, "W/m^2", "502");
  t.add("irradiance_semi_major", "Solar irradiance at the semi-major axis", "(2.4)", a.irradiance_semi_major, 1,
        "W/m^2", "589",
        "with the stated F_sun = 6.45e7 W/m^2 it is " + num(a.irradiance_semi_major) +
            "; 589 needs F_sun = " + num(589.0 / std::pow(in.sun_radius_m / in.mars_semi_major_axis_m, 2)) +
            " (the real value, 586 W/m^2, needs 6.29e7); R is 2.27936e11 m, not km");
  t.add("irradiance_surface", "Irradiance after the atmosphere F_a", "(2.5)", a.irradiance_surface, 1, "W/m^2", "530",
        "0.9 x 589 = 530: follows the slip of (2.4)");
  t.addRange("irradiance_latitude", "Irradiance at latitude 50 deg F50", "(2.6)", a.irradiance_latitude, 1, "W/m^2",
             "92", "341", "530 x sin[10, 40] deg = [92.0, 340.7]: follows (2.4)");
  t.add("solar_fraction_in_band", "Share of sunlight in the band (blackbody)", "(2.20)", a.solar_fraction_in_band, 1,
        "", "",
        "the study counts all of F as light in the band; kept, so the sun's numbers are upper bounds");

  t.addRange("radiance_target", "Target radiance R_T", "(2.7)-(2.8)", a.radiance_target, 1, "W/(m^2 sr)", "1.44",
             "58.58",
             "(2.7) swaps its labels: its text (and numbers) make the glossy mixture the optimal case and pure "
             "Lambertian the worst; the minimum 1.44 uses theta = 10 deg instead of 50 deg (" +
                 num(targetRadiance(in, 92.0, in.albedo_min, in.sun_incidence_max_deg, Brdf::kLambertian)) +
                 " with F50 = 92); the rest follows (2.4)");
  t.addRange("irradiance_sensor", "Irradiance on the sensor I_T", "(2.9)-(2.10)", a.irradiance_sensor, 1, "W/m^2",
             "0.0271", "1.1000", "follows (2.8)");
  t.addRange("power_per_pixel", "Sun power per pixel W_lum", "(2.11)-(2.12)", a.power_per_pixel, 1e12, "pW",
             "390.0", "15840",
             "the study prints [3.900, 158.40]e-10 W: the exponent is e-12 (1.1 W/m^2 x 144e-12 m^2 = 158.4e-12 W), "
             "as its own (2.20) uses");
  t.addRange("photons_per_pixel", "Sun photons per pixel per exposure N_p", "(2.20)", a.photons_per_pixel, 1e-6,
             "1e6 ph", "1.177", "47.810", "follows (2.8); (2.20) is right for a flat spectrum (mean wavelength)");
  t.addRange("photons_at_pixel", "Sun photons reaching a pixel N_CCD", "(2.21)", a.photons_per_pixel, 1, "ph",
             "0.1328", "5.3936",
             "(2.21) multiplies N_p by pi(Dsr/2)^2/(2 pi r^2) = " +
                 num(std::pow(in.aperture_diameter_m / 2, 2) / (2 * std::pow(in.distance_max_m, 2))) +
                 ": the aperture is already in (2.9), so it is applied twice (x1e-7); N_p already reaches the pixel");
  t.add("sun_band_efficiency", "Band efficiency QE x lens (sunlight)", "(2.22)", a.sun_band_efficiency, 1, "",
        "0.1568",
        "the study's ratio (2.22)/(2.21) = 0.1568 (its integral is a band mean); the default QE table is scaled to "
        "it, photon-weighted here");
  t.addRange("sun_electrons", "Sun photo-electrons per pixel Nen_CCD", "(2.22)", a.sun_electrons, 1, "e-", "0.0208",
             "0.8457",
             "x1e7 from (2.21); the brightest case is " + num(a.sun_electrons.max / in.full_well_e) +
                 " x the full well at ts = " + num(in.exposure_s) + " s");

  t.add("led_solid_angle", "LED solid angle Omega", "(2.13)", a.led_solid_angle_sr, 1, "sr", "0.2141");
  t.add("led_luminous_flux", "LED luminous flux C_LED Omega", "(2.13)", a.led_luminous_flux_lm, 1, "lm", "",
        "cd x sr = lm; an upper bound (84 cd is the on-axis intensity)");
  t.add("led_power_study", "LED power P_LED = flux / L_e", "(2.13)", a.led_power_study_w, 1, "W", "0.2997",
        "lm / (60 lm/W) is the ELECTRICAL input (60 lm/W is a plausible wall-plug efficacy; cf. 220 mW on the "
        "datasheet, 300 mW budget), not the light emitted");
  t.add("led_optical_power", "LED optical power flux / (683 V(lambda))", "(2.13)", a.led_optical_power_w, 1e3, "mW", "",
        "683 V(" + num(in.led_wavelength_m * 1e9) + " nm) = " + num(a.led_luminous_efficacy_radiation_lm_w) +
            " lm/W: the study's 'light' is " + num(study_scale_ratio) + " x too strong");
  t.add("led_lens_ratio", "LED collecting lens diameter / focal length", "(2.1)", a.led_lens_diameter_ratio, 1, "",
        num(std::tan(alpha)).substr(0, 6),
        "(2.1) d = f tan(alpha) is the radius: the diameter is 2 f tan(alpha)");
  t.add("dot_power", "Power per dot W_dot", "(2.13)", a.dot_power_w, 1e4, "1e-4 W", "4.4960",
        "the study uses the electrical power (0.15 x 0.2997 / 100 = 4.4960e-4 W); its 'loss factors' are used "
        "as transmissions");
  t.add("dot_irradiance", "Dot irradiance E_point", "(2.14)", a.dot_irradiance, 1, "W/m^2", "71.5558",
        "x" + num(study_scale_ratio) + " in the study (electrical power); A_point = 2 pi (1 mm)^2 makes E_point the "
        "peak of a Gaussian dot of sigma = 1 mm");
  t.addRange("led_power_per_pixel", "LED power per pixel W_LED", "§2.1.3.4", a.led_power_per_pixel, 1e12, "pW",
             "3.033", "33.271", "follows (2.14)");
  t.add("led_efficiency", "QE x lens at the LED wavelength", "§2.1.3.5 case 2", a.led_efficiency, 1, "", "27.44",
        "the study's Nen_LED / N_CCD(520 nm) = 27.4 > 1 is impossible: its LED photo-electrons carry a x100 slip "
        "(W_LED in 1e-10 W, as in (2.12)); / 100 = 0.274");
  t.addRange("led_electrons", "LED photo-electrons per pixel Nen_LED", "§2.1.3.5 case 2", a.led_electrons, 1, "e-",
             "2.4556", "26.9410", "x1e7 from (2.21), / " + num(study_scale_ratio) + " (optical power), /100 (slip)");

  t.add("read_noise", "Readout noise per pixel", "(2.15)-(2.16)", a.read_noise_e, 1, "e-", "2.3842e-05",
        "(2.15) divides the 25 e- RMS by the number of pixels (25 / 1048576 = 2.3842e-5); read noise is per pixel "
        "(the study's own table 2.1 lists 25 electrons)");
  t.add("dark_current", "Dark current per pixel at temperature_k", "(2.17)", a.dark_current_e_s, 1, "e-/s", "",
        "datasheet 30 pA/cm^2 at 20 C scaled by Janesick's law T^1.5 exp(-Eg/2kT)");
  t.add("dark_noise", "Dark current noise", "(2.17)-(2.18)", a.dark_noise_e, 1, "e-", "0.0067",
        "(2.17) as printed (T^(2/3), square root, 30 pA/cm^2) gives 0.034 e-; 0.0067 comes out with T^1 and no "
        "square root; the law is T^1.5 with D_FM in nA/cm^2 at 300 K. Negligible next to the readout noise");
  t.add("noise_floor", "Noise without sunlight N", "(2.19)", a.noise_floor_e, 1, "e-", "0.0067",
        "25 e- readout noise, not 0.0067");
  t.addRange("noise_sunlit", "Noise with sunlight", "(2.25)",
             { std::sqrt(a.sun_electrons.min + dark_e + r2), std::sqrt(a.sun_electrons.max + dark_e + r2) }, 1, "e-",
             "0.0219", "0.8457",
             "(2.25) takes delta_shot = Nen_CCD, the signal itself; shot noise is its square root");
  t.addRange("snr_sun", "SNR case 1: sun only", "(2.23)", a.snr_sun, 1, "", "3.1", "126.8",
             "the study divides photo-electrons 1e7 too few by a noise 4000 x too small; here S/sqrt(S + read^2 + "
             "dark), shot noise included");
  t.addRange("snr_led_night", "SNR case 2: LED at night", "(2.24)", a.snr_led_night, 1, "", "368", "4040",
             "same slips as case 1 plus the x100 of Nen_LED");
  t.addRange("snr_led_day", "SNR case 3: LED against the sun", "(2.26)", a.snr_led_day, 1, "", "32", "348",
             "(2.25) takes the sun's signal itself as its noise (not its square root), so 32 is the dot/sun ratio; "
             "348 pairs the LED at albedo 0.45 with the sun at 0.05, against the study's own albedo correlation; "
             "without the x100 slip its model gives 0.32 and 3.5: the LED does not outshine the sun");
  t.add("saturating_exposure", "Exposure at which the brightest pixel fills the well", "§2.1.3.5",
        a.saturating_exposure_s, 1e3, "ms", "",
        "the study's ts = " + num(in.exposure_s * 1e3) + " ms saturates the sensor in bright sun");
  t.add("snr_led_day_worst_unsaturated", "SNR case 3 worst, exposure within the full well", "§2.1.3.5",
        a.snr_led_day_worst_unsaturated, 1, "", "");
  t.add("dot_to_sun_ratio", "Dot / sun photo-electrons at sun_level 1", "simulator", dotToSunRatio(a), 1, "", "",
        "corrected physics (LightingParams::dot_to_sun_ratio)");
  t.add("dot_to_sun_ratio_study", "Dot / sun photo-electrons, study as stated", "simulator",
        dotToSunRatio(a, RadiometryModel::kStudyAsStated), 1, "", "32",
        "the study's worst-case SNR 32 is this ratio (its noise model); x100 slip and electrical power included")
      .agrees = true;
  return a;
}

// ---------------------------------------------------------------------------
// Simulator brightness

double DotSunElectrons::ratio() const
{
  return sun_e > 0.0 ? dot_e / sun_e : kInf;
}

double DotSunElectrons::snr() const
{
  const double var = dot_e + sun_e + dark_e + read_noise_e * read_noise_e;
  return var > 0.0 ? dot_e / std::sqrt(var) : 0.0;
}

DotSunElectrons dotAndSunElectrons(const SceneAnalysis& a, double albedo, double sun_level, RadiometryModel model,
                                   Brdf brdf, double exposure_s, double dot_sigma_m)
{
  const SceneInputs& in = a.inputs;
  if (!std::isfinite(albedo) || albedo < 0.0 || albedo > 1.0)
    fail("albedo", "must be in [0, 1], got " + num(albedo));
  if (!std::isfinite(sun_level) || sun_level < 0.0)
    fail("sun_level", "must be >= 0, got " + num(sun_level));
  const double t = exposure_s > 0.0 ? exposure_s : in.exposure_s;
  const Ctx c = makeCtx(in);
  DotSunElectrons out;
  out.read_noise_e = in.read_noise_e;
  out.dark_e = a.dark_current_e_s * t;
  const double sun_rad = targetRadiance(in, sun_level * a.irradiance_latitude.max, albedo, in.sun_incidence_min_deg, brdf);
  out.sun_e = sunElectrons(c, sun_rad, t);
  const bool study = model == RadiometryModel::kStudyAsStated;
  double e_dot = dotIrradiance(c, study ? a.led_power_study_w : a.led_optical_power_w);
  if (dot_sigma_m > 0.0)
    e_dot *= in.dot_area_m2 / (2.0 * kPi * dot_sigma_m * dot_sigma_m);
  out.dot_e = ledElectrons(c, targetRadiance(in, e_dot, albedo, in.led_incidence_deg, brdf), t) * (study ? 100.0 : 1.0);
  return out;
}

double dotToSunRatio(const SceneAnalysis& a, RadiometryModel model, double dot_sigma_m)
{
  // Albedo cancels; use 1 to avoid a 0/0 for a black surface.
  return dotAndSunElectrons(a, 1.0, 1.0, model, Brdf::kLambertian, -1.0, dot_sigma_m).ratio();
}

double dotToSunRatio(const SceneInputs& inputs, RadiometryModel model, double dot_sigma_m)
{
  return dotToSunRatio(analyseScene(inputs), model, dot_sigma_m);
}

double dotSnr(double ratio, double background_e, double read_noise_e, double dark_e)
{
  const double s = ratio * background_e;
  const double var = s + background_e + dark_e + read_noise_e * read_noise_e;
  return var > 0.0 ? s / std::sqrt(var) : 0.0;
}

double ratioForSnr(double target_snr, double background_e, double read_noise_e, double dark_e)
{
  if (!(background_e > 0.0) || !(target_snr >= 0.0))
    fail("ratioForSnr", "needs background_e > 0 and target_snr >= 0");
  // s^2 = q^2 (s + b + d + r^2): the positive root of s^2 - q^2 s - q^2 (b + d + r^2) = 0.
  const double q2 = target_snr * target_snr;
  const double s = 0.5 * (q2 + std::sqrt(q2 * q2 + 4.0 * q2 * (background_e + dark_e + read_noise_e * read_noise_e)));
  return s / background_e;
}

// ---------------------------------------------------------------------------
// Figure 2.2

ApertureSweep apertureSweep(const SceneInputs& in, int steps, int wavelength_count)
{
  in.validate();
  if (steps < 2 || wavelength_count < 1)
    fail("apertureSweep", "needs steps >= 2 and wavelength_count >= 1");
  ApertureSweep sw;
  for (int k = 0; k < wavelength_count; ++k)
  {
    const double u = wavelength_count == 1 ? 1.0 : static_cast<double>(k) / (wavelength_count - 1);
    sw.wavelengths_m.push_back(in.wavelength_min_m + u * (in.wavelength_max_m - in.wavelength_min_m));
  }
  for (int i = 0; i < steps; ++i)
  {
    ApertureSweepRow r;
    r.aperture_m = in.sweep_aperture_min_m + (in.sweep_aperture_max_m - in.sweep_aperture_min_m) * i / (steps - 1);
    r.doc_m = diameterOfConfusion(in, r.aperture_m, in.distance_max_m);
    for (double wl : sw.wavelengths_m)
      r.diffraction_m.push_back(diffractionSpot(in, r.aperture_m, wl));
    sw.rows.push_back(r);
  }
  return sw;
}

std::string apertureSweepCsv(const ApertureSweep& sw)
{
  std::ostringstream os;
  os << "aperture_mm,doc_um";
  for (double wl : sw.wavelengths_m)
    os << ",diffraction_" << std::lround(wl * 1e9) << "nm_um";
  os << "\n";
  char buf[64];
  for (const auto& r : sw.rows)
  {
    std::snprintf(buf, sizeof(buf), "%.4f,%.5f", r.aperture_m * 1e3, r.doc_m * 1e6);
    os << buf;
    for (double d : r.diffraction_m)
    {
      std::snprintf(buf, sizeof(buf), ",%.5f", d * 1e6);
      os << buf;
    }
    os << "\n";
  }
  return os.str();
}

cv::Mat renderApertureSweep(const SceneInputs& in, const ApertureSweep& sw, int width, int height)
{
  if (width < 300 || height < 200)
    fail("renderApertureSweep", "image too small (need at least 300 x 200)");
  if (sw.rows.size() < 2)
    fail("renderApertureSweep", "empty sweep");
  cv::Mat img(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const int left = 90, right = 30, top = 50, bottom = 70;
  const double x0 = sw.rows.front().aperture_m * 1e3, x1 = sw.rows.back().aperture_m * 1e3;
  double ymax = in.pixel_size_m * 1e6;
  for (const auto& r : sw.rows)
  {
    ymax = std::max(ymax, r.doc_m * 1e6);
    for (double d : r.diffraction_m)
      ymax = std::max(ymax, d * 1e6);
  }
  ymax = std::ceil(ymax / 5.0) * 5.0;
  const int pw = width - left - right, ph = height - top - bottom;
  auto px = [&](double x_mm) { return left + static_cast<int>(std::lround((x_mm - x0) / (x1 - x0) * pw)); };
  auto py = [&](double y_um) { return top + ph - static_cast<int>(std::lround(y_um / ymax * ph)); };
  const int font = cv::FONT_HERSHEY_SIMPLEX;
  const cv::Scalar black(0, 0, 0), grey(215, 215, 215);

  // Grid and ticks.
  const double xstep = (x1 - x0) > 3.0 ? 0.5 : 0.25;
  for (double x = std::ceil(x0 / xstep) * xstep; x <= x1 + 1e-9; x += xstep)
  {
    cv::line(img, { px(x), top }, { px(x), top + ph }, grey, 1);
    cv::line(img, { px(x), top + ph }, { px(x), top + ph + 6 }, black, 1);
    char b[16];
    std::snprintf(b, sizeof(b), "%.1f", x);
    cv::putText(img, b, { px(x) - 14, top + ph + 24 }, font, 0.5, black, 1, cv::LINE_AA);
  }
  const double ystep = ymax > 40 ? 10.0 : 5.0;
  for (double y = 0; y <= ymax + 1e-9; y += ystep)
  {
    cv::line(img, { left, py(y) }, { left + pw, py(y) }, grey, 1);
    cv::line(img, { left - 6, py(y) }, { left, py(y) }, black, 1);
    char b[16];
    std::snprintf(b, sizeof(b), "%.0f", y);
    cv::putText(img, b, { left - 40, py(y) + 5 }, font, 0.5, black, 1, cv::LINE_AA);
  }
  cv::rectangle(img, { left, top }, { left + pw, top + ph }, black, 1);
  cv::putText(img, "aperture diameter Dsr [mm]", { left + pw / 2 - 120, height - 20 }, font, 0.6, black, 1,
              cv::LINE_AA);
  cv::Mat ylabel(30, 260, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(ylabel, "spot diameter [um]", { 30, 21 }, font, 0.6, black, 1, cv::LINE_AA);
  cv::rotate(ylabel, ylabel, cv::ROTATE_90_COUNTERCLOCKWISE);
  if (ylabel.rows <= height && ylabel.cols <= left)
    ylabel.copyTo(img(cv::Rect(2, top + ph / 2 - ylabel.rows / 2, ylabel.cols, ylabel.rows)));
  char title[160];
  std::snprintf(title, sizeof(title), "Diameter of confusion (r = %.1f m, focus %.1f m) and diffraction spots",
                in.distance_max_m, in.focus_distance_m);
  cv::putText(img, title, { left, 30 }, font, 0.6, black, 1, cv::LINE_AA);

  // Reference lines: the pixel and the chosen aperture.
  const cv::Scalar pixel_colour(0, 150, 0), aperture_colour(120, 120, 120);
  for (int x = left; x < left + pw; x += 16)
    cv::line(img, { x, py(in.pixel_size_m * 1e6) }, { std::min(x + 10, left + pw), py(in.pixel_size_m * 1e6) },
             pixel_colour, 2);
  const double dsr = in.aperture_diameter_m * 1e3;
  if (dsr >= x0 && dsr <= x1)
  {
    for (int y = top; y < top + ph; y += 12)
      cv::line(img, { px(dsr), y }, { px(dsr), std::min(y + 6, top + ph) }, aperture_colour, 2);
    char b[48];
    std::snprintf(b, sizeof(b), "Dsr = %.2f mm", dsr);
    cv::putText(img, b, { px(dsr) + 6, top + 18 }, font, 0.5, aperture_colour, 1, cv::LINE_AA);
  }

  // Curves: DoC black, diffraction blue (short wavelengths) to red.
  std::vector<cv::Scalar> colours;
  for (size_t k = 0; k < sw.wavelengths_m.size(); ++k)
  {
    const double u = sw.wavelengths_m.size() == 1 ? 1.0 : static_cast<double>(k) / (sw.wavelengths_m.size() - 1);
    colours.emplace_back(255 * (1 - u), 150 * std::sin(u * kPi), 255 * u);
  }
  cv::Rect clip(left, top, pw + 1, ph + 1);
  auto polyline = [&](const std::function<double(const ApertureSweepRow&)>& f, const cv::Scalar& col) {
    for (size_t i = 1; i < sw.rows.size(); ++i)
    {
      cv::Point a(px(sw.rows[i - 1].aperture_m * 1e3), py(f(sw.rows[i - 1])));
      cv::Point b(px(sw.rows[i].aperture_m * 1e3), py(f(sw.rows[i])));
      if (cv::clipLine(clip, a, b))
        cv::line(img, a, b, col, 2, cv::LINE_AA);
    }
  };
  polyline([](const ApertureSweepRow& r) { return r.doc_m * 1e6; }, black);
  for (size_t k = 0; k < sw.wavelengths_m.size(); ++k)
    polyline([k](const ApertureSweepRow& r) { return r.diffraction_m[k] * 1e6; }, colours[k]);

  // Legend (top right, where the curves are low).
  const int lx = left + pw - 230;
  int ly = top + 20;
  cv::rectangle(img, { lx - 10, ly - 15 }, { left + pw - 8, ly + 22 * static_cast<int>(sw.wavelengths_m.size() + 2) - 8 },
                cv::Scalar(255, 255, 255), cv::FILLED);
  cv::rectangle(img, { lx - 10, ly - 15 }, { left + pw - 8, ly + 22 * static_cast<int>(sw.wavelengths_m.size() + 2) - 8 },
                black, 1);
  auto entry = [&](const std::string& text, const cv::Scalar& col) {
    cv::line(img, { lx, ly - 4 }, { lx + 30, ly - 4 }, col, 2, cv::LINE_AA);
    cv::putText(img, text, { lx + 40, ly + 1 }, font, 0.5, black, 1, cv::LINE_AA);
    ly += 22;
  };
  entry("diameter of confusion", black);
  for (size_t k = 0; k < sw.wavelengths_m.size(); ++k)
    entry("diffraction, " + std::to_string(std::lround(sw.wavelengths_m[k] * 1e9)) + " nm", colours[k]);
  entry("pixel " + num(in.pixel_size_m * 1e6) + " um", pixel_colour);
  return img;
}

// ---------------------------------------------------------------------------
// Table

std::string formatDesignTable(const SceneAnalysis& a)
{
  auto fmt = [](double v) {
    char b[32];
    if (!std::isfinite(v))
      return std::string(v > 0 ? "inf" : "nan");
    const double m = std::fabs(v);
    if (m != 0.0 && (m < 1e-3 || m >= 1e5))
      std::snprintf(b, sizeof(b), "%.4g", v);
    else
      std::snprintf(b, sizeof(b), "%.5g", v);
    return std::string(b);
  };
  auto value = [&](double lo, double hi, bool range) { return range ? "[" + fmt(lo) + ", " + fmt(hi) + "]" : fmt(lo); };
  std::ostringstream os;
  auto pad = [](const std::string& text, size_t width) {
    // Display width: UTF-8 continuation bytes (the "§") take no column.
    const size_t cols = std::count_if(text.begin(), text.end(), [](char ch) { return (ch & 0xC0) != 0x80; });
    return cols >= width ? text + " " : text + std::string(width - cols, ' ');
  };
  os << pad("quantity (study ref)", 63) << pad("computed", 23) << pad("unit", 12) << pad("  study", 21) << "note\n"
     << std::string(142, '-') << "\n";
  for (const auto& q : a.table)
  {
    const std::string study = q.has_study ? value(q.study, q.study_max, q.is_range && std::isfinite(q.study_max)) : "-";
    const std::string mark = q.has_study && !q.agrees ? "! " : "  ";
    os << pad(q.name + " " + q.ref, 63) << pad(value(q.value, q.value_max, q.is_range), 23) << pad(q.unit, 12)
       << mark << pad(study, 19) << q.note << "\n";
  }
  os << "\n'!' marks a study value that differs from the computed one beyond the precision it is printed with.\n";
  return os.str();
}

}  // namespace structured_light_stabilizer
