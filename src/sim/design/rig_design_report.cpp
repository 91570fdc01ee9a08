// The design calculator's outputs: the table, the CSV, the plot (drawn with
// OpenCV like the aperture sweep) and the recommended rig's YAML.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/sim/design/rig_design.h"

namespace structured_light_stabilizer
{

namespace
{

std::string filterName(const RigParams& rig)
{
  if (!rig.filter.enabled)
    return "none";
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.0f nm", rig.filter.fwhm_m * 1e9);
  return buf;
}

std::string row(const RigEvaluation& e, const char* label)
{
  char buf[400];
  const RigParams& r = e.rig;
  std::snprintf(buf, sizeof(buf), "%-6s %-13s %4.1f %-5s %6.2f %-6s %-3s %9.4g %7.1f %7.1f %7.3f %7.3f %9.3g  %s",
                label, e.emitter_name.c_str(), r.beam_sigma_rad * 1e3, r.pulsed ? "pulse" : "cont", r.exposure_s * 1e3,
                filterName(r).c_str(), r.strobe ? "yes" : "no", e.worst_ratio, e.worst.snr_single_textured,
                e.worst.snr_strobed_textured, e.centroid_px, e.worst.speckle_px, e.required_electrical_w,
                e.feasible ? "ok" : e.why_not.c_str());
  return buf;
}

}  // namespace

std::string formatDesignTable(const DesignResult& res, size_t max_rows)
{
  const DesignInputs& in = res.inputs;
  const DesignConditions& c = in.conditions;
  std::ostringstream os;
  char buf[512];
  std::snprintf(buf, sizeof(buf),
                "Worst case: sun_level %.2f (F50 %.0f W/m^2), albedo %.2f-%.2f, %.1f-%.1f m, field centre and "
                "corner, emitter +-%.0f K;\n  texture +-%.0f %% at %.0f mm, roughness %.1f mm, compensated ambient "
                "misaligned %.3f px.\nTarget: effective SNR >= %.0f, centroid <= %.3f px, dot sigma >= %.1f px; "
                "budget %.0f mW electrical at %.0f Hz, %d-bit output.\n\n",
                c.sun_level, c.sun_level * res.analysis.irradiance_latitude.max, c.albedo_min, c.albedo_max,
                c.distance_min_m, c.distance_max_m, 0.5 * c.temperature_range_k, c.texture.contrast * 100,
                c.texture.period_m * 1e3, c.texture.roughness_m * 1e3, c.texture.ambient_misalignment_px, in.target.snr,
                in.target.centroid_px, in.target.min_dot_sigma_px, in.options.electrical_budget_w * 1e3,
                in.options.frame_rate_hz, in.options.output_bits);
  os << buf;
  os << "rank   emitter       mrad drive  exp_ms filter strb dot/sun   SNR_1   SNR_2 cent_px speckle   need_W  "
        "verdict\n";
  os << row(res.study, "study") << "\n";
  os << row(res.study_in_well, "study*") << "\n";
  if (res.recommended >= 0)
    os << row(res.rigs[res.recommended], "BEST") << "\n";
  size_t feasible = 0;
  for (const auto& e : res.rigs)
    feasible += e.feasible ? 1 : 0;
  const size_t n = max_rows == 0 ? res.rigs.size() : std::min(max_rows, res.rigs.size());
  for (size_t i = 0; i < n; ++i)
    os << row(res.rigs[i], std::to_string(i + 1).c_str()) << "\n";
  std::snprintf(buf, sizeof(buf),
                "\n%zu of %zu rigs feasible. SNR_1: one frame, the fine texture as clutter; SNR_2: strobed "
                "difference; cent_px: worst RMS centroid error of the rig's mode; need_W: average electrical "
                "power that just reaches the target.\n",
                feasible, res.rigs.size());
  os << buf;
  return os.str();
}

std::string formatRigDetails(const DesignResult& res)
{
  if (res.recommended < 0)
    return "";
  const RigEvaluation& e = res.rigs[res.recommended];
  const DotSignal& w = e.worst;
  const SimRadiometry sim = simulatorRadiometry(res.analysis, e.rig);
  char buf[1600];
  std::snprintf(
      buf, sizeof(buf),
      "Recommended rig, term by term (worst case of the SNR):\n"
      "  drive: %.3g mJ per projector-on exposure, %.3g W optical during it%s, %.0f mW electrical on average\n"
      "  one dot: %.3g uJ, sigma %.2f mm on the rock, %.2f px in the image\n"
      "  electrons per pixel: dot peak %.0f, sunlit rock %.0f, read+quantisation %.1f RMS, dark %.3g\n"
      "  SNR one frame %.1f (%.1f with the texture), strobed %.1f (%.1f with the texture)\n"
      "  centroid (worst case %.3f px): noise %.4f px, speckle %.4f px, texture bias in one frame %.3f px\n"
      "  camera full scale %.0f e- (%d bits); brightest sunlit rock %.2f of the full well; filter needs >= %.1f nm\n"
      "  simulator (8-bit DN): exposure %.4g, dot_to_sun_ratio %.4g (3 mm reference dot), gain %.4g DN/e-, read "
      "noise %.3g DN\n",
      w.pulse_energy_j * 1e3, w.peak_optical_w, w.peak_limited ? " (the emitter's limit)" : "",
      w.average_electrical_w * 1e3, w.dot_energy_j * 1e6, w.dot_sigma_m * 1e3, w.dot_sigma_px, w.dot_e, w.sun_e,
      w.read_noise_e, w.dark_e, w.snr_single, w.snr_single_textured, w.snr_strobed, w.snr_strobed_textured,
      e.centroid_px,
      e.rig.strobe ? e.worst_centroid.centroid_noise_strobed_px : e.worst_centroid.centroid_noise_single_px,
      e.worst_centroid.speckle_px, e.worst_centroid.texture_bias_single_px, e.rig.full_scale_e, e.rig.output_bits,
      e.ambient_fill, e.required_filter_m * 1e9, sim.exposure, sim.dot_to_sun_ratio, sim.gain_dn_per_electron,
      sim.read_noise_dn);
  return buf;
}

std::string designCsv(const DesignResult& res)
{
  std::ostringstream os;
  os << "emitter,beam_sigma_mrad,pulsed,exposure_ms,filter_fwhm_nm,strobe,worst_dot_sun_ratio,snr_single,"
        "snr_strobed,effective_snr,centroid_px,speckle_px,texture_bias_px,dot_sigma_px,pulse_energy_mj,"
        "peak_optical_w,average_electrical_w,required_electrical_w,full_scale_e,additions,feasible,why_not\n";
  char buf[512];
  for (const auto& e : res.rigs)
  {
    const RigParams& r = e.rig;
    std::snprintf(buf, sizeof(buf),
                  "%s,%.3g,%d,%.4g,%.4g,%d,%.5g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%d,%d,%s\n",
                  e.emitter_name.c_str(), r.beam_sigma_rad * 1e3, r.pulsed ? 1 : 0, r.exposure_s * 1e3,
                  r.filter.enabled ? r.filter.fwhm_m * 1e9 : 0.0, r.strobe ? 1 : 0, e.worst_ratio,
                  e.worst.snr_single_textured, e.worst.snr_strobed_textured, e.effective_snr, e.centroid_px,
                  e.worst.speckle_px, e.worst_centroid.texture_bias_single_px, e.worst.dot_sigma_px,
                  e.worst.pulse_energy_j * 1e3, e.worst.peak_optical_w, e.worst.average_electrical_w,
                  e.required_electrical_w, r.full_scale_e, e.additions, e.feasible ? 1 : 0, e.why_not.c_str());
    os << buf;
  }
  return os.str();
}

// ---------------------------------------------------------------------------
// Plot

namespace
{

struct Axes
{
  cv::Rect box;
  double x0, x1, y0, y1;  // log10 ranges
  cv::Point at(double x, double y) const
  {
    const double u = (std::log10(x) - x0) / (x1 - x0), v = (std::log10(y) - y0) / (y1 - y0);
    return {box.x + static_cast<int>(u * box.width), box.y + box.height - static_cast<int>(v * box.height)};
  }
};

void drawAxes(cv::Mat& img, const Axes& ax, const std::string& title, const std::string& ylabel)
{
  const cv::Scalar grey(200, 200, 200), black(0, 0, 0);
  for (int e = static_cast<int>(std::floor(ax.y0)); e <= static_cast<int>(std::ceil(ax.y1)); ++e)
  {
    const double v = std::pow(10.0, e);
    if (e < ax.y0 || e > ax.y1)
      continue;
    cv::line(img, ax.at(std::pow(10.0, ax.x0), v), ax.at(std::pow(10.0, ax.x1), v), grey, 1);
    char buf[32];
    std::snprintf(buf, sizeof(buf), "%g", v);
    cv::putText(img, buf, ax.at(std::pow(10.0, ax.x0), v) + cv::Point(-48, 5), cv::FONT_HERSHEY_SIMPLEX, 0.4, black);
  }
  for (double x : {0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 33.0})
  {
    if (std::log10(x) < ax.x0 || std::log10(x) > ax.x1)
      continue;
    cv::line(img, ax.at(x, std::pow(10.0, ax.y0)), ax.at(x, std::pow(10.0, ax.y1)), grey, 1);
    char buf[32];
    std::snprintf(buf, sizeof(buf), "%g", x);
    cv::putText(img, buf, ax.at(x, std::pow(10.0, ax.y0)) + cv::Point(-8, 18), cv::FONT_HERSHEY_SIMPLEX, 0.4, black);
  }
  cv::rectangle(img, ax.box, black, 1);
  cv::putText(img, title, {ax.box.x, ax.box.y - 10}, cv::FONT_HERSHEY_SIMPLEX, 0.5, black, 1);
  cv::putText(img, ylabel, {ax.box.x - 55, ax.box.y - 10}, cv::FONT_HERSHEY_SIMPLEX, 0.4, black);
  cv::putText(img, "exposure (ms)", {ax.box.x + ax.box.width / 2 - 40, ax.box.y + ax.box.height + 36},
              cv::FONT_HERSHEY_SIMPLEX, 0.45, black);
}

// The four modes drawn per emitter: the study's way (continuous, one
// frame), pulsed with a filter (one frame), pulsed and strobed without and
// with a filter.
struct Mode
{
  const char* label;
  bool pulsed, filter, strobe;
  int thickness;
  int marker;  // 0 none, 1 circle, 2 square
};
const Mode kModes[] = {{"continuous, one frame", false, false, false, 1, 0},
                       {"pulsed + filter, one frame", true, true, false, 1, 1},
                       {"pulsed, strobed", true, false, true, 2, 2},
                       {"pulsed + filter, strobed", true, true, true, 3, 0}};

// Per emitter and mode, at the recommended divergence (or the first), the
// best filter width per exposure, sorted by exposure.
std::map<std::pair<std::string, int>, std::vector<const RigEvaluation*>> curves(const DesignResult& res)
{
  const double sigma =
      res.recommended >= 0 ? res.rigs[res.recommended].rig.beam_sigma_rad : res.inputs.options.beam_sigma_rad.front();
  std::map<std::pair<std::string, int>, std::vector<const RigEvaluation*>> out;
  for (const auto& e : res.rigs)
  {
    if (std::fabs(e.rig.beam_sigma_rad - sigma) > 1e-9)
      continue;
    for (int m = 0; m < 4; ++m)
    {
      const Mode& mode = kModes[m];
      if (e.rig.pulsed != mode.pulsed || e.rig.filter.enabled != mode.filter || e.rig.strobe != mode.strobe)
        continue;
      auto& list = out[{e.emitter_name, m}];
      auto same = std::find_if(list.begin(), list.end(),
                               [&](const RigEvaluation* p) { return p->rig.exposure_s == e.rig.exposure_s; });
      if (same == list.end())
        list.push_back(&e);
      else if (e.effective_snr > (*same)->effective_snr)
        *same = &e;
    }
  }
  for (auto& kv : out)
    std::sort(kv.second.begin(), kv.second.end(),
              [](const RigEvaluation* a, const RigEvaluation* b) { return a->rig.exposure_s < b->rig.exposure_s; });
  return out;
}

void drawMarker(cv::Mat& img, cv::Point p, int marker, const cv::Scalar& colour)
{
  if (marker == 1)
    cv::circle(img, p, 3, colour, cv::FILLED);
  else if (marker == 2)
    cv::rectangle(img, p - cv::Point(3, 3), p + cv::Point(3, 3), colour, cv::FILLED);
}

void drawCurve(cv::Mat& img, const Axes& ax, const std::vector<const RigEvaluation*>& pts, bool ratio, const Mode& mode,
               const cv::Scalar& colour)
{
  // Clamped to the axes: a value off the scale is drawn on its edge.
  auto value = [&](const RigEvaluation* e) {
    return std::min(std::max(ratio ? e->worst_ratio : e->effective_snr, std::pow(10.0, ax.y0)), std::pow(10.0, ax.y1));
  };
  for (size_t i = 0; i < pts.size(); ++i)
  {
    const cv::Point p = ax.at(pts[i]->rig.exposure_s * 1e3, value(pts[i]));
    drawMarker(img, p, mode.marker, colour);
    if (i + 1 < pts.size())
      cv::line(img, p, ax.at(pts[i + 1]->rig.exposure_s * 1e3, value(pts[i + 1])), colour, mode.thickness, cv::LINE_AA);
  }
}

// Emitter colours, then the modes' styles.
void drawLegend(cv::Mat& img, const std::vector<std::string>& emitters, const cv::Scalar* palette, int x)
{
  int y = 50;
  for (size_t k = 0; k < emitters.size(); ++k, y += 18)
  {
    cv::line(img, {x, y - 4}, {x + 25, y - 4}, palette[k % 6], 3);
    cv::putText(img, emitters[k], {x + 30, y}, cv::FONT_HERSHEY_SIMPLEX, 0.42, {0, 0, 0});
  }
  y += 10;
  for (const Mode& mode : kModes)
  {
    cv::line(img, {x, y - 4}, {x + 25, y - 4}, {0, 0, 0}, mode.thickness);
    drawMarker(img, {x + 12, y - 4}, mode.marker, {0, 0, 0});
    cv::putText(img, mode.label, {x + 30, y}, cv::FONT_HERSHEY_SIMPLEX, 0.42, {0, 0, 0});
    y += 18;
  }
  cv::putText(img, "recommended: red circle", {x, y + 10}, cv::FONT_HERSHEY_SIMPLEX, 0.42, {0, 0, 255});
}

}  // namespace

cv::Mat renderDesignPlot(const DesignResult& res, int width, int height)
{
  cv::Mat img(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  const int pw = (width - 420) / 2, ph = height - 110;
  const Axes snr_ax{cv::Rect(70, 40, pw, ph), std::log10(0.2), std::log10(40.0), -1.0, 4.0};
  const Axes ratio_ax{cv::Rect(140 + pw, 40, pw, ph), std::log10(0.2), std::log10(40.0), -3.0, 3.0};
  drawAxes(img, snr_ax, "worst-case effective SNR", "");
  drawAxes(img, ratio_ax, "worst-case dot / sunlit rock", "");
  cv::line(img, snr_ax.at(0.2, res.inputs.target.snr), snr_ax.at(40.0, res.inputs.target.snr), {0, 0, 255}, 1);
  cv::putText(img, "target", snr_ax.at(0.22, res.inputs.target.snr) + cv::Point(0, -5), cv::FONT_HERSHEY_SIMPLEX, 0.4,
              {0, 0, 255});
  const cv::Scalar palette[] = {{180, 119, 31}, {14, 127, 255},  {44, 160, 44},
                                {40, 39, 214},  {189, 103, 148}, {75, 86, 140}};
  std::vector<std::string> emitters;
  for (const auto& e : res.inputs.options.emitters)
    emitters.push_back(e.name);
  for (const auto& kv : curves(res))
  {
    const size_t k = std::find(emitters.begin(), emitters.end(), kv.first.first) - emitters.begin();
    drawCurve(img, snr_ax, kv.second, false, kModes[kv.first.second], palette[k % 6]);
    drawCurve(img, ratio_ax, kv.second, true, kModes[kv.first.second], palette[k % 6]);
  }
  drawLegend(img, emitters, palette, width - 270);
  if (res.recommended >= 0)
  {
    const RigEvaluation& best = res.rigs[res.recommended];
    cv::circle(img, snr_ax.at(best.rig.exposure_s * 1e3, best.effective_snr), 8, {0, 0, 255}, 2);
    cv::circle(img, ratio_ax.at(best.rig.exposure_s * 1e3, best.worst_ratio), 8, {0, 0, 255}, 2);
  }
  return img;
}

std::string recommendedRigYaml(const DesignResult& res)
{
  if (res.recommended < 0)
    return "";
  const RigEvaluation& e = res.rigs[res.recommended];
  char buf[600];
  std::snprintf(buf, sizeof(buf),
                "The rig the design calculator recommends (rosrun structured_light_stabilizer design_rig;\n"
                "docs/daylight.md): %s, beam %.1f mrad, %s, exposure %.2f ms, filter %s, strobe %s.\n"
                "Worst case (sun_level %.2f, albedo %.2f-%.2f, %.1f-%.1f m): dot/sun %.3g, effective SNR %.1f,\n"
                "centroid %.3f px RMS; needs %.0f mW of the %.0f mW budget.",
                e.emitter_name.c_str(), e.rig.beam_sigma_rad * 1e3, e.rig.pulsed ? "pulsed" : "continuous",
                e.rig.exposure_s * 1e3, filterName(e.rig).c_str(), e.rig.strobe ? "on" : "off",
                res.inputs.conditions.sun_level, res.inputs.conditions.albedo_min, res.inputs.conditions.albedo_max,
                res.inputs.conditions.distance_min_m, res.inputs.conditions.distance_max_m, e.worst_ratio,
                e.effective_snr, e.centroid_px, e.required_electrical_w * 1e3, e.rig.electrical_budget_w * 1e3);
  RigParams rig = e.rig;
  rig.name = "daylight_" + e.emitter_name;
  return rigToYaml(rig, buf);
}

}  // namespace structured_light_stabilizer
