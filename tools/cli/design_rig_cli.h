// The design_rig tool's command line (tools/design_rig.cpp;
// docs/daylight.md), callable in-process: the arguments without the
// program's name, the report to `out`, the problems to `err`. Returns the
// exit status: 0 done (also when nothing is feasible), 1 bad inputs or an
// unwritable output, 2 bad usage.
#pragma once

#include <ostream>
#include <string>
#include <vector>

namespace structured_light_stabilizer
{

int designRigMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);

}  // namespace structured_light_stabilizer
