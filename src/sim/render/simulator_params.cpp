#include "structured_light_stabilizer/sim/render/simulator_params.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "sim/render/rig_motion.h"

namespace structured_light_stabilizer
{

namespace
{

bool finitePositive(double v)
{
  return std::isfinite(v) && v > 0.0;
}
bool finiteNonNegative(double v)
{
  return std::isfinite(v) && v >= 0.0;
}

// Each check below appends "reason; " to why.

void checkSensor(const SensorParams& sensor, std::ostringstream& why)
{
  const std::string cam = sensor.camera.validate();
  if (!cam.empty())
    why << "camera: " << cam << "; ";
  if (!finitePositive(sensor.pixel_size_m) || !finitePositive(sensor.focal_length_m) ||
      !finitePositive(sensor.aperture_diameter_m))
    why << "pixel size, focal length and aperture must be positive; ";
  if (!(sensor.focus_distance_m > sensor.focal_length_m) || !std::isfinite(sensor.focus_distance_m))
    why << "focus distance " << sensor.focus_distance_m << " m must exceed the focal length; ";
  if (!finiteNonNegative(sensor.read_noise_dn))
    why << "read_noise_dn must be >= 0; ";
  if (!finitePositive(sensor.gain_dn_per_electron))
    why << "gain_dn_per_electron must be > 0; ";
  if (!(sensor.exposure_time_s >= 0.0 && sensor.exposure_time_s <= 1.0) || sensor.exposure_samples < 1 ||
      sensor.exposure_samples > 64)
    why << "exposure_time_s " << sensor.exposure_time_s << " must be in [0, 1] and exposure_samples "
        << sensor.exposure_samples << " in [1, 64]; ";
  if (!(sensor.full_well_dn >= 1.0 && sensor.full_well_dn <= 1e6))
    why << "full_well_dn " << sensor.full_well_dn << " is outside [1, 1e6]; ";
  if (sensor.output_bits < 8 || sensor.output_bits > 16)
    why << "output_bits " << sensor.output_bits << " is outside [8, 16]; ";
}

void checkRock(const RockParams& rock, std::ostringstream& why)
{
  if (!(rock.distance_m >= 0.2 && rock.distance_m <= 20.0))
    why << "rock distance " << rock.distance_m << " m is outside [0.2, 20]; ";
  if (!(rock.width_m > 0.0 && rock.width_m <= 5.0 && rock.height_m > 0.0 && rock.height_m <= 5.0))
    why << "rock size " << rock.width_m << " x " << rock.height_m << " m is outside (0, 5]; ";
  if (!(rock.relief_m >= 0.0 && rock.relief_m <= 1.0))
    why << "rock relief " << rock.relief_m << " m is outside [0, 1]; ";
  if (!std::isfinite(rock.step_height_m) || !std::isfinite(rock.step_x_m) || std::abs(rock.step_height_m) > 1.0)
    why << "rock step height must be finite and within [-1, 1] m; ";
  if (!(rock.relief_m + std::abs(rock.step_height_m) < 0.8 * rock.distance_m))
    why << "rock relief must stay well in front of the camera (< 0.8 x distance); ";
  if (!(rock.albedo_min >= 0.0 && rock.albedo_min <= rock.albedo_max && rock.albedo_max <= 1.0))
    why << "albedo range [" << rock.albedo_min << ", " << rock.albedo_max << "] must satisfy 0 <= min <= max <= 1; ";
  if (!(rock.green_to_red >= 0.0 && rock.green_to_red <= 2.0 && rock.blue_to_red >= 0.0 && rock.blue_to_red <= 2.0))
    why << "rock colour green_to_red " << rock.green_to_red << ", blue_to_red " << rock.blue_to_red
        << " must be in [0, 2]; ";
  if (!(rock.texture_scale_m >= 0.002 && rock.texture_scale_m <= 1.0))
    why << "texture_scale_m " << rock.texture_scale_m << " is outside [0.002, 1]; ";
  if (!(rock.fine_texture_period_m == 0.0 ||
        (rock.fine_texture_period_m >= 0.004 && rock.fine_texture_period_m <= 1.0)))
    why << "fine_texture_period_m " << rock.fine_texture_period_m << " must be 0 (off) or within [0.004, 1]; ";
  if (!(rock.fine_texture_amplitude >= 0.0 && rock.fine_texture_amplitude <= 0.9))
    why << "fine_texture_amplitude " << rock.fine_texture_amplitude << " is outside [0, 0.9]; ";
  if (!(rock.fine_texture_green >= 0.0 && rock.fine_texture_green <= 0.9))
    why << "fine_texture_green " << rock.fine_texture_green << " is outside [0, 0.9]; ";
  if (!(rock.nir_to_red_ratio > 0.0 && rock.nir_to_red_ratio <= 5.0))
    why << "nir_to_red_ratio " << rock.nir_to_red_ratio << " is outside (0, 5]; ";
  if (!(std::abs(rock.tilt_x_rad) < 1.2 && std::abs(rock.tilt_y_rad) < 1.2))
    why << "rock tilt must stay below 1.2 rad; ";
}

void checkTarget(const TargetParams& target, std::ostringstream& why)
{
  if (target.kind != TargetKind::kChessboard)
    return;
  const ChessboardParams& b = target.chessboard;
  if (b.cols < 2 || b.rows < 2 || b.cols > 60 || b.rows > 60)
    why << "chessboard inner corners " << b.cols << " x " << b.rows << " are outside [2, 60]; ";
  if (!(b.square_m >= 0.005 && b.square_m <= 1.0) || !(b.margin_m >= 0.0 && b.margin_m <= 1.0))
    why << "chessboard square " << b.square_m << " m must be in [0.005, 1] and margin " << b.margin_m
        << " m in [0, 1]; ";
  else if ((std::max(b.cols, b.rows) + 1) * b.square_m + 2.0 * b.margin_m > 5.0)
    why << "chessboard larger than 5 m; ";
  if (!(b.black >= 0.0 && b.black <= b.white && b.white <= 1.0))
    why << "chessboard reflectances must satisfy 0 <= black <= white <= 1; ";
  if (!(b.distance_m >= 0.2 && b.distance_m <= 20.0))
    why << "chessboard distance " << b.distance_m << " m is outside [0.2, 20]; ";
  if (!(std::abs(b.tilt_x_rad) < 1.4 && std::abs(b.tilt_y_rad) < 1.4) || !std::isfinite(b.roll_rad) ||
      !b.offset_m.allFinite())
    why << "chessboard tilts must stay below 1.4 rad, roll and offset finite; ";
}

// The band a colour's wavelength must lie in (nm).
void wavelengthBand(ProjectorColor color, double* lo, double* hi)
{
  switch (color)
  {
    case ProjectorColor::kGreen:
      *lo = 490.0;
      *hi = 570.0;
      return;
    case ProjectorColor::kRed:
      *lo = 600.0;
      *hi = 700.0;
      return;
    case ProjectorColor::kBlue:
      *lo = 420.0;
      *hi = 490.0;
      return;
    case ProjectorColor::kNir:
      *lo = 780.0;
      *hi = 1000.0;
      return;
    case ProjectorColor::kWhite:
      *lo = 400.0;
      *hi = 700.0;
      return;
  }
}

void checkProjector(const ProjectorParams& projector, std::ostringstream& why)
{
  double lo = 0.0, hi = 0.0;
  wavelengthBand(projector.color, &lo, &hi);
  if (!(projector.wavelength_nm >= lo && projector.wavelength_nm <= hi))
    why << "projector wavelength " << projector.wavelength_nm << " nm is outside the "
        << projectorColorName(projector.color) << " band [" << lo << ", " << hi << "] nm; ";
  if (projector.rows < 1 || projector.cols < 1 || projector.rows > 100 || projector.cols > 100)
    why << "projector grid " << projector.rows << " x " << projector.cols << " is outside [1, 100]; ";
  if (!projector.origin_m.allFinite() || !std::isfinite(projector.pitch_x_rad) ||
      !std::isfinite(projector.pitch_y_rad) || !std::isfinite(projector.roll_rad))
    why << "projector origin, pitch and roll must be finite; ";
  if (!finitePositive(projector.converge_distance_m))
    why << "projector converge distance must be positive; ";
  if (!finiteNonNegative(projector.beam_sigma_rad) || projector.beam_sigma_rad > 0.1)
    why << "beam_sigma_rad " << projector.beam_sigma_rad << " is outside [0, 0.1]; ";
  if (!finiteNonNegative(projector.power_scale))
    why << "power_scale must be >= 0; ";
}

void checkLighting(const LightingParams& lighting, std::ostringstream& why)
{
  if (!finiteNonNegative(lighting.sun_level) || !finiteNonNegative(lighting.dot_to_sun_ratio) ||
      !finitePositive(lighting.exposure))
    why << "sun_level, dot_to_sun_ratio must be >= 0 and exposure > 0; ";
  if (!lighting.sun_direction.allFinite() || !(lighting.sun_direction.norm() > 1e-9) ||
      !finiteNonNegative(lighting.sky_ambient) || lighting.sky_ambient > 1.0)
    why << "sun_direction must be a finite non-zero vector and sky_ambient in [0, 1]; ";
}

void checkMotion(const RigMotionParams& motion, std::ostringstream& why)
{
  if (!finiteNonNegative(motion.jitter_translation_m) || !finiteNonNegative(motion.jitter_rotation_rad) ||
      !finiteNonNegative(motion.jitter_frequency_hz) || !finiteNonNegative(motion.step_period_s) ||
      !finiteNonNegative(motion.return_period_s) || !motion.drift_velocity_mps.allFinite() ||
      !motion.drift_angular_velocity_radps.allFinite() || !motion.step_translation_m.allFinite())
    why << "motion amplitudes, frequency and periods must be finite and >= 0; ";
  why << sim::rigMotionProblems(motion);  // the closed loop's disturbance (rig_motion.cpp)
}

void checkClutter(const ClutterParams& clutter, std::ostringstream& why)
{
  if (clutter.green_specks < 0 || clutter.olive_minerals < 0 || clutter.green_blobs < 0 ||
      clutter.green_specks > 100000 || clutter.olive_minerals > 100000 || clutter.green_blobs > 100000)
    why << "clutter counts must be in [0, 100000]; ";
}

}  // namespace

std::string SimulatorParams::validate() const
{
  std::ostringstream why;
  checkSensor(sensor, why);
  checkRock(rock, why);
  checkTarget(target, why);
  checkProjector(projector, why);
  if (projector.color == ProjectorColor::kNir && !isMonochrome(sensor.output))
    why << "an NIR projector needs a monochrome output (mono8, mono16): a colour camera's IR-cut filter blocks 850 "
           "nm; ";
  checkLighting(lighting, why);
  checkMotion(motion, why);
  if (rock_subsample < 1 || rock_subsample > 4)
    why << "rock_subsample " << rock_subsample << " is outside [1, 4]; ";
  checkClutter(clutter, why);
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);  // the last "; "
  return s;
}

namespace
{

struct ColorName
{
  ProjectorColor color;
  double nominal_nm;
};
constexpr ColorName kColors[] = {{ProjectorColor::kGreen, 520.0},
                                 {ProjectorColor::kRed, 638.0},
                                 {ProjectorColor::kBlue, 450.0},
                                 {ProjectorColor::kNir, 850.0},
                                 {ProjectorColor::kWhite, 550.0}};

struct OutputName
{
  SensorOutput output;
  const char* encoding;
};
constexpr OutputName kOutputs[] = {{SensorOutput::kBgr8, "bgr8"},
                                   {SensorOutput::kRgb8, "rgb8"},
                                   {SensorOutput::kMono8, "mono8"},
                                   {SensorOutput::kMono16, "mono16"},
                                   {SensorOutput::kBayerRggb8, "bayer_rggb8"},
                                   {SensorOutput::kBayerBggr8, "bayer_bggr8"},
                                   {SensorOutput::kBayerGbrg8, "bayer_gbrg8"},
                                   {SensorOutput::kBayerGrbg8, "bayer_grbg8"},
                                   {SensorOutput::kBgr16, "bgr16"},
                                   {SensorOutput::kRgb16, "rgb16"}};

}  // namespace

double nominalWavelengthNm(ProjectorColor color)
{
  for (const ColorName& c : kColors)
    if (c.color == color)
      return c.nominal_nm;
  return 520.0;
}

const char* encodingName(SensorOutput output)
{
  for (const OutputName& o : kOutputs)
    if (o.output == output)
      return o.encoding;
  return "?";
}

bool sensorOutputFromEncoding(const std::string& encoding, SensorOutput* output)
{
  for (const OutputName& o : kOutputs)
    if (encoding == o.encoding)
    {
      *output = o.output;
      return true;
    }
  return false;
}

bool isMonochrome(SensorOutput output)
{
  return output == SensorOutput::kMono8 || output == SensorOutput::kMono16;
}

bool isBayer(SensorOutput output)
{
  return output == SensorOutput::kBayerRggb8 || output == SensorOutput::kBayerBggr8 ||
         output == SensorOutput::kBayerGbrg8 || output == SensorOutput::kBayerGrbg8;
}

double LightingParams::sceneDotToSunRatio(RadiometryModel model)
{
  // analyseScene() integrates spectra: compute each model once.
  static const double study =
      dotToSunRatio(SceneInputs(), RadiometryModel::kStudyAsStated, kReferenceBeamSigmaRad * kReferenceDistanceM);
  static const double corrected =
      dotToSunRatio(SceneInputs(), RadiometryModel::kCorrected, kReferenceBeamSigmaRad * kReferenceDistanceM);
  return model == RadiometryModel::kStudyAsStated ? study : corrected;
}

}  // namespace structured_light_stabilizer
