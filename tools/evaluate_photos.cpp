// evaluate_photos: the SpotDetector on real photographs of projected dots
// against hand-checked labels (test/data/real/README.md); the options are
// documented in tools/cli/evaluate_photos_cli.cpp.
#include <iostream>
#include <string>
#include <vector>

#include "cli/evaluate_photos_cli.h"

int main(int argc, char** argv)
{
  return structured_light_stabilizer::evaluatePhotosMain(std::vector<std::string>(argv + 1, argv + argc), std::cout,
                                                         std::cerr);
}
