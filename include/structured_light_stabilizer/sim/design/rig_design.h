// The daylight design calculator (docs/daylight.md): every combination of
// the rig's options (emitter, beam divergence, drive, exposure, band-pass
// filter, strobing) evaluated at the worst case of the conditions (sun
// level, albedo range, distance range, rock texture), the least demanding
// one that reaches the target chosen, and the results as a table, a CSV, a
// plot and the chosen rig's YAML for the simulator (radiometry.h).
//
// Worst case of a rig: the lowest effective SNR (and largest centroid error)
// over {darkest, brightest albedo} x {nearest, farthest distance} x {field
// centre, field corner} x {coldest, hottest emitter}, under the given sun on
// a Lambertian surface at the study's brightest incidence (10 deg). The
// effective SNR is the strobed one (with the texture the compensation
// leaves) for a strobed rig, the single-frame one (with all of the fine
// texture as clutter) otherwise.
//
// Feasible: effective SNR >= target, centroid <= target, dot sigma in the
// image >= min_dot_sigma_px, the brightest sunlit rock below the full well,
// a laser's filter at least as wide as its line, drift and the field's
// shift need. Demand, the ranking of feasible rigs: first the number of
// additions to the study's rig (pulsed drive, band-pass filter, laser
// diode, strobing), then the average electrical power it needs to just
// reach the targets.
//
// Pure functions; designRig() throws std::invalid_argument on bad inputs.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/sim/design/beam_design.h"
#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace structured_light_stabilizer
{

struct DesignConditions
{
  double sun_level = 1.0;  // the study's brightest sun
  double albedo_min = 0.05;
  double albedo_max = 0.45;
  double distance_min_m = 1.0;
  double distance_max_m = 2.0;
  TextureConditions texture;
  double temperature_range_k = 100.0;  // the emitter's operating range (its line drifts)
};

struct DesignTarget
{
  // Effective SNR of the dot's peak at the worst case: at 20 a detection
  // threshold of 5-6 x the background's noise misses no dot and makes no
  // false one; the centroid's bound is the stricter requirement.
  double snr = 20.0;
  double centroid_px = 0.03;      // RMS centroid error at the worst case (the pipeline's bound: 0.05)
  double min_dot_sigma_px = 1.5;  // sub-pixel centroids need a dot of >= 1.5-2 px sigma
  // The camera's gain: the brightest sunlit rock at this share of the
  // output's range (brighter dots clip).
  double ambient_fill = 0.5;
};

struct NamedEmitter
{
  std::string name;
  EmitterParams emitter;
};

struct DesignOptions
{
  std::vector<NamedEmitter> emitters;
  std::vector<double> beam_sigma_rad;
  std::vector<bool> pulsed;
  std::vector<double> exposure_s;
  std::vector<double> filter_fwhm_m;  // 0 = no filter
  std::vector<bool> strobe;
  double filter_transmission = 0.9;
  double filter_effective_index = 2.0;
  double electrical_budget_w = 0.3;
  double frame_rate_hz = 30.0;
  int output_bits = 12;
};

struct DesignInputs
{
  SceneInputs scene;
  DesignConditions conditions;
  DesignTarget target;
  DesignOptions options;
  BeamDesignOptions beams;  // the beam x focus table (beam_design.h), apart from the rig search
};

// The study's scene and the default option grid (config/rig_design.yaml
// documents it): the study's LED, a high-power green LED, a green and a red
// laser diode.
DesignInputs defaultDesignInputs();
// Reads the design's YAML over the defaults (sections conditions, target,
// options, emitters; every key optional, unknown keys refused). The scene
// comes from `scene` (the scene analysis's inputs). Throws
// std::invalid_argument with the source, line and reason.
DesignInputs designInputsFromYaml(const std::string& yaml_text, const std::string& source = "<string>",
                                  const SceneInputs& scene = SceneInputs());
DesignInputs loadDesignInputs(const std::string& path, const SceneInputs& scene = SceneInputs());

struct RigEvaluation
{
  std::string emitter_name;
  RigParams rig;             // with the filter centred and the camera's full scale chosen
  DotSignal worst;           // at the worst case of the effective SNR
  DotSignal worst_centroid;  // at the worst case of the centroid error
  double worst_ratio = 0.0;  // lowest dot/sun ratio over the cases
  double effective_snr = 0.0;
  double centroid_px = 0.0;
  double ambient_fill = 0.0;  // brightest sunlit rock / full well
  double required_filter_m = 0.0;
  double required_electrical_w = 0.0;  // average, to just reach the targets (NaN: never)
  int additions = 0;                   // pulsed + filter + laser + strobe
  bool feasible = false;
  std::string why_not;  // the first failed requirement
};

struct DesignResult
{
  DesignInputs inputs;
  SceneAnalysis analysis;
  std::vector<RigEvaluation> rigs;  // feasible first, by demand; then the others by effective SNR
  int recommended = -1;             // index into rigs; -1 when nothing is feasible
  RigEvaluation study;              // the study's rig at the same worst case
  RigEvaluation study_in_well;      // the same with the exposure that keeps the sunlit rock in the well
};

// Evaluates one rig at the worst case of the conditions.
RigEvaluation evaluateDesign(const SceneAnalysis& analysis, const DesignInputs& inputs, const RigParams& rig);
DesignResult designRig(const DesignInputs& inputs);

// The first max_rows rows (0 = all) as aligned text, the study's rig and the
// recommended one first.
std::string formatDesignTable(const DesignResult& result, size_t max_rows = 25);
// The recommended rig's drive, dot and electrons at its worst case, term by term.
std::string formatRigDetails(const DesignResult& result);
std::string designCsv(const DesignResult& result);
// Worst-case effective SNR and dot/sun ratio versus exposure, one curve per
// emitter x drive x filter x strobing, the target and the recommended rig
// marked (BGR image).
cv::Mat renderDesignPlot(const DesignResult& result, int width = 1200, int height = 700);
// The recommended rig's YAML (rigToYaml) with the design's summary as a comment.
std::string recommendedRigYaml(const DesignResult& result);

}  // namespace structured_light_stabilizer
