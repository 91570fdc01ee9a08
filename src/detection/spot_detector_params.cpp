// Checks of the SpotDetector's settings (spot_detector.h): sanitize() of each
// group (the ranges of its .def first, then the rules between fields),
// validate() = the first change sanitize() would make on a copy.
#include "structured_light_stabilizer/detection/spot_detector.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "detection/method.h"

namespace structured_light_stabilizer
{

namespace
{
using Changes = params::Changes;
using params::clampTo;

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

template <typename Params>
std::string firstChange(Params copy)
{
  const Changes changes = copy.sanitize();
  return changes.empty() ? std::string() : changes.front();
}
}  // namespace

// The ranges come from the .def files (clampToRanges); here what else a
// value must satisfy.
Changes BaselineParams::sanitize()
{
  Changes changes;
  clampToRanges(&changes);
  if (blur_kernel % 2 == 0)
  {
    changes.push_back("blur_kernel " + std::to_string(blur_kernel) + " is even, using " +
                      std::to_string(blur_kernel + 1));
    ++blur_kernel;
  }
  orderPair(&h_min, &h_max, "h_min", "h_max", &changes);
  orderPair(&s_min, &s_max, "s_min", "s_max", &changes);
  orderPair(&v_min, &v_max, "v_min", "v_max", &changes);
  if (max_area > 0 && min_area > max_area)
    orderPair(&min_area, &max_area, "min_area", "max_area", &changes);
  return changes;
}

Changes ColourTestParams::sanitize()
{
  Changes changes;
  clampToRanges(&changes);
  return changes;
}

Changes FastParams::sanitize()
{
  Changes changes;
  clampToRanges(&changes);  // colour_test's too
  clampTo(&max_candidates, 1, 1000000, "max_candidates", &changes);
  clampTo(&matched_sigma_px, 0.0, 10.0, "matched_sigma_px", &changes);
  clampTo(&matched_detect_snr, 1.0, 100.0, "matched_detect_snr", &changes);
  clampTo(&matched_peak_snr, 1.0, 100.0, "matched_peak_snr", &changes);
  orderPair(&min_sigma_px, &max_sigma_px, "min_sigma_px", "max_sigma_px", &changes);
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
  for (std::string& change : baseline.sanitize())
    changes.push_back(std::move(change));
  clampTo(&projector_rows, 1, 1000, "projector_rows", &changes);
  clampTo(&projector_cols, 1, 1000, "projector_cols", &changes);
  for (std::string& change : fast.sanitize())
    changes.push_back(std::move(change));
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
