// The stabilised image's warp (control/image_stabilizer.h) against rendered
// frames with ground truth: the simulator renders the rock (projector off,
// noise off) at the lock and after a known motion; warped with the true pose
// and the locked map, the rock at the dots must stand where it stood in the
// reference image (the rock's texture registered by least squares in a window
// at each dot, on the noise-free radiance), while in the raw frame it moved by pixels. The exact
// source pixel of the map's own points equals their projection; the plane
// model errs by the relief's parallax; bad inputs are refused.
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/control/image_stabilizer.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

using namespace structured_light_stabilizer;

namespace
{

SimulatorParams quietScene()
{
  SimulatorParams p;
  p.keep_linear = true;  // the radiance before quantisation: sub-0.01 px shifts measurable
  p.sensor.natural_vignetting = false;  // fixed to the camera, not the rock
  p.rock_subsample = 1;
  p.rock.relief_m = 0.25;  // parallax that a plane cannot model
  // 4 mm and 3 mrad in 1 s: the open loop of a vibrating arm.
  p.motion.drift_velocity_mps = Eigen::Vector3d(0.003, -0.002, 0.0015);
  p.motion.drift_angular_velocity_radps = Eigen::Vector3d(0.002, -0.0015, 0.001);
  return p;
}

// The green channel, lightly smoothed: the least-squares shift needs
// gradients that the 3x3 derivative measures right.
cv::Mat green(const cv::Mat& linear)
{
  cv::Mat channels[3], f, smooth;
  cv::split(linear, channels);
  channels[1].convertTo(f, CV_64F);
  cv::GaussianBlur(f, smooth, cv::Size(0, 0), 2.0);
  return smooth;
}

// Shift of `moved` against `reference` in a window centred at p (px): the
// least-squares (Lucas-Kanade) solution of the texture's brightness
// constancy, iterated; valid below a pixel. NaN when the window leaves the
// image or has no texture.
cv::Point2d shiftAt(const cv::Mat& reference, const cv::Mat& moved, const cv::Point2d& p, int half = 20)
{
  const cv::Rect r(static_cast<int>(std::lround(p.x)) - half, static_cast<int>(std::lround(p.y)) - half, 2 * half,
                   2 * half);
  const cv::Rect border(2, 2, reference.cols - 4, reference.rows - 4);
  if ((r & border) != r)
    return cv::Point2d(NAN, NAN);
  cv::Mat gx, gy;
  const cv::Rect around(r.x - 1, r.y - 1, r.width + 2, r.height + 2);
  cv::Sobel(reference(around), gx, CV_64F, 1, 0, 3, 1.0 / 8.0);
  cv::Sobel(reference(around), gy, CV_64F, 0, 1, 3, 1.0 / 8.0);
  cv::Point2d d(0.0, 0.0);
  for (int iteration = 0; iteration < 5; ++iteration)
  {
    // moved(x) = reference(x - d): the residual's gradient along -d.
    double a = 0, b = 0, c = 0, ex = 0, ey = 0;
    for (int y = r.y; y < r.y + r.height; ++y)
      for (int x = r.x; x < r.x + r.width; ++x)
      {
        const double sx = x + d.x, sy = y + d.y;
        const int x0 = static_cast<int>(std::floor(sx)), y0 = static_cast<int>(std::floor(sy));
        const double fx = sx - x0, fy = sy - y0;
        const double m = (1 - fy) * ((1 - fx) * moved.at<double>(y0, x0) + fx * moved.at<double>(y0, x0 + 1)) +
                         fy * ((1 - fx) * moved.at<double>(y0 + 1, x0) + fx * moved.at<double>(y0 + 1, x0 + 1));
        const double e = m - reference.at<double>(y, x);
        const double u = gx.at<double>(y - around.y, x - around.x), v = gy.at<double>(y - around.y, x - around.x);
        a += u * u, b += u * v, c += v * v, ex += u * e, ey += v * e;
      }
    const double det = a * c - b * b;
    if (!(det > 1e-12 * (a + c) * (a + c)))
      return cv::Point2d(NAN, NAN);
    d.x -= (c * ex - b * ey) / det;
    d.y -= (a * ey - b * ex) / det;
  }
  return d;
}

struct Shifts
{
  double rms = 0.0, worst = 0.0;
  int n = 0;
};

Shifts shiftsAt(const cv::Mat& reference, const cv::Mat& moved, const std::vector<cv::Point2d>& at)
{
  Shifts s;
  for (const cv::Point2d& p : at)
  {
    const cv::Point2d d = shiftAt(reference, moved, p);
    if (!std::isfinite(d.x))
      continue;
    const double e = std::hypot(d.x, d.y);
    s.rms += e * e;
    s.worst = std::max(s.worst, e);
    ++s.n;
  }
  if (s.n > 0)
    s.rms = std::sqrt(s.rms / s.n);
  return s;
}

}  // namespace

TEST(ImageStabilizer, TheRockStandsStillAtTheDots)
{
  const Simulator sim(quietScene());
  FrameRequest off;
  off.projector_on = false;
  const SimFrame ref = sim.render(0.0, off);
  const SimFrame cur = sim.render(1.0, off);
  const ProjectorCalibration& projector = sim.projector();
  ReferenceSurface surface;
  std::string why;
  ASSERT_TRUE(surface.build(projector.rows, projector.cols, ref.points, StabilizerSurface::kSurface, &why)) << why;
  ImageStabilizer stabilizer;
  ASSERT_TRUE(stabilizer.setReference(sim.camera(), surface, &why)) << why;
  cv::Mat warped;
  ASSERT_TRUE(stabilizer.warp(cur.linear, cur.delta, &warped, &why)) << why;
  std::vector<cv::Point2d> dots;
  double raw_sq = 0.0;
  for (size_t b = 0; b < ref.pixels.size(); ++b)
    if (ref.visible[b])
    {
      dots.push_back(ref.pixels[b]);
      const cv::Point2d now = sim.camera().project(cur.delta * ref.points[b]);
      raw_sq += std::pow(now.x - ref.pixels[b].x, 2) + std::pow(now.y - ref.pixels[b].y, 2);
    }
  ASSERT_GT(dots.size(), 90u);
  const double raw_rms = std::sqrt(raw_sq / dots.size());
  const cv::Mat g_ref = green(ref.linear);
  const Shifts stab = shiftsAt(g_ref, green(warped), dots);
  // The measurement checked: the reference shifted by a known subpixel
  // amount (multiples of 1/32 px: warpAffine's interpolation table is exact there).
  cv::Mat shifted;
  const cv::Mat M = (cv::Mat_<double>(2, 3) << 1, 0, 0.3125, 0, 1, -0.1875);
  cv::warpAffine(g_ref, shifted, M, g_ref.size(), cv::INTER_LINEAR);
  const cv::Point2d known = shiftAt(g_ref, shifted, dots[40]);
  std::printf("[ MEASURE ] rock at the dots, 4 mm 3 mrad: raw %.2f px RMS, stabilised %.4f px RMS (worst %.4f), %d "
              "dots; a known (0.3125, -0.1875) px shift measures (%.4f, %.4f)\n",
              raw_rms, stab.rms, stab.worst, stab.n, known.x, known.y);
  EXPECT_NEAR(known.x, 0.3125, 0.01);
  EXPECT_NEAR(known.y, -0.1875, 0.01);
  EXPECT_GT(raw_rms, 3.0);  // the motion is visible
  EXPECT_GT(stab.n, 90);
  EXPECT_LT(stab.rms, 0.03);
  EXPECT_LT(stab.worst, 0.1);

  // The map's own points: the warp reads exactly where they are now (the
  // outer ring of beams, beyond the surface's cells, reads the plane).
  double worst_inner = 0.0, worst_edge = 0.0;
  for (size_t b = 0; b < ref.pixels.size(); ++b)
  {
    if (!ref.visible[b])
      continue;
    cv::Point2d source;
    ASSERT_TRUE(stabilizer.sourcePixel(ref.pixels[b], cur.delta, &source));
    const cv::Point2d truth = sim.camera().project(cur.delta * ref.points[b]);
    const int r = static_cast<int>(b) / projector.cols, c = static_cast<int>(b) % projector.cols;
    const bool edge = r == 0 || c == 0 || r == projector.rows - 1 || c == projector.cols - 1;
    double& worst = edge ? worst_edge : worst_inner;
    worst = std::max(worst, std::hypot(source.x - truth.x, source.y - truth.y));
  }
  EXPECT_LT(worst_inner, 1e-3);
  EXPECT_LT(worst_edge, 0.15);

  // A plane through the map errs by the relief's parallax (translation over depth differences).
  ReferenceSurface plane;
  ASSERT_TRUE(plane.build(projector.rows, projector.cols, ref.points, StabilizerSurface::kPlane, &why)) << why;
  ImageStabilizer flat;
  ASSERT_TRUE(flat.setReference(sim.camera(), plane, &why)) << why;
  ASSERT_TRUE(flat.warp(cur.linear, cur.delta, &warped, &why));
  const Shifts planar = shiftsAt(g_ref, green(warped), dots);
  std::printf("[ MEASURE ] with the plane: %.3f px RMS (worst %.3f)\n", planar.rms, planar.worst);
  EXPECT_LT(planar.rms, 0.5);
  EXPECT_GT(planar.rms, 1.5 * stab.rms);
}

TEST(ImageStabilizer, BadInputsAreRefused)
{
  std::string why;
  ReferenceSurface surface;
  std::vector<Eigen::Vector3d> few(4, Eigen::Vector3d(NAN, NAN, NAN));
  few[0] = Eigen::Vector3d(0, 0, 1.5);
  EXPECT_FALSE(surface.build(2, 2, few, StabilizerSurface::kSurface, &why));
  EXPECT_NE(why.find("fewer than 3"), std::string::npos) << why;
  std::vector<Eigen::Vector3d> line = {Eigen::Vector3d(0, 0, 1.5), Eigen::Vector3d(0.1, 0, 1.5),
                                       Eigen::Vector3d(0.2, 0, 1.5), Eigen::Vector3d(0.3, 0, 1.5)};
  EXPECT_FALSE(surface.build(2, 2, line, StabilizerSurface::kPlane, &why));
  EXPECT_NE(why.find("line"), std::string::npos) << why;
  EXPECT_FALSE(surface.build(3, 3, line, StabilizerSurface::kPlane, &why));  // not rows x cols

  ImageStabilizer stabilizer;
  cv::Mat out;
  EXPECT_FALSE(stabilizer.warp(cv::Mat(10, 10, CV_8UC3), Eigen::Isometry3d::Identity(), &out, &why));
  EXPECT_NE(why.find("no reference"), std::string::npos) << why;
  std::vector<Eigen::Vector3d> square = {Eigen::Vector3d(-0.1, -0.1, 1.5), Eigen::Vector3d(0.1, -0.1, 1.5),
                                         Eigen::Vector3d(-0.1, 0.1, 1.5), Eigen::Vector3d(0.1, 0.1, 1.5)};
  ASSERT_TRUE(surface.build(2, 2, square, StabilizerSurface::kPlane, &why)) << why;
  ASSERT_TRUE(stabilizer.setReference(CameraModel::studyDesign(), surface, &why)) << why;
  EXPECT_FALSE(stabilizer.warp(cv::Mat(10, 10, CV_8UC3), Eigen::Isometry3d::Identity(), &out, &why));
  EXPECT_NE(why.find("reference camera is 1024x1024"), std::string::npos) << why;
  Eigen::Isometry3d nan = Eigen::Isometry3d::Identity();
  nan.translation().x() = NAN;
  EXPECT_FALSE(stabilizer.warp(cv::Mat(1024, 1024, CV_8UC3, cv::Scalar::all(0)), nan, &out, &why));
  EXPECT_NE(why.find("not finite"), std::string::npos) << why;
  // Identity pose: the image unchanged (inside the map's plane everywhere).
  cv::Mat ramp(1024, 1024, CV_8UC1);
  for (int y = 0; y < ramp.rows; ++y)
    for (int x = 0; x < ramp.cols; ++x)
      ramp.at<uint8_t>(y, x) = static_cast<uint8_t>((x + 3 * y) % 251);
  ASSERT_TRUE(stabilizer.warp(ramp, Eigen::Isometry3d::Identity(), &out, &why)) << why;
  EXPECT_EQ(cv::norm(ramp, out, cv::NORM_INF), 0.0);
  ImageStabilizerParams bad;
  bad.grid_step_px = 1;
  EXPECT_THROW(ImageStabilizer{bad}, std::invalid_argument);
}
