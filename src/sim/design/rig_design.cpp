// The design calculator's search (rig_design.h): every combination of the
// options at the worst case of the conditions, the feasible ones ranked by
// demand.
#include "structured_light_stabilizer/sim/design/rig_design.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

using detail::kNaN;

double fieldCornerDeg(const SceneAnalysis& a)
{
  // The image's corner: tan = sqrt(2) tan(half field) for a square sensor.
  return std::atan(std::sqrt(2.0) * std::tan(a.fov_half_deg * detail::kPi / 180.0)) * 180.0 / detail::kPi;
}

// The texture the rig's camera sees: a band-pass filter leaves no other
// colour plane to predict the albedo from.
TextureConditions textureFor(const DesignInputs& in, const RigParams& rig)
{
  TextureConditions t = in.conditions.texture;
  if (rig.filter.enabled)
    t.albedo_reference_residual = 1.0;
  return t;
}

// The cases the worst is taken over, the given sun at the brightest incidence.
std::vector<ViewConditions> worstCaseViews(const SceneAnalysis& a, const DesignInputs& in)
{
  const DesignConditions& c = in.conditions;
  std::vector<ViewConditions> views;
  for (double albedo : {c.albedo_min, c.albedo_max})
    for (double d : {c.distance_min_m, c.distance_max_m})
      for (double field : {0.0, fieldCornerDeg(a)})
        for (double dt : {-0.5 * c.temperature_range_k, 0.5 * c.temperature_range_k})
        {
          ViewConditions v;
          v.sun_level = c.sun_level;
          v.albedo = albedo;
          v.distance_m = d;
          v.sun_incidence_deg = a.inputs.sun_incidence_min_deg;
          v.emitter_incidence_deg = a.inputs.led_incidence_deg;
          v.brdf = Brdf::kLambertian;
          v.field_angle_deg = field;
          v.emitter_temperature_offset_k = dt;
          views.push_back(v);
        }
  return views;
}

double effectiveSnr(const RigParams& rig, const DotSignal& s)
{
  return rig.strobe ? s.snr_strobed_textured : s.snr_single_textured;
}

double centroidOf(const RigParams& rig, const DotSignal& s)
{
  return rig.strobe ? s.centroid_strobed_px : s.centroid_single_px;
}

struct Worst
{
  DotSignal snr_case, centroid_case;
  double snr = detail::kInf, centroid = 0.0, ratio = detail::kInf;
};

Worst worstOf(const SceneAnalysis& a, const DesignInputs& in, const RigParams& rig,
              const std::vector<ViewConditions>& views)
{
  Worst w;
  const TextureConditions tex = textureFor(in, rig);
  for (const ViewConditions& v : views)
  {
    const DotSignal s = evaluateRig(a, rig, v, tex);
    w.ratio = std::min(w.ratio, s.ratio);
    if (effectiveSnr(rig, s) < w.snr)
    {
      w.snr = effectiveSnr(rig, s);
      w.snr_case = s;
    }
    if (centroidOf(rig, s) >= w.centroid)
    {
      w.centroid = centroidOf(rig, s);
      w.centroid_case = s;
    }
  }
  return w;
}

// The camera's full scale: the brightest sunlit rock (brightest albedo, the
// glossy BRDF, the nearest distance) at ambient_fill of the range, never
// above the full well; *brightest: that rock's electrons. Dots brighter than
// the rest of the range clip (the detector takes their centroids from the
// flanks): the gain serves the dimmest dots, whose quantisation is the
// worst case's noise at 8 bits.
double chooseFullScale(const SceneAnalysis& a, const DesignInputs& in, RigParams rig, double* brightest)
{
  const DesignConditions& c = in.conditions;
  rig.full_scale_e = a.inputs.full_well_e;
  ViewConditions bright;
  bright.sun_level = c.sun_level;
  bright.albedo = c.albedo_max;
  bright.distance_m = c.distance_min_m;
  bright.sun_incidence_deg = a.inputs.sun_incidence_min_deg;
  bright.brdf = Brdf::kLambertianGlossy;
  *brightest = evaluateRig(a, rig, bright).sun_e;
  return std::min(a.inputs.full_well_e, *brightest / in.target.ambient_fill);
}

bool meets(const DesignTarget& t, const Worst& w)
{
  return w.snr >= t.snr && w.centroid <= t.centroid_px;
}

// The average electrical power that just reaches the targets: the budget
// bisected (the pulse energy grows with it until the emitter's limit).
double requiredPower(const SceneAnalysis& a, const DesignInputs& in, RigParams rig,
                     const std::vector<ViewConditions>& views)
{
  double lo = 0.0, hi = rig.electrical_budget_w;
  for (int i = 0; i < 14; ++i)
  {
    rig.electrical_budget_w = 0.5 * (lo + hi);
    (meets(in.target, worstOf(a, in, rig, views)) ? hi : lo) = rig.electrical_budget_w;
  }
  rig.electrical_budget_w = hi;
  return evaluateRig(a, rig, views.front(), textureFor(in, rig)).average_electrical_w;
}

std::string firstFailure(const DesignInputs& in, const RigEvaluation& e)
{
  const DesignTarget& t = in.target;
  char buf[160];
  if (e.ambient_fill > 1.0)
    std::snprintf(buf, sizeof(buf), "sunlit rock saturates (%.2f x full well)", e.ambient_fill);
  else if (e.rig.filter.enabled && e.rig.emitter.kind == EmitterKind::kLaserDiode &&
           e.rig.filter.fwhm_m < e.required_filter_m)
    std::snprintf(buf, sizeof(buf), "filter %.0f nm narrower than the %.1f nm the line needs",
                  e.rig.filter.fwhm_m * 1e9, e.required_filter_m * 1e9);
  else if (e.worst.dot_sigma_px < t.min_dot_sigma_px)
    std::snprintf(buf, sizeof(buf), "dot sigma %.2f px < %.2f", e.worst.dot_sigma_px, t.min_dot_sigma_px);
  else if (e.effective_snr < t.snr)
    std::snprintf(buf, sizeof(buf), "SNR %.1f < %.0f", e.effective_snr, t.snr);
  else if (e.centroid_px > t.centroid_px)
    std::snprintf(buf, sizeof(buf), "centroid %.3f px > %.3f", e.centroid_px, t.centroid_px);
  else
    return "";
  return buf;
}

void checkInputs(const DesignInputs& in)
{
  const DesignConditions& c = in.conditions;
  const DesignOptions& o = in.options;
  auto fail = [](const std::string& why) { throw std::invalid_argument("rig_design: " + why); };
  if (!(c.albedo_min > 0.0 && c.albedo_min <= c.albedo_max && c.albedo_max <= 1.0))
    fail("conditions: need 0 < albedo_min <= albedo_max <= 1");
  if (!(c.distance_min_m > 0.0 && c.distance_min_m <= c.distance_max_m))
    fail("conditions: need 0 < distance_min_m <= distance_max_m");
  if (!(c.sun_level >= 0.0) || !(c.temperature_range_k >= 0.0))
    fail("conditions: sun_level and temperature_range_k must be >= 0");
  if (!(c.texture.contrast >= 0.0) || !(c.texture.period_m > 0.0) || !(c.texture.roughness_m >= 0.0) ||
      !(c.texture.ambient_misalignment_px >= 0.0) || !(c.texture.ambient_noise_scale >= 0.0))
    fail("conditions.texture: contrast, roughness, misalignment, noise scale >= 0 and period > 0");
  if (!(in.target.snr > 0.0) || !(in.target.centroid_px > 0.0) || !(in.target.ambient_fill > 0.0) ||
      in.target.ambient_fill > 1.0)
    fail("target: snr and centroid_px must be > 0, ambient_fill in (0, 1]");
  if (o.emitters.empty() || o.beam_sigma_rad.empty() || o.pulsed.empty() || o.exposure_s.empty() ||
      o.filter_fwhm_m.empty() || o.strobe.empty())
    fail("options: every list needs at least one value");
}

}  // namespace

RigEvaluation evaluateDesign(const SceneAnalysis& a, const DesignInputs& in, const RigParams& rig_in)
{
  RigEvaluation e;
  e.rig = rig_in;
  e.rig.validate();
  // The filter centred on the emitter's line as the field spreads it: the
  // passband moves to shorter wavelengths off axis.
  const double corner = std::sin(fieldCornerDeg(a) * detail::kPi / 180.0) / e.rig.filter.effective_index;
  const double shift = e.rig.emitter.wavelength_m * (1.0 - std::sqrt(1.0 - corner * corner));
  e.rig.filter.centre_m = e.rig.emitter.wavelength_m + 0.5 * shift;
  e.required_filter_m = requiredFilterWidth(a, e.rig, in.conditions.temperature_range_k);
  double brightest = 0.0;
  e.rig.full_scale_e = chooseFullScale(a, in, e.rig, &brightest);
  e.ambient_fill = brightest / a.inputs.full_well_e;
  e.additions = (e.rig.pulsed ? 1 : 0) + (e.rig.filter.enabled ? 1 : 0) +
                (e.rig.emitter.kind == EmitterKind::kLaserDiode ? 1 : 0) + (e.rig.strobe ? 1 : 0);

  const std::vector<ViewConditions> views = worstCaseViews(a, in);
  const Worst w = worstOf(a, in, e.rig, views);
  e.worst = w.snr_case;
  e.worst_centroid = w.centroid_case;
  e.worst_ratio = w.ratio;
  e.effective_snr = w.snr;
  e.centroid_px = w.centroid;
  e.why_not = firstFailure(in, e);
  e.feasible = e.why_not.empty();
  e.required_electrical_w = e.feasible ? requiredPower(a, in, e.rig, views) : kNaN;
  return e;
}

DesignResult designRig(const DesignInputs& in)
{
  checkInputs(in);
  DesignResult r;
  r.inputs = in;
  r.analysis = analyseScene(in.scene);
  const DesignOptions& o = in.options;
  for (const NamedEmitter& em : o.emitters)
    for (double sigma : o.beam_sigma_rad)
      for (bool pulsed : o.pulsed)
        for (double exposure : o.exposure_s)
          for (double width : o.filter_fwhm_m)
            for (bool strobe : o.strobe)
            {
              if (exposure * o.frame_rate_hz > 1.0)
                continue;  // does not fit in a frame
              RigParams rig;
              rig.name = em.name;
              rig.emitter = em.emitter;
              rig.beam_sigma_rad = sigma;
              rig.pulsed = pulsed;
              rig.electrical_budget_w = o.electrical_budget_w;
              rig.exposure_s = exposure;
              rig.frame_rate_hz = o.frame_rate_hz;
              rig.strobe = strobe;
              rig.filter.enabled = width > 0.0;
              rig.filter.fwhm_m = width > 0.0 ? width : rig.filter.fwhm_m;
              rig.filter.transmission = o.filter_transmission;
              rig.filter.effective_index = o.filter_effective_index;
              rig.output_bits = o.output_bits;
              r.rigs.push_back(evaluateDesign(r.analysis, in, rig));
              r.rigs.back().emitter_name = em.name;
            }
  std::stable_sort(r.rigs.begin(), r.rigs.end(),
                   [](const RigEvaluation& x, const RigEvaluation& y)
                   {
                     if (x.feasible != y.feasible)
                       return x.feasible;
                     if (x.feasible && x.additions != y.additions)
                       return x.additions < y.additions;
                     if (x.feasible)
                       return x.required_electrical_w < y.required_electrical_w;
                     return x.effective_snr > y.effective_snr;
                   });
  r.recommended = !r.rigs.empty() && r.rigs.front().feasible ? 0 : -1;
  RigParams study = RigParams::studyDesign(r.analysis);
  study.output_bits = o.output_bits;
  r.study = evaluateDesign(r.analysis, in, study);
  r.study.emitter_name = "study_led";
  // The study's LED as designed, but exposed so that the sunlit rock stays
  // in the well (0.1 s saturates it 10-20 x in full sun).
  study.exposure_s = std::floor(r.analysis.saturating_exposure_s * 1e4) * 1e-4;
  study.frame_rate_hz = std::min(o.frame_rate_hz, 1.0 / study.exposure_s);
  r.study_in_well = evaluateDesign(r.analysis, in, study);
  r.study_in_well.emitter_name = "study_led";
  return r;
}

}  // namespace structured_light_stabilizer
