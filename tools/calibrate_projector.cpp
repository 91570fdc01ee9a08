// calibrate_projector: the projector's beam rays from recorded chessboard
// views (docs/calibration.md).
//
//   calibrate_projector --images DIR --camera-info FILE.yaml --board COLSxROWS --square METRES
//                       --output projector.yaml [--rows R --cols C] [--margin METRES]
//                       [--projector-color green|red|blue|nir|white] [--model auto|central|per-beam]
//                       [--report FILE.png]
//
// Reads every image of DIR (sorted by name), prints per view (board found,
// dots used, residual) and per beam (views, residual, distance from the
// common centre, predicted sigma), writes the general projector YAML and a
// PNG report (default: the output's name with .png). Exit status: 0 done;
// 1 bad usage; 2 the camera_info file is unusable; 3 an image is
// unreadable; 4 fewer than two views have the board and its dots; 5 a beam
// is seen in fewer than two views; 6 no view shows the whole pattern; 7 the
// fit failed; 8 an output cannot be written.
#include <iostream>
#include <string>
#include <vector>

#include "cli/calibrate_projector_cli.h"

int main(int argc, char** argv)
{
  return structured_light_stabilizer::calibrateProjectorMain(std::vector<std::string>(argv + 1, argv + argc), std::cout,
                                                             std::cerr);
}
