// libFuzzer target: the scene analysis inputs loader on arbitrary text.
// It must either load inputs that the analysis accepts, or refuse with a
// message; never crash, hang or let another exception type escape.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "structured_light_stabilizer/sim/scene_analysis.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size)
{
  using namespace structured_light_stabilizer;
  const std::string text(reinterpret_cast<const char*>(data), size);
  SceneInputs inputs;
  try
  {
    inputs = sceneInputsFromYaml(text, "fuzz.yaml");
  }
  catch (const std::invalid_argument& e)
  {
    if (std::string(e.what()).empty())
      std::abort();  // refused without saying why
    return 0;
  }
  // Accepted inputs must analyse without an error.
  const SceneAnalysis analysis = analyseScene(inputs);
  if (analysis.table.empty())
    std::abort();
  (void)dotToSunRatio(analysis);
  return 0;
}
