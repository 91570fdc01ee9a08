// The study's optical and radiometric design (its Part 2, §2.1), computed
// (docs/scene_analysis.md). Section numbers (§2.1.x) and equation numbers
// ((2.x)) below are the study's, summarised in docs/study.md.
//
// Contract: SceneInputs holds every input of §2.1 in SI units (metres,
// seconds, watts, kelvin; angles in degrees where the name says _deg), with
// the study's values as defaults. analyseScene() validates them (throws
// std::invalid_argument naming the field and the reason) and returns every
// quantity of §2.1 both as typed fields (SI units) and as a table row with its
// unit, the value the study states and a note where the study differs.
//
// "Computed" values follow the physics from the inputs. Where the study's
// arithmetic is wrong (unit slips, read noise divided by the pixel count, the
// aperture applied twice, shot noise taken as the signal itself, lumens
// divided by a wall-plug efficacy) the computed value is the correct one and
// the note says what the study did. Where the study makes a modelling
// simplification (all of the sun's flux inside 400-800 nm, the irradiance on
// the horizontal ground projected a second time onto the rock) the model is
// kept so that the numbers stay comparable, and the note says so.
//
// Photo-electrons are per pixel per exposure. Radiances are W/(m^2 sr).
// Every function is pure and may be called from any thread.
//
// Where each part lives (src/sim/): scene_inputs (defaults, validation,
// YAML), scene_model (building blocks, the simulator's brightness),
// scene_analysis (analyseScene, part by part), scene_table (the design table
// and its notes), aperture_sweep (figure 2.2).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

namespace structured_light_stabilizer
{

struct SceneInputs
{
  // Scene (study's delimitations).
  double target_height_m = 2.0;  // H: largest target the image must hold
  double distance_min_m = 1.0;   // camera-target distance range
  double distance_max_m = 2.0;   // D in tan(FoV/2) = H / (2 D)

  // Camera (§2.1.1, FTT1010M datasheet).
  int pixels_x = 1024;
  int pixels_y = 1024;
  double pixel_size_m = 12e-6;
  double sensor_height_m = 12.288e-3;   // CCDh, image section height
  double focus_distance_m = 1.0;        // rf
  double aperture_diameter_m = 1.9e-3;  // Dsr, effective entrance aperture
  double wavelength_min_m = 400e-9;
  double wavelength_max_m = 800e-9;
  double exposure_s = 0.1;             // ts
  double camera_axis_angle_deg = 0.0;  // alpha_CT, camera axis vs target normal
  double lens_transmission = 0.8;      // alphaLens: the study states no value
  // Quantum efficiency of the CCD, (wavelength m, QE) sorted by wavelength,
  // linearly interpolated. The study uses the datasheet curve (its fig. 2.3);
  // the default approximates it (front-illuminated frame-transfer CCD, peak
  // 0.34 at 510 nm), see config/scene_analysis.yaml.
  std::vector<std::pair<double, double>> quantum_efficiency = defaultQuantumEfficiency();
  double read_noise_e = 25.0;                    // RMS readout noise per pixel (datasheet)
  double dark_current_a_m2 = 30e-12 / 1e-4;      // 30 pA/cm^2 (datasheet max) ...
  double dark_reference_temperature_k = 293.15;  // ... at 20 C
  double temperature_k = 197.0;                  // sensor temperature on Mars
  double full_well_e = 350e3;                    // linear full well Qlin (datasheet typical)

  // Sun and Mars (§2.1.3.1).
  double sun_surface_flux_w_m2 = 6.45e7;  // F_sun at the sun's surface
  double sun_radius_m = 6.956e8;
  double mars_perihelion_m = 2.06644e11;
  double mars_aphelion_m = 2.49228e11;
  double mars_semi_major_axis_m = 2.27936e11;
  double atmosphere_loss = 0.10;        // fraction absorbed/scattered
  double latitude_deg = 50.0;           // sun elevation at most 90 - latitude
  double sun_elevation_min_deg = 10.0;  // the rover stops below this

  // Target (§1.1.3, §2.1.3.2).
  double albedo_min = 0.05;
  double albedo_max = 0.45;
  double sun_incidence_min_deg = 10.0;  // theta: target normal vs sun beam
  double sun_incidence_max_deg = 50.0;
  double glossy_fraction = 0.1;  // BRDF = (1-g) Lambertian + g glossy

  // LED projector (§2.1.2, LED datasheet in annex .2).
  double led_luminous_intensity_cd = 84.0;
  double led_beam_angle_deg = 30.0;          // full diffusion angle
  double led_luminous_efficacy_lm_w = 60.0;  // study's L_e (a wall-plug efficacy)
  double led_wavelength_m = 520e-9;
  double led_lens_transmission = 0.5;  // study's "LFLed"
  double led_grid_transmission = 0.3;  // study's "LFGLed"
  int dot_rows = 10;
  int dot_cols = 10;
  double dot_area_m2 = 6.2832e-6;   // A_point = 2 pi (1 mm)^2
  double led_incidence_deg = 10.0;  // theta_LED: target normal vs LED beam

  // Figure 2.2 sweep.
  double sweep_aperture_min_m = 1e-3;
  double sweep_aperture_max_m = 5e-3;

  static std::vector<std::pair<double, double>> defaultQuantumEfficiency();

  // Throws std::invalid_argument("scene_analysis: <field>: <reason>").
  void validate() const;
};

// Reads inputs from YAML text / a file: every key optional (study default),
// unknown keys rejected (a typo must not silently fall back to a default).
// Throws std::invalid_argument with the file, line and reason.
SceneInputs sceneInputsFromYaml(const std::string& yaml_text, const std::string& source = "<string>");
SceneInputs loadSceneInputs(const std::string& path);

struct Range
{
  double min = 0.0;
  double max = 0.0;
};

// One line of the design table. value_max / study_max are NaN for scalars;
// study is NaN when the study gives no number.
struct Quantity
{
  std::string key;  // stable identifier, e.g. "fov_full"
  std::string name;
  std::string ref;  // where in the study: "(2.4)", "§2.1.1.2", "table 2.1"
  double value = 0.0;
  double value_max = 0.0;
  bool is_range = false;
  std::string unit;  // display unit; value is already scaled to it
  double study = 0.0;
  double study_max = 0.0;
  bool has_study = false;
  bool agrees = true;  // within the precision the study states
  std::string note;
};

// Which surface the photo-electron counts refer to.
enum class Brdf
{
  kLambertian,        // the study's worst case
  kLambertianGlossy,  // (1-g) Lambertian + g constant lobe: the study's optimal case
};

struct SceneAnalysis
{
  SceneInputs inputs;

  // Camera geometry.
  double fov_half_deg = 0.0;
  double fov_full_deg = 0.0;
  double efl_m = 0.0;
  double focal_length_m = 0.0;
  double f_number = 0.0;
  double doc_far_m = 0.0;            // diameter of confusion at distance_max
  double doc_near_m = 0.0;           // at distance_min
  double diffraction_min_m = 0.0;    // Airy diameter at wavelength_min
  double diffraction_max_m = 0.0;    // at wavelength_max
  double balanced_aperture_m = 0.0;  // DoC(far) = diffraction(wavelength_max)
  double dof_formula_m = 0.0;        // the study's DoF formula
  double dof_near_m = 0.0;           // limits where DoC = DoC(far)
  double dof_far_m = 0.0;

  // Sun.
  double sun_temperature_k = 0.0;       // blackbody temperature implied by F_sun
  double solar_fraction_in_band = 0.0;  // blackbody flux share in [wl_min, wl_max]
  double irradiance_perihelion = 0.0;   // W/m^2, top of atmosphere
  double irradiance_aphelion = 0.0;
  double irradiance_semi_major = 0.0;
  double irradiance_surface = 0.0;  // F_a, after the atmosphere
  Range irradiance_latitude;        // F50 over the sun elevation range

  // Sunlit target and sensor (ranges over albedo, theta, F50 and the BRDF).
  Range radiance_target;             // W/(m^2 sr)
  Range irradiance_sensor;           // W/m^2
  Range power_per_pixel;             // W
  Range photons_per_pixel;           // per exposure, flat spectrum over the band
  double sun_band_efficiency = 0.0;  // photon-weighted mean of QE * lens transmission
  Range sun_electrons;               // photo-electrons per pixel

  // LED.
  double led_solid_angle_sr = 0.0;
  double led_luminous_flux_lm = 0.0;
  double led_power_study_w = 0.0;                     // flux / L_e: an electrical power
  double led_luminous_efficacy_radiation_lm_w = 0.0;  // 683 V(lambda)
  double led_optical_power_w = 0.0;                   // flux / (683 V(lambda))
  double led_lens_diameter_ratio = 0.0;               // collecting lens d / f = 2 tan(alpha)
  double dot_power_w = 0.0;
  double dot_irradiance = 0.0;  // W/m^2
  Range led_power_per_pixel;    // W
  double led_efficiency = 0.0;  // QE * lens transmission at the LED wavelength
  Range led_electrons;

  // Noise and SNR.
  double read_noise_e = 0.0;
  double dark_current_e_s = 0.0;               // per pixel at temperature_k
  double dark_noise_e = 0.0;                   // sqrt(dark electrons)
  double noise_floor_e = 0.0;                  // sqrt(read^2 + dark^2)
  Range snr_sun;                               // case 1, sun only
  Range snr_led_night;                         // case 2
  Range snr_led_day;                           // case 3, albedo and BRDF shared by both lights
  double saturating_exposure_s = 0.0;          // brightest pixel reaches full_well_e
  double snr_led_day_worst_unsaturated = 0.0;  // case 3 worst at that exposure

  std::vector<Quantity> table;
};

// Throws std::invalid_argument when the inputs are out of range.
SceneAnalysis analyseScene(const SceneInputs& inputs);

// Diameter of confusion on the sensor (m) of a point at distance_m, for an
// aperture diameter (docs/study.md §2.1.1.4).
double diameterOfConfusion(const SceneInputs& in, double aperture_m, double distance_m);
// Airy disc diameter (first zero) on the sensor (m): 2 EFL tan(1.22 lambda / D).
double diffractionSpot(const SceneInputs& in, double aperture_m, double wavelength_m);
// Quantum efficiency interpolated in the table (clamped to its ends).
double quantumEfficiency(const SceneInputs& in, double wavelength_m);
// CIE 1931 photopic luminous efficiency V(lambda), 0 outside 380-780 nm.
double photopicEfficiency(double wavelength_m);

// Target radiance W/(m^2 sr) under an irradiance (W/m^2, measured as the study
// does), albedo, incidence angle and BRDF (study (2.7), labels corrected).
double targetRadiance(const SceneInputs& in, double irradiance, double albedo, double incidence_deg, Brdf brdf);

// --- Brightness for the simulator ------------------------------------------
// sun_level: 0 = night, 1 = the brightest sun of the study (F50 at the highest
// elevation, incidence sun_incidence_min_deg), matching
// LightingParams::sun_level. The dot is the peak of the projected spot.
enum class RadiometryModel
{
  kCorrected,      // LED optical power from 683 V(lambda); sqrt shot noise
  kStudyAsStated,  // LED "power" = flux / 60 lm/W and its photo-electrons x100
                   // (the slip that gives the study's SNR 32 / 348)
};

struct DotSunElectrons
{
  double sun_e = 0.0;  // per pixel, sunlit surface at this sun_level
  double dot_e = 0.0;  // per pixel, added by the dot's peak
  double read_noise_e = 0.0;
  double dark_e = 0.0;  // dark electrons (variance)
  // dot_e / sun_e at this sun_level (inf at night).
  double ratio() const;
  // dot_e / sqrt(dot_e + sun_e + dark_e + read^2): the dot's SNR over the background.
  double snr() const;
};

// Photo-electrons per pixel for a surface of this albedo and BRDF.
// exposure_s <= 0 uses inputs.exposure_s. dot_sigma_m <= 0 spreads the dot's
// power over the study's A_point (= a Gaussian of sigma 1 mm); otherwise the
// dot is a Gaussian of that sigma on the rock (peak = power / (2 pi sigma^2)).
DotSunElectrons dotAndSunElectrons(const SceneAnalysis& analysis, double albedo, double sun_level,
                                   RadiometryModel model = RadiometryModel::kCorrected, Brdf brdf = Brdf::kLambertian,
                                   double exposure_s = -1.0, double dot_sigma_m = -1.0);

// Ratio of the dot's peak photo-electrons to the sunlit surface's at
// sun_level = 1 (independent of albedo; the BRDF cancels because the study's
// LED and brightest-sun incidences are both 10 deg). This is what
// LightingParams::dot_to_sun_ratio means when the simulator renders radiance
// in photo-electron units. It scales as 1 / dot_sigma^2.
//
// For the simulator (LightingParams::dot_to_sun_ratio refers to its 2 mrad
// beam at 1.5 m, i.e. a dot of sigma 3 mm; sun_level 1 = this sun_level 1):
//   dotToSunRatio(SceneInputs(), kStudyAsStated, 3e-3) = 3.66: the brightness
//     the study claims (its worst-case "SNR 32" is this ratio x 9 for its
//     1 mm dot); worst case sun_level 1, albedo 0.05; its weakest daylight
//     sun is sun_level 0.176 (F50 = 94 W/m^2 at 50 deg), night 0.
//   dotToSunRatio(SceneInputs(), kCorrected, 3e-3) = 0.0045: the physics of
//     the study's LED (0.041 for its 1 mm dot).
// The SNR a ratio gives in an image depends on the electrons behind a DN:
// see ratioForSnr().
double dotToSunRatio(const SceneAnalysis& analysis, RadiometryModel model = RadiometryModel::kCorrected,
                     double dot_sigma_m = -1.0);
double dotToSunRatio(const SceneInputs& inputs, RadiometryModel model = RadiometryModel::kCorrected,
                     double dot_sigma_m = -1.0);

// SNR of a dot of `ratio` times the background over a background of
// background_e electrons, with shot, read and dark noise.
double dotSnr(double ratio, double background_e, double read_noise_e, double dark_e = 0.0);
// The ratio that gives target_snr over that background (inverse of dotSnr).
double ratioForSnr(double target_snr, double background_e, double read_noise_e, double dark_e = 0.0);

// --- Figure 2.2 -------------------------------------------------------------
struct ApertureSweepRow
{
  double aperture_m = 0.0;
  double doc_m = 0.0;                 // at distance_max
  std::vector<double> diffraction_m;  // one per sweep wavelength
};
struct ApertureSweep
{
  std::vector<double> wavelengths_m;  // 400, 500, ..., 800 nm for the defaults
  std::vector<ApertureSweepRow> rows;
};
ApertureSweep apertureSweep(const SceneInputs& in, int steps = 201, int wavelength_count = 5);
std::string apertureSweepCsv(const ApertureSweep& sweep);
// A plot of the sweep (BGR image): DoC, diffraction spots, the pixel size and
// the chosen aperture.
cv::Mat renderApertureSweep(const SceneInputs& in, const ApertureSweep& sweep, int width = 1000, int height = 700);

// The design table as aligned text.
std::string formatDesignTable(const SceneAnalysis& analysis);

}  // namespace structured_light_stabilizer
