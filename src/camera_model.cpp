#include "structured_light_stabilizer/camera_model.h"

#include <cmath>
#include <sstream>

#include <Eigen/LU>

#include "structured_light_stabilizer/detail/math.h"

namespace structured_light_stabilizer
{

namespace
{
double coeff(const std::vector<double>& D, size_t i)
{
  return i < D.size() ? D[i] : 0.0;
}
}  // namespace

CameraModel CameraModel::studyDesign()
{
  CameraModel m;
  m.width = 1024;
  m.height = 1024;
  const double focal_m = 12.14e-3;
  const double pixel_m = 12e-6;
  m.fx = m.fy = focal_m / pixel_m;
  // Centre of a 1024-pixel row in the pixel-centre convention.
  m.cx = (m.width - 1) * 0.5;
  m.cy = (m.height - 1) * 0.5;
  m.distortion = DistortionModel::kNone;
  return m;
}

std::string CameraModel::validate() const
{
  std::ostringstream why;
  if (width <= 0 || height <= 0)
    why << "image size " << width << "x" << height << " is not positive; ";
  for (double v : {fx, fy, cx, cy})
  {
    if (!std::isfinite(v))
    {
      why << "intrinsics contain NaN or infinity; ";
      break;
    }
  }
  if (!(fx > 0.0) || !(fy > 0.0))
    why << "focal length fx=" << fx << " fy=" << fy
        << " must be positive (K is all zeros when the camera is uncalibrated); ";
  for (double d : D)
  {
    if (!std::isfinite(d))
    {
      why << "distortion coefficients contain NaN or infinity; ";
      break;
    }
  }
  if (distortion == DistortionModel::kEquidistant && D.size() != 4)
    why << "equidistant distortion needs 4 coefficients, got " << D.size() << "; ";
  if (distortion == DistortionModel::kPlumbBob && D.size() != 5 && D.size() != 4)
    why << "plumb_bob distortion needs 5 coefficients, got " << D.size() << "; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

bool CameraModel::hasDistortion() const
{
  if (distortion == DistortionModel::kNone)
    return false;
  for (double d : D)
    if (d != 0.0)
      return true;
  return false;
}

Eigen::Vector2d CameraModel::distortNormalized(const Eigen::Vector2d& xy) const
{
  const double x = xy.x(), y = xy.y();
  if (distortion == DistortionModel::kPlumbBob)
  {
    const double k1 = coeff(D, 0), k2 = coeff(D, 1), p1 = coeff(D, 2), p2 = coeff(D, 3), k3 = coeff(D, 4);
    const double r2 = x * x + y * y;
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
  }
  if (distortion == DistortionModel::kEquidistant)
  {
    const double r = std::sqrt(x * x + y * y);
    if (r < 1e-12)
      return xy;
    const double th = std::atan(r);
    const double th2 = th * th;
    const double thd = th * (1.0 + th2 * (coeff(D, 0) + th2 * (coeff(D, 1) + th2 * (coeff(D, 2) + th2 * coeff(D, 3)))));
    return xy * (thd / r);
  }
  return xy;
}

cv::Point2d CameraModel::project(const Eigen::Vector3d& p) const
{
  if (!(p.z() > 0.0))
    return {detail::kNaN, detail::kNaN};
  const Eigen::Vector2d d = distortNormalized({p.x() / p.z(), p.y() / p.z()});
  return {fx * d.x() + cx, fy * d.y() + cy};
}

Eigen::Vector2d CameraModel::normalize(const cv::Point2d& pixel) const
{
  const Eigen::Vector2d distorted((pixel.x - cx) / fx, (pixel.y - cy) / fy);
  if (!hasDistortion())
    return distorted;
  // Gauss-Newton on distort(u) = distorted, numeric Jacobian; converges in a
  // few iterations for any physically sensible lens.
  Eigen::Vector2d u = distorted;
  for (int it = 0; it < 30; ++it)
  {
    const Eigen::Vector2d r = distortNormalized(u) - distorted;
    if (r.squaredNorm() < 1e-26)
      break;
    const double h = 1e-7;
    Eigen::Matrix2d J;
    J.col(0) = (distortNormalized(u + Eigen::Vector2d(h, 0)) - distortNormalized(u - Eigen::Vector2d(h, 0))) / (2 * h);
    J.col(1) = (distortNormalized(u + Eigen::Vector2d(0, h)) - distortNormalized(u - Eigen::Vector2d(0, h))) / (2 * h);
    const double det = J.determinant();
    if (!std::isfinite(det) || std::abs(det) < 1e-12)
      break;
    u -= J.inverse() * r;
  }
  return u;
}

Eigen::Vector3d CameraModel::ray(const cv::Point2d& pixel) const
{
  const Eigen::Vector2d n = normalize(pixel);
  return Eigen::Vector3d(n.x(), n.y(), 1.0).normalized();
}

bool CameraModel::parseDistortionModel(const std::string& name, DistortionModel* model)
{
  if (name.empty() || name == "none")
    *model = DistortionModel::kNone;
  else if (name == "plumb_bob")
    *model = DistortionModel::kPlumbBob;
  else if (name == "equidistant" || name == "fisheye")
    *model = DistortionModel::kEquidistant;
  else
    return false;
  return true;
}

std::string CameraModel::distortionModelName(DistortionModel model)
{
  switch (model)
  {
    case DistortionModel::kPlumbBob:
      return "plumb_bob";
    case DistortionModel::kEquidistant:
      return "equidistant";
    default:
      return "plumb_bob";
  }
}

}  // namespace structured_light_stabilizer
