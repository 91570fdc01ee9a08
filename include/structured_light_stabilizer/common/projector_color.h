// The projector's colour, shared by the SpotDetector (~projector_color)
// and the simulator (ProjectorParams::color): one enum, one spelling of the
// names ("green", "red", "blue", "nir", "white"). Plain data, no ROS.
#pragma once

#include <string>

namespace structured_light_stabilizer
{

enum class ProjectorColor
{
  kGreen = 0,  // 520 nm (the study's)
  kRed = 1,    // 635-660 nm lasers
  kBlue = 2,   // 450 nm
  kNir = 3,    // 850 nm: a monochrome camera (a colour camera's IR-cut filter blocks it)
  kWhite = 4,  // broadband
};

// The name ("green", ...); "unknown" for a value outside the enum.
const char* projectorColorName(ProjectorColor color);
// Parses a name; false (and *color untouched) for another one.
bool projectorColorFromName(const std::string& name, ProjectorColor* color);

}  // namespace structured_light_stabilizer
