// The calibrate_projector tool's command line (tools/calibrate_projector.cpp;
// docs/calibration.md), callable in-process: the arguments without the
// program's name, the report to `out`, the problems to `err`. Returns the
// tool's exit status (0 done; 1 bad usage; 2 the camera_info file is
// unusable; 3 an image is unreadable; 4 fewer than two views have the board
// and its dots; 5 a beam is seen in fewer than two views; 6 no view shows
// the whole pattern; 7 the fit failed; 8 an output cannot be written).
#pragma once

#include <ostream>
#include <string>
#include <vector>

namespace structured_light_stabilizer
{

int calibrateProjectorMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);

}  // namespace structured_light_stabilizer
