// The evaluate_daylight tool's command line (tools/evaluate_daylight.cpp;
// docs/daylight.md), callable in-process: the arguments without the
// program's name, the report to `out`, the problems to `err`. Returns the
// exit status: 0 done, 1 a failed run (an unreadable rig), 2 bad usage.
#pragma once

#include <ostream>
#include <string>
#include <vector>

namespace structured_light_stabilizer
{

int evaluateDaylightMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);

}  // namespace structured_light_stabilizer
