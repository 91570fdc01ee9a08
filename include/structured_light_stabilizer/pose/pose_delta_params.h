// Settings of the PoseDelta estimator and of its registration solver, ROS-free.
// Units are in the names (_m metres, _rad radians, _px pixels); the ROS
// parameter and dynamic_reconfigure names (cfg/PoseDelta.cfg) are the same
// without the struct. validate() says what is unusable; nothing here throws.
#pragma once

#include <string>

#include "structured_light_stabilizer/common/params.h"

namespace structured_light_stabilizer
{

enum class PoseDeltaMode
{
  kReference,    // every frame against the locked reference (no drift)
  kFrameToFrame  // against the previous valid frame, deltas chained
};

struct PoseDeltaParams
{
#define SLS_PARAMS_STRUCT PoseDeltaParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/pose/pose_delta_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  double maxSigmaRotationRad() const { return max_sigma_rotation_deg * 3.14159265358979323846 / 180.0; }

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

}  // namespace structured_light_stabilizer
