// Accuracy of PoseDelta from image to pose on the simulator (the accuracy
// scenes of test/support/pose_delta_chain.h): simulator image -> SpotDetector ->
// Triangulator -> PoseDelta, rig jitter +-10 mm / +-1 deg, per seed and
// pooled, each axis's RMS error next to the 1-sigma the estimator reports.
//
// Usage: evaluate_pose_delta [scenes (comma list, default all)] [first seed (1)]
//        [seeds (4)] [frames per seed (30)] [name=value ...] [--flag value ...]
// dt=seconds sets the time between frames (default 0.1).
// name=value (or --param name=value) sets any field of the stages' settings:
// PoseDelta's (pose/pose_delta_params.def), the SpotDetector's and the
// Triangulator's; a name of more than one stage takes its stage first
// (detector., triangulator., pose.); bools 0/1, enums by name, e.g.
// use_texture=0 detector.normalise_albedo=0.
// Experiments, each a flag:
//   --true-surface box|image   the reference surface from the simulator's rock at the lock
//                              (over the dots' box, or the whole image: the texture's depths too)
//   --projector-off-lock 0|1   the lock's texture from a projector-off exposure of its instant
//   --vignetting 0|1, --grid RxC, --noise-free 0|1, --relief M, --colour-texture A   the scene (support/scene_ablations.h)
// Scenes: weak_texture, missing_dots, worst_snr, flat_textured, rough, textureless,
// mono, bgr16, bgr16_as_bgr8, strobed, strobed_one_side.
#include <iostream>
#include <string>
#include <vector>

#include "cli/evaluate_pose_delta_cli.h"

int main(int argc, char** argv)
{
  return structured_light_stabilizer::evaluatePoseDeltaMain(std::vector<std::string>(argv + 1, argv + argc), std::cout,
                                                            std::cerr);
}
