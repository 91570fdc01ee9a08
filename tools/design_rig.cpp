// design_rig: the daylight design calculator (docs/daylight.md). Evaluates
// every combination of the rig's options at the worst case of the
// conditions, prints the table with the study's rig and the recommended one
// first, and writes the CSV, the plot and the recommended rig's YAML (the
// simulator reads it: CameraDriver ~rig); then the beam x focus table with
// each design's relief floor (beam_design.h), measured on the simulator.
//
//   design_rig [design.yaml] [--scene scene.yaml] [--rows N] [--csv FILE] [--png FILE] [--rig-yaml FILE]
//              [--beams 0|1]
//
// Exit status 0 on success (also when nothing is feasible: the table says
// why), 1 on bad inputs or an unwritable output, 2 on bad usage.
#include <iostream>
#include <string>
#include <vector>

#include "cli/design_rig_cli.h"

int main(int argc, char** argv)
{
  return structured_light_stabilizer::designRigMain(std::vector<std::string>(argv + 1, argv + argc), std::cout,
                                                    std::cerr);
}
