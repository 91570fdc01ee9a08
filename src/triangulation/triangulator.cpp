#include "structured_light_stabilizer/triangulation/triangulator.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "triangulation/epipolar_assignment.h"
#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/detection/spot_detector.h"

namespace structured_light_stabilizer
{

namespace
{

// The params, once the camera, the projector and they are known to be
// usable (the geometry is built from them next).
const TriangulatorParams& checked(const CameraModel& camera, const ProjectorCalibration& projector,
                                  const TriangulatorParams& params)
{
  std::string why = camera.validate();
  if (!why.empty())
    throw std::invalid_argument("camera model: " + why);
  why = projector.validate();
  if (!why.empty())
    throw std::invalid_argument("projector calibration: " + why);
  why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("triangulator config: " + why);
  return params;
}

// Reconciles the single-frame identification with the one made with the
// tracking prior. Each can be wrong where the other is right. On a grid
// whose rows are parallel to the baseline, a depth change of one beam pitch
// of disparity between two frames makes the pattern look unmoved, each dot
// where its row neighbour was: the prior then reads every row shifted by a
// column, which the single frame (seeing the rows' ends) does not.
// Conversely the single frame may read an object's dots shifted along their
// rows where the prior does not. A spot the two give to different beams is
// given to none; when that happens to more than max(2, half the spots they
// agree on), only the pairs both agree on are kept and the prior counts as
// not used. Returns whether the prior is trusted.
bool reconcile(const std::vector<int>& with_prior, const std::vector<Eigen::Vector2d>& previous_px,
               std::vector<int>* beam_of_spot)
{
  std::vector<int>& single = *beam_of_spot;
  int agree = 0, disagree = 0;
  for (size_t j = 0; j < single.size(); ++j)
    if (single[j] >= 0 && with_prior[j] >= 0)
      (single[j] == with_prior[j] ? agree : disagree) += 1;
  const bool trusted = disagree <= std::max(2, agree / 2);
  for (size_t j = 0; j < single.size(); ++j)
  {
    // A beam without a prior gets only what the single frame proves.
    const bool unprimed = with_prior[j] >= 0 && !previous_px[with_prior[j]].allFinite();
    const bool conflict = (single[j] >= 0 && with_prior[j] >= 0 && single[j] != with_prior[j]) ||
                          (unprimed && single[j] != with_prior[j]);
    if (conflict || (!trusted && single[j] != with_prior[j]))
      single[j] = -1;
    else if (trusted)
      single[j] = with_prior[j];
  }
  return trusted;
}

}  // namespace

std::string TriangulatorParams::validate() const
{
  std::ostringstream why;
  if (!(min_depth > 0.0) || !(max_depth > min_depth) || !std::isfinite(max_depth))
    why << "depth range [" << min_depth << ", " << max_depth << "] m must satisfy 0 < min < max; ";
  if (!(max_epipolar_distance_px > 0.0) || !std::isfinite(max_epipolar_distance_px))
    why << "max_epipolar_distance_px = " << max_epipolar_distance_px << " must be > 0; ";
  if (!(max_ray_gap > 0.0) || !std::isfinite(max_ray_gap))
    why << "max_ray_gap = " << max_ray_gap << " m must be > 0; ";
  if (!(ambiguity_margin >= 0.0) || !std::isfinite(ambiguity_margin))
    why << "ambiguity_margin = " << ambiguity_margin << " must be >= 0; ";
  if (!(prediction_tolerance_px >= 0.0) || !std::isfinite(prediction_tolerance_px))
    why << "prediction_tolerance_px = " << prediction_tolerance_px << " must be >= 0; ";
  if (!(tracking_radius_px > 0.0) || !std::isfinite(tracking_radius_px))
    why << "tracking_radius_px = " << tracking_radius_px << " must be > 0; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

bool triangulateBeam(const Eigen::Vector3d& camera_ray, const BeamRay& beam, Eigen::Vector3d* point, double* gap)
{
  const Eigen::Vector3d v = camera_ray.normalized();
  const Eigen::Vector3d u = beam.direction.normalized();
  const Eigen::Vector3d& o = beam.origin;
  // Minimise |o + s u - t v|^2 over the beam parameter s and the camera-ray
  // parameter t (camera centre at the origin).
  const double b = u.dot(v);
  const double denom = 1.0 - b * b;
  if (!(denom > 1e-12))
    return false;
  const double t = (v.dot(o) - b * u.dot(o)) / denom;
  const double s = t * b - u.dot(o);
  const Eigen::Vector3d on_beam = o + s * u;
  if (point)
    *point = on_beam;
  if (gap)
    *gap = (on_beam - t * v).norm();
  return std::isfinite(s) && std::isfinite(t);
}

std::vector<int> rowSortOrder(const Spots& spots, int cols)
{
  // The detector's sort reorders the spots themselves; tag them with their
  // index to read the order back.
  Spots tagged = spots;
  for (size_t k = 0; k < tagged.size(); ++k)
    tagged[k].beam = static_cast<int>(k);
  sortIntoRows(&tagged, cols, 0, false);
  std::vector<int> order(tagged.size());
  for (size_t k = 0; k < tagged.size(); ++k)
    order[k] = tagged[k].beam;
  return order;
}

Triangulator::Triangulator(const CameraModel& camera, const ProjectorCalibration& projector,
                           const TriangulatorParams& params)
  : params_(checked(camera, projector, params)),
    geometry_(camera, projector, params.min_depth, params.max_depth, params.prediction_tolerance_px)
{
}

EpipolarAssignment Triangulator::assignEpipolar(const std::vector<Eigen::Vector2d>& undistorted_px,
                                                const std::vector<Eigen::Vector2d>* previous_px) const
{
  return detail::assignEpipolar(geometry_, params_, undistorted_px, previous_px);
}

TriangulationResult Triangulator::process(const Spots& spots) const
{
  return process(spots, nullptr);
}

TriangulationResult Triangulator::process(const Spots& spots, const TriangulationResult* previous) const
{
  const int n_beams = geometry_.beamCount();
  TriangulationResult res;
  res.points.assign(n_beams, Eigen::Vector3d::Constant(detail::kNaN));
  res.ray_gap.assign(n_beams, detail::kNaN);
  res.intensity.assign(n_beams, 0.0f);
  res.spot_of_beam.assign(n_beams, -1);
  res.beam_of_spot.assign(spots.size(), -1);

  std::vector<Eigen::Vector2d> undistorted(spots.size());
  for (size_t j = 0; j < spots.size(); ++j)
  {
    undistorted[j] = geometry_.undistortPixel(spots[j].x, spots[j].y);
    if (!undistorted[j].allFinite())
      ++res.dropped_nan;
  }
  if (params_.assignment == BeamAssignment::kSort)
  {
    triangulateAssigned(spots, undistorted, assignBySort(spots, undistorted), &res);
    return res;
  }
  const EpipolarAssignment assigned = assignWithPrior(undistorted, previous);
  res.ambiguous = assigned.ambiguous;
  res.tracked = assigned.tracked;
  triangulateAssigned(spots, undistorted, assigned.beam_of_spot, &res);
  res.predicted.assign(n_beams, Eigen::Vector3d::Constant(detail::kNaN));
  for (int i = 0; i < static_cast<int>(assigned.track_px.size()); ++i)
  {
    Eigen::Vector3d p;
    if (!res.points[i].allFinite() && assigned.track_px[i].allFinite() &&
        geometry_.triangulatePixel(i, assigned.track_px[i], &p))
      res.predicted[i] = p;
  }
  return res;
}

// The study's sort of the finite spots: the k-th in row order is beam k.
std::vector<int> Triangulator::assignBySort(const Spots& spots, const std::vector<Eigen::Vector2d>& undistorted) const
{
  Spots finite;
  std::vector<int> index;
  for (size_t j = 0; j < spots.size(); ++j)
  {
    if (undistorted[j].allFinite())
    {
      finite.push_back(spots[j]);
      index.push_back(static_cast<int>(j));
    }
  }
  std::vector<int> beam_of_spot(spots.size(), -1);
  const std::vector<int> order = rowSortOrder(finite, geometry_.cols());
  for (size_t k = 0; k < order.size() && static_cast<int>(k) < geometry_.beamCount(); ++k)
    beam_of_spot[index[order[k]]] = static_cast<int>(k);
  return beam_of_spot;
}

// The single-frame identification, reconciled with the one made with the
// tracking prior when `previous` gives one (see process()).
EpipolarAssignment Triangulator::assignWithPrior(const std::vector<Eigen::Vector2d>& undistorted,
                                                 const TriangulationResult* previous) const
{
  const int n_beams = geometry_.beamCount();
  EpipolarAssignment single = assignEpipolar(undistorted);
  if (!previous || static_cast<int>(previous->points.size()) != n_beams)
    return single;
  std::vector<Eigen::Vector2d> previous_px(n_beams, Eigen::Vector2d::Constant(detail::kNaN));
  std::vector<uint8_t> remembered(n_beams, 0);
  for (int i = 0; i < n_beams; ++i)
  {
    if (previous->points[i].allFinite() && previous->points[i].z() > 0.0)
      previous_px[i] = geometry_.projectUndistorted(previous->points[i]);
    remembered[i] = i < static_cast<int>(previous->predicted.size()) && previous->predicted[i].allFinite();
  }
  const EpipolarAssignment tracked = detail::assignEpipolar(geometry_, params_, undistorted, &previous_px, &remembered);
  if (tracked.tracked < 0 || !reconcile(tracked.beam_of_spot, previous_px, &single.beam_of_spot))
    return single;
  single.ambiguous = tracked.ambiguous;
  single.tracked = tracked.tracked;
  single.track_px = tracked.track_px;
  return single;
}

// Triangulates every assigned spot and keeps the points that pass the ray
// gap and depth checks; fills the per-beam outputs and the counters.
void Triangulator::triangulateAssigned(const Spots& spots, const std::vector<Eigen::Vector2d>& undistorted,
                                       const std::vector<int>& beam_of_spot, TriangulationResult* res) const
{
  double gap_sum = 0.0;
  for (size_t j = 0; j < spots.size(); ++j)
  {
    const int i = beam_of_spot[j];
    if (i < 0)
    {
      ++res->unassigned_spots;
      continue;
    }
    Eigen::Vector3d p;
    double gap = 0.0;
    if (!triangulateBeam(geometry_.cameraRay(undistorted[j]), geometry_.projector().beams[i], &p, &gap) ||
        !(gap <= params_.max_ray_gap))
    {
      ++res->rejected_gap;
      continue;
    }
    if (!(p.z() >= params_.min_depth && p.z() <= params_.max_depth))
    {
      ++res->rejected_depth;
      continue;
    }
    res->points[i] = p;
    res->ray_gap[i] = gap;
    res->intensity[i] = spots[j].intensity;
    res->spot_of_beam[i] = static_cast<int>(j);
    res->beam_of_spot[j] = i;
    ++res->valid_points;
    gap_sum += gap;
  }
  res->mean_ray_gap = res->valid_points > 0 ? gap_sum / res->valid_points : 0.0;
}

}  // namespace structured_light_stabilizer
