#include "structured_light_stabilizer/triangulation/beam_geometry.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>

#include "structured_light_stabilizer/common/math.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace structured_light_stabilizer
{
namespace detail
{

BeamGeometry::BeamGeometry(const CameraModel& camera, const ProjectorCalibration& projector, double min_depth,
                           double max_depth, double prediction_tolerance_px)
  : camera_(camera), projector_(projector)
{
  segments_.resize(projector_.beams.size());
  for (int i = 0; i < static_cast<int>(projector_.beams.size()); ++i)
  {
    // The beam parameterised by camera depth: direction z > 0 is guaranteed
    // by ProjectorCalibration::validate().
    segments_[i].near_px = pixelAtDepth(i, min_depth);
    segments_[i].far_px = pixelAtDepth(i, max_depth);
  }
  // Smoothness scale: half the image distance between neighbouring beams
  // (median over the grid, at mid-range depth), so that reading a dot as its
  // neighbour's (a shift by one column) costs the cap while the relief
  // between neighbours costs little at any depth. Without neighbours: twice
  // the prediction tolerance.
  std::vector<double> pitch;
  const auto mid = [&](int i) { return 0.5 * (segments_[i].near_px + segments_[i].far_px); };
  for (int i = 0; i < beamCount(); ++i)
  {
    if ((i + 1) % cols() != 0)
      pitch.push_back((mid(i + 1) - mid(i)).norm());
    if (i + cols() < beamCount())
      pitch.push_back((mid(i + cols()) - mid(i)).norm());
  }
  beam_pitch_px_ = medianInPlace(pitch.begin(), pitch.end());
  smoothness_scale_px_ = beam_pitch_px_ > 0.0 ? 0.5 * beam_pitch_px_ : 2.0 * prediction_tolerance_px;
}

double BeamGeometry::segmentDistance2(int beam, const Eigen::Vector2d& px) const
{
  const Eigen::Vector2d& a = segments_[beam].near_px;
  const Eigen::Vector2d ab = segments_[beam].far_px - a;
  const double len2 = ab.squaredNorm();
  double t = len2 > 0.0 ? (px - a).dot(ab) / len2 : 0.0;
  t = std::min(1.0, std::max(0.0, t));
  return (a + t * ab - px).squaredNorm();
}

Eigen::Vector2d BeamGeometry::projectUndistorted(const Eigen::Vector3d& p) const
{
  return Eigen::Vector2d(camera_.fx * p.x() / p.z() + camera_.cx, camera_.fy * p.y() / p.z() + camera_.cy);
}

Eigen::Vector2d BeamGeometry::undistortPixel(double x, double y) const
{
  if (!std::isfinite(x) || !std::isfinite(y))
    return Eigen::Vector2d(kNaN, kNaN);
  const Eigen::Vector2d n = camera_.normalize(cv::Point2d(x, y));
  return Eigen::Vector2d(camera_.fx * n.x() + camera_.cx, camera_.fy * n.y() + camera_.cy);
}

Eigen::Vector3d BeamGeometry::cameraRay(const Eigen::Vector2d& px) const
{
  return Eigen::Vector3d((px.x() - camera_.cx) / camera_.fx, (px.y() - camera_.cy) / camera_.fy, 1.0);
}

Eigen::Vector2d BeamGeometry::pixelAtDepth(int beam, double z) const
{
  const BeamRay& b = projector_.beams[beam];
  return projectUndistorted(b.pointAt((z - b.origin.z()) / b.direction.z()));
}

bool BeamGeometry::triangulatePixel(int beam, const Eigen::Vector2d& px, Eigen::Vector3d* p) const
{
  double gap = 0.0;
  return triangulateBeam(cameraRay(px), projector_.beams[beam], p, &gap);
}

double BeamGeometry::smoothnessCost(int beam, const Eigen::Vector2d& px, const Eigen::Vector3d& q) const
{
  const double e = (pixelAtDepth(beam, q.z()) - px).norm() / smoothness_scale_px_;
  return std::isfinite(e) ? std::min(1.0, e * e) : 1.0;
}

bool BeamGeometry::predictPixel(int beam, const std::vector<Eigen::Vector3d>& support, Eigen::Vector2d* px) const
{
  if (support.empty())
    return false;
  const BeamRay& b = projector_.beams[beam];
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : support)
    centroid += p;
  centroid /= static_cast<double>(support.size());
  // Local plane through the neighbours when they span one, else the
  // fronto-parallel plane at their mean depth.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  if (support.size() >= 3)
  {
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (const auto& p : support)
      cov += (p - centroid) * (p - centroid).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es;
    es.computeDirect(cov);
    // Collinear supports (smallest two eigenvalues tiny) give no plane.
    if (es.eigenvalues()(1) > 1e-2 * es.eigenvalues()(2))
      normal = es.eigenvectors().col(0);
  }
  const double denom = normal.dot(b.direction);
  if (std::abs(denom) < 1e-6)
    return false;
  const double s = normal.dot(centroid - b.origin) / denom;
  const Eigen::Vector3d hit = b.pointAt(s);
  if (!(hit.z() > 0.0))
    return false;
  *px = projectUndistorted(hit);
  return px->allFinite();
}

void BeamGeometry::neighbours(int beam, int out[8]) const
{
  const int r = beam / cols(), c = beam % cols();
  int n = 0;
  for (int dr = -1; dr <= 1; ++dr)
    for (int dc = -1; dc <= 1; ++dc)
      if (dr != 0 || dc != 0)
        out[n++] = r + dr >= 0 && r + dr < rows() && c + dc >= 0 && c + dc < cols() ? (r + dr) * cols() + c + dc : -1;
}

}  // namespace detail
}  // namespace structured_light_stabilizer
