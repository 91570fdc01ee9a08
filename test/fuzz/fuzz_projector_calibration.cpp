// libFuzzer target: the projector calibration YAML loader on arbitrary text.
// It must either load a consistent calibration or refuse with a message;
// never crash, hang or accept an inconsistent one.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "structured_light_stabilizer/calibration/projector_calibration.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size)
{
  using namespace structured_light_stabilizer;
  const std::string text(reinterpret_cast<const char*>(data), size);
  ProjectorCalibration calibration;
  std::string error;
  if (parseProjectorCalibration(text, &calibration, &error))
  {
    if (!calibration.validate().empty())
      std::abort();  // accepted something inconsistent
  }
  else if (error.empty())
  {
    std::abort();  // refused without saying why
  }
  return 0;
}
