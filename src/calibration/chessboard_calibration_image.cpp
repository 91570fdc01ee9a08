// The picture of a chessboard calibration (chessboard_calibration.h):
// residuals per beam as the pattern's grid, and the fitted rays with the
// boards seen from above.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/calibration/chessboard_calibration.h"

namespace structured_light_stabilizer
{

namespace
{

void text(cv::Mat& img, const std::string& s, cv::Point p, double scale = 0.45, cv::Scalar colour = {30, 30, 30})
{
  cv::putText(img, s, p, cv::FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv::LINE_AA);
}

// Blue (0) .. red (worst) through green and yellow.
cv::Scalar heat(double f)
{
  f = std::max(0.0, std::min(1.0, f));
  return f < 0.5 ? cv::Scalar(255 * (1 - 2 * f), 200, 255 * 2 * f) : cv::Scalar(0, 255 * (2 - 2 * f), 255);
}

// Left panel: each beam's RMS residual (px) at its place in the pattern.
void drawResiduals(const ChessboardCalibrationResult& res, cv::Mat& img, cv::Rect area)
{
  const JointFitResult& fit = res.fit;
  const int rows = fit.calibration.rows, cols = fit.calibration.cols;
  double worst = 1e-3;
  for (const JointFitBeamReport& b : fit.beams)
    worst = std::max(worst, b.rms_px);
  const int cell = std::min((area.width - 20) / cols, (area.height - 80) / rows);
  text(img, "RMS residual per beam (px), rows x cols as projected", {area.x + 10, area.y + 22}, 0.5);
  char buf[64];
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < cols; ++c)
    {
      const JointFitBeamReport& b = fit.beams[r * cols + c];
      const cv::Rect box(area.x + 10 + c * cell, area.y + 40 + r * cell, cell - 2, cell - 2);
      cv::rectangle(img, box, heat(b.rms_px / worst), cv::FILLED);
      std::snprintf(buf, sizeof(buf), "%.2f", b.rms_px);
      text(img, buf, {box.x + 3, box.y + box.height / 2 + 4}, 0.33);
    }
  std::snprintf(buf, sizeof(buf), "blue 0 px .. red %.3f px; model %s, %zu outlier(s)", worst,
                projectorModelName(fit.model), fit.outliers.size());
  text(img, buf, {area.x + 10, area.y + 40 + rows * cell + 22});
}

// Right panel: x (right) against z (up the panel) in the camera frame: the
// camera, the fitted rays to beyond the farthest board, and each used
// board's trace in the y = 0 plane region it covers.
void drawTopView(const ChessboardCalibrationResult& res, const BoardParams& board, cv::Mat& img, cv::Rect area)
{
  const JointFitResult& fit = res.fit;
  double zmax = 0.5, xmin = -0.2, xmax = 0.4;
  for (const Eigen::Isometry3d& p : fit.poses)
    zmax = std::max(zmax, p.translation().z() + 0.4);
  for (const BeamRay& r : fit.calibration.beams)
  {
    const Eigen::Vector3d far = r.pointAt((zmax - r.origin.z()) / r.direction.z());
    xmin = std::min({xmin, far.x(), r.origin.x()});
    xmax = std::max({xmax, far.x(), r.origin.x()});
  }
  const double zmin = -0.1;
  const double scale = std::min((area.width - 40) / (xmax - xmin), (area.height - 60) / (zmax - zmin));
  const auto px = [&](double x, double z)
  {
    return cv::Point(area.x + 20 + static_cast<int>((x - xmin) * scale),
                     area.y + area.height - 30 - static_cast<int>((z - zmin) * scale));
  };
  text(img, "seen from above: x (m) right, z (m) up; camera at (0, 0)", {area.x + 10, area.y + 22}, 0.5);
  for (const BeamRay& r : fit.calibration.beams)
  {
    const Eigen::Vector3d far = r.pointAt((zmax - r.origin.z()) / r.direction.z());
    cv::line(img, px(r.origin.x(), r.origin.z()), px(far.x(), far.z()), {60, 160, 60}, 1, cv::LINE_AA);
  }
  for (const Eigen::Isometry3d& p : fit.poses)
  {
    const Eigen::Vector3d a = p * Eigen::Vector3d(-board.square_m, 0.5 * board.rows * board.square_m, 0.0);
    const Eigen::Vector3d b = p * Eigen::Vector3d(board.cols * board.square_m, 0.5 * board.rows * board.square_m, 0.0);
    cv::line(img, px(a.x(), a.z()), px(b.x(), b.z()), {40, 40, 200}, 2, cv::LINE_AA);
  }
  cv::circle(img, px(0, 0), 5, {0, 0, 0}, cv::FILLED);
  cv::circle(img, px(fit.centre.x(), fit.centre.z()), 5, {200, 60, 60}, cv::FILLED);
  text(img, "camera", px(0, 0) + cv::Point(8, 16));
  text(img, "projector centre", px(fit.centre.x(), fit.centre.z()) + cv::Point(8, 16));
  for (double z = 0.0; z <= zmax; z += 0.5)
  {
    cv::line(img, px(xmin, z), px(xmin, z) + cv::Point(8, 0), {0, 0, 0});
    char buf[16];
    std::snprintf(buf, sizeof(buf), "z %.1f m", z);
    text(img, buf, px(xmin, z) + cv::Point(14, 4), 0.4);
  }
  text(img, "green: fitted rays; red: the boards", {area.x + 10, area.y + area.height - 8});
}

}  // namespace

cv::Mat drawCalibrationReport(const ChessboardCalibrationResult& res, const BoardParams& board)
{
  cv::Mat img(620, 1240, CV_8UC3, cv::Scalar(255, 255, 255));
  if (!res.ok)
  {
    text(img, "calibration failed: " + res.error.substr(0, 120), {20, 40}, 0.55, {0, 0, 200});
    return img;
  }
  drawResiduals(res, img, cv::Rect(0, 0, 560, 620));
  drawTopView(res, board, img, cv::Rect(560, 0, 680, 620));
  return img;
}

}  // namespace structured_light_stabilizer
