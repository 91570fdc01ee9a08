// The radiometric model of a projector + camera rig in daylight
// (docs/daylight.md): from the rig (emitter LED or laser diode, its optical
// power and efficiency, beam divergence, continuous or pulsed drive
// synchronised with the exposure, exposure time, band-pass filter, strobing)
// and the scene of the study (camera, sun, target: scene_analysis.h) to the
// photo-electrons of a dot and of the sunlit rock in one pixel, the noise,
// the detection SNR and the centroid precision; and the brightness, gain and
// noise the simulator renders for that rig (simulatorRadiometry()).
//
// Contract: SI units everywhere unless a name says otherwise (_nm, _mrad,
// _ms in the YAML only). Electrons are per pixel per exposure. The sun's
// spectrum is a blackbody at the temperature its surface flux implies,
// scaled to the irradiance of the study (F50 at sun_level 1); kFlatInBand
// puts all of it into the camera's band as the study does (so that the
// corrected study LED gives dotToSunRatio()'s 0.0045). Pure functions: any
// thread. validate() and the functions that call it throw
// std::invalid_argument("radiometry: <field>: <reason>").
#pragma once

#include <string>

#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace structured_light_stabilizer
{

struct SimulatorParams;

enum class EmitterKind
{
  kLed,         // incoherent: no speckle; a broad spectrum (tens of nm)
  kLaserDiode,  // narrow spectrum (a multimode diode: ~1-2 nm); speckle on rough rock
};

enum class SunSpectrum
{
  kBlackbody,   // Planck at T_sun, scaled to the study's irradiance (the truth, up to Mars' dust)
  kFlatInBand,  // the study's simplification: all of the flux, flat over the camera's band
};

struct EmitterParams
{
  EmitterKind kind = EmitterKind::kLed;
  double wavelength_m = 520e-9;       // centre (peak) wavelength at the operating temperature
  double spectral_fwhm_m = 30e-9;     // Gaussian spectrum of this full width at half maximum
  double cw_optical_power_w = 0.0;    // optical power at the rated continuous drive
  double wall_plug_efficiency = 0.1;  // optical / electrical
  // Largest optical power of a pulse / the continuous rating (a pulsed LED
  // takes a few times its rated current at a low duty cycle; a laser diode
  // is limited by facet damage: ~1).
  double peak_power_factor = 1.0;
  // Share of the emitted light that lands in the dots (the study's LED:
  // collecting lens 0.5 x grid 0.3; a laser with a diffractive element ~0.7).
  double projector_efficiency = 0.15;
  double thermal_drift_m_per_k = 0.05e-9;  // shift of the centre wavelength with temperature

  // The study's LED (docs/study.md §2.1.2): 84 cd over a 30 deg cone is
  // 17.98 lm, 37.1 mW of 520 nm light from 0.2997 W electrical (12.4 %).
  static EmitterParams studyLed(const SceneAnalysis& analysis);
};

// A band-pass interference filter in front of the lens: a flat top of
// `transmission` over [centre - fwhm/2, centre + fwhm/2] at normal
// incidence, nothing outside. Off axis its passband moves to shorter
// wavelengths: centre * sqrt(1 - (sin(theta) / effective_index)^2).
struct BandPassFilter
{
  bool enabled = false;
  double centre_m = 520e-9;
  double fwhm_m = 40e-9;
  double transmission = 0.9;
  double effective_index = 2.0;

  double transmissionAt(double wavelength_m, double field_angle_rad = 0.0) const;
};

struct RigParams
{
  std::string name = "rig";
  EmitterParams emitter;
  double beam_sigma_rad = 0.002;  // 1-sigma divergence of one beam (dot sigma = this x distance)
  // Pulsed: the emitter is on only during the exposures with the projector
  // on, at up to peak_power_factor x its rating, within the average
  // electrical budget. Continuous: on all the time at min(rating, budget).
  bool pulsed = false;
  double electrical_budget_w = 0.3;  // average electrical power available (the study: 300 mW)
  double exposure_s = 0.1;
  double frame_rate_hz = 30.0;  // camera frames per second (both kinds when strobing)
  // Projector on in every second frame only; the others are ambient frames
  // subtracted from their neighbours (SpotDetector ~strobe).
  bool strobe = false;
  BandPassFilter filter;
  // Camera readout: electrons at the top of the output range (0: the full
  // well) and the output's bit depth.
  double full_scale_e = 0.0;
  int output_bits = 8;
  SunSpectrum sun_spectrum = SunSpectrum::kBlackbody;

  // The study's rig: its LED on continuously, 0.1 s exposure, no filter.
  static RigParams studyDesign(const SceneAnalysis& analysis);
  // The rig the design calculator recommends (config/rig_daylight.yaml, the
  // same values; docs/daylight.md): a pulsed 1 W 520 nm laser diode, 1.5
  // mrad beams, 2 ms exposures, no filter, strobed.
  static RigParams recommendedDaylight();
  // Throws std::invalid_argument naming the field.
  void validate() const;
};

// Where a dot is seen and how.
struct ViewConditions
{
  double sun_level = 1.0;  // 1 = the study's brightest sun (F50 max), 0 = night
  double albedo = 0.05;
  double distance_m = 2.0;              // projector (and camera) to the rock
  double sun_incidence_deg = 10.0;      // rock normal vs sun
  double emitter_incidence_deg = 10.0;  // rock normal vs beam (the study: 10 deg)
  Brdf brdf = Brdf::kLambertian;
  double field_angle_deg = 0.0;               // off-axis angle in the camera (filter shift, cos^4 vignetting)
  double emitter_temperature_offset_k = 0.0;  // from the design temperature (moves the emitter's line)
};

// The rock's fine texture and what the strobed subtraction leaves of it.
struct TextureConditions
{
  double contrast = 0.25;     // amplitude of the albedo's fine variation, a fraction of the albedo
  double period_m = 0.02;     // its spatial period on the rock
  double roughness_m = 5e-4;  // RMS height of the surface within a dot (laser speckle)
  // Misalignment (px) of the motion-compensated ambient image (measured:
  // docs/daylight.md) and the noise variance of that image relative to one
  // frame's (0.5: two frames blended halfway).
  double ambient_misalignment_px = 0.05;
  double ambient_noise_scale = 0.5;
  // Share of the albedo's variation a colour camera's reference plane does
  // not predict (hue varies too); 1 for a monochrome camera.
  double albedo_reference_residual = 1.0;
};

// One pixel at a dot's peak, per exposure with the projector on.
struct DotSignal
{
  // Drive.
  double pulse_energy_j = 0.0;  // optical energy emitted during one projector-on exposure
  double peak_optical_w = 0.0;  // optical power during the exposure
  double average_electrical_w = 0.0;
  bool peak_limited = false;  // the pulse is capped by peak_power_factor, not by the budget
  double dot_energy_j = 0.0;  // energy in one dot
  // Geometry.
  double dot_sigma_m = 0.0;   // on the rock
  double dot_sigma_px = 0.0;  // in the image, with defocus, diffraction and the pixel
  // Electrons.
  double sun_e = 0.0;         // sunlit rock (the ambient level under the dot)
  double dot_e = 0.0;         // added by the dot's peak
  double dark_e = 0.0;        // dark electrons (shot noise variance)
  double read_noise_e = 0.0;  // RMS, with the output's quantisation (full scale / (2^bits - 1) / sqrt(12))
  double ratio = 0.0;         // dot_e / sun_e (inf at night)
  // SNR of the peak over the noise of the background it sits on: one frame;
  // the strobed difference (on minus the compensated ambient); and both
  // with the rock's fine texture counted as clutter (its unknown part under
  // the dot: all of it in one frame, what misalignment leaves when strobed).
  double snr_single = 0.0;
  double snr_strobed = 0.0;
  double snr_single_textured = 0.0;
  double snr_strobed_textured = 0.0;
  // Centroid error (px, RMS): noise (Cramer-Rao bound of a Gaussian spot on
  // a background), the fine texture's bias under the dot (unknown albedo in
  // one frame; known from the ambient frame when strobed), laser speckle.
  double centroid_noise_single_px = 0.0;
  double centroid_noise_strobed_px = 0.0;
  double texture_bias_single_px = 0.0;
  double speckle_px = 0.0;
  double centroid_single_px = 0.0;   // total, one frame
  double centroid_strobed_px = 0.0;  // total, strobed
};

// The dot and the sunlit rock under it for a rig, a view and a texture.
DotSignal evaluateRig(const SceneAnalysis& analysis, const RigParams& rig, const ViewConditions& view,
                      const TextureConditions& texture = TextureConditions());

// Electrons of a white Lambertian surface facing the sun at sun_level 1, in
// one exposure of the rig, through its filter (the simulator's sun scale).
double whiteSunElectrons(const SceneAnalysis& analysis, const RigParams& rig);
// Peak electrons of a dot of sigma_m on a white Lambertian surface at normal
// incidence (no image blur), one exposure with the projector on.
double whiteDotElectrons(const SceneAnalysis& analysis, const RigParams& rig, double sigma_m);
// Speckle contrast of the emitter's light on a surface of this RMS height
// (Gaussian spectrum and heights; for an LED the formula gives a few per
// cent, and its spatial incoherence would lower that further).
double speckleContrast(const EmitterParams& emitter, double roughness_m);
// The narrowest filter that passes the emitter everywhere in the image over
// a temperature range: its spectral width, thermal drift and the filter's
// shift at the corner of the field (a filter centred between the line and
// its shifted position passes both).
double requiredFilterWidth(const SceneAnalysis& analysis, const RigParams& rig, double temperature_range_k);

// What the simulator renders for a rig (LightingParams, SensorParams,
// ProjectorParams in DN of its 8-bit scale).
struct SimRadiometry
{
  double exposure = 1.0;          // LightingParams::exposure
  double dot_to_sun_ratio = 0.0;  // LightingParams::dot_to_sun_ratio (the 3 mm reference dot)
  double gain_dn_per_electron = 0.01;
  double read_noise_dn = 1.0;
  double beam_sigma_rad = 0.002;
  double wavelength_nm = 520.0;
  double full_scale_e = 0.0;  // electrons at 255 DN
};
SimRadiometry simulatorRadiometry(const SceneAnalysis& analysis, const RigParams& rig);
// The study's design as stated on the simulator's historical camera (100
// e-/DN, 1 DN read noise, exposure 1, the 2 mrad beam, dot/sun 3.66): what
// `radiometry: study` renders, the frames of every figure measured before
// the corrected radiometry.
SimRadiometry studySimRadiometry();
// The recommended rig (RigParams::recommendedDaylight()) lighting every
// frame (not strobed), on the study's scene; computed once.
const SimRadiometry& recommendedSimRadiometry();
// The simulator's default params with studySimRadiometry(): for the tests
// and benchmarks about the study's brightness.
SimulatorParams studySimulatorParams();
// Sets those fields of the simulator's params.
void applySimRadiometry(const SimRadiometry& radiometry, SimulatorParams* params);

// The rig as YAML (the `rig:` document the design tool writes and the
// simulator reads) and back. Every key optional (the study's rig), unknown
// keys refused; throws std::invalid_argument with the source, line and
// reason.
std::string rigToYaml(const RigParams& rig, const std::string& comment = "");
RigParams rigFromYaml(const SceneAnalysis& analysis, const std::string& yaml_text,
                      const std::string& source = "<string>");
RigParams loadRig(const SceneAnalysis& analysis, const std::string& path);

}  // namespace structured_light_stabilizer
