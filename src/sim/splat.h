// Image-space Gaussians ("splats"): how projector dots (added light) and
// clutter patches (reflectance blended over the rock) reach the pixels. The
// frame is composed row by row, so a splat is applied one row at a time.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "structured_light_stabilizer/camera_model.h"

namespace structured_light_stabilizer
{
namespace sim
{

// An image-space Gaussian (inverse covariance a, b, c in px^-2 about the
// centre cx, cy), cut where q = a dx^2 + 2 b dx dy + c dy^2 exceeds q_max:
// a projector dot (added) or a clutter patch (blended over the rock).
struct Splat
{
  double cx = 0.0, cy = 0.0;
  double a = 0.0, b = 0.0, c = 0.0;
  double q_max = 0.0;
  int v0 = 0, v1 = -1;                  // rows it touches (inclusive)
  float value[3] = {0.0f, 0.0f, 0.0f};  // B, G, R amplitude (dot) or radiance (patch)
  bool blend = false;                   // patch: out = (1 - w) out + w value
  bool flat_top = false;                // patch: w = min(1, 2.5 g), a soft-edged disc
};

// Sets the inverse covariance and the rows of a splat of covariance S (px^2);
// false when it is degenerate or outside the image.
bool setSplatShape(Splat* sp, const Eigen::Matrix2d& S, double q_max, int height);

// Applies a splat to row v (CV_32FC3 pixels, `width` of them).
void applySplatRow(const Splat& sp, int v, int width, float* row);

// 2x3 Jacobian of the (distorted) projection at a camera-frame point: maps a
// covariance on the rock to one in the image.
Eigen::Matrix<double, 2, 3> projectionJacobian(const CameraModel& cam, const Eigen::Vector3d& X);

// The splats of a frame indexed by bands of rows, applied to one row in the
// order they were added (patches before dots: a dot lights the patch too).
class SplatRows
{
public:
  SplatRows(std::vector<Splat> splats, int height);

  void applyRow(int v, int width, float* row) const;

private:
  static constexpr int kBand = 16;
  std::vector<Splat> splats_;
  std::vector<std::vector<int>> bands_;  // per band of kBand rows: indices into splats_, in order
};

}  // namespace sim
}  // namespace structured_light_stabilizer
