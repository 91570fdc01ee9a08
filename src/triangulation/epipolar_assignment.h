// Internal to the Triangulator's epipolar identification (triangulator.h
// gives the contract and the order of the stages). Pixels are undistorted,
// points in the camera optical frame (metres), beams row-major.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/triangulation/beam_geometry.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace structured_light_stabilizer
{
namespace detail
{

// A spot within the gate of a beam's epipolar segment.
struct Candidate
{
  int beam;
  int spot;
  double cost;  // (distance / gate)^2, in [0, 1]
};

// The gated candidate pairs, listed per beam and per spot (indices into
// `pairs`). Stages may remove pairs from the lists, never from `pairs`.
struct CandidateGraph
{
  std::vector<Candidate> pairs;
  std::vector<std::vector<int>> of_beam, of_spot;
};

// Open beams and spots linked by candidate pairs.
struct Component
{
  std::vector<int> beams, spots;
};

// The beam <-> spot pairs accepted so far, as every stage reads and extends
// them.
struct Assignment
{
  Assignment(int n_beams, int n_spots);

  std::vector<int> spot_of_beam;                // -1 = none
  std::vector<int> beam_of_spot;                // -1 = none
  std::vector<Eigen::Vector3d> accepted_point;  // per beam, NaN = none
  // Per beam: its pair was contested (the beam, or one of its candidate
  // spots, had more than one candidate) and settled with the surface prior;
  // only neighbours can confirm such a pair.
  std::vector<char> contested;
  // Per beam: settled by the joint line reading, which already compared it
  // with its neighbours (the neighbour check leaves it).
  std::vector<char> proven;

  void accept(int beam, int spot, const Eigen::Vector3d& point);
  void drop(int beam);
};

// The whole identification (epipolar_assigner.cpp): Triangulator::assignEpipolar.
EpipolarAssignment assignEpipolar(const BeamGeometry& geometry, const TriangulatorParams& params,
                                  const std::vector<Eigen::Vector2d>& spots_px,
                                  const std::vector<Eigen::Vector2d>* previous_px,
                                  const std::vector<uint8_t>* remembered = nullptr);

// Stage 1 (epipolar_assigner.cpp): every spot within `gate_px` of a
// segment. NaN spots have no candidates.
CandidateGraph gateCandidates(const BeamGeometry& geometry, const std::vector<Eigen::Vector2d>& spots_px,
                              double gate_px);

// The radius around a tracked dot's prediction: tracking_sigmas times the
// measured spread of this frame's tracked dots about the common motion,
// within [min_tracking_radius_px, tracking_radius_px]; tracking_radius_px
// when the spread is unknown (NaN) or tracking_sigmas is 0.
double trackingRadius(const TriangulatorParams& params, double spread_px);

// Stage 2 (tracking_prior.cpp): settles the beams whose dot is where last
// frame's dot (`previous_px`, per beam, NaN = none) moved to and removes the
// candidates of primed beams that lie far from it. Returns how many beams it
// settled, or -1 when the prior is not usable (nothing changed then).
// *track_px (when given): where each primed beam's dot is predicted in this
// frame (undistorted px; NaN for the others), filled when the prior is usable.
// `remembered` (optional, per beam): the previous position is itself a
// prediction (the dot was missing last frame; BeamTracker's memory).
int applyTrackingPrior(const BeamGeometry& geometry, const TriangulatorParams& params,
                       const std::vector<Eigen::Vector2d>& spots_px, const std::vector<Eigen::Vector2d>& previous_px,
                       CandidateGraph* graph, Assignment* assignment, std::vector<Eigen::Vector2d>* track_px = nullptr,
                       const std::vector<uint8_t>* remembered = nullptr);

// Stage 3b (line_reader.cpp): joint reading of the grid lines whose beams
// share an epipolar line. `lines` are candidate-graph components on one grid
// row (or column). Accepted pairs are flagged proven.
void readLines(const BeamGeometry& geometry, const TriangulatorParams& params,
               const std::vector<Eigen::Vector2d>& spots_px, const std::vector<Component>& lines,
               Assignment* assignment);

// Surface prior (surface_prior.cpp). Support of `beam`: 2 when accepted
// neighbours (8-neighbourhood) lie on opposite sides, 1 when only one side
// has them (then *support holds the accepted beams within two rows/columns,
// >= 3, spanning two rows and two columns), 0 when there is too little;
// *support receives their points.
int supportOf(const BeamGeometry& geometry, int beam, const Assignment& assignment,
              std::vector<Eigen::Vector3d>* support);

// Surface prior pixel (surface_prior.cpp) of every open beam with
// candidates, from its accepted neighbours: on both sides, or (`one_sided`)
// extrapolated from one side. NaN = no prior.
std::vector<Eigen::Vector2d> surfacePrior(const BeamGeometry& geometry, const CandidateGraph& graph,
                                          const Assignment& assignment, bool one_sided);

// Stage 4 (surface_prior.cpp): drops accepted pairs that disagree with the
// surface of their accepted neighbours; proven pairs are not revisited.
void rejectInconsistent(const BeamGeometry& geometry, double tolerance_px, const std::vector<Eigen::Vector2d>& spots_px,
                        Assignment* assignment);

}  // namespace detail
}  // namespace structured_light_stabilizer
