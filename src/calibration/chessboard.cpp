#include "structured_light_stabilizer/calibration/chessboard.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

#include <Eigen/Dense>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "calibration/calibration_geometry.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

using Vector6d = Eigen::Matrix<double, 6, 1>;

// Starting pose from a planar PnP on the undistorted corners (K = I), so any
// distortion model of the CameraModel works.
bool initialPose(const CameraModel& camera, const BoardParams& params, const std::vector<cv::Point2d>& corners,
                 const std::vector<char>& used, Eigen::Isometry3d* pose)
{
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (size_t k = 0; k < corners.size(); ++k)
  {
    if (!used[k])
      continue;
    const Eigen::Vector3d b = params.corner(static_cast<int>(k));
    const Eigen::Vector2d n = camera.normalize(corners[k]);
    object.emplace_back(b.x(), b.y(), 0.0);
    image.emplace_back(n.x(), n.y());
  }
  if (object.size() < 4)
    return false;
  cv::Mat rvec, tvec;
  if (!cv::solvePnP(object, image, cv::Mat::eye(3, 3, CV_64F), cv::Mat(), rvec, tvec, false, cv::SOLVEPNP_IPPE))
    return false;
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d Re;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      Re(r, c) = R.at<double>(r, c);
  pose->linear() = Re;
  pose->translation() = Eigen::Vector3d(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
  return pose->translation().z() > 0.0;
}

// Sum of squared reprojection errors of the used corners (px^2); +inf when
// a corner falls behind the camera.
double cornerCost(const CameraModel& camera, const BoardParams& params, const std::vector<cv::Point2d>& corners,
                  const std::vector<char>& used, const Eigen::Isometry3d& pose, int* n_used)
{
  double sum = 0.0;
  int n = 0;
  for (size_t k = 0; k < corners.size(); ++k)
  {
    if (!used[k])
      continue;
    const cv::Point2d p = camera.project(pose * params.corner(static_cast<int>(k)));
    if (!std::isfinite(p.x))
      return detail::kInf;
    sum += detail::square(p.x - corners[k].x) + detail::square(p.y - corners[k].y);
    ++n;
  }
  if (n_used)
    *n_used = n;
  return sum;
}

// Mean of the image at the centres of the squares of each parity; false when
// too few squares are in the image.
bool measureSquares(const cv::Mat& img, const CameraModel& camera, const BoardParams& params,
                    const Eigen::Isometry3d& pose, double* even_level, double* odd_level)
{
  std::vector<double> even, odd;
  for (int j = -1; j < params.rows; ++j)
    for (int i = -1; i < params.cols; ++i)
    {
      const Eigen::Vector3d b((i + 0.5) * params.square_m, (j + 0.5) * params.square_m, 0.0);
      const cv::Point2d p = camera.project(pose * b);
      if (!(p.x >= 1 && p.y >= 1 && p.x < img.cols - 2 && p.y < img.rows - 2))
        continue;
      cv::Mat patch;
      cv::getRectSubPix(img, cv::Size(3, 3), cv::Point2f(static_cast<float>(p.x), static_cast<float>(p.y)), patch,
                        CV_32F);
      (((i + j) % 2 + 2) % 2 == 0 ? even : odd).push_back(cv::mean(patch)[0]);
    }
  if (even.size() < 3 || odd.size() < 3)
    return false;
  // Medians: a dot on a square's centre must not move its level.
  *even_level = detail::median(even);
  *odd_level = detail::median(odd);
  return true;
}

}  // namespace

std::string BoardParams::validate() const
{
  std::ostringstream why;
  if (cols < 2 || rows < 2)
    why << "the board needs at least 2 x 2 inner corners, got " << cols << " x " << rows << "; ";
  if (!(square_m > 0.0) || !std::isfinite(square_m))
    why << "the square size must be positive (metres), got " << square_m << "; ";
  if (!(margin_m >= 0.0) || !std::isfinite(margin_m))
    why << "the margin must be >= 0 (metres), got " << margin_m << "; ";
  std::string s = why.str();
  if (s.size() >= 2)
    s.resize(s.size() - 2);
  return s;
}

bool parseBoardSize(const std::string& text, int* cols, int* rows)
{
  int c = 0, r = 0;
  char x = 0, extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &c, &x, &r, &extra) != 3 || (x != 'x' && x != 'X') || c < 2 || r < 2)
    return false;
  *cols = c;
  *rows = r;
  return true;
}

bool refineBoardPose(const CameraModel& camera, const BoardParams& params, const std::vector<cv::Point2d>& corners,
                     const std::vector<char>& used, Eigen::Isometry3d* pose, double* rms_px)
{
  if (pose->matrix().isIdentity() && !initialPose(camera, params, corners, used, pose))
    return false;
  int n = 0;
  double cost = cornerCost(camera, params, corners, used, *pose, &n);
  if (n < 4 || !std::isfinite(cost))
    return false;
  double lambda = 1e-3;
  for (int it = 0; it < 50; ++it)
  {
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Vector6d g = Vector6d::Zero();
    for (size_t k = 0; k < corners.size(); ++k)
    {
      if (!used[k])
        continue;
      const Eigen::Vector3d b = params.corner(static_cast<int>(k));
      const Eigen::Vector2d r0 = detail::toVec(camera.project(*pose * b)) - detail::toVec(corners[k]);
      Eigen::Matrix<double, 2, 6> J;
      for (int p = 0; p < 6; ++p)
      {
        Vector6d inc = Vector6d::Zero();
        inc(p) = 1e-7;
        J.col(p) = (detail::toVec(camera.project(detail::applyPoseIncrement(*pose, inc) * b)) -
                    detail::toVec(camera.project(detail::applyPoseIncrement(*pose, -inc) * b))) /
                   2e-7;
      }
      H += J.transpose() * J;
      g += J.transpose() * r0;
    }
    Eigen::Isometry3d candidate;
    bool converged = false;
    const bool accepted = detail::levenbergMarquardtIteration(
        &cost, &lambda,
        [&](double l)
        {
          Eigen::Matrix<double, 6, 6> A = H;
          A.diagonal() *= 1.0 + l;
          return Vector6d(-A.ldlt().solve(g));
        },
        [&](const Vector6d& step, double* c)
        {
          candidate = detail::applyPoseIncrement(*pose, step);
          *c = cornerCost(camera, params, corners, used, candidate, nullptr);
          return true;
        },
        [&] { *pose = candidate; }, &converged);
    if (!accepted || converged)
      break;
  }
  *rms_px = std::sqrt(cost / n);
  return pose->translation().z() > 0.0 && std::isfinite(*rms_px);
}

ChessboardDetection detectChessboard(const cv::Mat& img, const CameraModel& camera, const BoardParams& params)
{
  ChessboardDetection det;
  det.why = params.validate();
  if (det.why.empty())
    det.why = camera.validate();
  if (det.why.empty() && (img.type() != CV_8UC1 || img.cols != camera.width || img.rows != camera.height))
    det.why = "the board image must be 8-bit, one channel, of the camera's size " + std::to_string(camera.width) + "x" +
              std::to_string(camera.height);
  if (!det.why.empty())
    return det;
  const cv::Size pattern(params.cols, params.rows);
  std::vector<cv::Point2f> found;
  // The sector-based detector is the more accurate and copes with blur; the
  // classic one with cornerSubPix is the fallback.
  bool ok = cv::findChessboardCornersSB(img, pattern, found, cv::CALIB_CB_NORMALIZE_IMAGE);
  if (!ok)
    ok = cv::findChessboardCorners(
        img, pattern, found, cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK);
  if (!ok || static_cast<int>(found.size()) != params.cornerCount())
  {
    det.why = "no chessboard of " + std::to_string(params.cols) + "x" + std::to_string(params.rows) +
              " inner corners found (whole board in view? --board COLSxROWS counts inner corners)";
    return det;
  }
  // Both detectors leave about 0.1 px of error (measured on the renderer of
  // test/support/chessboard_scene.h); the gradient-orthogonality refinement
  // over a window of a fifth of a square brings it to about 0.04 px.
  std::vector<double> pitch;
  for (int k = 0; k + 1 < params.cornerCount(); ++k)
    if ((k + 1) % params.cols != 0)
      pitch.push_back(std::hypot(found[k + 1].x - found[k].x, found[k + 1].y - found[k].y));
  const int half = std::max(3, std::min(10, static_cast<int>(std::lround(0.2 * detail::median(pitch)))));
  det.corner_window_px = half;
  cv::cornerSubPix(img, found, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
  for (const cv::Point2f& p : found)
    det.corners.emplace_back(p.x, p.y);
  det.corner_used.assign(det.corners.size(), 1);
  if (!refineBoardPose(camera, params, det.corners, det.corner_used, &det.pose, &det.corner_rms_px))
  {
    det.why = "the chessboard's pose could not be estimated (degenerate corners?)";
    return det;
  }
  double even = 0.0, odd = 0.0;
  if (!measureSquares(img, camera, params, det.pose, &even, &odd))
  {
    det.why = "too few squares of the board lie in the image";
    return det;
  }
  det.square00_white = even > odd;
  det.white_level = std::max(even, odd);
  det.black_level = std::min(even, odd);
  det.found = true;
  det.why.clear();
  return det;
}

double boardAlbedo(const BoardParams& params, bool square00_white, double black_ratio, double x, double y)
{
  const double s = params.square_m, m = params.margin_m;
  if (x < -s - m || y < -s - m || x > params.cols * s + m || y > params.rows * s + m)
    return detail::kNaN;
  if (x < -s || y < -s || x > params.cols * s || y > params.rows * s)
    return 1.0;
  const long i = static_cast<long>(std::floor(x / s)), j = static_cast<long>(std::floor(y / s));
  const bool even = ((i + j) % 2 + 2) % 2 == 0;
  return even == square00_white ? 1.0 : black_ratio;
}

bool pixelToBoard(const CameraModel& camera, const Eigen::Isometry3d& pose, const cv::Point2d& pixel,
                  Eigen::Vector2d* board_xy)
{
  const Eigen::Vector2d n = camera.normalize(pixel);
  Eigen::Vector3d hit;
  if (!detail::linePlaneHit(pose, Eigen::Vector3d::Zero(), Eigen::Vector3d(n.x(), n.y(), 1.0), &hit))
    return false;
  *board_xy = (pose.inverse() * hit).head<2>();
  return true;
}

namespace
{

// Region of a board point: square index (i, j) packed, kMargin or kOutside.
constexpr long kMargin = -1000000;
constexpr long kOutside = -2000000;

long boardRegion(const BoardParams& params, double x, double y)
{
  const double s = params.square_m, m = params.margin_m;
  if (!std::isfinite(x) || x < -s - m || y < -s - m || x > params.cols * s + m || y > params.rows * s + m)
    return kOutside;
  if (x < -s || y < -s || x > params.cols * s || y > params.rows * s)
    return kMargin;
  return static_cast<long>(std::floor(x / s)) * 4096 + static_cast<long>(std::floor(y / s));
}

// Board coordinates at the corners of the cells of `rect` divided `sub`
// times per pixel: corner (i, j) sits at pixel (rect.x - 0.5 + i / sub,
// rect.y - 0.5 + j / sub). Exact every 8 px, bilinear in between (the map
// is a smooth, distorted homography: the interpolation error is far below
// 1e-3 px at this step).
void boardCoordinatesAtCellCorners(const CameraModel& camera, const Eigen::Isometry3d& pose, const cv::Rect& rect,
                                   int sub, cv::Mat* bx, cv::Mat* by)
{
  const int step = 8;
  const int gw = rect.width / step + 2, gh = rect.height / step + 2;
  cv::Mat gx(gh, gw, CV_64F), gy(gh, gw, CV_64F);
  for (int j = 0; j < gh; ++j)
    for (int i = 0; i < gw; ++i)
    {
      Eigen::Vector2d b;
      const bool ok = pixelToBoard(camera, pose, cv::Point2d(rect.x + i * step - 0.5, rect.y + j * step - 0.5), &b);
      gx.at<double>(j, i) = ok ? b.x() : detail::kNaN;
      gy.at<double>(j, i) = ok ? b.y() : detail::kNaN;
    }
  bx->create(rect.height * sub + 1, rect.width * sub + 1, CV_64F);
  by->create(rect.height * sub + 1, rect.width * sub + 1, CV_64F);
  for (int v = 0; v < bx->rows; ++v)
    for (int u = 0; u < bx->cols; ++u)
    {
      const double pu = static_cast<double>(u) / sub / step, pv = static_cast<double>(v) / sub / step;
      const int i = std::min(gw - 2, static_cast<int>(pu)), j = std::min(gh - 2, static_cast<int>(pv));
      const double fu = pu - i, fv = pv - j;
      const auto lerp = [&](const cv::Mat& g)
      {
        return (1 - fv) * ((1 - fu) * g.at<double>(j, i) + fu * g.at<double>(j, i + 1)) +
               fv * ((1 - fu) * g.at<double>(j + 1, i) + fu * g.at<double>(j + 1, i + 1));
      };
      bx->at<double>(v, u) = lerp(gx);
      by->at<double>(v, u) = lerp(gy);
    }
}

// Mean albedo over a cell given the board coordinates of its corners: one
// value when the corners lie in one square, else ns x ns samples of the
// bilinear footprint; NaN when any part lies beyond the print.
float cellAlbedo(const BoardParams& params, bool square00_white, double black_ratio, const double x[4],
                 const double y[4], int ns)
{
  const long r00 = boardRegion(params, x[0], y[0]);
  const bool uniform = r00 == boardRegion(params, x[1], y[1]) && r00 == boardRegion(params, x[2], y[2]) &&
                       r00 == boardRegion(params, x[3], y[3]);
  if (uniform && r00 == kOutside)
    return std::numeric_limits<float>::quiet_NaN();
  if (uniform && r00 != kMargin)
    return static_cast<float>(boardAlbedo(params, square00_white, black_ratio, 0.25 * (x[0] + x[1] + x[2] + x[3]),
                                          0.25 * (y[0] + y[1] + y[2] + y[3])));
  // Corners order: (0,0), (1,0), (0,1), (1,1).
  double sum = 0.0;
  for (int b = 0; b < ns; ++b)
    for (int a = 0; a < ns; ++a)
    {
      const double fa = (a + 0.5) / ns, fb = (b + 0.5) / ns;
      const double px = (1 - fb) * ((1 - fa) * x[0] + fa * x[1]) + fb * ((1 - fa) * x[2] + fa * x[3]);
      const double py = (1 - fb) * ((1 - fa) * y[0] + fa * y[1]) + fb * ((1 - fa) * y[2] + fa * y[3]);
      const double alb = boardAlbedo(params, square00_white, black_ratio, px, py);
      if (std::isnan(alb))
        return std::numeric_limits<float>::quiet_NaN();
      sum += alb;
    }
  return static_cast<float>(sum / (ns * ns));
}

}  // namespace

cv::Mat renderBoardAlbedoWindow(const CameraModel& camera, const BoardParams& params, const Eigen::Isometry3d& pose,
                                bool square00_white, double black_ratio, const cv::Rect& rect, int subsample,
                                int edge_samples)
{
  const int sub = std::max(1, subsample);
  cv::Mat bx, by;
  boardCoordinatesAtCellCorners(camera, pose, rect, sub, &bx, &by);
  cv::Mat out(rect.height * sub, rect.width * sub, CV_32F);
  const int ns = std::max(1, edge_samples);
  for (int v = 0; v < out.rows; ++v)
    for (int u = 0; u < out.cols; ++u)
    {
      const double x[4] = {bx.at<double>(v, u), bx.at<double>(v, u + 1), bx.at<double>(v + 1, u),
                           bx.at<double>(v + 1, u + 1)};
      const double y[4] = {by.at<double>(v, u), by.at<double>(v, u + 1), by.at<double>(v + 1, u),
                           by.at<double>(v + 1, u + 1)};
      out.at<float>(v, u) = cellAlbedo(params, square00_white, black_ratio, x, y, ns);
    }
  return out;
}

cv::Mat renderBoardAlbedo(const CameraModel& camera, const BoardParams& params, const Eigen::Isometry3d& pose,
                          bool square00_white, double black_ratio, const cv::Size& size, int edge_samples)
{
  // Only the pixels of the print's image (its border sampled densely, since
  // lens distortion bends it) are rendered; the rest is NaN.
  const double s = params.square_m, m = params.margin_m;
  const double x0 = -s - m, y0 = -s - m, x1 = params.cols * s + m, y1 = params.rows * s + m;
  double u0 = size.width, v0 = size.height, u1 = -1.0, v1 = -1.0;
  for (int k = 0; k <= 64; ++k)
  {
    const double f = k / 64.0;
    for (const Eigen::Vector3d& b :
         {Eigen::Vector3d(x0 + f * (x1 - x0), y0, 0), Eigen::Vector3d(x0 + f * (x1 - x0), y1, 0),
          Eigen::Vector3d(x0, y0 + f * (y1 - y0), 0), Eigen::Vector3d(x1, y0 + f * (y1 - y0), 0)})
    {
      const cv::Point2d p = camera.project(pose * b);
      if (!std::isfinite(p.x))
      {
        u0 = v0 = 0.0;  // part of the print behind the camera: render everything
        u1 = size.width;
        v1 = size.height;
        continue;
      }
      u0 = std::min(u0, p.x);
      v0 = std::min(v0, p.y);
      u1 = std::max(u1, p.x);
      v1 = std::max(v1, p.y);
    }
  }
  const cv::Rect box = cv::Rect(cv::Point(static_cast<int>(std::floor(u0)) - 2, static_cast<int>(std::floor(v0)) - 2),
                                cv::Point(static_cast<int>(std::ceil(u1)) + 3, static_cast<int>(std::ceil(v1)) + 3)) &
                       cv::Rect(0, 0, size.width, size.height);
  cv::Mat out(size, CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  if (box.area() > 0)
    renderBoardAlbedoWindow(camera, params, pose, square00_white, black_ratio, box, 1, edge_samples).copyTo(out(box));
  return out;
}

}  // namespace structured_light_stabilizer
