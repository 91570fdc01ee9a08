#include "structured_light_stabilizer/calibration/projector_calibrator.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include <Eigen/Dense>
#include <yaml-cpp/yaml.h>

#include "calibration/calibration_geometry.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace structured_light_stabilizer
{

namespace
{

// Per beam: (view index, board point in the camera frame), in view order.
using BoardPoints = std::vector<std::vector<std::pair<size_t, Eigen::Vector3d>>>;

// Board plane of a view as (n, c) with n . p = c, n unit, facing the camera.
bool boardPlane(const BoardView& view, Eigen::Vector3d* n, double* c)
{
  if (view.plane_normal.squaredNorm() > 0.0)
  {
    const double len = view.plane_normal.norm();
    *n = view.plane_normal / len;
    *c = view.plane_offset / len;
  }
  else
  {
    *n = Eigen::Vector3d::UnitZ();
    *c = view.distance_m;
  }
  if (*c < 0.0)
  {
    *n = -*n;
    *c = -*c;
  }
  return std::isfinite(*c) && *c > 0.0 && n->allFinite();
}

// Beam id of every spot of a view: the spots' own ids, or the study's row
// sort when none is given and the view holds the full pattern.
bool viewBeamIds(const BoardView& view, int rows, int cols, std::vector<int>* ids, std::string* error)
{
  ids->assign(view.spots.size(), -1);
  bool any = false;
  for (size_t j = 0; j < view.spots.size(); ++j)
  {
    (*ids)[j] = view.spots[j].beam;
    any |= view.spots[j].beam >= 0;
  }
  if (any)
    return true;
  if (static_cast<int>(view.spots.size()) != rows * cols)
  {
    *error = "spots carry no beam ids and there are " + std::to_string(view.spots.size()) +
             " of them, not rows*cols = " + std::to_string(rows * cols) + " (cannot sort them into rows)";
    return false;
  }
  const std::vector<int> order = rowSortOrder(view.spots, cols);
  for (size_t k = 0; k < order.size(); ++k)
    (*ids)[order[k]] = static_cast<int>(k);
  return true;
}

std::string viewName(size_t v, const BoardView& view)
{
  std::ostringstream s;
  s << "view " << v;
  if (view.plane_normal.squaredNorm() == 0.0)
    s << " (board at " << view.distance_m << " m)";
  return s.str();
}

// Board points of every beam, in view order.
bool collectBoardPoints(const CameraModel& camera, const std::vector<BoardView>& views,
                        const BoardCalibrationParams& params, BoardPoints* per_beam, std::string* error)
{
  const int n_beams = params.rows * params.cols;
  per_beam->assign(n_beams, {});
  for (size_t v = 0; v < views.size(); ++v)
  {
    const BoardView& view = views[v];
    Eigen::Vector3d n;
    double c = 0.0;
    if (!boardPlane(view, &n, &c))
    {
      *error = viewName(v, view) + ": the board plane is not in front of the camera";
      return false;
    }
    std::vector<int> ids;
    std::string why;
    if (!viewBeamIds(view, params.rows, params.cols, &ids, &why))
    {
      *error = viewName(v, view) + ": " + why;
      return false;
    }
    std::vector<char> seen(n_beams, 0);
    for (size_t j = 0; j < view.spots.size(); ++j)
    {
      const int b = ids[j];
      if (b < 0)
        continue;
      if (b >= n_beams)
      {
        *error = viewName(v, view) + ": spot " + std::to_string(j) + " has beam " + std::to_string(b) +
                 " but the pattern has " + std::to_string(n_beams) + " beams";
        return false;
      }
      if (seen[b])
      {
        *error = viewName(v, view) + ": beam " + std::to_string(b) + " appears twice";
        return false;
      }
      seen[b] = 1;
      const Spot& s = view.spots[j];
      if (!std::isfinite(s.x) || !std::isfinite(s.y))
      {
        *error = viewName(v, view) + ": spot " + std::to_string(j) + " (beam " + std::to_string(b) + ") is NaN";
        return false;
      }
      const Eigen::Vector2d xy = camera.normalize(cv::Point2d(s.x, s.y));
      const Eigen::Vector3d ray(xy.x(), xy.y(), 1.0);
      const double denom = n.dot(ray);
      if (!(denom > 1e-9))
      {
        *error = viewName(v, view) + ": the ray of beam " + std::to_string(b) + " does not meet the board";
        return false;
      }
      (*per_beam)[b].push_back({v, ray * (c / denom)});
    }
  }
  return true;
}

bool commonCentre(const std::vector<BeamRay>& beams, Eigen::Vector3d* centre)
{
  return detail::closestPointToLines(beams, centre);
}

using detail::distanceToLine;

// RMS reprojection residual (pixels) of a fitted beam over its board views.
double reprojectionResidual(const CameraModel& camera, const std::vector<BoardView>& views,
                            const std::vector<std::pair<size_t, Eigen::Vector3d>>& points, const BeamRay& ray)
{
  double sum2 = 0.0;
  for (const auto& vp : points)
  {
    Eigen::Vector3d n;
    double c = 0.0;
    boardPlane(views[vp.first], &n, &c);
    const double s = (c - n.dot(ray.origin)) / n.dot(ray.direction);
    const cv::Point2d fit = camera.project(ray.pointAt(s));
    const cv::Point2d obs = camera.project(vp.second);
    sum2 += (fit.x - obs.x) * (fit.x - obs.x) + (fit.y - obs.y) * (fit.y - obs.y);
  }
  return points.empty() ? 0.0 : std::sqrt(sum2 / points.size());
}

void finishReport(const CameraModel& camera, const std::vector<BoardView>& views, const BoardPoints& per_beam,
                  const BoardCalibrationParams& params, bool use_centre, BoardCalibrationResult* res)
{
  const auto& beams = res->calibration.beams;
  const bool have_centre = use_centre && beams.size() >= 3 && commonCentre(beams, &res->common_centre);
  res->beams.assign(beams.size(), BeamFit());
  res->poor_beams = 0;
  for (size_t i = 0; i < beams.size(); ++i)
  {
    BeamFit& f = res->beams[i];
    f.views = static_cast<int>(per_beam[i].size());
    f.residual_px = reprojectionResidual(camera, views, per_beam[i], beams[i]);
    f.origin_distance_m = have_centre ? distanceToLine(res->common_centre, beams[i]) : 0.0;
    std::ostringstream why;
    if (f.residual_px > params.max_residual_px)
      why << "reprojection residual " << f.residual_px << " px > " << params.max_residual_px << " px; ";
    if (have_centre && params.max_origin_distance_m > 0.0 && f.origin_distance_m > params.max_origin_distance_m)
      why << "passes " << f.origin_distance_m * 1e3 << " mm from the common projector centre (> "
          << params.max_origin_distance_m * 1e3 << " mm); ";
    f.why = why.str();
    f.poor = !f.why.empty();
    if (f.poor)
      ++res->poor_beams;
  }
}

// The result's error when the camera model is unusable.
bool usableCamera(const CameraModel& camera, BoardCalibrationResult* res)
{
  const std::string why = camera.validate();
  if (!why.empty())
    res->error = "camera model: " + why;
  return why.empty();
}

// Board points of every beam, and a calibration of the right size to fill.
bool startCalibration(const CameraModel& camera, const std::vector<BoardView>& views,
                      const BoardCalibrationParams& params, BoardPoints* per_beam, BoardCalibrationResult* res)
{
  if (!collectBoardPoints(camera, views, params, per_beam, &res->error))
    return false;
  res->calibration.rows = params.rows;
  res->calibration.cols = params.cols;
  res->calibration.beams.resize(per_beam->size());
  return true;
}

// Least-squares 3D line through the board points of beam i (principal axis
// of their scatter), pointing away from the camera.
bool fitBeamLine(const std::vector<std::pair<size_t, Eigen::Vector3d>>& pts, int i, int cols, BeamRay* ray,
                 std::string* error)
{
  if (pts.size() < 2)
  {
    *error = "beam " + std::to_string(i) + " (row " + std::to_string(i / cols) + ", col " + std::to_string(i % cols) +
             ") was seen on " + std::to_string(pts.size()) + " board(s); it needs two or more";
    return false;
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& vp : pts)
    mean += vp.second;
  mean /= static_cast<double>(pts.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& vp : pts)
    scatter += (vp.second - mean) * (vp.second - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(scatter);
  Eigen::Vector3d dir = es.eigenvectors().col(2);
  if (!(es.eigenvalues()(2) > 1e-12))
  {
    *error = "beam " + std::to_string(i) + ": its board points coincide (boards at the same distance?)";
    return false;
  }
  if (dir.z() < 0.0)
    dir = -dir;
  if (!(dir.z() > 1e-6))
  {
    *error = "beam " + std::to_string(i) + " runs parallel to the boards";
    return false;
  }
  ray->direction = dir.normalized();
  ray->origin = mean;
  return true;
}

}  // namespace

std::string BoardCalibrationResult::report() const
{
  std::ostringstream s;
  if (!ok)
    return "calibration failed: " + error;
  s.precision(4);
  s << "projector calibration: " << calibration.rows << " x " << calibration.cols << " beams, common centre ["
    << common_centre.x() << ", " << common_centre.y() << ", " << common_centre.z() << "] m\n";
  double worst_px = 0.0, worst_mm = 0.0;
  for (size_t i = 0; i < beams.size(); ++i)
  {
    worst_px = std::max(worst_px, beams[i].residual_px);
    worst_mm = std::max(worst_mm, beams[i].origin_distance_m * 1e3);
    if (beams[i].poor)
      s << "  beam " << i << " (row " << i / calibration.cols << ", col " << i % calibration.cols
        << ") fits poorly: " << beams[i].why << "\n";
  }
  s << "worst reprojection residual " << worst_px << " px, worst distance from the common centre " << worst_mm
    << " mm, " << poor_beams << " poor beam(s)";
  return s.str();
}

BoardCalibrationResult calibrateFromBoards(const CameraModel& camera, const std::vector<BoardView>& views,
                                           const BoardCalibrationParams& params)
{
  BoardCalibrationResult res;
  if (!usableCamera(camera, &res))
    return res;
  if (params.rows <= 0 || params.cols <= 0)
  {
    res.error = "rows and cols must be positive";
    return res;
  }
  if (views.size() < 2)
  {
    res.error = "need board views at two or more distances, got " + std::to_string(views.size());
    return res;
  }
  BoardPoints per_beam;
  if (!startCalibration(camera, views, params, &per_beam, &res))
    return res;
  ProjectorCalibration& cal = res.calibration;
  for (size_t i = 0; i < per_beam.size(); ++i)
    if (!fitBeamLine(per_beam[i], static_cast<int>(i), params.cols, &cal.beams[i], &res.error))
      return res;
  // Express every origin as the point of its beam nearest the projector
  // centre (a readable file; the ray itself is unchanged).
  Eigen::Vector3d centre;
  if (commonCentre(cal.beams, &centre))
  {
    for (BeamRay& r : cal.beams)
      r.origin = r.pointAt((centre - r.origin).dot(r.direction));
  }
  res.ok = true;
  finishReport(camera, views, per_beam, params, true, &res);
  return res;
}

BoardCalibrationResult calibrateFromOneBoard(const CameraModel& camera, const BoardView& view,
                                             const Eigen::Vector3d& projector_origin,
                                             const BoardCalibrationParams& params)
{
  BoardCalibrationResult res;
  if (!usableCamera(camera, &res))
    return res;
  if (!projector_origin.allFinite())
  {
    res.error = "the projector origin is not finite";
    return res;
  }
  const std::vector<BoardView> views{view};
  BoardPoints per_beam;
  if (!startCalibration(camera, views, params, &per_beam, &res))
    return res;
  ProjectorCalibration& cal = res.calibration;
  for (size_t i = 0; i < per_beam.size(); ++i)
  {
    if (per_beam[i].empty())
    {
      res.error = "beam " + std::to_string(i) + " has no dot on the board";
      return res;
    }
    const Eigen::Vector3d d = per_beam[i][0].second - projector_origin;
    if (!(d.z() > 1e-9))
    {
      res.error = "beam " + std::to_string(i) + ": its dot is not in front of the projector origin";
      return res;
    }
    cal.beams[i].origin = projector_origin;
    cal.beams[i].direction = d.normalized();
  }
  res.common_centre = projector_origin;
  res.ok = true;
  // One view cannot check a fit; the report only restates the origin.
  finishReport(camera, views, per_beam, params, false, &res);
  return res;
}

bool loadBoardView(const std::string& path, BoardView* view, std::string* error)
{
  try
  {
    const YAML::Node root = YAML::LoadFile(path);
    BoardView v;
    if (root["plane"])
    {
      const YAML::Node p = root["plane"];
      if (!p.IsSequence() || p.size() != 4)
      {
        *error = path + ": 'plane' must be [nx, ny, nz, offset] (line " + std::to_string(p.Mark().line + 1) + ")";
        return false;
      }
      v.plane_normal = Eigen::Vector3d(p[0].as<double>(), p[1].as<double>(), p[2].as<double>());
      v.plane_offset = p[3].as<double>();
    }
    else if (root["distance"])
    {
      v.distance_m = root["distance"].as<double>();
    }
    else
    {
      *error = path + ": needs 'distance' (metres) or 'plane'";
      return false;
    }
    const YAML::Node spots = root["spots"];
    if (!spots || !spots.IsSequence())
    {
      *error = path + ": missing or non-list 'spots'";
      return false;
    }
    for (size_t k = 0; k < spots.size(); ++k)
    {
      const YAML::Node s = spots[k];
      if (!s.IsSequence() || s.size() < 2 || s.size() > 3)
      {
        *error = path + ": spot " + std::to_string(k) + " must be [x, y] or [x, y, beam] (line " +
                 std::to_string(s.Mark().line + 1) + ")";
        return false;
      }
      Spot spot;
      spot.x = s[0].as<double>();
      spot.y = s[1].as<double>();
      spot.beam = s.size() == 3 ? s[2].as<int>() : -1;
      v.spots.push_back(spot);
    }
    *view = v;
    return true;
  }
  catch (const YAML::Exception& e)
  {
    *error = path + ": " + e.what();
    return false;
  }
}

bool saveBoardView(const std::string& path, const BoardView& view, std::string* error)
{
  std::ofstream out(path);
  if (!out)
  {
    *error = "cannot write '" + path + "'";
    return false;
  }
  out.precision(12);
  if (view.plane_normal.squaredNorm() > 0.0)
    out << "plane: [" << view.plane_normal.x() << ", " << view.plane_normal.y() << ", " << view.plane_normal.z() << ", "
        << view.plane_offset << "]\n";
  else
    out << "distance: " << view.distance_m << "\n";
  out << "spots:  # [x, y, beam] distorted pixels, beam -1 = unknown\n";
  for (const Spot& s : view.spots)
    out << "  - [" << s.x << ", " << s.y << ", " << s.beam << "]\n";
  if (!out)
  {
    *error = "write to '" + path + "' failed";
    return false;
  }
  return true;
}

bool loadCameraModelYaml(const std::string& path, CameraModel* camera, std::string* error)
{
  try
  {
    const YAML::Node root = YAML::LoadFile(path);
    CameraModel m;
    m.width = root["image_width"].as<int>();
    m.height = root["image_height"].as<int>();
    const YAML::Node k = root["camera_matrix"]["data"];
    if (!k || !k.IsSequence() || k.size() != 9)
    {
      *error = path + ": camera_matrix.data must hold 9 numbers";
      return false;
    }
    m.fx = k[0].as<double>();
    m.cx = k[2].as<double>();
    m.fy = k[4].as<double>();
    m.cy = k[5].as<double>();
    const std::string model = root["distortion_model"] ? root["distortion_model"].as<std::string>() : "";
    if (!CameraModel::parseDistortionModel(model, &m.distortion))
    {
      *error = path + ": unknown distortion_model '" + model + "'";
      return false;
    }
    if (root["distortion_coefficients"] && root["distortion_coefficients"]["data"])
      for (const auto& d : root["distortion_coefficients"]["data"])
        m.D.push_back(d.as<double>());
    const std::string why = m.validate();
    if (!why.empty())
    {
      *error = path + ": " + why;
      return false;
    }
    *camera = m;
    return true;
  }
  catch (const YAML::Exception& e)
  {
    *error = path + ": " + e.what();
    return false;
  }
}

}  // namespace structured_light_stabilizer
