// analyseScene(): the study's design (docs/study.md §2.1) computed part by
// part, in the order of the study: camera geometry, the sun, the LED, the
// sunlit target on the sensor, the LED dot, noise and the three SNR cases;
// then the design table (scene_table.cpp).
#include <algorithm>
#include <cmath>
#include <vector>

#include "sim/design/scene_model.h"

namespace structured_light_stabilizer
{

using namespace scene;

namespace
{

// The extremes the study's ranges are taken over.
struct Extremes
{
  double f50[2];  // sun irradiance on the ground, lowest and highest elevation
  double albedo[2];
  double theta[2];  // sun incidence on the target, deg
  Brdf brdf[2];
};

Extremes extremesOf(const SceneAnalysis& a)
{
  const SceneInputs& in = a.inputs;
  return {{a.irradiance_latitude.min, a.irradiance_latitude.max},
          {in.albedo_min, in.albedo_max},
          {in.sun_incidence_min_deg, in.sun_incidence_max_deg},
          {Brdf::kLambertian, Brdf::kLambertianGlossy}};
}

// Field of view, focal lengths, blur spots and depth of field (§2.1.1).
void analyseOptics(SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  a->fov_half_deg = rad2deg(std::atan(0.5 * in.target_height_m / in.distance_max_m));
  a->fov_full_deg = 2.0 * a->fov_half_deg;
  a->efl_m = eflOf(in);
  a->focal_length_m = focalOf(in, a->efl_m);
  a->f_number = a->focal_length_m / in.aperture_diameter_m;
  a->doc_far_m = diameterOfConfusion(in, in.aperture_diameter_m, in.distance_max_m);
  a->doc_near_m = diameterOfConfusion(in, in.aperture_diameter_m, in.distance_min_m);
  a->diffraction_min_m = diffractionSpot(in, in.aperture_diameter_m, in.wavelength_min_m);
  a->diffraction_max_m = diffractionSpot(in, in.aperture_diameter_m, in.wavelength_max_m);
  // DoC grows with the aperture, the diffraction spot shrinks: bisect the crossing.
  double lo = 1e-6, hi = a->efl_m;
  for (int i = 0; i < 200; ++i)
  {
    const double m = 0.5 * (lo + hi);
    if (diameterOfConfusion(in, m, in.distance_max_m) < diffractionSpot(in, m, in.wavelength_max_m))
      lo = m;
    else
      hi = m;
  }
  a->balanced_aperture_m = 0.5 * (lo + hi);

  const double m = a->efl_m / in.focus_distance_m;
  const double c = a->doc_far_m;
  const double den = m * m - (c / in.aperture_diameter_m) * (c / in.aperture_diameter_m);
  a->dof_formula_m = den > 0 ? 2.0 * a->f_number * c * (m + 1.0) / den : kInf;
  // Distances whose DoC equals the far-end DoC: the sharp zone of the design.
  const double rf = in.focus_distance_m;
  const double k = c * (rf - a->focal_length_m) / (in.aperture_diameter_m * a->focal_length_m);
  a->dof_near_m = rf / (1.0 + k);
  a->dof_far_m = k < 1.0 ? rf / (1.0 - k) : kInf;
}

// Blackbody sun, irradiance at Mars and on the ground at the latitude (§2.1.3.1).
void analyseSun(SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  a->sun_temperature_k = std::pow(in.sun_surface_flux_w_m2 / kStefanBoltzmann, 0.25);
  a->solar_fraction_in_band = integrate([&](double l) { return planckExitance(l, a->sun_temperature_k); },
                                        in.wavelength_min_m, in.wavelength_max_m) /
                              (kStefanBoltzmann * std::pow(a->sun_temperature_k, 4));
  auto flux = [&](double r) { return in.sun_surface_flux_w_m2 * std::pow(in.sun_radius_m / r, 2); };
  a->irradiance_perihelion = flux(in.mars_perihelion_m);
  a->irradiance_aphelion = flux(in.mars_aphelion_m);
  a->irradiance_semi_major = flux(in.mars_semi_major_axis_m);
  a->irradiance_surface = (1.0 - in.atmosphere_loss) * a->irradiance_semi_major;
  const double elev_max = 90.0 - in.latitude_deg;
  a->irradiance_latitude = {a->irradiance_surface * std::sin(deg2rad(in.sun_elevation_min_deg)),
                            a->irradiance_surface * std::sin(deg2rad(elev_max))};
}

// LED flux, its power as the study takes it and as light, one dot's power and
// irradiance (§2.1.2, §2.1.3.4).
void analyseLed(const SensorModel& c, SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  const double alpha = deg2rad(0.5 * in.led_beam_angle_deg);
  a->led_solid_angle_sr = 2.0 * kPi * (1.0 - std::cos(alpha));
  a->led_luminous_flux_lm = in.led_luminous_intensity_cd * a->led_solid_angle_sr;
  a->led_power_study_w = a->led_luminous_flux_lm / in.led_luminous_efficacy_lm_w;
  a->led_luminous_efficacy_radiation_lm_w = kMaxLuminousEfficacy * photopicEfficiency(in.led_wavelength_m);
  a->led_optical_power_w = a->led_luminous_flux_lm / a->led_luminous_efficacy_radiation_lm_w;
  a->led_lens_diameter_ratio = 2.0 * std::tan(alpha);
  a->dot_power_w =
      in.led_lens_transmission * in.led_grid_transmission * a->led_optical_power_w / (in.dot_rows * in.dot_cols);
  a->dot_irradiance = dotIrradiance(c, a->led_optical_power_w);
  a->sun_band_efficiency = c.sun_eff;
  a->led_efficiency = c.led_eff;
}

// Sunlit target radiance over the extremes, and what reaches a pixel:
// irradiance, power, photons, photo-electrons (§2.1.3.2-3).
void analyseSunlitTarget(const SensorModel& c, SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  const Extremes x = extremesOf(*a);
  Range rad{kInf, -kInf};
  for (double f : x.f50)
    for (double al : x.albedo)
      for (double th : x.theta)
        for (Brdf b : x.brdf)
        {
          const double r = targetRadiance(in, f, al, th, b);
          rad.min = std::min(rad.min, r);
          rad.max = std::max(rad.max, r);
        }
  a->radiance_target = rad;
  a->irradiance_sensor = {rad.min * c.cam, rad.max * c.cam};
  a->power_per_pixel = {a->irradiance_sensor.min * c.pixel_area, a->irradiance_sensor.max * c.pixel_area};
  const double photons_per_joule = c.band_mean_wl / (kPlanck * kLightSpeed);
  a->photons_per_pixel = {a->power_per_pixel.min * in.exposure_s * photons_per_joule,
                          a->power_per_pixel.max * in.exposure_s * photons_per_joule};
  a->sun_electrons = {sunElectrons(c, rad.min, in.exposure_s), sunElectrons(c, rad.max, in.exposure_s)};
}

// The LED dot seen by the camera: worst (dark Lambertian) and best (bright
// glossy) surface.
void analyseLedDot(const SensorModel& c, SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  const double led_rad_min =
      targetRadiance(in, a->dot_irradiance, in.albedo_min, in.led_incidence_deg, Brdf::kLambertian);
  const double led_rad_max =
      targetRadiance(in, a->dot_irradiance, in.albedo_max, in.led_incidence_deg, Brdf::kLambertianGlossy);
  a->led_power_per_pixel = {led_rad_min * c.cam * c.pixel_area, led_rad_max * c.cam * c.pixel_area};
  a->led_electrons = {ledElectrons(c, led_rad_min, in.exposure_s), ledElectrons(c, led_rad_max, in.exposure_s)};
}

// Read noise, dark current at the sensor's temperature, the noise floor (§2.1.3.5).
void analyseNoise(const SensorModel& c, SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  a->read_noise_e = in.read_noise_e;
  // Janesick's dark current law, scaled from the datasheet's reference
  // point: D(T) = D(Tref) (T/Tref)^1.5 exp(Eg(Tref)/2kTref - Eg(T)/2kT).
  const double t = in.temperature_k, tr = in.dark_reference_temperature_k;
  const double ref_e_s = in.dark_current_a_m2 * c.pixel_area / kElementaryCharge;
  a->dark_current_e_s =
      ref_e_s * std::pow(t / tr, 1.5) *
      std::exp(siliconBandGapEv(tr) / (2 * kBoltzmannEv * tr) - siliconBandGapEv(t) / (2 * kBoltzmannEv * t));
  const double dark_e = a->dark_current_e_s * in.exposure_s;
  a->dark_noise_e = std::sqrt(dark_e);
  a->noise_floor_e = std::sqrt(in.read_noise_e * in.read_noise_e + dark_e);
}

// SNR of signal s over background b (electrons) with shot, dark and read
// noise, the exposure scaled by `scale`.
struct SnrModel
{
  double dark_e, r2;
  double operator()(double s, double b, double scale) const
  {
    return s * scale / std::sqrt((s + b) * scale + dark_e * scale + r2);
  }
};

// The three SNR cases (§2.1.3.5): sun only, LED at night, LED against the sun;
// and case 3 at the exposure that keeps the brightest pixel in the well.
void analyseSnr(const SensorModel& c, SceneAnalysis* a)
{
  const SceneInputs& in = a->inputs;
  const SnrModel snr{a->dark_current_e_s * in.exposure_s, in.read_noise_e * in.read_noise_e};
  a->snr_sun = {snr(a->sun_electrons.min, 0, 1), snr(a->sun_electrons.max, 0, 1)};
  a->snr_led_night = {snr(a->led_electrons.min, 0, 1), snr(a->led_electrons.max, 0, 1)};

  // Case 3: the same surface (albedo, BRDF) reflects both lights; the sun's
  // strength and incidence vary independently of it.
  const Extremes x = extremesOf(*a);
  Range day{kInf, -kInf};
  double brightest = 0.0;
  struct Corner
  {
    double s, b;
  };
  std::vector<Corner> corners;
  for (double al : x.albedo)
    for (Brdf br : x.brdf)
    {
      const double s =
          ledElectrons(c, targetRadiance(in, a->dot_irradiance, al, in.led_incidence_deg, br), in.exposure_s);
      for (double f : x.f50)
        for (double th : x.theta)
        {
          const double b = sunElectrons(c, targetRadiance(in, f, al, th, br), in.exposure_s);
          const double v = snr(s, b, 1);
          day.min = std::min(day.min, v);
          day.max = std::max(day.max, v);
          brightest = std::max(brightest, s + b);
          corners.push_back({s, b});
        }
    }
  a->snr_led_day = day;
  a->saturating_exposure_s = in.exposure_s * in.full_well_e / brightest;
  const double scale = std::min(1.0, in.full_well_e / brightest);
  double worst = kInf;
  for (const auto& k : corners)
    worst = std::min(worst, snr(k.s, k.b, scale));
  a->snr_led_day_worst_unsaturated = worst;
}

}  // namespace

SceneAnalysis analyseScene(const SceneInputs& inputs)
{
  inputs.validate();
  SceneAnalysis a;
  a.inputs = inputs;
  analyseOptics(&a);
  analyseSun(&a);
  const SensorModel c = makeSensorModel(a.inputs);
  analyseLed(c, &a);
  analyseSunlitTarget(c, &a);
  analyseLedDot(c, &a);
  analyseNoise(c, &a);
  analyseSnr(c, &a);
  buildDesignTable(&a);
  return a;
}

}  // namespace structured_light_stabilizer
