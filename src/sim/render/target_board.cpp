#include "sim/render/target_board.h"

#include <algorithm>
#include <cmath>

#include <opencv2/core.hpp>

#include "sim/render/optics.h"
#include "sim/render/rock_render.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

// Diffraction of the sunlit print: the middle of the visible band.
constexpr double kWhiteLightNm = 550.0;

// Standard normal CDF.
double normalCdf(double z)
{
  return 0.5 * std::erfc(-z * M_SQRT1_2);
}

}  // namespace

ChessboardPattern::ChessboardPattern(const ChessboardParams& params)
  : p_(params), cx_(0.5 * (params.cols - 1) * params.square_m), cy_(0.5 * (params.rows - 1) * params.square_m)
{
}

// Cells j (of width square) along the axis: the squares are j = -1 .. n - 1,
// parity +1 for odd j (so the square (-1, -1) is dark: the product is +1).
// The Gaussian blur takes the cell under b and its two neighbours (sigma is
// held to a quarter square, so farther cells weigh < 3e-5); far from any edge
// the sharp value is exact.
void ChessboardPattern::blurredAxis(double b, double sigma, int n, double* wave, double* inside) const
{
  const double sq = p_.square_m;
  sigma = std::min(sigma, 0.25 * sq);
  const double f = b / sq;
  const int k = static_cast<int>(std::floor(f));
  auto cell_wave = [n](int j) { return j < -1 || j > n - 1 ? 0.0 : (j % 2 != 0 ? 1.0 : -1.0); };
  auto cell_inside = [n](int j) { return j < -1 || j > n - 1 ? 0.0 : 1.0; };
  const double edge_distance = std::min(f - k, k + 1 - f) * sq;
  if (!(edge_distance < 5.0 * sigma))
  {
    *wave = cell_wave(k);
    *inside = cell_inside(k);
    return;
  }
  *wave = *inside = 0.0;
  for (int j = k - 1; j <= k + 1; ++j)
  {
    const double w = normalCdf(((j + 1) * sq - b) / sigma) - normalCdf((j * sq - b) / sigma);
    *wave += cell_wave(j) * w;
    *inside += cell_inside(j) * w;
  }
}

double ChessboardPattern::reflectance(double x, double y, double blur_x, double blur_y) const
{
  double wx, ix, wy, iy;
  blurredAxis(x + cx_, blur_x, p_.cols, &wx, &ix);
  blurredAxis(y + cy_, blur_y, p_.rows, &wy, &iy);
  // Darkness 1 on dark squares, 0 on light ones and the margin: the
  // separable product 0.5 (inside_x inside_y + wave_x wave_y).
  const double darkness = 0.5 * (ix * iy + wx * wy);
  return p_.white - (p_.white - p_.black) * darkness;
}

RockParams boardSlab(const ChessboardParams& board, const RockParams& rock)
{
  RockParams r = rock;
  r.width_m = (board.cols + 1) * board.square_m + 2.0 * board.margin_m;
  r.height_m = (board.rows + 1) * board.square_m + 2.0 * board.margin_m;
  r.relief_m = 0.0;
  r.step_height_m = 0.0;
  r.tilt_x_rad = r.tilt_y_rad = 0.0;
  r.distance_m = board.distance_m;
  r.fine_texture_period_m = 0.0;
  return r;
}

Eigen::Isometry3d boardRockFromCamera0(const ChessboardParams& board)
{
  Eigen::Isometry3d T_cam0_rock = Eigen::Isometry3d::Identity();
  T_cam0_rock.linear() = (Eigen::AngleAxisd(board.tilt_x_rad, Eigen::Vector3d::UnitX()) *
                          Eigen::AngleAxisd(board.tilt_y_rad, Eigen::Vector3d::UnitY()) *
                          Eigen::AngleAxisd(board.roll_rad, Eigen::Vector3d::UnitZ()))
                             .toRotationMatrix();
  T_cam0_rock.translation() = Eigen::Vector3d(board.offset_m.x(), board.offset_m.y(), board.distance_m);
  return T_cam0_rock.inverse();
}

namespace
{

// One row of board samples: each pixel's ray meets the plane z = 0 of the
// rock frame; the print is box-filtered over the pixel's footprint on the
// board (as a Gaussian of the box's variance, per board axis).
void boardRow(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor, const FrameGeometry& g,
              double sun, int v, float* row)
{
  const CameraModel& cam = sensor.camera;
  const bool vignetting = sensor.natural_vignetting;
  const double sharp_var = kPixelBoxVariance + detail::square(diffractionSigmaPx(sensor, kWhiteLightNm));
  const Eigen::Matrix3d& R = g.R;
  const Eigen::Vector3d& o = g.o;
  const double shade = std::max(0.0, -rock.sun_dir.z()) + rock.sky;
  for (int u = 0; u < sampling.rw; ++u)
  {
    double xn, yn;
    if (!sampling.ray_lut.empty())
    {
      const float* p = &sampling.ray_lut[2 * (static_cast<size_t>(v) * sampling.rw + u)];
      xn = p[0];
      yn = p[1];
    }
    else
    {
      xn = (u - cam.cx) / cam.fx;
      yn = (v - cam.cy) / cam.fy;
    }
    const Eigen::Vector3d d = R * Eigen::Vector3d(xn, yn, 1.0);
    const double s = -o.z() / d.z();
    const double x = o.x() + s * d.x(), y = o.y() + s * d.y();
    double scale = sun;
    if (vignetting)
    {
      const double q = 1.0 + xn * xn + yn * yn;
      scale /= q * q;
    }
    float* out = row + 3 * u;
    if (!(s > 0.0) || !rock.inside(x, y))
    {
      for (int c = 0; c < 3; ++c)
        out[c] = static_cast<float>(kBackgroundBgr[c] * (rock.sky + 0.5) * scale);
      continue;
    }
    // d(x, y)/d(xn, yn) on the plane, then per pixel.
    const double kx = o.z() / (d.z() * d.z());
    const Eigen::Vector3d dp_dx = s * R.col(0) + kx * R(2, 0) * d, dp_dy = s * R.col(1) + kx * R(2, 1) * d;
    const double xu = dp_dx.x() / cam.fx, xv = dp_dy.x() / cam.fy, yu = dp_dx.y() / cam.fx, yv = dp_dy.y() / cam.fy;
    // The camera frame depth of the point is s (the ray's z is 1).
    const double var_px = sharp_var + detail::square(defocusSigmaPx(sensor, s));
    const double rho =
        rock.board->reflectance(x, y, std::sqrt((xu * xu + xv * xv) * var_px), std::sqrt((yu * yu + yv * yv) * var_px));
    for (int c = 0; c < 3; ++c)
      out[c] = static_cast<float>(rho * shade * scale);
  }
}

}  // namespace

void renderBoardSamples(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor,
                        const FrameGeometry& g, double sun, float* rows)
{
  const size_t stride = sampling.stride();
  cv::parallel_for_(cv::Range(0, sampling.rh),
                    [&](const cv::Range& range)
                    {
                      for (int v = range.start; v < range.end; ++v)
                        boardRow(rock, sampling, sensor, g, sun, v, rows + stride * v);
                    });
}

void boardTruth(const ChessboardParams& board, const CameraModel& cam, const FrameGeometry& g, Eigen::Isometry3d* pose,
                std::vector<cv::Point2d>* corners)
{
  *pose = g.T_cr * Eigen::Translation3d(-ChessboardPattern(board).centre());
  corners->assign(static_cast<size_t>(board.cols) * board.rows, cv::Point2d(detail::kNaN, detail::kNaN));
  for (int j = 0; j < board.rows; ++j)
    for (int i = 0; i < board.cols; ++i)
    {
      const Eigen::Vector3d X = *pose * Eigen::Vector3d(i * board.square_m, j * board.square_m, 0.0);
      if (!(X.z() > 0.0))
        continue;
      const cv::Point2d p = cam.project(X);
      if (p.x >= 0.0 && p.y >= 0.0 && p.x <= cam.width - 1 && p.y <= cam.height - 1)
        (*corners)[static_cast<size_t>(j) * board.cols + i] = p;
    }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
