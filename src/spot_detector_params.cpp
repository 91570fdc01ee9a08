// Checks of the SpotDetector's settings (spot_detector.h): sanitize() of each
// group in the order of its fields, validate() = the first change sanitize()
// would make on a copy.
#include "structured_light_stabilizer/spot_detector.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "spot_detector_method.h"

namespace structured_light_stabilizer
{

namespace
{
using Changes = std::vector<std::string>;

void clampInt(int* v, int lo, int hi, const char* name, Changes* changes)
{
  const int c = std::min(std::max(*v, lo), hi);
  if (c != *v)
  {
    std::ostringstream s;
    s << name << " " << *v << " out of [" << lo << ", " << hi << "], clamped to " << c;
    changes->push_back(s.str());
    *v = c;
  }
}

void clampDouble(double* v, double lo, double hi, const char* name, Changes* changes)
{
  const double c = std::isfinite(*v) ? std::min(std::max(*v, lo), hi) : lo;
  if (c != *v)
  {
    std::ostringstream s;
    s << name << " " << *v << " out of [" << lo << ", " << hi << "], clamped to " << c;
    changes->push_back(s.str());
    *v = c;
  }
}

template <typename T>
void orderPair(T* lo, T* hi, const char* lo_name, const char* hi_name, Changes* changes)
{
  if (*lo > *hi)
  {
    std::ostringstream s;
    s << lo_name << " " << *lo << " > " << hi_name << " " << *hi << ", swapped";
    changes->push_back(s.str());
    std::swap(*lo, *hi);
  }
}

void append(Changes more, Changes* changes)
{
  for (std::string& change : more)
    changes->push_back(std::move(change));
}

template <typename Params>
std::string firstChange(Params copy)
{
  const Changes changes = copy.sanitize();
  return changes.empty() ? std::string() : changes.front();
}
}  // namespace

Changes BaselineParams::sanitize()
{
  Changes changes;
  clampInt(&blur_kernel, 1, 31, "blur_kernel", &changes);
  if (blur_kernel % 2 == 0)
  {
    changes.push_back("blur_kernel " + std::to_string(blur_kernel) + " is even, using " +
                      std::to_string(blur_kernel + 1));
    ++blur_kernel;
  }
  clampInt(&h_min, 0, 179, "h_min", &changes);
  clampInt(&h_max, 0, 179, "h_max", &changes);
  clampInt(&s_min, 0, 255, "s_min", &changes);
  clampInt(&s_max, 0, 255, "s_max", &changes);
  clampInt(&v_min, 0, 255, "v_min", &changes);
  clampInt(&v_max, 0, 255, "v_max", &changes);
  orderPair(&h_min, &h_max, "h_min", "h_max", &changes);
  orderPair(&s_min, &s_max, "s_min", "s_max", &changes);
  orderPair(&v_min, &v_max, "v_min", "v_max", &changes);
  clampInt(&erosions, 0, 20, "erosions", &changes);
  clampInt(&dilations, 0, 20, "dilations", &changes);
  clampInt(&min_area, 0, 1000000, "min_area", &changes);
  clampInt(&max_area, 0, 1000000, "max_area", &changes);
  if (max_area > 0 && min_area > max_area)
    orderPair(&min_area, &max_area, "min_area", "max_area", &changes);
  return changes;
}

Changes ColourTestParams::sanitize()
{
  Changes changes;
  clampDouble(&led_red_ratio, 0.0, 10.0, "led_red_ratio", &changes);
  clampDouble(&led_blue_ratio, 0.0, 10.0, "led_blue_ratio", &changes);
  clampDouble(&max_red_deficit, 0.0, 100.0, "max_red_deficit", &changes);
  clampDouble(&max_red_excess, 0.0, 100.0, "max_red_excess", &changes);
  clampDouble(&max_chroma_error, 0.0, 100.0, "max_chroma_error", &changes);
  return changes;
}

Changes FastParams::sanitize()
{
  Changes changes;
  clampInt(&detect_threshold, 1, 255, "detect_threshold", &changes);
  clampDouble(&red_weight, 0.0, 1.0, "red_weight", &changes);
  clampInt(&min_peak, 1, 255, "min_peak", &changes);
  clampDouble(&intensity_snr, 0.0, 1000.0, "intensity_snr", &changes);
  clampInt(&mono_threshold, 1, 255, "mono_threshold", &changes);
  clampInt(&min_pixels, 1, 10000, "min_pixels", &changes);
  clampInt(&coarse_threshold, 0, 255, "coarse_threshold", &changes);
  clampInt(&max_candidates, 1, 1000000, "max_candidates", &changes);
  clampDouble(&matched_sigma_px, 0.0, 10.0, "matched_sigma_px", &changes);
  clampDouble(&matched_detect_snr, 1.0, 100.0, "matched_detect_snr", &changes);
  clampDouble(&matched_peak_snr, 1.0, 100.0, "matched_peak_snr", &changes);
  clampInt(&window_radius_px, 0, 24, "window_radius_px", &changes);
  clampDouble(&albedo_floor_dn, 0.0, 255.0, "albedo_floor_dn", &changes);
  clampDouble(&min_sigma_px, 0.0, 20.0, "min_sigma_px", &changes);
  clampDouble(&max_sigma_px, 0.3, 20.0, "max_sigma_px", &changes);
  orderPair(&min_sigma_px, &max_sigma_px, "min_sigma_px", "max_sigma_px", &changes);
  append(colour_test.sanitize(), &changes);
  clampInt(&saturation_level, 1, 255, "saturation_level", &changes);
  return changes;
}

Changes SpotDetectorParams::sanitize()
{
  Changes changes;
  if (!isRegisteredMethod(method))
  {
    changes.push_back("method " + std::to_string(static_cast<int>(method)) + " is not registered, using fast");
    method = SpotMethod::kFast;
  }
  if (std::string(projectorColorName(projector_color)) == "unknown")
  {
    changes.push_back("projector_color " + std::to_string(static_cast<int>(projector_color)) +
                      " is not a colour, using green");
    projector_color = ProjectorColor::kGreen;
  }
  append(baseline.sanitize(), &changes);
  clampInt(&projector_rows, 1, 1000, "projector_rows", &changes);
  clampInt(&projector_cols, 1, 1000, "projector_cols", &changes);
  append(fast.sanitize(), &changes);
  return changes;
}

std::string BaselineParams::validate() const
{
  return firstChange(*this);
}

std::string ColourTestParams::validate() const
{
  return firstChange(*this);
}

std::string FastParams::validate() const
{
  return firstChange(*this);
}

std::string SpotDetectorParams::validate() const
{
  return firstChange(*this);
}

}  // namespace structured_light_stabilizer
