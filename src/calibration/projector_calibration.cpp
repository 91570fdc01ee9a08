#include "structured_light_stabilizer/calibration/projector_calibration.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include <Eigen/Geometry>
#include <yaml-cpp/yaml.h>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

std::string at(const YAML::Node& node)
{
  // A missing key yields an invalid node whose Mark() throws.
  if (!node.IsDefined())
    return "";
  const YAML::Mark m = node.Mark();
  if (m.line < 0)
    return "";
  return " (line " + std::to_string(m.line + 1) + ")";
}

bool readVector3(const YAML::Node& node, const std::string& what, Eigen::Vector3d* v, std::string* error)
{
  if (!node || !node.IsSequence() || node.size() != 3)
  {
    *error = what + " must be a list of 3 numbers" + at(node);
    return false;
  }
  for (int i = 0; i < 3; ++i)
  {
    try
    {
      (*v)[i] = node[i].as<double>();
    }
    catch (const YAML::Exception&)
    {
      *error = what + " element " + std::to_string(i) + " is not a number" + at(node[i]);
      return false;
    }
    if (!std::isfinite((*v)[i]))
    {
      *error = what + " element " + std::to_string(i) + " is not finite" + at(node[i]);
      return false;
    }
  }
  return true;
}

bool readPositiveInt(const YAML::Node& root, const char* key, int* value, std::string* error)
{
  const YAML::Node node = root[key];
  if (!node)
  {
    *error = std::string("missing key '") + key + "'";
    return false;
  }
  try
  {
    *value = node.as<int>();
  }
  catch (const YAML::Exception&)
  {
    *error = std::string("'") + key + "' is not an integer" + at(node);
    return false;
  }
  if (*value <= 0 || *value > 1000)
  {
    *error = std::string("'") + key + "' = " + std::to_string(*value) + " is out of range [1, 1000]" + at(node);
    return false;
  }
  return true;
}

// The study's per-beam form (docs/study.md §2.3, formulas 2.28-2.30):
// x = z tan(alpha) - d_x, y = z tan(beta) - d_y, i.e. a ray from
// (-d_x, -d_y, 0) along (tan(alpha), tan(beta), 1).
bool readStudyBeam(const YAML::Node& b, const std::string& what, BeamRay* ray, std::string* error)
{
  double v[4];
  const char* keys[4] = {"tan_alpha", "tan_beta", "d_x", "d_y"};
  for (int i = 0; i < 4; ++i)
  {
    const YAML::Node n = b[keys[i]];
    if (!n)
    {
      *error = what + " has neither origin/direction nor '" + keys[i] + "'" + at(b);
      return false;
    }
    try
    {
      v[i] = n.as<double>();
    }
    catch (const YAML::Exception&)
    {
      *error = what + " '" + keys[i] + "' is not a number" + at(n);
      return false;
    }
    if (!std::isfinite(v[i]))
    {
      *error = what + " '" + keys[i] + "' is not finite" + at(n);
      return false;
    }
  }
  ray->origin = Eigen::Vector3d(-v[2], -v[3], 0.0);
  ray->direction = Eigen::Vector3d(v[0], v[1], 1.0).normalized();
  return true;
}

// An angle given as `<name>_rad` or `<name>_deg`; absent -> *value unchanged
// unless required.
bool readAngle(const YAML::Node& g, const std::string& name, bool required, double* value, std::string* error)
{
  const YAML::Node rad = g[name + "_rad"], deg = g[name + "_deg"];
  if (rad && deg)
  {
    *error = "grid: give " + name + "_rad or " + name + "_deg, not both" + at(rad);
    return false;
  }
  if (!rad && !deg)
  {
    if (required)
      *error = "grid: missing " + name + "_rad (or " + name + "_deg)" + at(g);
    return !required;
  }
  const YAML::Node n = rad ? rad : deg;
  try
  {
    *value = n.as<double>() * (rad ? 1.0 : detail::kPi / 180.0);
  }
  catch (const YAML::Exception&)
  {
    *error = "grid: " + name + " is not a number" + at(n);
    return false;
  }
  if (!std::isfinite(*value))
  {
    *error = "grid: " + name + " is not finite" + at(n);
    return false;
  }
  return true;
}

// The grid form (docs/interface.md): one origin, a central direction, pitch
// angles and an in-plane roll; expanded by makeGridProjector.
bool readGrid(const YAML::Node& g, int rows, int cols, ProjectorCalibration* cal, std::string* error)
{
  if (!g.IsMap())
  {
    *error = "'grid' must be a map" + at(g);
    return false;
  }
  Eigen::Vector3d origin, centre;
  double pitch_x = 0.0, pitch_y = 0.0, roll = 0.0;
  if (!readVector3(g["origin"], "grid origin", &origin, error) ||
      !readVector3(g["centre_direction"], "grid centre_direction", &centre, error) ||
      !readAngle(g, "pitch_x", true, &pitch_x, error) || !readAngle(g, "pitch_y", true, &pitch_y, error) ||
      !readAngle(g, "roll", false, &roll, error))
    return false;
  if (centre.norm() < 1e-9)
  {
    *error = "grid centre_direction is zero" + at(g["centre_direction"]);
    return false;
  }
  *cal = makeGridProjector(rows, cols, origin, centre, pitch_x, pitch_y, roll);
  const std::string why = cal->validate();
  if (!why.empty())
  {
    *error = "grid: " + why + at(g);
    return false;
  }
  return true;
}

// One entry of the general form (origin/direction) or of the study's form.
bool readBeam(const YAML::Node& b, const std::string& what, BeamRay* ray, std::string* error)
{
  if (!b.IsMap())
  {
    *error = what + " must be a map" + at(b);
    return false;
  }
  if (b["origin"] || b["direction"])
  {
    if (!readVector3(b["origin"], what + " origin", &ray->origin, error) ||
        !readVector3(b["direction"], what + " direction", &ray->direction, error))
      return false;
    const double n = ray->direction.norm();
    if (n < 1e-9)
    {
      *error = what + " direction is zero" + at(b["direction"]);
      return false;
    }
    ray->direction /= n;
  }
  else if (!readStudyBeam(b, what, ray, error))
  {
    return false;
  }
  if (ray->direction.z() <= 0.0)
  {
    *error = what + " points away from the scene (direction z <= 0)" + at(b);
    return false;
  }
  return true;
}

// The `beams` list: rows * cols entries, row-major.
bool readBeamList(const YAML::Node& beams, ProjectorCalibration* cal, std::string* error)
{
  if (!beams || !beams.IsSequence())
  {
    *error = "missing or non-list 'beams'" + at(beams);
    return false;
  }
  if (static_cast<int>(beams.size()) != cal->rows * cal->cols)
  {
    *error = "rows*cols = " + std::to_string(cal->rows * cal->cols) + " but 'beams' has " +
             std::to_string(beams.size()) + " entries" + at(beams);
    return false;
  }
  for (size_t i = 0; i < beams.size(); ++i)
  {
    BeamRay ray;
    if (!readBeam(beams[i], "beam " + std::to_string(i), &ray, error))
      return false;
    cal->beams.push_back(ray);
  }
  return true;
}

// parseProjectorCalibration without its guard against yaml-cpp exceptions.
bool parseProjectorCalibrationUnguarded(const std::string& yaml_text, ProjectorCalibration* out, std::string* error)
{
  YAML::Node root;
  try
  {
    root = YAML::Load(yaml_text);
  }
  catch (const YAML::Exception& e)
  {
    *error = std::string("not valid YAML: ") + e.what();
    return false;
  }
  if (!root.IsMap())
  {
    *error = "the top level must be a map with rows, cols and beams";
    return false;
  }
  ProjectorCalibration cal;
  if (!readPositiveInt(root, "rows", &cal.rows, error) || !readPositiveInt(root, "cols", &cal.cols, error))
    return false;
  if (root["grid"] && root["beams"])
  {
    *error = "give either 'beams' or 'grid', not both" + at(root["grid"]);
    return false;
  }
  const bool ok =
      root["grid"] ? readGrid(root["grid"], cal.rows, cal.cols, &cal, error) : readBeamList(root["beams"], &cal, error);
  if (ok)
    *out = cal;
  return ok;
}

}  // namespace

std::string ProjectorCalibration::validate() const
{
  if (rows <= 0 || cols <= 0)
    return "rows and cols must be positive (rows=" + std::to_string(rows) + ", cols=" + std::to_string(cols) + ")";
  if (static_cast<int>(beams.size()) != rows * cols)
    return "rows*cols = " + std::to_string(rows * cols) + " but " + std::to_string(beams.size()) + " beams are given";
  for (size_t i = 0; i < beams.size(); ++i)
  {
    const BeamRay& b = beams[i];
    if (!b.origin.allFinite() || !b.direction.allFinite())
      return "beam " + std::to_string(i) + " has a non-finite origin or direction";
    if (std::abs(b.direction.norm() - 1.0) > 1e-6)
      return "beam " + std::to_string(i) + " direction is not a unit vector";
    if (b.direction.z() <= 0.0)
      return "beam " + std::to_string(i) + " points away from the scene (direction z <= 0)";
  }
  return "";
}

ProjectorCalibration makeGridProjector(int rows, int cols, const Eigen::Vector3d& origin,
                                       const Eigen::Vector3d& centre_direction, double pitch_x_rad, double pitch_y_rad,
                                       double roll_rad)
{
  ProjectorCalibration cal;
  cal.rows = rows;
  cal.cols = cols;
  // Frame of the projector: z along the central beam, x/y as close to the
  // camera's as possible, then rolled about z.
  const Eigen::Vector3d z = centre_direction.normalized();
  Eigen::Vector3d x = (Eigen::Vector3d::UnitX() - z * z.x()).normalized();
  Eigen::Vector3d y = z.cross(x);
  const Eigen::AngleAxisd roll(roll_rad, z);
  x = roll * x;
  y = roll * y;
  for (int r = 0; r < rows; ++r)
  {
    for (int c = 0; c < cols; ++c)
    {
      const double ax = (c - 0.5 * (cols - 1)) * pitch_x_rad;
      const double ay = (r - 0.5 * (rows - 1)) * pitch_y_rad;
      BeamRay b;
      b.origin = origin;
      b.direction = (z + std::tan(ax) * x + std::tan(ay) * y).normalized();
      cal.beams.push_back(b);
    }
  }
  return cal;
}

bool parseProjectorCalibration(const std::string& yaml_text, ProjectorCalibration* out, std::string* error)
{
  std::string local_error;
  if (!error)
    error = &local_error;
  // yaml-cpp signals many malformations by exceptions; none may escape.
  try
  {
    return parseProjectorCalibrationUnguarded(yaml_text, out, error);
  }
  catch (const std::exception& e)
  {
    *error = std::string("malformed projector calibration: ") + e.what();
    return false;
  }
}

bool loadProjectorCalibration(const std::string& path, ProjectorCalibration* out, std::string* error)
{
  std::ifstream in(path);
  if (!in)
  {
    if (error)
      *error = "cannot open projector calibration '" + path + "'";
    return false;
  }
  std::stringstream ss;
  ss << in.rdbuf();
  if (!parseProjectorCalibration(ss.str(), out, error))
  {
    if (error)
      *error = path + ": " + *error;
    return false;
  }
  return true;
}

bool saveProjectorCalibration(const std::string& path, const ProjectorCalibration& cal, std::string* error)
{
  const std::string why = cal.validate();
  if (!why.empty())
  {
    if (error)
      *error = "refusing to write an inconsistent calibration: " + why;
    return false;
  }
  std::ofstream out(path);
  if (!out)
  {
    if (error)
      *error = "cannot write '" + path + "'";
    return false;
  }
  out.precision(12);
  out << "# structured_light_stabilizer projector calibration: one ray per beam,\n"
      << "# camera optical frame, metres; beams row-major (beam = r * cols + c).\n";
  out << "rows: " << cal.rows << "\ncols: " << cal.cols << "\nbeams:\n";
  for (const BeamRay& b : cal.beams)
  {
    out << "  - origin: [" << b.origin.x() << ", " << b.origin.y() << ", " << b.origin.z() << "]\n"
        << "    direction: [" << b.direction.x() << ", " << b.direction.y() << ", " << b.direction.z() << "]\n";
  }
  if (!out)
  {
    if (error)
      *error = "write to '" + path + "' failed";
    return false;
  }
  return true;
}

}  // namespace structured_light_stabilizer
