// Beam divergence and camera focus as one design (docs/daylight.md, "Beam
// and focus"): the relief floor of each pair of a beam's divergence and the
// camera's focus distance, ROS-free.
//
// A dot's light is the beam's irradiance over its footprint on the rock;
// on relief each part of the footprint meets the rock at its own depth and
// incidence, so the light's centroid is not the beam's hit point, whatever
// the detector does: the relief floor. A narrower beam averages less
// relief; the image still needs a dot of at least min_dot_sigma_px, which
// defocus can give (a blur spreads the light without moving its centroid):
// a narrower beam with the camera focused nearer than the rock.
//
// The floor is measured on the simulator (sim/render/simulator.h, its
// SimFrame::light_centroids against pixels): uniform albedo, no sun, no
// noise, the design's beam and focus, the options' relief, each distance
// with frames over rock seeds 1-`seeds` under +-10 mm / +-1 deg jitter (the
// dots on other parts of the rock). Relief finer than the simulator's 4 mm height
// grid is not rendered. Pure functions; throw std::invalid_argument on bad
// options.
#pragma once

#include <string>
#include <vector>

namespace structured_light_stabilizer
{

struct DesignInputs;

struct BeamDesignOptions
{
  std::vector<double> beam_sigma_rad = {0.5e-3, 0.75e-3, 1.0e-3, 1.5e-3};
  std::vector<double> focus_distance_m = {1.0, 0.5, 0.3, 0.25};
  double relief_m = 0.15;  // the rock's peak-to-peak relief
  int seeds = 2;           // rock seeds 1..seeds
  int frames = 2;          // per distance and rock seed
};

struct BeamDesign
{
  double beam_sigma_rad = 0.0;
  double focus_distance_m = 0.0;
  struct At
  {
    double distance_m = 0.0;
    double footprint_sigma_mm = 0.0;  // the beam on the rock
    double dot_sigma_px = 0.0;        // in the image, mean over the dots
    double floor_px = 0.0;            // RMS of the light's centroid from the hit point
    double floor_along_px = 0.0;      // its part along the epipolar line
    double depth_percent = 0.0;       // the depth error that part makes, RMS, % of z
    int dots = 0;
  };
  std::vector<At> at;  // at the conditions' nearest and farthest distance
  bool dot_ok = false;  // the dot's sigma reaches min_dot_sigma_px at every distance
};

// Every beam x focus of inputs.beams at the conditions' distances.
std::vector<BeamDesign> designBeams(const DesignInputs& inputs);
// As aligned text, with what each column is.
std::string formatBeamDesigns(const std::vector<BeamDesign>& designs, const DesignInputs& inputs);

}  // namespace structured_light_stabilizer
