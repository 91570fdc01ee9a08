// libFuzzer target: the scene analysis inputs loader and the daylight rig
// loader (radiometry.h) on arbitrary text. Each must either load inputs
// that the analysis (or the rig model) accepts, or refuse with a message;
// never crash, hang or let another exception type escape.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace
{

// The same text as a rig: a rig that loads gives finite signals and a
// valid simulator radiometry.
void fuzzRig(const std::string& text)
{
  using namespace structured_light_stabilizer;
  static const SceneAnalysis study = analyseScene(SceneInputs());
  RigParams rig;
  try
  {
    rig = rigFromYaml(study, text, "fuzz_rig.yaml");
  }
  catch (const std::invalid_argument& e)
  {
    if (std::string(e.what()).empty())
      std::abort();
    return;
  }
  const DotSignal s = evaluateRig(study, rig, ViewConditions());
  const SimRadiometry r = simulatorRadiometry(study, rig);
  if (!(s.dot_e >= 0.0) || !(s.sun_e >= 0.0) || !(r.gain_dn_per_electron > 0.0) || !(r.exposure >= 0.0))
    std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size)
{
  using namespace structured_light_stabilizer;
  const std::string text(reinterpret_cast<const char*>(data), size);
  fuzzRig(text);
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
