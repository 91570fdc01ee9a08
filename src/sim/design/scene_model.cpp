// The scene analysis's physics: building blocks (public ones declared in
// scene_analysis.h, shared ones in scene_model.h) and the dot-versus-sun
// brightness the simulator uses.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "sim/design/scene_model.h"

namespace structured_light_stabilizer
{

namespace scene
{

void fail(const std::string& field, const std::string& reason)
{
  throw std::invalid_argument("scene_analysis: " + field + ": " + reason);
}

std::string num(double v)
{
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6g", v);
  return buf;
}

double integrate(const std::function<double(double)>& f, double a, double b, int n)
{
  const double h = (b - a) / n;
  double s = f(a) + f(b);
  for (int i = 1; i < n; ++i)
    s += f(a + i * h) * ((i % 2) ? 4.0 : 2.0);
  return s * h / 3.0;
}

double planckExitance(double wavelength_m, double t_k)
{
  const double a = 2.0 * kPi * kPlanck * kLightSpeed * kLightSpeed / std::pow(wavelength_m, 5);
  const double x = kPlanck * kLightSpeed / (wavelength_m * kBoltzmann * t_k);
  return a / std::expm1(x);
}

double siliconBandGapEv(double t_k)
{
  return 1.1557 - 7.021e-4 * t_k * t_k / (1108.0 + t_k);
}

double photonEnergy(double wavelength_m)
{
  return kPlanck * kLightSpeed / wavelength_m;
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

double cameraFactor(const SceneInputs& in, double efl)
{
  const double c = std::cos(deg2rad(in.camera_axis_angle_deg));
  const double r = in.aperture_diameter_m / efl;
  return kPi / 4.0 * r * r * c * c * c * c;
}

SensorModel makeSensorModel(const SceneInputs& in)
{
  SensorModel c{in, 0, 0, 0, 0, 0, 0};
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

double sunElectrons(const SensorModel& c, double radiance, double exposure)
{
  const double w = radiance * c.cam * c.pixel_area;
  return w * exposure * c.band_mean_wl / (kPlanck * kLightSpeed) * c.sun_eff;
}

double ledElectrons(const SensorModel& c, double radiance, double exposure)
{
  const double w = radiance * c.cam * c.pixel_area;
  return w * exposure / photonEnergy(c.in.led_wavelength_m) * c.led_eff;
}

double dotIrradiance(const SensorModel& c, double led_power)
{
  const int n = c.in.dot_rows * c.in.dot_cols;
  return c.in.led_lens_transmission * c.in.led_grid_transmission * led_power / n / c.in.dot_area_m2;
}

}  // namespace scene

using namespace scene;

namespace
{

// CIE 1931 2-degree photopic V(lambda), 380-780 nm in 10 nm steps.
const double kPhotopic[] = {
    0.000039, 0.000120, 0.000396, 0.001210, 0.004000, 0.011600, 0.023000, 0.038000, 0.060000, 0.090980, 0.139020,
    0.208020, 0.323000, 0.503000, 0.710000, 0.862000, 0.954000, 0.994950, 0.995000, 0.952000, 0.870000, 0.757000,
    0.631000, 0.503000, 0.381000, 0.265000, 0.175000, 0.107000, 0.061000, 0.032000, 0.017000, 0.008210, 0.004102,
    0.002091, 0.001047, 0.000520, 0.000249, 0.000120, 0.000060, 0.000030, 0.000015,
};

}  // namespace

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
  const SensorModel c = makeSensorModel(in);
  DotSunElectrons out;
  out.read_noise_e = in.read_noise_e;
  out.dark_e = a.dark_current_e_s * t;
  const double sun_rad =
      targetRadiance(in, sun_level * a.irradiance_latitude.max, albedo, in.sun_incidence_min_deg, brdf);
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

}  // namespace structured_light_stabilizer
