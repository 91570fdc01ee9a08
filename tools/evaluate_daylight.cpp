// evaluate_daylight: the pipeline's core (detector, triangulator, PoseDelta)
// on simulated daylight, one frame or strobed, against the simulator's
// truth (docs/daylight.md, "Measured"). Per case: recall (dots within 3 px
// of their true pixel / visible dots) pooled and its worst frame; centroid
// RMS against the beam's hit point (what depth needs), its part along the
// epipolar line, against the dot's own light and its footprint (the light
// over the albedo: what a detector can reach), and how far the light lies
// from the hit point; wrong beams, depth RMS (mm and % of z), pose RMS and
// the share of valid poses.
//
//   evaluate_daylight [--rig FILE] [--ratio R] [--strobe 0|1] [--sun S] [--distance D]... [--seeds A,B]
//                     [--frames N] [--texture PERIOD_M] [--albedo A] [--sweep R1,R2,...] [--motion M]
//                     [--full-resolution-tracking 0|1] [--output ENCODING] [--output-bits N]
//                     [--unrounded 0|1] [--true-ambient 0|1] [--focus M] [--rock-subsample N]
//                     [--camera-rate HZ] [--extrapolate 0|1] [--difference 0|1 [--normalise 0|1]]
//                     [--vignetting 0|1] [--grid RxC] [--noise-free 0|1] [--relief M] [--colour-texture A]
//                     [--param [detector.|triangulator.|pose.]name=value]...
//
// The camera: the rig's as designed (its output_bits: the recommended rig's
// 12 bits as bgr16), bgr8 without --rig; --output overrides it.
// --param sets any field of the stages' settings (their .def files), e.g.
// --param normalise_albedo=0 (the detector's albedo normalisation off).
// --true-ambient 1: the projector-off render at the on-frame's own time
// (noise of its own) instead of the compensated ambient.
//
// Strobed: the projector fires on every second frame (30 Hz camera, 15 Hz
// dot frames); the ambient frames around each on-frame are compensated to
// its time (ambient_compensation.h) and the dots are detected on the
// difference. --ratio overrides the rig's dot/sun ratio (the 3 mm
// reference dot); --sweep runs the cases for each ratio and prints one line
// per ratio (the lowest ratio at which each stage meets its bound).
#include <iostream>
#include <string>
#include <vector>

#include "cli/evaluate_daylight_cli.h"

int main(int argc, char** argv)
{
  return structured_light_stabilizer::evaluateDaylightMain(std::vector<std::string>(argv + 1, argv + argc), std::cout,
                                                           std::cerr);
}
