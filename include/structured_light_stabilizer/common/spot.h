// A detected dot, ROS-free mirror of structured_light_stabilizer/Centroid.
#pragma once

#include <vector>

namespace structured_light_stabilizer
{

struct Spot
{
  double x = 0.0;          // sub-pixel column (pixel centres at integers)
  double y = 0.0;          // sub-pixel row
  float area = 0.0f;       // pixels in the spot after segmentation
  float intensity = 0.0f;  // sum of the centroid weights
  int beam = -1;           // projector beam index (row-major), -1 = not assigned
};

using Spots = std::vector<Spot>;

}  // namespace structured_light_stabilizer
