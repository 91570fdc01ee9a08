// Beam identification and ray-ray triangulation, ROS-free.
//
// Contract: input spots are distorted sub-pixel centroids (OpenCV pixel
// convention) of one frame of a camera described by a CameraModel; the
// projector is a ProjectorCalibration (one ray per beam, camera optical
// frame, metres). Output, per beam (row-major, r * cols + c): the 3D point in
// the camera optical frame (metres; NaN when the beam has no accepted dot),
// the spot index it came from, the ray gap (metres) and the spot intensity.
// Depth means the z coordinate in the camera optical frame. A Triangulator
// is immutable after construction: its const methods may be called from
// several threads at once.
//
// Identification ("epipolar"; docs/triangulator.md): the dot of beam i can
// only lie on the image of that beam between min_depth and max_depth (its
// epipolar segment). Spots are undistorted with the camera model first, so
// the segments are straight lines in the undistorted image. The stages:
//  1. gating: the candidate pairs (spot within the gate of a segment);
//  2. tracking prior (optional): beams whose dot is where last frame's dot
//     moved to are settled first (tracking_prior.cpp);
//  3. per connected component of the candidate graph, a global minimum-cost
//     assignment (hungarian.h; each beam may stay without a spot, each spot
//     may be spurious). A pair is accepted only when every assignment
//     without it costs at least `ambiguity_margin` more; ambiguous pairs are
//     retried with a surface prior (the depth predicted from already
//     accepted neighbouring beams) and are left unassigned if still
//     ambiguous: a beam is never given a dot it cannot be proven to own.
//     Beams of one grid row whose segments overlap on one line (rows
//     parallel to the baseline) are read jointly, row with row: ordered
//     readings of each row, chained across rows with a depth-smoothness cost
//     and solved exactly (line_reader.cpp);
//  4. neighbour check: accepted dots that contradict their accepted
//     neighbours are dropped (surface_prior.cpp).
// "sort" is the study's method (rows of `cols` spots from the top, each
// sorted by x), kept for comparison.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/triangulation/beam_geometry.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/common/params.h"
#include "structured_light_stabilizer/common/spot.h"

namespace structured_light_stabilizer
{

enum class BeamAssignment
{
  kEpipolar,  // epipolar segments + global assignment (default)
  kSort,      // the study's row sort: only right when every dot is present and in order
};

struct TriangulatorParams
{
#define SLS_PARAMS_STRUCT TriangulatorParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/triangulation/triangulator_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  // Empty when usable, otherwise why not.
  std::string validate() const;
};

struct TriangulationResult
{
  std::vector<Eigen::Vector3d> points;  // per beam; NaN = no valid point
  std::vector<double> ray_gap;          // per beam, metres; NaN = no point
  std::vector<float> intensity;         // per beam, from the spot; 0 = no point
  std::vector<int> spot_of_beam;        // per beam, index into the input spots; -1 = none
  std::vector<int> beam_of_spot;        // per spot, accepted beam; -1 = none
  int valid_points = 0;                 // beams with a point
  int dropped_nan = 0;                  // spots with a non-finite centroid (ignored)
  int ambiguous = 0;                    // candidate pairs left unassigned because they could not be proven
  int rejected_gap = 0;                 // assigned beams whose ray gap exceeded max_ray_gap
  int rejected_depth = 0;               // assigned beams triangulated outside [min_depth, max_depth]
  int unassigned_spots = 0;             // spots that are spurious, ambiguous or outside every gate
  int tracked = -1;                     // beams settled by the tracking prior; -1 = no usable prior
  double mean_ray_gap = 0.0;            // metres, over the valid points (0 when none)
  // Per beam without a point this frame but with a tracking prior: the
  // point of the beam where the prior predicted its dot (NaN otherwise).
  // BeamTracker carries it to the next frame as the beam's prior, so a dot
  // missing for a few frames keeps its protection against spurious spots.
  std::vector<Eigen::Vector3d> predicted;
};

// Outcome of the epipolar identification alone (no triangulation).
struct EpipolarAssignment
{
  std::vector<int> beam_of_spot;  // per spot, beam; -1 = none
  int ambiguous = 0;              // pairs left unassigned because an alternative of nearly equal cost exists
  int tracked = -1;               // beams settled by the tracking prior; -1 = the prior was not usable (or none)
  std::vector<Eigen::Vector2d> track_px;  // per beam, the prior's prediction (undistorted px); empty or NaN = none
};

// Closest approach of the camera ray (through the camera centre along
// `camera_ray`) and a beam ray. Returns false when the rays are (nearly)
// parallel. *point is the point on the BEAM ray closest to the camera ray:
// the dot physically lies on the beam, and the camera ray carries the
// centroid noise, whose component across the epipolar line says nothing
// about depth (the midpoint would pull the point off the beam by half the
// gap). *gap is the distance between the two rays (metres). In the study's
// geometry (both rays in one plane) the gap is zero and the point is that of
// formulas 2.27-2.30 (docs/study.md §2.3).
bool triangulateBeam(const Eigen::Vector3d& camera_ray, const BeamRay& beam, Eigen::Vector3d* point, double* gap);

// The study's row sort (docs/study.md §2.4.2, §3.4; spot_detector.h's
// sortIntoRows): the `cols` topmost spots form a row, sorted by x, then the
// next `cols`, ... Returns the spot indices in beam order.
std::vector<int> rowSortOrder(const Spots& spots, int cols);

class Triangulator
{
public:
  // Throws std::invalid_argument when the camera, the projector or the
  // params are unusable (the message says which and why).
  Triangulator(const CameraModel& camera, const ProjectorCalibration& projector,
               const TriangulatorParams& params = TriangulatorParams());

  TriangulationResult process(const Spots& spots) const;
  // With a tracking prior: `previous` is this Triangulator's result for the
  // previous frame of the same camera and projector (its points give where
  // each beam's dot was). The prior is used only when at least half of the
  // beams that had a point last frame (and >= 3) find a single candidate
  // near their previous position after removing the pattern's median shift;
  // otherwise (a jump, a new scene) this is process(spots). The single-frame
  // solution is computed too and reconciled: a spot the two give to
  // different beams goes to none, a beam without a prior gets only what the
  // single frame proves, and when they disagree on more than max(2, half
  // the spots they agree on) only their common pairs are kept (tracked =
  // -1): on an axis-aligned grid a depth change of one beam pitch of
  // disparity between frames makes the pattern look unmoved. nullptr =
  // none. Only the epipolar assignment uses it. BeamTracker (beam_tracker.h)
  // keeps `previous` from frame to frame.
  TriangulationResult process(const Spots& spots, const TriangulationResult* previous) const;

  // Beam of every spot for already undistorted pixel positions (NaN entries
  // are ignored). `previous_px` (optional, per beam, undistorted px, NaN = no
  // dot) is the tracking prior.
  EpipolarAssignment assignEpipolar(const std::vector<Eigen::Vector2d>& undistorted_px,
                                    const std::vector<Eigen::Vector2d>* previous_px = nullptr) const;

  // Undistorted pixel position of a distorted pixel (NaN in, NaN out).
  Eigen::Vector2d undistortPixel(double x, double y) const { return geometry_.undistortPixel(x, y); }

  const CameraModel& camera() const { return geometry_.camera(); }
  const ProjectorCalibration& projector() const { return geometry_.projector(); }
  const TriangulatorParams& params() const { return params_; }
  const std::vector<EpipolarSegment>& segments() const { return geometry_.segments(); }
  // Median image distance between the segment midpoints of neighbouring
  // beams (undistorted px; 0 for a single beam). A dot read as its row
  // neighbour's moves by about this much.
  double beamPitchPx() const { return geometry_.beamPitchPx(); }

private:
  std::vector<int> assignBySort(const Spots& spots, const std::vector<Eigen::Vector2d>& undistorted) const;
  EpipolarAssignment assignWithPrior(const std::vector<Eigen::Vector2d>& undistorted,
                                     const TriangulationResult* previous) const;
  void triangulateAssigned(const Spots& spots, const std::vector<Eigen::Vector2d>& undistorted,
                           const std::vector<int>& beam_of_spot, TriangulationResult* res) const;

  TriangulatorParams params_;
  detail::BeamGeometry geometry_;
};

}  // namespace structured_light_stabilizer
