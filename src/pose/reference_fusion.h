// The reference surface fused from the lock period (docs/pose_delta.md,
// "Reference"): a smooth surface fitted to rock points scattered over it,
// the lock's dots and those of later frames moved back into the reference
// frame by their poses. Private to the pose stage.
//
// Contract: points in the reference camera frame (metres; NaN or behind the
// camera skipped). The surface is a BeamSurface on a regular grid of camera
// rays of the reference frame (normalised image coordinates) spanning the
// points, `refine` nodes per median spacing of the lock's dot map; each
// node's depth along its ray is fitted by least squares to the points
// around it, the surface between the nodes being the Catmull-Rom
// interpolation BeamSurface evaluates, with a weak prior on the second
// differences of the depths where the points leave a node free; a node with
// no point within 1.5 nodes is missing (NaN). Returns false when the points
// do not support a surface. Throws nothing.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/pose/beam_surface.h"

namespace structured_light_stabilizer
{
namespace fusion
{

struct SurfaceFit
{
  double spacing_m = 0.05;  // the lock's dot spacing (BeamSurface::medianSpacing())
  int refine = 3;           // grid nodes per dot spacing
  double noise_m = 1e-4;    // 1-sigma of a point's depth
  // 1-sigma of a second difference of the depths across three nodes: the
  // rock's curvature the prior allows (a node spacing of 1.7 cm on relief of
  // 10-40 cm features leaves several millimetres).
  double curvature_m = 0.003;
  double max_edge_ratio = 3.0;  // BeamSurface::build's
};

bool fitSurface(const std::vector<Eigen::Vector3d>& points, const SurfaceFit& fit, BeamSurface* surface);

}  // namespace fusion
}  // namespace structured_light_stabilizer
