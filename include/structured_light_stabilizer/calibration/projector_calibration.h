// Projector model: one ray per beam in the camera optical frame.
//
// Contract: beams are row-major (beam = r * cols + c); origin is a point on
// the beam in metres, direction is a unit vector (normalised on load). Every
// other file form (the study's per-beam tan(alpha), tan(beta), d_x, d_y) is
// converted to this one on load. See docs/interface.md for the YAML layout.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

namespace structured_light_stabilizer
{

struct BeamRay
{
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();

  Eigen::Vector3d pointAt(double s) const { return origin + s * direction; }
};

struct ProjectorCalibration
{
  int rows = 0;
  int cols = 0;
  std::vector<BeamRay> beams;  // rows * cols, row-major

  int beamCount() const { return rows * cols; }
  bool empty() const { return beams.empty(); }

  // Empty when consistent, otherwise the reason, naming the beam at fault.
  std::string validate() const;
};

// A regular grid of beams from one origin: beam (r, c) leaves `origin` at
// angles ((c - (cols-1)/2) * pitch_x, (r - (rows-1)/2) * pitch_y) around the
// central direction `centre_direction`, the whole grid rotated in-plane by
// `roll_rad` about that direction.
ProjectorCalibration makeGridProjector(int rows, int cols, const Eigen::Vector3d& origin,
                                       const Eigen::Vector3d& centre_direction, double pitch_x_rad, double pitch_y_rad,
                                       double roll_rad);

// Loads a projector calibration YAML. Returns false and fills *error with a
// message naming the line or the beam at fault when the file is missing,
// malformed or inconsistent.
bool loadProjectorCalibration(const std::string& path, ProjectorCalibration* out, std::string* error);

// Same, from YAML text already in memory (used by the fuzzer and the tests).
bool parseProjectorCalibration(const std::string& yaml_text, ProjectorCalibration* out, std::string* error);

// Writes the general per-beam ray form.
bool saveProjectorCalibration(const std::string& path, const ProjectorCalibration& calibration, std::string* error);

}  // namespace structured_light_stabilizer
