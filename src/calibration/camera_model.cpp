#include "structured_light_stabilizer/calibration/camera_model.h"

#include <cmath>
#include <sstream>

#include <Eigen/LU>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{
double coeff(const std::vector<double>& D, size_t i)
{
  return i < D.size() ? D[i] : 0.0;
}

// The joined "a; b; c" of the reasons collected in `why`.
std::string reasons(const std::ostringstream& why)
{
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

// Brown-Conrady radial and tangential terms shared by plumb_bob and
// rational_polynomial (OpenCV's projectPoints); `radial` is the model's
// radial factor. Thin prism terms (s1..s4) when D has 12 values.
Eigen::Vector2d brownConrady(const Eigen::Vector2d& xy, double r2, double radial, const std::vector<double>& D)
{
  const double x = xy.x(), y = xy.y();
  const double p1 = coeff(D, 2), p2 = coeff(D, 3);
  Eigen::Vector2d out(x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                      y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y);
  if (D.size() >= 12)
  {
    out.x() += r2 * (coeff(D, 8) + r2 * coeff(D, 9));
    out.y() += r2 * (coeff(D, 10) + r2 * coeff(D, 11));
  }
  return out;
}
}  // namespace

// ---- SensorWindow

bool SensorWindow::isFullSensor(int sensor_width, int sensor_height) const
{
  return binning_x == 1 && binning_y == 1 &&
         roi(sensor_width, sensor_height) == cv::Rect(0, 0, sensor_width, sensor_height);
}

std::string SensorWindow::validate(int sensor_width, int sensor_height) const
{
  std::ostringstream why;
  if (binning_x < 1 || binning_y < 1)
    why << "binning " << binning_x << "x" << binning_y << " must be at least 1x1; ";
  if (x_offset < 0 || y_offset < 0 || width < 0 || height < 0)
    why << "ROI offsets and size must not be negative; ";
  else if ((width == 0) != (height == 0) || (width == 0 && (x_offset != 0 || y_offset != 0)))
    why << "ROI width and height must both be set (0 for both, with zero offsets, is the whole sensor); ";
  else
  {
    const cv::Rect r = roi(sensor_width, sensor_height);
    if (r.x + r.width > sensor_width || r.y + r.height > sensor_height)
      why << "ROI " << r.width << "x" << r.height << "+" << r.x << "+" << r.y << " exceeds the " << sensor_width << "x"
          << sensor_height << " sensor; ";
    else if (binning_x >= 1 && binning_y >= 1 && (r.width < binning_x || r.height < binning_y))
      why << "ROI " << r.width << "x" << r.height << " is smaller than one binned pixel; ";
  }
  return reasons(why);
}

cv::Rect SensorWindow::roi(int sensor_width, int sensor_height) const
{
  if (width == 0 && height == 0)
    return {0, 0, sensor_width, sensor_height};
  return {x_offset, y_offset, width, height};
}

cv::Size SensorWindow::imageSize(int sensor_width, int sensor_height) const
{
  const cv::Rect r = roi(sensor_width, sensor_height);
  return {r.width / std::max(1, binning_x), r.height / std::max(1, binning_y)};
}

cv::Point2d SensorWindow::toImage(const cv::Point2d& full) const
{
  return {(full.x - x_offset - (binning_x - 1) * 0.5) / binning_x,
          (full.y - y_offset - (binning_y - 1) * 0.5) / binning_y};
}

cv::Point2d SensorWindow::toFull(const cv::Point2d& image) const
{
  return {binning_x * image.x + (binning_x - 1) * 0.5 + x_offset,
          binning_y * image.y + (binning_y - 1) * 0.5 + y_offset};
}

// ---- CameraModel

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
    why << "equidistant distortion needs 4 coefficients (k1 k2 k3 k4), got " << D.size() << "; ";
  if (distortion == DistortionModel::kPlumbBob && D.size() != 5 && D.size() != 4)
    why << "plumb_bob distortion needs 5 coefficients (k1 k2 p1 p2 k3), got " << D.size() << "; ";
  if (distortion == DistortionModel::kRationalPolynomial && D.size() != 8 && D.size() != 12)
    why << "rational_polynomial distortion needs 8 coefficients (k1 k2 p1 p2 k3 k4 k5 k6; 12 with the thin "
           "prism s1..s4), got "
        << D.size() << "; ";
  return reasons(why);
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

CameraModel CameraModel::windowed(const SensorWindow& window) const
{
  CameraModel m = *this;
  const double bx = std::max(1, window.binning_x), by = std::max(1, window.binning_y);
  m.fx = fx / bx;
  m.fy = fy / by;
  // The principal point is a pixel position: moved like any pixel.
  const cv::Point2d c = window.toImage({cx, cy});
  m.cx = c.x;
  m.cy = c.y;
  const cv::Size size = window.imageSize(width, height);
  m.width = size.width;
  m.height = size.height;
  return m;
}

Eigen::Vector2d CameraModel::distortNormalized(const Eigen::Vector2d& xy) const
{
  const double r2 = xy.squaredNorm();
  if (distortion == DistortionModel::kPlumbBob)
  {
    const double radial = 1.0 + r2 * (coeff(D, 0) + r2 * (coeff(D, 1) + r2 * coeff(D, 4)));
    return brownConrady(xy, r2, radial, D);
  }
  if (distortion == DistortionModel::kRationalPolynomial)
  {
    const double num = 1.0 + r2 * (coeff(D, 0) + r2 * (coeff(D, 1) + r2 * coeff(D, 4)));
    const double den = 1.0 + r2 * (coeff(D, 5) + r2 * (coeff(D, 6) + r2 * coeff(D, 7)));
    // A denominator through zero folds the image: no pixel there.
    if (!(den > 0.0))
      return {detail::kNaN, detail::kNaN};
    return brownConrady(xy, r2, num / den, D);
  }
  if (distortion == DistortionModel::kEquidistant)
  {
    const double r = std::sqrt(r2);
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
  // Not converged (outside the region where the lens model is invertible,
  // e.g. beyond a rational model's fold): no ray rather than a wrong one.
  // 1e-8 in normalised units is 1e-5 px at f = 1000 px.
  if (!((distortNormalized(u) - distorted).norm() < 1e-8))
    return {detail::kNaN, detail::kNaN};
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
  else if (name == "rational_polynomial")
    *model = DistortionModel::kRationalPolynomial;
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
    case DistortionModel::kRationalPolynomial:
      return "rational_polynomial";
    default:
      return "plumb_bob";
  }
}

}  // namespace structured_light_stabilizer
