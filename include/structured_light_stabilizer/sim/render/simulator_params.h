// Settings of the scene simulator (simulator.h), one struct per part of the
// scene: the sensor and its optics, the rock, the projector, the lighting,
// the rig's motion and the clutter on the rock. Plain data with the study's
// design as defaults (docs/simulator.md); SimulatorParams::validate() says
// what is out of range. Units are SI unless the name says otherwise (_dn:
// 8-bit counts, _rad, _hz).
#pragma once

#include <cstdint>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/common/projector_color.h"
#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace structured_light_stabilizer
{

// Motion of the rig relative to the rock, a deterministic function of time.
struct RigMotionParams
{
  double jitter_translation_m = 0.0;                             // wind jitter amplitude, per axis
  double jitter_rotation_rad = 0.0;                              // wind jitter amplitude, per axis
  double jitter_frequency_hz = 0.7;                              // base frequency; axes use incommensurate multiples
  Eigen::Vector3d drift_velocity_mps = Eigen::Vector3d::Zero();  // slow drift, camera frame at t=0
  Eigen::Vector3d drift_angular_velocity_radps = Eigen::Vector3d::Zero();
  double step_period_s = 0.0;  // 0 = no steps; else a step every period
  Eigen::Vector3d step_translation_m = Eigen::Vector3d::Zero();
  // When > 0, the motion is periodic with this period and returns exactly to
  // the reference pose at every multiple of it (used by the return-to-identity test).
  double return_period_s = 0.0;

  // ---- The closed loop's disturbance (docs/stabilization.md, src/sim/rig_motion.cpp).
  // Vibration: band-limited random motion, RMS per axis, its power spectral
  // density proportional to f^vibration_spectrum_slope between the two
  // frequencies (min = max: one sine of that RMS); phases and frequencies
  // drawn from `seed`.
  double vibration_translation_rms_m = 0.0;
  double vibration_rotation_rms_rad = 0.0;
  double vibration_min_hz = 1.0;
  double vibration_max_hz = 8.0;
  double vibration_spectrum_slope = 0.0;
  // Each step also rotates by this, and ramps over step_rise_s (raised
  // cosine; 0 = instantaneous).
  Eigen::Vector3d step_rotation_rad = Eigen::Vector3d::Zero();
  double step_rise_s = 0.0;
  // The rotations of the motion turn the camera about this point (reference
  // camera frame, m; zero = the camera centre), e.g. a wheel's contact patch
  // when the rover tilts.
  Eigen::Vector3d pivot_m = Eigen::Vector3d::Zero();
  uint32_t seed = 1;
};

struct RockParams
{
  double distance_m = 1.5;  // distance of the rock's mean plane from the camera at t=0
  double width_m = 2.0;     // extent of the target (<= 2 x 2 m)
  double height_m = 2.0;
  double relief_m = 0.15;    // peak-to-peak relief of the height field (0 = flat board)
  double albedo_min = 0.05;  // textured albedo range of the red channel (docs/study.md §1.1.3)
  double albedo_max = 0.45;
  // The rock's colour: its green and blue albedo over its red, before the
  // slowly varying hue (defaults: the study's reddish rock, G/R 0.55-0.65;
  // a grey basalt is about 0.9 and 0.85).
  double green_to_red = 0.55;
  double blue_to_red = 0.36;
  double texture_scale_m = 0.02;  // size of the finest albedo features (>= 0.1: a weakly textured rock)
  // Optional fine texture (docs/simulator.md, "Rock"): a multiplicative
  // albedo modulation of this period (m; 0 = off; real rock: 0.01-0.03) and
  // relative amplitude (0.25 = albedo within about +-25 %), mostly brightness
  // with a little hue (R against B). Resolving it needs a finer vertex grid
  // (period / 8, >= 2 mm): more memory and build time when on.
  double fine_texture_period_m = 0.0;
  double fine_texture_amplitude = 0.25;
  // Colour texture at the same scale: the green albedo's own variation
  // against the red (0.15: green/red within about +-15 % over 1-3 cm), so
  // that the red channel no longer predicts the green under a dot. 0 = off.
  double fine_texture_green = 0.0;
  // Reflectance at 850 nm over the red reflectance (an NIR projector's dots):
  // iron-bearing rock reflects more in the near infrared than in the red.
  double nir_to_red_ratio = 1.25;
  double tilt_x_rad = 0.0;  // orientation of the mean plane (0 = facing the camera)
  double tilt_y_rad = 0.0;
  // Optional straight step along y at x = step_x_m: the side x > step_x_m lies
  // step_height_m farther from the camera (negative: nearer). For occlusion
  // and shadow tests; the step is one height-grid cell wide.
  double step_height_m = 0.0;
  double step_x_m = 0.0;
  uint32_t seed = 1;
};

// The projector's light; docs/simulator.md, "Colours and sensor
// outputs". ProjectorColor and its names (projectorColorName,
// projectorColorFromName) are the core's, shared with the SpotDetector
// (projector_color.h); the simulator's nominal wavelengths: green 520 nm (the
// study's), red 638 nm (635-660 nm lasers), blue 450 nm, nir 850 nm (a
// monochrome camera only: a colour camera's IR-cut filter blocks it), white
// broadband.
// The colour's nominal wavelength (white: 550 nm, for diffraction).
double nominalWavelengthNm(ProjectorColor color);

struct ProjectorParams
{
  int rows = 10;
  int cols = 10;
  Eigen::Vector3d origin_m = Eigen::Vector3d(0.25, 0.0, 0.0);  // baseline from the camera centre
  double pitch_x_rad = 0.035;
  double pitch_y_rad = 0.035;
  double roll_rad = 0.087;           // in-plane rotation of the grid (5 deg by default)
  double converge_distance_m = 1.5;  // the central beam crosses the optical axis here
  ProjectorColor color = ProjectorColor::kGreen;
  double wavelength_nm = 520.0;  // within the colour's band (validate()); sets the diffraction
  // Gaussian divergence of each beam (1-sigma, rad): a dot's sigma on the rock
  // grows with its distance from the projector, so its image size stays about
  // 2 px at any depth (3 mm at 1.5 m -> 2.0 px with fx = 1011.7 px).
  double beam_sigma_rad = recommendedSimRadiometry().beam_sigma_rad;  // the recommended rig's (1.5 mrad)
  double power_scale = 1.0;  // relative dot brightness (1 = the study's LED design)
};

// What the camera delivers: the ROS image encodings.
enum class SensorOutput
{
  kBgr8,
  kRgb8,
  kMono8,       // a monochrome camera: one channel
  kMono16,      // the same, 16 bits: DN * 257 (the 8-bit range, and so the default full well, over 65535)
  kBayerRggb8,  // a colour camera's raw mosaic: each pixel its own channel's signal and noise
  kBayerBggr8,
  kBayerGbrg8,
  kBayerGrbg8,
  // A colour camera's converter of more than 8 bits (the recommended rig's
  // 12), its pixels in 16 bits: DN * 257 rounded to its steps
  // (SensorParams::output_bits), MSB-aligned.
  kBgr16,
  kRgb16,
};

// The sensor_msgs encoding ("bgr8", "bayer_rggb8", ...) and back.
const char* encodingName(SensorOutput output);
bool sensorOutputFromEncoding(const std::string& encoding, SensorOutput* output);
bool isMonochrome(SensorOutput output);
bool isBayer(SensorOutput output);

// What a pixel's charge above the full well does.
enum class Blooming
{
  kNone,    // it is lost (an anti-blooming drain): the pixel clips at the full well
  kColumn,  // it spills along the column, half up, half down, into pixels with room (a frame-transfer CCD)
};

struct SensorParams
{
  CameraModel camera = CameraModel::studyDesign();
  double pixel_size_m = 12e-6;
  double focal_length_m = 12.14e-3;
  double focus_distance_m = 1.0;
  double aperture_diameter_m = 1.9e-3;
  // Gain and read noise of the recommended rig's camera (radiometry.h; the
  // historical camera of studySimRadiometry(): 0.01 DN/e-, 1 DN).
  double read_noise_dn = recommendedSimRadiometry().read_noise_dn;  // std dev in 8-bit counts (0 = off)
  bool shot_noise = true;
  // Conversion gain, DN per photo-electron: shot noise variance = signal_dn * gain.
  // 0.01 = 100 e-/DN, a 25.5 ke- full well over the 8-bit range.
  double gain_dn_per_electron = recommendedSimRadiometry().gain_dn_per_electron;
  // Natural vignetting: image irradiance falls as cos^4 of the off-axis angle
  // (the study's eq. 2.9 factor; 0.45 in the corners of this 53 deg lens).
  bool natural_vignetting = true;
  SensorOutput output = SensorOutput::kBgr8;
  // The converter's bits of the 16-bit outputs (mono16, bgr16, rgb16), 8-16:
  // a pixel is DN * 257 rounded to a multiple of 2^(16 - output_bits) (12:
  // steps of 16/257 DN). The 8-bit outputs round to whole DN.
  int output_bits = 16;
  // Charge at which a pixel is full, in DN (8-bit counts; 255 = the 8-bit
  // range, 25.5 ke- at the default gain). Below 255 the 8-bit image clips
  // there, before the read noise.
  double full_well_dn = 255.0;
  Blooming blooming = Blooming::kNone;
  // Exposure-time motion blur (option; 0 = an instantaneous exposure): the
  // frame integrates the rig's motion over this exposure, centred on the
  // frame's time (the ground truth's instant), in exposure_samples
  // sub-exposures of the rock (the dots take as many as their smear needs).
  double exposure_time_s = 0.0;
  int exposure_samples = 8;
};

struct LightingParams
{
  // DN of a white Lambertian surface facing the sun at sun_level = 1 (exposure
  // 1): the brightest red rock (reflectance 0.45) reaches 230 DN in red.
  static constexpr double kSunFullScaleDn = 510.0;
  // dot_to_sun_ratio refers to a beam of this divergence hitting the rock at
  // this distance at normal incidence (a dot of sigma 3 mm on the rock).
  static constexpr double kReferenceBeamSigmaRad = 0.002;
  static constexpr double kReferenceDistanceM = 1.5;

  // The dot-versus-sun brightness of the study's design (scene_analysis.h,
  // dotToSunRatio() for the reference dot above): kStudyAsStated = 3.66 (the
  // brightness the study claims: its worst case "SNR 32" for a 1 mm dot),
  // kCorrected = 0.0045 (the physics of its LED: dots invisible in daylight).
  static double sceneDotToSunRatio(RadiometryModel model);

  // 0 = night, 1 = the study's brightest case (F50 = 341 W/m^2, optimal BRDF).
  double sun_level = 0.5;
  // Ratio of a dot's peak radiance (green channel) to the radiance of the
  // same surface facing the sun at sun_level = 1, both at normal incidence.
  // Default: the study as stated (above).
  // Default: the recommended daylight rig's corrected physics (radiometry.h,
  // docs/daylight.md); studySimRadiometry() is the study as stated.
  double dot_to_sun_ratio = recommendedSimRadiometry().dot_to_sun_ratio;
  double exposure = recommendedSimRadiometry().exposure;  // global scale applied before quantisation

  // Scene lighting, baked into the rock's shading when the simulator is built
  // (updateLive() keeps the built ones). Direction towards the sun in the
  // rock frame (z away from the camera), and the diffuse sky light as a
  // fraction of the direct sun on a surface facing it (faces turned away from
  // the sun are dim, not black).
  Eigen::Vector3d sun_direction = Eigen::Vector3d(-0.40, -0.45, -0.80).normalized();
  double sky_ambient = 0.08;
};

struct ClutterParams
{
  int green_specks = 0;    // small green specks (1-3 px)
  int olive_minerals = 0;  // olive/green-brown patches (should not be detected)
  int green_blobs = 0;     // dot-sized green blobs on the rock (spurious dots)
};

// A printed chessboard, OpenCV's convention: `cols` x `rows` inner
// corners, corner (i, j) at (i * square_m, j * square_m, 0) in the board
// frame (x along a row of corners, y down the rows, z into the board, away
// from the camera); the outer square at the corner (-1, -1) is black. The
// squares sit inside a white printed margin; the board is flat.
struct ChessboardParams
{
  int cols = 10;  // inner corners per row
  int rows = 8;   // inner corners per column
  double square_m = 0.08;
  double margin_m = 0.04;            // white margin around the outer squares
  double black = 0.03, white = 0.5;  // reflectance, every band (white / black ~ 16)
  // Pose at t = 0: the centre of the inner corners at `distance_m` along the
  // optical axis plus `offset_m` (camera x, y), the board rotated by
  // Rx(tilt_x) Ry(tilt_y) Rz(roll) from facing the camera squarely.
  double distance_m = 1.5;
  double tilt_x_rad = 0.0, tilt_y_rad = 0.0, roll_rad = 0.0;
  Eigen::Vector2d offset_m = Eigen::Vector2d::Zero();
};

enum class TargetKind
{
  kRock,        // the rock of RockParams
  kChessboard,  // a flat printed chessboard (ChessboardParams) instead
};

// What the camera looks at (docs/simulator.md, "Targets").
struct TargetParams
{
  TargetKind kind = TargetKind::kRock;
  ChessboardParams chessboard;
};

struct SimulatorParams
{
  SensorParams sensor;
  RockParams rock;
  TargetParams target;
  ProjectorParams projector;
  LightingParams lighting;
  RigMotionParams motion;
  ClutterParams clutter;
  uint32_t noise_seed = 42;
  // The rock is ray-cast on every rock_subsample-th pixel (centres of n x n
  // blocks); in between, the surface point is interpolated and each pixel
  // reads the reflectance at its own point (the radiance is blended only
  // across silhouettes and steps, and under motion blur); 1 = every pixel.
  // 2 matches 1 within 0.3 % (mean; the fine texture at 2 m) for 60 % of its
  // cost. Dots, clutter, noise and all ground truth are per pixel and exact
  // whatever the value. In [1, 4].
  int rock_subsample = 2;
  // Keep the noise-free linear radiance (CV_32FC3, DN, before noise, clipping
  // and quantisation) in SimFrame::linear; for tests.
  bool keep_linear = false;
  // Fill SimFrame::light_centroids and footprint_centroids (a sum over each
  // dot's pixels, about 1 ms a frame); for the evaluation tools. The image
  // is the same either way.
  bool dot_centroid_truth = false;

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

}  // namespace structured_light_stabilizer
