// Names of the projector's colours (projector_color.h).
#include "structured_light_stabilizer/common/projector_color.h"

namespace structured_light_stabilizer
{

namespace
{
const char* const kNames[] = {"green", "red", "blue", "nir", "white"};
constexpr int kCount = 5;
}  // namespace

const char* projectorColorName(ProjectorColor color)
{
  const int i = static_cast<int>(color);
  return i >= 0 && i < kCount ? kNames[i] : "unknown";
}

bool projectorColorFromName(const std::string& name, ProjectorColor* color)
{
  for (int i = 0; i < kCount; ++i)
  {
    if (name == kNames[i])
    {
      *color = static_cast<ProjectorColor>(i);
      return true;
    }
  }
  return false;
}

}  // namespace structured_light_stabilizer
