// The rig's radiometry (radiometry.h, docs/daylight.md): drive -> pulse
// energy -> dot fluence on the rock -> radiance -> photo-electrons through
// the lens, the filter and the sensor's quantum efficiency; the sun the same
// way from its spectrum; then the noise, the SNRs and the centroid error.
#include "structured_light_stabilizer/sim/design/radiometry.h"

#include <algorithm>
#include <cmath>

#include "sim/design/scene_model.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{

using namespace scene;
using detail::square;

namespace
{

[[noreturn]] void refuse(const std::string& field, const std::string& reason)
{
  throw std::invalid_argument("radiometry: " + field + ": " + reason);
}

void requirePositive(double v, const char* field)
{
  if (!std::isfinite(v) || v <= 0.0)
    refuse(field, "must be a positive number, got " + num(v));
}

void requireFraction(double v, const char* field)
{
  if (!std::isfinite(v) || v <= 0.0 || v > 1.0)
    refuse(field, "must be in (0, 1], got " + num(v));
}

constexpr double kFwhmToSigma = 1.0 / 2.354820045;

// Electrons per joule of light reaching the sensor with this normalised
// spectrum (1/m), through the lens, the filter (at a field angle) and the
// quantum efficiency, over [lo, hi].
double electronsPerJoule(const SceneInputs& in, const BandPassFilter& filter, double field_angle_rad,
                         const std::function<double(double)>& spectrum, double lo, double hi)
{
  auto f = [&](double l) { return spectrum(l) * in.lens_transmission * quantumEfficiency(in, l) / photonEnergy(l); };
  if (!filter.enabled)
    return integrate(f, lo, hi, 400);
  // Only the passband (moved off axis) counts: integrate over it alone, so
  // that its sharp edges are exact.
  const double s = std::sin(field_angle_rad) / filter.effective_index;
  const double centre = filter.centre_m * std::sqrt(std::max(0.0, 1.0 - s * s));
  const double a = std::max(lo, centre - 0.5 * filter.fwhm_m), b = std::min(hi, centre + 0.5 * filter.fwhm_m);
  return b > a ? filter.transmission * integrate(f, a, b, 200) : 0.0;
}

// Electrons per joule of the sun's light (per joule of its total irradiance).
double sunElectronsPerJoule(const SceneAnalysis& a, const RigParams& rig, double field_angle_rad)
{
  const SceneInputs& in = a.inputs;
  const double lo = in.wavelength_min_m, hi = in.wavelength_max_m;
  if (rig.sun_spectrum == SunSpectrum::kFlatInBand)
    return electronsPerJoule(
        in, rig.filter, field_angle_rad, [&](double) { return 1.0 / (hi - lo); }, lo, hi);
  const double t = a.sun_temperature_k, total = kStefanBoltzmann * std::pow(t, 4);
  return electronsPerJoule(
      in, rig.filter, field_angle_rad, [&](double l) { return planckExitance(l, t) / total; }, lo, hi);
}

// Electrons per joule of the emitter's light (Gaussian spectrum), its centre
// moved by shift_m (temperature).
double emitterElectronsPerJoule(const SceneAnalysis& a, const RigParams& rig, double field_angle_rad, double shift_m)
{
  const EmitterParams& e = rig.emitter;
  const double centre = e.wavelength_m + shift_m;
  const double s = std::max(e.spectral_fwhm_m * kFwhmToSigma, 1e-12);
  auto g = [&](double l) { return std::exp(-0.5 * square((l - centre) / s)) / (s * std::sqrt(2.0 * kPi)); };
  return electronsPerJoule(a.inputs, rig.filter, field_angle_rad, g, centre - 5.0 * s, centre + 5.0 * s);
}

// Optical energy of one projector-on exposure, with the power and the
// average electrical power it takes.
void drive(const RigParams& rig, DotSignal* out)
{
  const EmitterParams& e = rig.emitter;
  const double budget_optical = rig.electrical_budget_w * e.wall_plug_efficiency;
  const double on_rate = rig.frame_rate_hz / (rig.strobe ? 2.0 : 1.0);  // projector-on exposures per second
  double power;
  if (rig.pulsed)
  {
    // On only during the exposures: the budget is shared by on_rate pulses.
    const double from_budget = budget_optical / on_rate / rig.exposure_s;
    const double limit = e.cw_optical_power_w * e.peak_power_factor;
    power = std::min(from_budget, limit);
    out->peak_limited = limit < from_budget;
    out->average_electrical_w = power * rig.exposure_s * on_rate / e.wall_plug_efficiency;
  }
  else
  {
    // On all the time, or every second frame period when strobing.
    const double duty = rig.strobe ? 0.5 : 1.0;
    power = std::min(e.cw_optical_power_w, budget_optical / duty);
    out->peak_limited = e.cw_optical_power_w < budget_optical / duty;
    out->average_electrical_w = power * duty / e.wall_plug_efficiency;
  }
  out->peak_optical_w = power;
  out->pulse_energy_j = power * rig.exposure_s;
}

double focalPx(const SceneAnalysis& a)
{
  return a.focal_length_m / a.inputs.pixel_size_m;
}

// Variance (px^2) the lens and the pixel add to a dot's image at distance_m.
double imageBlurVariance(const SceneAnalysis& a, double distance_m, double wavelength_m)
{
  const SceneInputs& in = a.inputs;
  const double defocus = diameterOfConfusion(in, in.aperture_diameter_m, distance_m) / 4.0 / in.pixel_size_m;
  const double image_distance = 1.0 / (1.0 / a.focal_length_m - 1.0 / in.focus_distance_m);
  const double diffraction = 0.42 * wavelength_m * image_distance / in.aperture_diameter_m / in.pixel_size_m;
  return square(defocus) + square(diffraction) + 1.0 / 12.0;
}

// SNRs, the texture's clutter and the centroid errors from the electrons.
void noiseAndCentroid(const SceneAnalysis& a, const RigParams& rig, const ViewConditions& view,
                      const TextureConditions& tex, double sigma_geo_px, DotSignal* s)
{
  const double floor_var = s->dark_e + square(s->read_noise_e);
  const double var1 = s->dot_e + s->sun_e + floor_var;
  const double var2 = var1 + tex.ambient_noise_scale * (s->sun_e + floor_var);
  // The fine texture: a sinusoid of amplitude `contrast`; RMS over its phase.
  const double period_px = tex.period_m * focalPx(a) / view.distance_m;
  const double k = 2.0 * kPi / period_px;
  const double clutter1 = tex.albedo_reference_residual * tex.contrast / std::sqrt(2.0) * s->sun_e;
  const double clutter2 = tex.contrast * k * tex.ambient_misalignment_px / std::sqrt(2.0) * s->sun_e;
  auto snr = [&](double var) { return var > 0.0 ? s->dot_e / std::sqrt(var) : 0.0; };
  s->snr_single = snr(var1);
  s->snr_strobed = snr(var2);
  s->snr_single_textured = snr(var1 + square(clutter1));
  s->snr_strobed_textured = snr(var2 + square(clutter2));

  // Cramer-Rao bound of a Gaussian spot's centre (Thompson et al. 2002, one
  // axis): (sigma^2 + 1/12) / N + 8 pi sigma^4 b / N^2 with N = peak 2 pi
  // sigma^2 the spot's electrons and b the background variance per pixel;
  // the second term is 2 b / (pi peak^2).
  const double sigma2 = square(s->dot_sigma_px);
  const double n_total = s->dot_e * 2.0 * kPi * sigma2;
  auto crb = [&](double background_var)
  {
    if (!(s->dot_e > 0.0))
      return kInf;
    return std::sqrt((sigma2 + 1.0 / 12.0) / n_total + 2.0 * background_var / (kPi * square(s->dot_e)));
  };
  s->centroid_noise_single_px = crb(var1 - s->dot_e + square(clutter1));
  s->centroid_noise_strobed_px = crb(var2 - s->dot_e + square(clutter2));
  // The dot's own light times the albedo under it: the centroid moves by
  // sigma^2 d(ln albedo)/dx, sigma the footprint's (a blur keeps centroids);
  // for a sinusoid a k sigma^2 exp(-k^2 sigma^2 / 2) at most.
  const double sg2 = square(sigma_geo_px);
  s->texture_bias_single_px = rig.strobe ? 0.0
                                         : tex.albedo_reference_residual * tex.contrast * k * sg2 *
                                               std::exp(-0.5 * k * k * sg2) / std::sqrt(2.0);
  // Speckle (Dorsch, Haeusler and Herrmann 1994): the centroid of a speckled
  // spot wanders by C lambda / (2 pi sin u), u the aperture's half angle seen
  // from the rock; in the image that is C lambda f / (pi D) pixels.
  s->speckle_px = speckleContrast(rig.emitter, tex.roughness_m) * rig.emitter.wavelength_m * focalPx(a) /
                  (kPi * a.inputs.aperture_diameter_m);
  s->centroid_single_px =
      std::sqrt(square(s->centroid_noise_single_px) + square(s->texture_bias_single_px) + square(s->speckle_px));
  s->centroid_strobed_px = std::sqrt(square(s->centroid_noise_strobed_px) + square(s->speckle_px));
}

}  // namespace

// ---------------------------------------------------------------------------

EmitterParams EmitterParams::studyLed(const SceneAnalysis& a)
{
  EmitterParams e;
  e.kind = EmitterKind::kLed;
  e.wavelength_m = a.inputs.led_wavelength_m;
  e.spectral_fwhm_m = 30e-9;  // a green InGaN LED (the datasheet gives none)
  e.cw_optical_power_w = a.led_optical_power_w;
  e.wall_plug_efficiency = a.led_optical_power_w / a.led_power_study_w;
  e.peak_power_factor = 1.0;  // the study drives it continuously
  e.projector_efficiency = a.inputs.led_lens_transmission * a.inputs.led_grid_transmission;
  e.thermal_drift_m_per_k = 0.04e-9;
  return e;
}

double BandPassFilter::transmissionAt(double wavelength_m, double field_angle_rad) const
{
  if (!enabled)
    return 1.0;
  const double s = std::sin(field_angle_rad) / effective_index;
  const double centre = centre_m * std::sqrt(std::max(0.0, 1.0 - s * s));
  return std::fabs(wavelength_m - centre) <= 0.5 * fwhm_m ? transmission : 0.0;
}

RigParams RigParams::studyDesign(const SceneAnalysis& a)
{
  RigParams rig;
  rig.name = "study_led";
  rig.emitter = EmitterParams::studyLed(a);
  rig.beam_sigma_rad = 0.002;
  rig.pulsed = false;
  rig.electrical_budget_w = a.led_power_study_w;
  rig.exposure_s = a.inputs.exposure_s;
  rig.frame_rate_hz = 1.0 / rig.exposure_s;  // the study states no frame rate
  return rig;
}

RigParams RigParams::recommendedDaylight()
{
  RigParams rig;
  rig.name = "daylight_green_ld_1w";
  EmitterParams& e = rig.emitter;
  e.kind = EmitterKind::kLaserDiode;
  e.wavelength_m = 520e-9;
  e.spectral_fwhm_m = 1.5e-9;
  e.cw_optical_power_w = 1.0;
  e.wall_plug_efficiency = 0.12;
  e.peak_power_factor = 1.0;
  e.projector_efficiency = 0.7;
  e.thermal_drift_m_per_k = 0.06e-9;
  rig.beam_sigma_rad = 1.5e-3;
  rig.pulsed = true;
  rig.electrical_budget_w = 0.3;
  rig.exposure_s = 2e-3;
  rig.frame_rate_hz = 30.0;
  rig.strobe = true;
  rig.filter.enabled = false;
  rig.full_scale_e = 138468.0;  // the brightest sunlit rock at half the range (rig_design.h)
  rig.output_bits = 12;
  return rig;
}

void RigParams::validate() const
{
  const EmitterParams& e = emitter;
  if (!std::isfinite(e.wavelength_m) || e.wavelength_m < 350e-9 || e.wavelength_m > 1100e-9)
    refuse("emitter.wavelength", "must be in [350, 1100] nm, got " + num(e.wavelength_m * 1e9) + " nm");
  requirePositive(e.spectral_fwhm_m, "emitter.spectral_fwhm");
  if (e.spectral_fwhm_m > 0.2 * e.wavelength_m)
    refuse("emitter.spectral_fwhm",
           "must be at most a fifth of the wavelength, got " + num(e.spectral_fwhm_m * 1e9) + " nm");
  requirePositive(e.cw_optical_power_w, "emitter.cw_optical_power_w");
  requireFraction(e.wall_plug_efficiency, "emitter.wall_plug_efficiency");
  if (!std::isfinite(e.peak_power_factor) || e.peak_power_factor < 1.0 || e.peak_power_factor > 100.0)
    refuse("emitter.peak_power_factor", "must be in [1, 100], got " + num(e.peak_power_factor));
  requireFraction(e.projector_efficiency, "emitter.projector_efficiency");
  if (!std::isfinite(e.thermal_drift_m_per_k) || e.thermal_drift_m_per_k < 0.0)
    refuse("emitter.thermal_drift", "must be >= 0");
  if (!std::isfinite(beam_sigma_rad) || beam_sigma_rad <= 0.0 || beam_sigma_rad > 0.1)
    refuse("beam_sigma", "must be in (0, 100] mrad, got " + num(beam_sigma_rad * 1e3) + " mrad");
  requirePositive(electrical_budget_w, "electrical_budget_w");
  if (!std::isfinite(exposure_s) || exposure_s <= 0.0 || exposure_s > 10.0)
    refuse("exposure", "must be in (0, 10] s, got " + num(exposure_s) + " s");
  requirePositive(frame_rate_hz, "frame_rate_hz");
  if (exposure_s * frame_rate_hz > 1.0 + 1e-9)
    refuse("exposure", num(exposure_s * 1e3) + " ms does not fit in a frame at " + num(frame_rate_hz) + " Hz");
  if (filter.enabled)
  {
    requirePositive(filter.centre_m, "filter.centre");
    requirePositive(filter.fwhm_m, "filter.fwhm");
    requireFraction(filter.transmission, "filter.transmission");
    if (!std::isfinite(filter.effective_index) || filter.effective_index < 1.0)
      refuse("filter.effective_index", "must be >= 1");
  }
  if (!std::isfinite(full_scale_e) || full_scale_e < 0.0)
    refuse("camera.full_scale_e", "must be >= 0 (0 = the full well)");
  if (output_bits < 8 || output_bits > 16)
    refuse("camera.output_bits", "must be in [8, 16], got " + std::to_string(output_bits));
}

double speckleContrast(const EmitterParams& e, double roughness_m)
{
  // Two wavelengths decorrelate their speckle over a surface of RMS height
  // h as exp(-(4 pi h dnu / c)^2); averaged over a Gaussian spectrum of RMS
  // width sigma_lambda the contrast is (1 + (8 pi h sigma_lambda /
  // lambda^2)^2)^(-1/4) (normal incidence). An LED's spatial incoherence
  // lowers it further (not counted).
  const double x = 8.0 * kPi * std::max(0.0, roughness_m) * e.spectral_fwhm_m * kFwhmToSigma / square(e.wavelength_m);
  return std::pow(1.0 + x * x, -0.25);
}

double requiredFilterWidth(const SceneAnalysis& a, const RigParams& rig, double temperature_range_k)
{
  // The corner of the (square) image sees the filter most obliquely.
  const double corner = std::atan(std::sqrt(2.0) * std::tan(scene::deg2rad(a.fov_half_deg)));
  const double edge = std::sin(corner) / rig.filter.effective_index;
  const double angle_shift = rig.emitter.wavelength_m * (1.0 - std::sqrt(std::max(0.0, 1.0 - edge * edge)));
  return rig.emitter.spectral_fwhm_m + rig.emitter.thermal_drift_m_per_k * temperature_range_k + angle_shift;
}

double whiteSunElectrons(const SceneAnalysis& a, const RigParams& rig)
{
  const SensorModel c = makeSensorModel(a.inputs);
  const double radiance = a.irradiance_latitude.max / kPi;  // white Lambertian, normal incidence
  return radiance * c.cam * c.pixel_area * rig.exposure_s * sunElectronsPerJoule(a, rig, 0.0);
}

double whiteDotElectrons(const SceneAnalysis& a, const RigParams& rig, double sigma_m)
{
  rig.validate();
  DotSignal d;
  drive(rig, &d);
  const SensorModel c = makeSensorModel(a.inputs);
  const double fluence = d.pulse_energy_j * rig.emitter.projector_efficiency / (a.inputs.dot_rows * a.inputs.dot_cols) /
                         (2.0 * kPi * sigma_m * sigma_m);
  return fluence / kPi * c.cam * c.pixel_area * emitterElectronsPerJoule(a, rig, 0.0, 0.0);
}

DotSignal evaluateRig(const SceneAnalysis& a, const RigParams& rig, const ViewConditions& view,
                      const TextureConditions& tex)
{
  rig.validate();
  const SceneInputs& in = a.inputs;
  if (!(view.distance_m > 0.0) || !(view.albedo >= 0.0 && view.albedo <= 1.0) || !(view.sun_level >= 0.0))
    refuse("view", "needs distance > 0, albedo in [0, 1], sun_level >= 0");
  DotSignal s;
  drive(rig, &s);
  s.dot_energy_j = s.pulse_energy_j * rig.emitter.projector_efficiency / (in.dot_rows * in.dot_cols);
  s.dot_sigma_m = rig.beam_sigma_rad * view.distance_m;
  const double sigma_geo_px = s.dot_sigma_m * focalPx(a) / view.distance_m;
  const double blur_var = imageBlurVariance(a, view.distance_m, rig.emitter.wavelength_m);
  s.dot_sigma_px = std::sqrt(square(sigma_geo_px) + blur_var);

  const SensorModel c = makeSensorModel(in);
  const double field = scene::deg2rad(view.field_angle_deg);
  const double vignetting = std::pow(std::cos(field), 4);
  const double sun_rad =
      targetRadiance(in, view.sun_level * a.irradiance_latitude.max, view.albedo, view.sun_incidence_deg, view.brdf);
  s.sun_e = sun_rad * c.cam * c.pixel_area * vignetting * rig.exposure_s * sunElectronsPerJoule(a, rig, field);
  // Peak fluence across the beam (J/m^2; targetRadiance() applies the cos of
  // the incidence, as for the sun's irradiance), the radiance of the lit
  // surface over the exposure, and the image's blur spreading the peak.
  const double fluence = s.dot_energy_j / (2.0 * kPi * square(s.dot_sigma_m));
  const double dot_rad = targetRadiance(in, fluence, view.albedo, view.emitter_incidence_deg, view.brdf);
  const double blur = square(sigma_geo_px) / square(s.dot_sigma_px);
  const double shift = rig.emitter.thermal_drift_m_per_k * view.emitter_temperature_offset_k;
  s.dot_e = dot_rad * c.cam * c.pixel_area * vignetting * emitterElectronsPerJoule(a, rig, field, shift) * blur;
  s.dark_e = a.dark_current_e_s * rig.exposure_s;
  const double full_scale = rig.full_scale_e > 0.0 ? rig.full_scale_e : in.full_well_e;
  const double step = full_scale / (std::pow(2.0, rig.output_bits) - 1.0);
  s.read_noise_e = std::sqrt(square(in.read_noise_e) + square(step) / 12.0);
  s.ratio = s.sun_e > 0.0 ? s.dot_e / s.sun_e : kInf;
  noiseAndCentroid(a, rig, view, tex, sigma_geo_px, &s);
  return s;
}

// ---------------------------------------------------------------------------

SimRadiometry simulatorRadiometry(const SceneAnalysis& a, const RigParams& rig)
{
  rig.validate();
  SimRadiometry r;
  r.full_scale_e = rig.full_scale_e > 0.0 ? rig.full_scale_e : a.inputs.full_well_e;
  r.gain_dn_per_electron = 255.0 / r.full_scale_e;
  const double white = whiteSunElectrons(a, rig);
  r.exposure = white * r.gain_dn_per_electron / LightingParams::kSunFullScaleDn;
  const double ref_sigma = LightingParams::kReferenceBeamSigmaRad * LightingParams::kReferenceDistanceM;
  r.dot_to_sun_ratio = whiteDotElectrons(a, rig, ref_sigma) / white;
  r.read_noise_dn = a.inputs.read_noise_e * r.gain_dn_per_electron;
  r.beam_sigma_rad = rig.beam_sigma_rad;
  r.wavelength_nm = rig.emitter.wavelength_m * 1e9;
  return r;
}

SimRadiometry studySimRadiometry()
{
  SimRadiometry r;
  r.exposure = 1.0;
  r.dot_to_sun_ratio = LightingParams::sceneDotToSunRatio(RadiometryModel::kStudyAsStated);
  r.gain_dn_per_electron = 0.01;
  r.read_noise_dn = 1.0;
  r.beam_sigma_rad = 0.002;
  r.wavelength_nm = 520.0;
  r.full_scale_e = 25500.0;
  return r;
}

const SimRadiometry& recommendedSimRadiometry()
{
  static const SimRadiometry r = []
  {
    RigParams rig = RigParams::recommendedDaylight();
    rig.strobe = false;  // the projector lights every frame unless the driver strobes
    return simulatorRadiometry(analyseScene(SceneInputs()), rig);
  }();
  return r;
}

SimulatorParams studySimulatorParams()
{
  SimulatorParams p;
  applySimRadiometry(studySimRadiometry(), &p);
  return p;
}

void applySimRadiometry(const SimRadiometry& r, SimulatorParams* p)
{
  p->lighting.exposure = r.exposure;
  p->lighting.dot_to_sun_ratio = r.dot_to_sun_ratio;
  p->sensor.gain_dn_per_electron = r.gain_dn_per_electron;
  p->sensor.read_noise_dn = r.read_noise_dn;
  p->projector.beam_sigma_rad = r.beam_sigma_rad;
  p->projector.wavelength_nm = r.wavelength_nm;
}

}  // namespace structured_light_stabilizer
