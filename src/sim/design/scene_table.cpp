// The design table of the scene analysis: every quantity of the study's
// §2.1 (docs/study.md) with its unit, the value the study prints and a note where the study
// differs (the notes are the findings; docs/scene_analysis.md summarises
// them). One function per part of the study.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "sim/design/scene_model.h"

namespace structured_light_stabilizer
{

using namespace scene;

namespace
{

// Decimal places of a number printed as text ("26.6" -> 1).
int decimalsOf(const std::string& s)
{
  const auto dot = s.find('.');
  if (dot == std::string::npos)
    return 0;
  size_t end = dot + 1;
  while (end < s.size() && std::isdigit(static_cast<unsigned char>(s[end])))
    ++end;
  return static_cast<int>(end - dot - 1);
}

class TableBuilder
{
public:
  explicit TableBuilder(std::vector<Quantity>* t) : t_(t) {}

  // value in SI, scale to the display unit; study as printed (display unit),
  // empty when the study gives no number (study_lo, study_hi for ranges).
  Quantity& add(const std::string& key, const std::string& name, const std::string& ref, double value_si, double scale,
                const std::string& unit, const std::string& study, const std::string& note = "")
  {
    Quantity q = labelled(key, name, ref, unit, note);
    q.value = value_si * scale;
    q.value_max = kNaN;
    setStudy(&q, study);
    if (q.has_study)
      q.agrees = within(q.value, q.study, study);
    t_->push_back(q);
    return t_->back();
  }

  Quantity& addRange(const std::string& key, const std::string& name, const std::string& ref, Range r_si, double scale,
                     const std::string& unit, const std::string& study_lo = "", const std::string& study_hi = "",
                     const std::string& note = "")
  {
    Quantity q = labelled(key, name, ref, unit, note);
    q.is_range = true;
    q.value = r_si.min * scale;
    q.value_max = r_si.max * scale;
    setStudy(&q, study_lo);
    if (!study_hi.empty())
      q.study_max = std::stod(study_hi);
    if (q.has_study)
      q.agrees = within(q.value, q.study, study_lo) && within(q.value_max, q.study_max, study_hi);
    t_->push_back(q);
    return t_->back();
  }

private:
  static Quantity labelled(const std::string& key, const std::string& name, const std::string& ref,
                           const std::string& unit, const std::string& note)
  {
    Quantity q;
    q.key = key;
    q.name = name;
    q.ref = ref;
    q.unit = unit;
    q.note = note;
    return q;
  }
  static void setStudy(Quantity* q, const std::string& s)
  {
    q->study = kNaN;
    q->study_max = kNaN;
    if (s.empty())
      return;
    q->has_study = true;
    q->study = std::stod(s);
  }
  // Agreement to the precision the study prints: half a unit in its last digit.
  static bool within(double v, double study, const std::string& text)
  {
    const double tol = 0.5 * std::pow(10.0, -decimalsOf(text)) * (1.0 + 1e-9);
    return std::fabs(v - study) <= tol;
  }

  std::vector<Quantity>* t_;
};

void addOpticsRows(const SceneAnalysis& a, TableBuilder& t)
{
  const SceneInputs& in = a.inputs;
  t.add("fov_half", "Field of view, half angle", "§2.1.1.2", a.fov_half_deg, 1, "deg", "26.6",
        "the study's \"FoV = 26.6 x 26.6 deg\" is this half angle");
  t.add("fov_full", "Field of view, full angle", "§2.1.1.2, table 2.1", a.fov_full_deg, 1, "deg", "26.6",
        "tan(FoV/2) = H/(2D) gives FoV = " + num(std::round(a.fov_full_deg * 10) / 10) +
            " deg; the study reports the half angle as the FoV (and compares it with Navcam's full 45 deg)");
  t.add("efl", "Effective focal length EFL", "§2.1.1.3", a.efl_m, 1e3, "mm", "12.29");
  t.add("focal_length", "Focal length f (focus at rf)", "§2.1.1.3", a.focal_length_m, 1e3, "mm", "12.14");
  t.add("f_number", "f-number f/Dsr", "table 2.1", a.f_number, 1, "", "");
  t.add("doc_far", "Diameter of confusion at distance_max", "§2.1.1.4", a.doc_far_m, 1e3, "mm", "0.0117");
  t.add("doc_near", "Diameter of confusion at distance_min", "§2.1.1.4", a.doc_near_m, 1e6, "um", "");
  t.add("diffraction_min", "Diffraction spot at wavelength_min", "§2.1.1.4", a.diffraction_min_m, 1e6, "um", "");
  t.add("diffraction_max", "Diffraction spot at wavelength_max", "§2.1.1.4", a.diffraction_max_m, 1e6, "um", "",
        a.diffraction_max_m > in.pixel_size_m
            ? "larger than the " + num(in.pixel_size_m * 1e6) + " um pixel: at " + num(in.aperture_diameter_m * 1e3) +
                  " mm not \"all the curves\" of fig. 2.2 are under the pixel"
            : "");
  t.add("balanced_aperture", "Aperture where DoC(far) = diffraction(wl_max)", "fig. 2.2", a.balanced_aperture_m, 1e3,
        "mm", "1.9",
        "the study's choice 1.9 mm keeps the DoC under the pixel (up to " +
            num(in.pixel_size_m / (a.doc_far_m / in.aperture_diameter_m) * 1e3) +
            " mm); no aperture keeps both curves under 12 um at 800 nm; they cross at " +
            num(diffractionSpot(in, a.balanced_aperture_m, in.wavelength_max_m) * 1e6) + " um")
      .agrees = true;
  t.add("dof", "Depth of field (study's formula)", "§2.1.1.4", a.dof_formula_m, 1, "m", "1.33");
  t.addRange("dof_limits", "Sharp zone (DoC <= DoC(far))", "table 2.1", {a.dof_near_m, a.dof_far_m}, 1, "m", "0.67",
             "2");
  t.add("max_relief", "Largest relief DoF/2", "§2.1.1.4", a.dof_formula_m / 2, 1e2, "cm", "66.5",
        "the study halves the rounded 1.33 m");
}

void addSunRows(const SceneAnalysis& a, TableBuilder& t)
{
  const SceneInputs& in = a.inputs;
  t.add("sun_temperature", "Sun temperature implied by F_sun", "(2.2)", a.sun_temperature_k, 1, "K", "",
        "the sun's effective temperature is 5772 K (F_sun = 6.29e7 W/m^2); the stated 6.45e7 is 2.5% high");
  t.add("irradiance_perihelion", "Solar irradiance at perihelion", "(2.3)", a.irradiance_perihelion, 1, "W/m^2", "730",
        "the study truncates " + num(a.irradiance_perihelion) + " to 730");
  t.add("irradiance_aphelion", "Solar irradiance at aphelion", "(2.3)", a.irradiance_aphelion, 1, "W/m^2", "502");
  t.add("irradiance_semi_major", "Solar irradiance at the semi-major axis", "(2.4)", a.irradiance_semi_major, 1,
        "W/m^2", "589",
        "with the stated F_sun = 6.45e7 W/m^2 it is " + num(a.irradiance_semi_major) +
            "; 589 needs F_sun = " + num(589.0 / std::pow(in.sun_radius_m / in.mars_semi_major_axis_m, 2)) +
            " (the real value, 586 W/m^2, needs 6.29e7); R is 2.27936e11 m, not km");
  t.add("irradiance_surface", "Irradiance after the atmosphere F_a", "(2.5)", a.irradiance_surface, 1, "W/m^2", "530",
        "0.9 x 589 = 530: follows the slip of (2.4)");
  t.addRange("irradiance_latitude", "Irradiance at latitude 50 deg F50", "(2.6)", a.irradiance_latitude, 1, "W/m^2",
             "92", "341", "530 x sin[10, 40] deg = [92.0, 340.7]: follows (2.4)");
  t.add("solar_fraction_in_band", "Share of sunlight in the band (blackbody)", "(2.20)", a.solar_fraction_in_band, 1,
        "", "", "the study counts all of F as light in the band; kept, so the sun's numbers are upper bounds");
}

void addSunlitTargetRows(const SceneAnalysis& a, TableBuilder& t)
{
  const SceneInputs& in = a.inputs;
  t.addRange("radiance_target", "Target radiance R_T", "(2.7)-(2.8)", a.radiance_target, 1, "W/(m^2 sr)", "1.44",
             "58.58",
             "(2.7) swaps its labels: its text (and numbers) make the glossy mixture the optimal case and pure "
             "Lambertian the worst; the minimum 1.44 uses theta = 10 deg instead of 50 deg (" +
                 num(targetRadiance(in, 92.0, in.albedo_min, in.sun_incidence_max_deg, Brdf::kLambertian)) +
                 " with F50 = 92); the rest follows (2.4)");
  t.addRange("irradiance_sensor", "Irradiance on the sensor I_T", "(2.9)-(2.10)", a.irradiance_sensor, 1, "W/m^2",
             "0.0271", "1.1000", "follows (2.8)");
  t.addRange("power_per_pixel", "Sun power per pixel W_lum", "(2.11)-(2.12)", a.power_per_pixel, 1e12, "pW", "390.0",
             "15840",
             "the study prints [3.900, 158.40]e-10 W: the exponent is e-12 (1.1 W/m^2 x 144e-12 m^2 = 158.4e-12 W), "
             "as its own (2.20) uses");
  t.addRange("photons_per_pixel", "Sun photons per pixel per exposure N_p", "(2.20)", a.photons_per_pixel, 1e-6,
             "1e6 ph", "1.177", "47.810", "follows (2.8); (2.20) is right for a flat spectrum (mean wavelength)");
  t.addRange("photons_at_pixel", "Sun photons reaching a pixel N_CCD", "(2.21)", a.photons_per_pixel, 1, "ph", "0.1328",
             "5.3936",
             "(2.21) multiplies N_p by pi(Dsr/2)^2/(2 pi r^2) = " +
                 num(std::pow(in.aperture_diameter_m / 2, 2) / (2 * std::pow(in.distance_max_m, 2))) +
                 ": the aperture is already in (2.9), so it is applied twice (x1e-7); N_p already reaches the pixel");
  t.add("sun_band_efficiency", "Band efficiency QE x lens (sunlight)", "(2.22)", a.sun_band_efficiency, 1, "", "0.1568",
        "the study's ratio (2.22)/(2.21) = 0.1568 (its integral is a band mean); the default QE table is scaled to "
        "it, photon-weighted here");
  t.addRange("sun_electrons", "Sun photo-electrons per pixel Nen_CCD", "(2.22)", a.sun_electrons, 1, "e-", "0.0208",
             "0.8457",
             "x1e7 from (2.21); the brightest case is " + num(a.sun_electrons.max / in.full_well_e) +
                 " x the full well at ts = " + num(in.exposure_s) + " s");
}

void addLedRows(const SceneAnalysis& a, TableBuilder& t)
{
  const SceneInputs& in = a.inputs;
  const double alpha = deg2rad(0.5 * in.led_beam_angle_deg);
  const double study_scale_ratio = a.led_power_study_w / a.led_optical_power_w;
  t.add("led_solid_angle", "LED solid angle Omega", "(2.13)", a.led_solid_angle_sr, 1, "sr", "0.2141");
  t.add("led_luminous_flux", "LED luminous flux C_LED Omega", "(2.13)", a.led_luminous_flux_lm, 1, "lm", "",
        "cd x sr = lm; an upper bound (84 cd is the on-axis intensity)");
  t.add("led_power_study", "LED power P_LED = flux / L_e", "(2.13)", a.led_power_study_w, 1, "W", "0.2997",
        "lm / (60 lm/W) is the ELECTRICAL input (60 lm/W is a plausible wall-plug efficacy; cf. 220 mW on the "
        "datasheet, 300 mW budget), not the light emitted");
  t.add("led_optical_power", "LED optical power flux / (683 V(lambda))", "(2.13)", a.led_optical_power_w, 1e3, "mW", "",
        "683 V(" + num(in.led_wavelength_m * 1e9) + " nm) = " + num(a.led_luminous_efficacy_radiation_lm_w) +
            " lm/W: the study's 'light' is " + num(study_scale_ratio) + " x too strong");
  t.add("led_lens_ratio", "LED collecting lens diameter / focal length", "(2.1)", a.led_lens_diameter_ratio, 1, "",
        num(std::tan(alpha)).substr(0, 6), "(2.1) d = f tan(alpha) is the radius: the diameter is 2 f tan(alpha)");
  t.add("dot_power", "Power per dot W_dot", "(2.13)", a.dot_power_w, 1e4, "1e-4 W", "4.4960",
        "the study uses the electrical power (0.15 x 0.2997 / 100 = 4.4960e-4 W); its 'loss factors' are used "
        "as transmissions");
  t.add("dot_irradiance", "Dot irradiance E_point", "(2.14)", a.dot_irradiance, 1, "W/m^2", "71.5558",
        "x" + num(study_scale_ratio) +
            " in the study (electrical power); A_point = 2 pi (1 mm)^2 makes E_point the "
            "peak of a Gaussian dot of sigma = 1 mm");
  t.addRange("led_power_per_pixel", "LED power per pixel W_LED", "§2.1.3.4", a.led_power_per_pixel, 1e12, "pW", "3.033",
             "33.271", "follows (2.14)");
  t.add("led_efficiency", "QE x lens at the LED wavelength", "§2.1.3.5 case 2", a.led_efficiency, 1, "", "27.44",
        "the study's Nen_LED / N_CCD(520 nm) = 27.4 > 1 is impossible: its LED photo-electrons carry a x100 slip "
        "(W_LED in 1e-10 W, as in (2.12)); / 100 = 0.274");
  t.addRange("led_electrons", "LED photo-electrons per pixel Nen_LED", "§2.1.3.5 case 2", a.led_electrons, 1, "e-",
             "2.4556", "26.9410", "x1e7 from (2.21), / " + num(study_scale_ratio) + " (optical power), /100 (slip)");
}

void addNoiseAndSnrRows(const SceneAnalysis& a, TableBuilder& t)
{
  const SceneInputs& in = a.inputs;
  const double dark_e = a.dark_current_e_s * in.exposure_s;
  const double r2 = in.read_noise_e * in.read_noise_e;
  t.add("read_noise", "Readout noise per pixel", "(2.15)-(2.16)", a.read_noise_e, 1, "e-", "2.3842e-05",
        "(2.15) divides the 25 e- RMS by the number of pixels (25 / 1048576 = 2.3842e-5); read noise is per pixel "
        "(the study's own table 2.1 lists 25 electrons)");
  t.add("dark_current", "Dark current per pixel at temperature_k", "(2.17)", a.dark_current_e_s, 1, "e-/s", "",
        "datasheet 30 pA/cm^2 at 20 C scaled by Janesick's law T^1.5 exp(-Eg/2kT)");
  t.add("dark_noise", "Dark current noise", "(2.17)-(2.18)", a.dark_noise_e, 1, "e-", "0.0067",
        "(2.17) as printed (T^(2/3), square root, 30 pA/cm^2) gives 0.034 e-; 0.0067 comes out with T^1 and no "
        "square root; the law is T^1.5 with D_FM in nA/cm^2 at 300 K. Negligible next to the readout noise");
  t.add("noise_floor", "Noise without sunlight N", "(2.19)", a.noise_floor_e, 1, "e-", "0.0067",
        "25 e- readout noise, not 0.0067");
  t.addRange("noise_sunlit", "Noise with sunlight", "(2.25)",
             {std::sqrt(a.sun_electrons.min + dark_e + r2), std::sqrt(a.sun_electrons.max + dark_e + r2)}, 1, "e-",
             "0.0219", "0.8457", "(2.25) takes delta_shot = Nen_CCD, the signal itself; shot noise is its square root");
  t.addRange("snr_sun", "SNR case 1: sun only", "(2.23)", a.snr_sun, 1, "", "3.1", "126.8",
             "the study divides photo-electrons 1e7 too few by a noise 4000 x too small; here S/sqrt(S + read^2 + "
             "dark), shot noise included");
  t.addRange("snr_led_night", "SNR case 2: LED at night", "(2.24)", a.snr_led_night, 1, "", "368", "4040",
             "same slips as case 1 plus the x100 of Nen_LED");
  t.addRange("snr_led_day", "SNR case 3: LED against the sun", "(2.26)", a.snr_led_day, 1, "", "32", "348",
             "(2.25) takes the sun's signal itself as its noise (not its square root), so 32 is the dot/sun ratio; "
             "348 pairs the LED at albedo 0.45 with the sun at 0.05, against the study's own albedo correlation; "
             "without the x100 slip its model gives 0.32 and 3.5: the LED does not outshine the sun");
  t.add("saturating_exposure", "Exposure at which the brightest pixel fills the well", "§2.1.3.5",
        a.saturating_exposure_s, 1e3, "ms", "",
        "the study's ts = " + num(in.exposure_s * 1e3) + " ms saturates the sensor in bright sun");
  t.add("snr_led_day_worst_unsaturated", "SNR case 3 worst, exposure within the full well", "§2.1.3.5",
        a.snr_led_day_worst_unsaturated, 1, "", "");
  t.add("dot_to_sun_ratio", "Dot / sun photo-electrons at sun_level 1", "simulator", dotToSunRatio(a), 1, "", "",
        "corrected physics (LightingParams::dot_to_sun_ratio)");
  t.add("dot_to_sun_ratio_study", "Dot / sun photo-electrons, study as stated", "simulator",
        dotToSunRatio(a, RadiometryModel::kStudyAsStated), 1, "", "32",
        "the study's worst-case SNR 32 is this ratio (its noise model); x100 slip and electrical power included")
      .agrees = true;
}

}  // namespace

namespace scene
{

void buildDesignTable(SceneAnalysis* a)
{
  TableBuilder t(&a->table);
  addOpticsRows(*a, t);
  addSunRows(*a, t);
  addSunlitTargetRows(*a, t);
  addLedRows(*a, t);
  addNoiseAndSnrRows(*a, t);
}

}  // namespace scene

// ---------------------------------------------------------------------------
// Table

std::string formatDesignTable(const SceneAnalysis& a)
{
  auto fmt = [](double v)
  {
    char b[32];
    if (!std::isfinite(v))
      return std::string(v > 0 ? "inf" : "nan");
    const double m = std::fabs(v);
    if (m != 0.0 && (m < 1e-3 || m >= 1e5))
      std::snprintf(b, sizeof(b), "%.4g", v);
    else
      std::snprintf(b, sizeof(b), "%.5g", v);
    return std::string(b);
  };
  auto value = [&](double lo, double hi, bool range) { return range ? "[" + fmt(lo) + ", " + fmt(hi) + "]" : fmt(lo); };
  std::ostringstream os;
  auto pad = [](const std::string& text, size_t width)
  {
    // Display width: UTF-8 continuation bytes (the "§") take no column.
    const size_t cols = std::count_if(text.begin(), text.end(), [](char ch) { return (ch & 0xC0) != 0x80; });
    return cols >= width ? text + " " : text + std::string(width - cols, ' ');
  };
  os << pad("quantity (study ref)", 63) << pad("computed", 23) << pad("unit", 12) << pad("  study", 21) << "note\n"
     << std::string(142, '-') << "\n";
  for (const auto& q : a.table)
  {
    const std::string study = q.has_study ? value(q.study, q.study_max, q.is_range && std::isfinite(q.study_max)) : "-";
    const std::string mark = q.has_study && !q.agrees ? "! " : "  ";
    os << pad(q.name + " " + q.ref, 63) << pad(value(q.value, q.value_max, q.is_range), 23) << pad(q.unit, 12) << mark
       << pad(study, 19) << q.note << "\n";
  }
  os << "\n'!' marks a study value that differs from the computed one beyond the precision it is printed with.\n";
  return os.str();
}

}  // namespace structured_light_stabilizer
