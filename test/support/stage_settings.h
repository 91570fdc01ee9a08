// The settings of the pipeline's stages as the evaluation tools take them
// (tools/evaluate_daylight, tools/evaluate_pose_delta): the SpotDetector's,
// the Triangulator's (with its BeamTracker's) and PoseDelta's settings
// structs, each field settable by name from its .def (common/params.h), so
// that an ablation of any stage is a flag:
//   --param [detector.|triangulator.|pose.]name=value
// An unqualified name must name a field of exactly one stage (`enabled` is
// both the detector's and the Triangulator's: qualify it). Bools 0/1,
// enums by name. Values are checked by each struct's validate() when the
// settings are used.
#pragma once

#include <string>

#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/pose/pose_delta_params.h"
#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace sls_test
{

struct StageSettings
{
  structured_light_stabilizer::SpotDetectorParams detector;
  structured_light_stabilizer::TriangulatorParams triangulator;
  structured_light_stabilizer::BeamTrackerParams tracker;  // the Triangulator nodelet's tracking prior
  structured_light_stabilizer::PoseDeltaParams pose;

  // "[stage.]name=value" into the named field; "" when set, else why not.
  std::string set(const std::string& setting)
  {
    const size_t eq = setting.find('=');
    if (eq == std::string::npos)
      return "'" + setting + "' is not name=value";
    std::string name = setting.substr(0, eq);
    const std::string value = setting.substr(eq + 1);
    std::string stage;
    const size_t dot = name.find('.');
    if (dot != std::string::npos)
    {
      stage = name.substr(0, dot);
      name = name.substr(dot + 1);
      if (stage != "detector" && stage != "triangulator" && stage != "pose")
        return "'" + stage + "' is no stage (detector, triangulator, pose)";
    }
    const bool in_detector = (stage.empty() || stage == "detector") && detector.has(name);
    const bool in_triangulator =
        (stage.empty() || stage == "triangulator") && (triangulator.has(name) || tracker.has(name));
    const bool in_pose = (stage.empty() || stage == "pose") && pose.has(name);
    const int stages = int(in_detector) + int(in_triangulator) + int(in_pose);
    if (stages == 0)
      return "no " + (stage.empty() ? std::string("stage") : stage) + " has a setting '" + name + "'";
    if (stages > 1)
      return "'" + name + "' is a setting of more than one stage: write detector., triangulator. or pose. before it";
    bool ok = false;
    if (in_detector)
      ok = detector.set(name, value);
    else if (in_triangulator)
      ok = triangulator.has(name) ? triangulator.set(name, value) : tracker.set(name, value);
    else
      ok = pose.set(name, value);
    return ok ? "" : "'" + value + "' does not read as the type of " + name;
  }

  // Empty when every stage can use its settings, else the first problem.
  std::string validate() const
  {
    std::string why = detector.validate();
    if (why.empty())
      why = triangulator.validate();
    if (why.empty())
      why = pose.validate();
    return why;
  }
};

}  // namespace sls_test
