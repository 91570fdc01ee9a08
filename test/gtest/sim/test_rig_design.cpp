// The daylight rig model and design calculator (radiometry.h, rig_design.h,
// docs/daylight.md) against hand calculations written here, apart from the
// module's code path: the camera equation, the pulse budget, Planck's law
// through a narrow filter, the speckle and centroid formulas; then the
// search (the study's rig fails, the recommended one passes and just needs
// the power it states) and the YAML the simulator reads.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/design/rig_design.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

using namespace structured_light_stabilizer;

namespace
{

constexpr double kPi = 3.14159265358979323846;
constexpr double kH = 6.62607015e-34, kC = 299792458.0, kKb = 1.380649e-23, kSigma = 5.670374419e-8;

// The study's camera by hand: EFL from the half field, the camera equation
// factor (pi/4)(D/EFL)^2, the pixel area.
struct HandCamera
{
  double efl = 0.5 * 12.288e-3 / std::tan(std::atan(0.5 * 2.0 / 2.0));
  double cam = kPi / 4.0 * std::pow(1.9e-3 / efl, 2);
  double pixel_area = 12e-6 * 12e-6;
  double lens = 0.8;
};

// The default QE table read at one wavelength (linear interpolation, by hand
// for the two points the tests use).
double qeAt520()
{
  return 0.343 + (520.0 - 510.0) / (525.0 - 510.0) * (0.340 - 0.343);
}

SceneAnalysis study()
{
  static const SceneAnalysis a = analyseScene(SceneInputs());
  return a;
}

// A green laser rig with a line so narrow that its spectrum is one wavelength.
RigParams narrowLineRig()
{
  RigParams rig = RigParams::studyDesign(study());
  rig.emitter.kind = EmitterKind::kLaserDiode;
  rig.emitter.wavelength_m = 520e-9;
  rig.emitter.spectral_fwhm_m = 0.01e-9;
  rig.emitter.cw_optical_power_w = 0.05;
  rig.emitter.wall_plug_efficiency = 0.1;
  rig.emitter.projector_efficiency = 0.6;
  rig.electrical_budget_w = 1.0;  // the rating (50 mW) limits, not the budget
  rig.exposure_s = 4e-3;
  rig.frame_rate_hz = 30.0;
  return rig;
}

}  // namespace

TEST(RigRadiometry, ContinuousDotElectronsMatchTheCameraEquation)
{
  const RigParams rig = narrowLineRig();
  const HandCamera hc;
  // 50 mW for 4 ms, 60 % into 100 dots; a 3 mm Gaussian on white
  // Lambertian rock at normal incidence: peak fluence E / (2 pi sigma^2),
  // radiance fluence / pi, per pixel through the camera equation, photons
  // at 520 nm, QE x lens.
  const double dot_j = 0.05 * 4e-3 * 0.6 / 100.0;
  const double fluence = dot_j / (2.0 * kPi * 9e-6);
  const double electrons = fluence / kPi * hc.cam * hc.pixel_area / (kH * kC / 520e-9) * qeAt520() * hc.lens;
  EXPECT_NEAR(whiteDotElectrons(study(), rig, 3e-3), electrons, 1e-3 * electrons);
}

TEST(RigRadiometry, PulsedDriveSharesTheBudgetUpToThePeakLimit)
{
  RigParams rig = narrowLineRig();
  rig.pulsed = true;
  rig.emitter.cw_optical_power_w = 1.0;
  rig.emitter.wall_plug_efficiency = 0.12;
  rig.electrical_budget_w = 0.3;
  rig.exposure_s = 2e-3;
  rig.strobe = true;  // 15 projector-on exposures per second at 30 Hz
  ViewConditions view;
  DotSignal s = evaluateRig(study(), rig, view);
  // Budget: 0.3 W x 0.12 / 15 = 2.4 mJ; the 1 W limit over 2 ms: 2 mJ.
  EXPECT_NEAR(s.pulse_energy_j, 2e-3, 1e-12);
  EXPECT_TRUE(s.peak_limited);
  EXPECT_NEAR(s.average_electrical_w, 2e-3 * 15 / 0.12, 1e-9);
  // 0.5 ms: the budget limits (2.4 mJ would need 4.8 W).
  rig.exposure_s = 0.5e-3;
  s = evaluateRig(study(), rig, view);
  EXPECT_NEAR(s.pulse_energy_j, 0.5e-3 * 1.0, 1e-12);  // still the 1 W limit: 0.5 mJ < 2.4 mJ
  rig.emitter.peak_power_factor = 10.0;
  s = evaluateRig(study(), rig, view);
  EXPECT_NEAR(s.pulse_energy_j, 0.3 * 0.12 / 15, 1e-12);
  EXPECT_FALSE(s.peak_limited);
  EXPECT_NEAR(s.average_electrical_w, 0.3, 1e-9);
}

TEST(RigRadiometry, CorrectedStudyLedGivesTheSceneAnalysisRatio)
{
  // The rig model with the study's flat sun spectrum reproduces the scene
  // analysis's corrected ratio (0.0045 for the 3 mm dot) by another path.
  RigParams rig = RigParams::studyDesign(study());
  rig.sun_spectrum = SunSpectrum::kFlatInBand;
  rig.emitter.spectral_fwhm_m = 0.01e-9;  // the scene analysis takes one wavelength
  const double ratio = whiteDotElectrons(study(), rig, 3e-3) / whiteSunElectrons(study(), rig);
  EXPECT_NEAR(ratio, dotToSunRatio(study(), RadiometryModel::kCorrected, 3e-3), 2e-3 * ratio);
  EXPECT_NEAR(ratio, 0.0045, 0.0001);
  // The blackbody puts about half of the flux outside 400-800 nm, the
  // study's model none: the true ratio is about twice as high.
  rig.sun_spectrum = SunSpectrum::kBlackbody;
  const double truth = whiteDotElectrons(study(), rig, 3e-3) / whiteSunElectrons(study(), rig);
  EXPECT_GT(truth / ratio, 1.8);
  EXPECT_LT(truth / ratio, 2.3);
}

TEST(RigRadiometry, NarrowFilterPassesPlancksShareOfTheSun)
{
  RigParams rig = narrowLineRig();
  rig.filter.enabled = true;
  rig.filter.centre_m = 520e-9;
  rig.filter.fwhm_m = 1e-9;
  rig.filter.transmission = 0.9;
  // By hand: the sun's temperature from its surface flux, Planck's share of
  // the flux per metre at 520 nm times 1 nm, through the filter, the lens
  // and the QE.
  const double t = std::pow(6.45e7 / kSigma, 0.25);
  const double l = 520e-9;
  const double planck = 2 * kPi * kH * kC * kC / std::pow(l, 5) / std::expm1(kH * kC / (l * kKb * t));
  const double share = planck * 1e-9 / (kSigma * std::pow(t, 4));
  const HandCamera hc;
  const double f50 = study().irradiance_latitude.max;
  const double electrons =
      f50 * share / kPi * hc.cam * hc.pixel_area * rig.exposure_s * 0.9 * hc.lens * qeAt520() / (kH * kC / l);
  EXPECT_NEAR(whiteSunElectrons(study(), rig), electrons, 2e-3 * electrons);
  // Off axis the passband moves blue: centre sqrt(1 - (sin(theta)/n)^2).
  const double theta = 30.0 * kPi / 180.0;
  const double centre = 520e-9 * std::sqrt(1.0 - std::pow(0.5 / 2.0, 2));
  EXPECT_DOUBLE_EQ(rig.filter.transmissionAt(centre, theta), 0.9);
  EXPECT_DOUBLE_EQ(rig.filter.transmissionAt(520e-9, theta), 0.0);  // 16.6 nm off the shifted centre
}

TEST(RigRadiometry, SnrAndCentroidFollowTheirFormulas)
{
  RigParams rig = narrowLineRig();
  rig.output_bits = 16;
  ViewConditions view;
  view.albedo = 0.2;
  view.distance_m = 1.5;
  TextureConditions tex;
  tex.contrast = 0.0;
  tex.roughness_m = 0.0;
  const DotSignal s = evaluateRig(study(), rig, view, tex);
  const double read2 = 25.0 * 25.0 + std::pow(350e3 / 65535.0, 2) / 12.0;
  const double var = s.dot_e + s.sun_e + s.dark_e + read2;
  EXPECT_NEAR(s.snr_single, s.dot_e / std::sqrt(var), 1e-9 * s.snr_single);
  const double var2 = var + 0.5 * (s.sun_e + s.dark_e + read2);
  EXPECT_NEAR(s.snr_strobed, s.dot_e / std::sqrt(var2), 1e-9 * s.snr_strobed);
  // Thompson et al.: (sigma^2 + 1/12) / N + 8 pi sigma^4 b / N^2.
  const double sg = s.dot_sigma_px, n = s.dot_e * 2 * kPi * sg * sg, b = var - s.dot_e;
  const double crb = std::sqrt((sg * sg + 1.0 / 12.0) / n + 8 * kPi * std::pow(sg, 4) * b / (n * n));
  EXPECT_NEAR(s.centroid_noise_single_px, crb, 1e-9);
  // The dot image: 2 mrad x fx (fx = f / pixel) with the blur added: the
  // defocus disc's DoC / 4, diffraction 0.42 lambda N, the pixel's box.
  const double f = study().focal_length_m, fx = f / 12e-6;
  const double defocus = 1.9e-3 * 0.5 / 1.5 * f / (1.0 - f) / 4.0 / 12e-6;
  const double diffraction = 0.42 * 520e-9 / (1.0 / f - 1.0) / 1.9e-3 / 12e-6;
  const double blur2 = defocus * defocus + diffraction * diffraction + 1.0 / 12.0;
  EXPECT_NEAR(s.dot_sigma_px, std::sqrt(std::pow(0.002 * fx, 2) + blur2), 1e-9);
}

TEST(RigRadiometry, SpeckleAndTextureBias)
{
  EmitterParams laser;
  laser.kind = EmitterKind::kLaserDiode;
  laser.wavelength_m = 520e-9;
  laser.spectral_fwhm_m = 1.5e-9;
  // (1 + (8 pi h sigma_lambda / lambda^2)^2)^(-1/4), sigma_lambda = FWHM / 2.3548.
  const double x = 8 * kPi * 5e-4 * (1.5e-9 / 2.354820045) / (520e-9 * 520e-9);
  EXPECT_NEAR(speckleContrast(laser, 5e-4), std::pow(1 + x * x, -0.25), 1e-12);
  EXPECT_NEAR(speckleContrast(laser, 0.0), 1.0, 1e-12);  // a smooth surface: fully developed
  // The centroid's speckle wander C lambda f / (pi D) and the texture's bias
  // a k sigma^2 exp(-k^2 sigma^2 / 2) / sqrt(2) (RMS over the phase).
  RigParams rig = narrowLineRig();
  rig.emitter = laser;
  rig.emitter.cw_optical_power_w = 0.05;
  ViewConditions view;
  view.distance_m = 1.5;
  TextureConditions tex;
  const DotSignal s = evaluateRig(study(), rig, view, tex);
  const double fx = study().focal_length_m / 12e-6;
  EXPECT_NEAR(s.speckle_px, speckleContrast(laser, 5e-4) * 520e-9 * fx / (kPi * 1.9e-3), 1e-12);
  const double sg = 0.002 * fx, k = 2 * kPi / (0.02 * fx / 1.5);
  EXPECT_NEAR(s.texture_bias_single_px, 0.25 * k * sg * sg * std::exp(-0.5 * k * k * sg * sg) / std::sqrt(2.0), 1e-9);
  rig.strobe = true;  // the ambient frame gives the albedo under the dot
  EXPECT_EQ(evaluateRig(study(), rig, view, tex).texture_bias_single_px, 0.0);
}

TEST(RigDesign, StudyRigFailsAndTheRecommendedOneMeetsTheTarget)
{
  DesignInputs in = defaultDesignInputs();
  in.options.exposure_s = {0.5e-3, 1e-3, 2e-3, 5e-3, 33e-3};  // a lean grid: the test's time
  in.options.beam_sigma_rad = {1e-3, 1.5e-3, 2e-3};
  const DesignResult r = designRig(in);
  EXPECT_FALSE(r.study.feasible);
  EXPECT_FALSE(r.study_in_well.feasible);
  EXPECT_LT(r.study_in_well.worst_ratio, 0.02);
  ASSERT_GE(r.recommended, 0);
  const RigEvaluation& best = r.rigs[r.recommended];
  std::cout << "[ MEASURE ] recommended: " << best.emitter_name << " " << best.rig.exposure_s * 1e3 << " ms, SNR "
            << best.effective_snr << ", centroid " << best.centroid_px << " px, needs " << best.required_electrical_w
            << " W\n";
  EXPECT_GE(best.effective_snr, in.target.snr);
  EXPECT_LE(best.centroid_px, in.target.centroid_px);
  EXPECT_GE(best.worst.dot_sigma_px, in.target.min_dot_sigma_px);
  EXPECT_LE(best.required_electrical_w, in.options.electrical_budget_w);
  // A fine texture and a monochrome camera: one frame cannot know the albedo
  // under the dot, so every feasible rig strobes.
  for (const auto& e : r.rigs)
  {
    if (e.feasible)
    {
      EXPECT_TRUE(e.rig.strobe) << e.emitter_name;
    }
  }
  // At the power it states, the rig just reaches the target; 10 % less misses it.
  RigParams rig = best.rig;
  rig.electrical_budget_w = best.required_electrical_w * 1.001;
  EXPECT_TRUE(evaluateDesign(r.analysis, in, rig).feasible);
  rig.electrical_budget_w = best.required_electrical_w * 0.9;
  EXPECT_FALSE(evaluateDesign(r.analysis, in, rig).feasible);
  // A laser's filter must pass its line everywhere in the field: 1.5 nm +
  // 0.06 nm/K x 100 K + the shift at the corner (35.3 deg, n = 2).
  const double corner = std::atan(std::sqrt(2.0) * std::tan(r.analysis.fov_half_deg * kPi / 180.0));
  const double shift = 520e-9 * (1.0 - std::sqrt(1.0 - std::pow(std::sin(corner) / 2.0, 2)));
  RigParams laser = rig;
  laser.emitter.kind = EmitterKind::kLaserDiode;
  laser.emitter.wavelength_m = 520e-9;
  laser.emitter.spectral_fwhm_m = 1.5e-9;
  laser.emitter.thermal_drift_m_per_k = 0.06e-9;
  EXPECT_NEAR(requiredFilterWidth(r.analysis, laser, 100.0), 1.5e-9 + 6e-9 + shift, 1e-12);
}

TEST(RigDesign, OutputsAreWritten)
{
  DesignInputs in = defaultDesignInputs();
  in.options.emitters.resize(3);  // the study's LED, the green LED, the green laser
  in.options.exposure_s = {1e-3, 2e-3};
  const DesignResult r = designRig(in);
  const std::string table = formatDesignTable(r, 5);
  EXPECT_NE(table.find("study"), std::string::npos);
  EXPECT_NE(table.find("BEST"), std::string::npos);
  const std::string csv = designCsv(r);
  EXPECT_EQ(static_cast<size_t>(std::count(csv.begin(), csv.end(), '\n')), r.rigs.size() + 1);
  const cv::Mat plot = renderDesignPlot(r);
  EXPECT_EQ(plot.type(), CV_8UC3);
  EXPECT_GT(cv::countNonZero(plot.reshape(1) < 250), 1000);  // something drawn
  const std::string yaml = recommendedRigYaml(r);
  ASSERT_FALSE(yaml.empty());
  const RigParams back = rigFromYaml(r.analysis, yaml);
  const RigParams& rig = r.rigs[r.recommended].rig;
  EXPECT_NEAR(back.exposure_s, rig.exposure_s, 1e-12);
  EXPECT_NEAR(back.beam_sigma_rad, rig.beam_sigma_rad, 1e-12);
  EXPECT_EQ(back.pulsed, rig.pulsed);
  EXPECT_EQ(back.strobe, rig.strobe);
  EXPECT_EQ(back.filter.enabled, rig.filter.enabled);
  EXPECT_NEAR(back.emitter.cw_optical_power_w, rig.emitter.cw_optical_power_w, 1e-9);
  EXPECT_NEAR(back.full_scale_e, rig.full_scale_e, 1e-3 * rig.full_scale_e);
}

TEST(RigDesign, BadYamlIsAClearError)
{
  const SceneAnalysis a = study();
  auto refused = [&](const std::string& text, const std::string& needle)
  {
    try
    {
      rigFromYaml(a, text, "test.yaml");
    }
    catch (const std::invalid_argument& e)
    {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      return true;
    }
    return false;
  };
  EXPECT_TRUE(refused("rig:\n  exposure_ms: fast\n", "test.yaml:2"));
  EXPECT_TRUE(refused("rig:\n  exposure_mss: 2\n", "unknown key 'rig.exposure_mss'"));
  EXPECT_TRUE(refused("rig:\n  drive: sometimes\n", "continuous | pulsed"));
  EXPECT_TRUE(refused("rig:\n  exposure_ms: 50\n  frame_rate_hz: 30\n", "does not fit in a frame"));
  EXPECT_TRUE(refused("rig:\n  emitter: {wall_plug_efficiency: 1.5}\n", "wall_plug_efficiency"));
  EXPECT_TRUE(refused("rig: [\n", "not valid YAML"));
  try
  {
    designRig(designInputsFromYaml("target: {snr: -1}\n"));
    ADD_FAILURE() << "a negative target SNR was accepted";
  }
  catch (const std::invalid_argument& e)
  {
    EXPECT_NE(std::string(e.what()).find("target"), std::string::npos);
  }
}

TEST(RigDesign, SimulatorRadiometryIsTheRigsElectronsInDn)
{
  const SceneAnalysis a = study();
  RigParams rig = narrowLineRig();
  rig.full_scale_e = 1e5;
  const SimRadiometry r = simulatorRadiometry(a, rig);
  EXPECT_NEAR(r.gain_dn_per_electron, 255.0 / 1e5, 1e-15);
  // White sunlit rock at sun_level 1: kSunFullScaleDn x exposure DN = its electrons x gain.
  EXPECT_NEAR(LightingParams::kSunFullScaleDn * r.exposure, whiteSunElectrons(a, rig) * r.gain_dn_per_electron, 1e-9);
  EXPECT_NEAR(r.dot_to_sun_ratio, whiteDotElectrons(a, rig, 3e-3) / whiteSunElectrons(a, rig), 1e-12);
  EXPECT_NEAR(r.read_noise_dn, 25.0 * 255.0 / 1e5, 1e-12);
  SimulatorParams p;
  applySimRadiometry(r, &p);
  EXPECT_TRUE(p.validate().empty()) << p.validate();
  EXPECT_EQ(p.lighting.dot_to_sun_ratio, r.dot_to_sun_ratio);
  EXPECT_EQ(p.sensor.gain_dn_per_electron, r.gain_dn_per_electron);
}

TEST(RigDesign, ConfigFilesHoldTheRecommendedAndTheStudyRigs)
{
  const SceneAnalysis a = study();
  const RigParams file = loadRig(a, std::string(SLS_TEST_DATA_DIR) + "/../../config/rig_daylight.yaml");
  const RigParams code = RigParams::recommendedDaylight();
  EXPECT_EQ(rigToYaml(file), rigToYaml(code)) << "config/rig_daylight.yaml and RigParams::recommendedDaylight() differ";
  // The recommended rig is what the design calculator recommends with config/rig_design.yaml.
  const DesignResult r = designRig(loadDesignInputs(std::string(SLS_TEST_DATA_DIR) + "/../../config/rig_design.yaml"));
  ASSERT_GE(r.recommended, 0);
  RigParams best = r.rigs[r.recommended].rig;
  best.name = code.name;
  EXPECT_EQ(rigToYaml(best), rigToYaml(code));
  // The study's LED file: the LED as the scene analysis computes it.
  const RigParams led = loadRig(a, std::string(SLS_TEST_DATA_DIR) + "/../../config/rig_study_led.yaml");
  EXPECT_NEAR(led.emitter.cw_optical_power_w, a.led_optical_power_w, 1e-5);
  EXPECT_NEAR(led.electrical_budget_w, a.led_power_study_w, 1e-4);
  EXPECT_FALSE(led.pulsed);
}
