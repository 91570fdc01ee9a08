// Beam identification and ray-ray triangulation, ROS-free.
//
// Contract: input spots are distorted sub-pixel centroids (OpenCV pixel
// convention) of one frame of a camera described by a CameraModel; the
// projector is a ProjectorCalibration (one ray per beam, camera optical
// frame, metres). Output, per beam (row-major, r * cols + c): the 3D point in
// the camera optical frame (metres; NaN when the beam has no accepted dot),
// the spot index it came from, the ray gap (metres) and the spot intensity.
// Depth means the z coordinate in the camera optical frame.
//
// Identification ("epipolar"): the dot of beam i can only lie on the image of
// that beam between min_depth and max_depth (its epipolar segment). Spots are
// undistorted with the camera model first, so the segments are straight lines
// in the undistorted image. Spots and beams are matched by a global minimum-
// cost assignment (each beam may stay without a spot, each spot may be
// spurious) per connected component of the gated candidate graph. A pair is
// accepted only when every assignment without it costs at least
// `ambiguity_margin` more; ambiguous pairs are retried with a surface prior
// (the depth predicted from already accepted neighbouring beams) and are left
// unassigned if still ambiguous: a beam is never given a dot it cannot be
// proven to own. Beams of one grid row whose segments overlap on one line
// (rows parallel to the baseline) are read jointly, row with row: ordered
// readings of each row, chained across rows with a depth-smoothness cost
// and solved exactly (resolveLines). Accepted dots that contradict their
// accepted neighbours are dropped. "sort" is the study's method (rows of
// `cols` spots from the top, each sorted by x), kept for comparison.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/camera_model.h"
#include "structured_light_stabilizer/projector_calibration.h"
#include "structured_light_stabilizer/spot.h"

namespace structured_light_stabilizer
{

enum class BeamAssignment
{
  kEpipolar,  // epipolar segments + global assignment (default)
  kSort,      // the study's row sort: only right when every dot is present and in order
};

struct TriangulatorParams
{
  double min_depth = 0.8;  // metres, bounds of the epipolar segments and of accepted points
  double max_depth = 2.5;
  double max_epipolar_distance_px = 1.0;  // gate: spot distance to a beam's segment (undistorted px)
  double max_ray_gap = 0.004;             // metres: reject points whose camera and beam rays miss by more
  // Cost units are (distance / gate)^2, a missing beam or a spurious spot
  // costs 1 each. A pair is accepted when removing it costs >= this margin;
  // above 1, one spurious spot that happens to extend a shifted
  // interpretation of a row cannot make that interpretation win.
  double ambiguity_margin = 1.5;
  // Surface prior: tolerance (undistorted px along the segment) between a
  // spot and the position predicted from accepted neighbouring beams. Used to
  // settle ambiguous pairs and to drop accepted dots that contradict their
  // neighbours (spurious spots on the segment of a missing dot). 0 disables
  // both (ambiguous pairs are then rejected).
  double prediction_tolerance_px = 5.0;
  BeamAssignment assignment = BeamAssignment::kEpipolar;
  // Tracking prior (process() with a previous result): expected motion of a
  // dot between two frames beyond the common image shift of the pattern
  // (undistorted px). A beam whose only candidate lies within this radius of
  // where its dot was last frame (plus the common shift) is accepted first;
  // a beam that had a dot last frame is not given a spot farther than this.
  double tracking_radius_px = 1.5;

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
  int valid_points = 0;      // beams with a point
  int dropped_nan = 0;       // spots with a non-finite centroid (ignored)
  int ambiguous = 0;         // candidate pairs left unassigned because they could not be proven
  int rejected_gap = 0;      // assigned beams whose ray gap exceeded max_ray_gap
  int rejected_depth = 0;    // assigned beams triangulated outside [min_depth, max_depth]
  int unassigned_spots = 0;  // spots that are spurious, ambiguous or outside every gate
  int tracked = -1;          // beams settled by the tracking prior; -1 = no usable prior
  double mean_ray_gap = 0.0; // metres, over the valid points (0 when none)
};

// Closest approach of the camera ray (through the camera centre along
// `camera_ray`) and a beam ray. Returns false when the rays are (nearly)
// parallel. *point is the point on the BEAM ray closest to the camera ray:
// the dot physically lies on the beam, and the camera ray carries the
// centroid noise, whose component across the epipolar line says nothing
// about depth (the midpoint would pull the point off the beam by half the
// gap). *gap is the distance between the two rays (metres). In the study's
// geometry (both rays in one plane) the gap is zero and the point is that of
// formulas 2.27-2.30.
bool triangulateBeam(const Eigen::Vector3d& camera_ray, const BeamRay& beam, Eigen::Vector3d* point,
                     double* gap);

// The study's row sort (§2.4.2/§3.4; spot_detector.h's sortIntoRows): the
// `cols` topmost spots form a row, sorted by x, then the next `cols`, ...
// Returns the spot indices in beam order.
std::vector<int> rowSortOrder(const Spots& spots, int cols);

// Image of each beam between two depths, in undistorted pixel coordinates
// (fx * x/z + cx, fy * y/z + cy).
struct EpipolarSegment
{
  Eigen::Vector2d near_px = Eigen::Vector2d::Zero();  // at min_depth
  Eigen::Vector2d far_px = Eigen::Vector2d::Zero();   // at max_depth
};

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
  // none. Only the epipolar assignment uses it.
  TriangulationResult process(const Spots& spots, const TriangulationResult* previous) const;

  // Beam of every spot (-1 = none) for already undistorted pixel positions
  // (NaN entries are ignored). *ambiguous counts the pairs left unassigned
  // because an alternative of nearly equal cost exists. `previous_px`
  // (optional, per beam, undistorted px, NaN = no dot) is the tracking prior.
  // *tracked (optional) receives how many beams the prior settled (-1 when
  // it was not usable).
  std::vector<int> assignEpipolar(const std::vector<Eigen::Vector2d>& undistorted_px, int* ambiguous,
                                  const std::vector<Eigen::Vector2d>* previous_px = nullptr,
                                  int* tracked = nullptr) const;

  // Undistorted pixel position of a distorted pixel (NaN in, NaN out).
  Eigen::Vector2d undistortPixel(double x, double y) const;

  const CameraModel& camera() const { return camera_; }
  const ProjectorCalibration& projector() const { return projector_; }
  const TriangulatorParams& params() const { return params_; }
  const std::vector<EpipolarSegment>& segments() const { return segments_; }
  // Median image distance between the segment midpoints of neighbouring
  // beams (undistorted px; 0 for a single beam). A dot read as its row
  // neighbour's moves by about this much.
  double beamPitchPx() const { return beam_pitch_px_; }

private:
  Eigen::Vector2d projectUndistorted(const Eigen::Vector3d& p) const;
  // Undistorted pixel where beam i meets the plane through `support` points
  // (or the fronto-parallel plane at their mean depth); false if none.
  bool predictPixel(int beam, const std::vector<Eigen::Vector3d>& support, Eigen::Vector2d* px) const;

  // Support of the surface prior of `beam`: 2 when accepted neighbours
  // (8-neighbourhood) lie on opposite sides, 1 when only one side has them
  // (then *support holds the accepted beams within two rows/columns, >= 3),
  // 0 when there is too little; *support receives their points.
  int supportOf(int beam, const std::vector<int>& spot_of_beam, const std::vector<Eigen::Vector3d>& accepted_point,
                  std::vector<Eigen::Vector3d>* support) const;
  // Drops accepted pairs that disagree with the surface of their neighbours.
  // Pairs flagged in `proven` (settled by resolveLines) are not revisited.
  void rejectInconsistent(const std::vector<Eigen::Vector2d>& spots_px, const std::vector<char>& contested,
                          const std::vector<char>& proven, std::vector<int>* spot_of_beam,
                          std::vector<int>* beam_of_spot, std::vector<Eigen::Vector3d>* accepted_point) const;

  // Point of `beam` for an undistorted spot pixel; false when the rays are parallel.
  bool triangulatePixel(int beam, const Eigen::Vector2d& px, Eigen::Vector3d* p) const;
  // Smoothness cost (0..1) between the dot of `beam` at pixel `px` and a
  // grid neighbour's point `q` (8-neighbourhood): squared distance, in units
  // of half the beam pitch in the image, between px and where the beam would
  // be at q's depth, capped at 1 (a depth edge costs as much as a missing
  // dot; a dot read as its neighbour's, shifted by one pitch, costs the cap).
  double smoothnessCost(int beam, const Eigen::Vector2d& px, const Eigen::Vector3d& q) const;
  // Joint reading of the grid lines whose beams share an epipolar line (rows
  // parallel to the baseline): `lines` are the candidate-graph components
  // that lie on one grid row (or column). Each line gets a few ordered
  // readings (order-preserving matchings along the line by dynamic
  // programming, with depth smoothness between neighbouring beams: the best
  // one, the best through every candidate pair, the best without each pair
  // of the best one); the lines are chained (row r next to r + 1, smoothness
  // over the 8-neighbourhood) and solved exactly by min-sum dynamic
  // programming; a second round adds the readings that are best given the
  // neighbouring lines' optimum. A pair is accepted when every reading
  // without it costs at least ambiguity_margin more (min-marginals) and its
  // group of dots cannot slide along the line (a free beam next to it and
  // no smooth link to dots that cannot slide: an object in front of the
  // rock). Accepted beams are flagged in *proven. Returns how many.
  int resolveLines(const std::vector<std::pair<std::vector<int>, std::vector<int>>>& lines,
                   const std::vector<Eigen::Vector2d>& spots_px, std::vector<int>* spot_of_beam,
                   std::vector<int>* beam_of_spot, std::vector<Eigen::Vector3d>* accepted_point,
                   std::vector<char>* proven) const;

  CameraModel camera_;
  ProjectorCalibration projector_;
  TriangulatorParams params_;
  std::vector<EpipolarSegment> segments_;
  double beam_pitch_px_ = 0.0;
  double smoothness_scale_px_ = 10.0;  // see the constructor
};

}  // namespace structured_light_stabilizer
