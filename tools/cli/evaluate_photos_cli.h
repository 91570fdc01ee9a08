// evaluate_photos's command line (tools/cli/evaluate_photos_cli.cpp, where its
// usage is documented), callable in-process: the tests run it on a small case.
#pragma once

#include <ostream>
#include <string>
#include <vector>

namespace structured_light_stabilizer
{

// Returns the exit status: 0, 1 when an image failed to load or run, 2 on bad usage.
int evaluatePhotosMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err);

}  // namespace structured_light_stabilizer
