// Physics shared by the parts of the scene analysis (scene_*.cpp): constants,
// the camera equation, photo-electron counts, error reporting. Internal to
// the sim library. § numbers are the study's sections (docs/study.md).
#pragma once

#include <functional>
#include <limits>
#include <string>

#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace structured_light_stabilizer
{
namespace scene
{

using detail::kNaN;
using detail::kPi;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kPlanck = 6.62607015e-34;             // J s
constexpr double kLightSpeed = 299792458.0;            // m/s
constexpr double kBoltzmannEv = 8.617333262e-5;        // eV/K
constexpr double kBoltzmann = 1.380649e-23;            // J/K
constexpr double kStefanBoltzmann = 5.670374419e-8;    // W/(m^2 K^4)
constexpr double kElementaryCharge = 1.602176634e-19;  // C
constexpr double kMaxLuminousEfficacy = 683.0;         // lm/W at 555 nm

inline double deg2rad(double d)
{
  return d * kPi / 180.0;
}
inline double rad2deg(double r)
{
  return r * 180.0 / kPi;
}

// Throws std::invalid_argument("scene_analysis: <field>: <reason>").
[[noreturn]] void fail(const std::string& field, const std::string& reason);
// A number as the messages and notes print it (%.6g).
std::string num(double v);

// Simpson's rule on [a, b] with n (even) intervals.
double integrate(const std::function<double(double)>& f, double a, double b, int n = 2000);
// Spectral radiant exitance of a blackbody, W/(m^2 m).
double planckExitance(double wavelength_m, double t_k);
// Silicon band gap (eV) versus temperature (Varshni form used by Janesick).
double siliconBandGapEv(double t_k);
double photonEnergy(double wavelength_m);

// Effective focal length from the field of view the target needs (§2.1.1.3).
double eflOf(const SceneInputs& in);
// Focal length focused at focus_distance_m (thin lens).
double focalOf(const SceneInputs& in, double efl);
// Camera equation factor: sensor irradiance = radiance * this (study (2.9)).
double cameraFactor(const SceneInputs& in, double efl);

// What turns a target radiance into photo-electrons in one pixel.
struct SensorModel
{
  const SceneInputs& in;
  double efl;
  double cam;  // camera equation factor
  double pixel_area;
  double band_mean_wl;
  double sun_eff;  // photon-weighted QE * lens over the band
  double led_eff;  // QE * lens at the LED wavelength
};
SensorModel makeSensorModel(const SceneInputs& in);

// Photo-electrons per pixel from sunlight (flat spectrum over the band) or
// the LED's light, for a target radiance (W/(m^2 sr)) and an exposure (s).
double sunElectrons(const SensorModel& c, double radiance, double exposure);
double ledElectrons(const SensorModel& c, double radiance, double exposure);
// Peak irradiance of one dot (W/m^2) for an LED power (W).
double dotIrradiance(const SensorModel& c, double led_power);

// Fills analysis->table from the computed fields (scene_table.cpp).
void buildDesignTable(SceneAnalysis* analysis);

}  // namespace scene
}  // namespace structured_light_stabilizer
