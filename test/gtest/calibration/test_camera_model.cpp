// Camera model and projector calibration: projection/back-projection round
// trips against analytic values and against OpenCV's own implementation of
// each distortion model (cv::projectPoints, cv::fisheye::projectPoints,
// cv::undistortPoints), the sensor window (binning, ROI) against a binned
// rendering of a dot, and the calibration loader's refusals.
#include <cmath>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"

using namespace structured_light_stabilizer;

namespace
{
std::string precise(double v)
{
  std::ostringstream s;
  s.precision(17);
  s << v;
  return s.str();
}
}  // namespace

namespace
{
// A lens of each model, strong enough that 0.01 px errors would show
// (several pixels of distortion at the corners of the study's camera).
CameraModel lens(DistortionModel dm)
{
  CameraModel m = CameraModel::studyDesign();
  m.distortion = dm;
  m.fx = 1011.67;
  m.fy = 1009.3;
  m.cx = 515.2;
  m.cy = 507.9;
  switch (dm)
  {
    case DistortionModel::kPlumbBob:
      m.D = {-0.12, 0.03, 0.001, -0.0005, 0.002};
      break;
    case DistortionModel::kRationalPolynomial:
      // What camera_calibration writes for a wide lens: k4..k6 large.
      m.D = {0.8, -0.2, 0.0008, -0.0004, 0.01, 0.95, -0.05, 0.02};
      break;
    case DistortionModel::kEquidistant:
      m.D = {0.05, -0.01, 0.002, 0.0};
      break;
    default:
      break;
  }
  return m;
}

cv::Mat intrinsicMatrix(const CameraModel& m)
{
  return (cv::Mat_<double>(3, 3) << m.fx, 0, m.cx, 0, m.fy, m.cy, 0, 0, 1);
}

// Points in front of the camera spread over the image (x/z, y/z within +-0.45).
std::vector<cv::Point3d> gridPoints()
{
  std::vector<cv::Point3d> pts;
  for (double x = -0.45; x <= 0.451; x += 0.09)
    for (double y = -0.45; y <= 0.451; y += 0.09)
      pts.emplace_back(1.3 * x, 1.3 * y, 1.3);
  return pts;
}
}  // namespace

TEST(CameraModel, StudyDesignIntrinsics)
{
  const CameraModel m = CameraModel::studyDesign();
  EXPECT_EQ(m.width, 1024);
  // f = 12.14 mm over 12 um pixels.
  EXPECT_NEAR(m.fx, 1011.6667, 1e-3);
  EXPECT_TRUE(m.validate().empty());
  // A point on the optical axis lands on the principal point.
  const cv::Point2d c = m.project({0, 0, 1.5});
  EXPECT_NEAR(c.x, 511.5, 1e-12);
  EXPECT_NEAR(c.y, 511.5, 1e-12);
}

TEST(CameraModel, DistortionRoundTrip)
{
  for (DistortionModel dm :
       {DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial, DistortionModel::kEquidistant})
  {
    const CameraModel m = lens(dm);
    ASSERT_TRUE(m.validate().empty()) << m.validate();
    double worst = 0.0;
    for (double x = -0.45; x <= 0.45; x += 0.05)
    {
      for (double y = -0.45; y <= 0.45; y += 0.05)
      {
        const Eigen::Vector3d p(x, y, 1.0);
        const cv::Point2d px = m.project(p * 1.7);
        const Eigen::Vector3d r = m.ray(px);
        worst = std::max(worst, (r - p.normalized()).norm());
      }
    }
    // The inverse must be far below the 0.01 px level that the detector aims at:
    // 1e-9 rad at fx = 1012 px is 1e-6 px.
    EXPECT_LT(worst, 1e-9) << CameraModel::distortionModelName(dm);
  }
}

// Independent check: OpenCV's projectPoints implements plumb_bob (5 values),
// rational_polynomial (8) and the thin prism (12); cv::fisheye the
// equidistant model. Our project() must agree to far below 0.01 px.
TEST(CameraModel, ProjectionMatchesOpenCvForEveryModel)
{
  const std::vector<cv::Point3d> pts = gridPoints();
  const cv::Mat rvec = cv::Mat::zeros(3, 1, CV_64F), tvec = cv::Mat::zeros(3, 1, CV_64F);
  for (DistortionModel dm :
       {DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial, DistortionModel::kEquidistant})
  {
    CameraModel m = lens(dm);
    ASSERT_TRUE(m.validate().empty()) << m.validate();
    std::vector<cv::Point2d> cv_px;
    if (dm == DistortionModel::kEquidistant)
      cv::fisheye::projectPoints(pts, cv_px, rvec, tvec, intrinsicMatrix(m), m.D);
    else
      cv::projectPoints(pts, rvec, tvec, intrinsicMatrix(m), m.D, cv_px);
    double worst = 0.0, largest_distortion = 0.0;
    for (size_t i = 0; i < pts.size(); ++i)
    {
      const cv::Point2d ours = m.project({pts[i].x, pts[i].y, pts[i].z});
      worst = std::max(worst, cv::norm(ours - cv_px[i]));
      const cv::Point2d pinhole(m.fx * pts[i].x / pts[i].z + m.cx, m.fy * pts[i].y / pts[i].z + m.cy);
      largest_distortion = std::max(largest_distortion, cv::norm(ours - pinhole));
    }
    const std::string name = CameraModel::distortionModelName(dm);
    EXPECT_LT(worst, 1e-6) << name;
    EXPECT_GT(largest_distortion, 3.0) << name << ": the lens is too weak for the test to mean anything";
  }
  // Thin prism: 12 rational coefficients.
  CameraModel m = lens(DistortionModel::kRationalPolynomial);
  m.D.insert(m.D.end(), {0.001, -0.0005, 0.0007, 0.0002});
  ASSERT_TRUE(m.validate().empty()) << m.validate();
  std::vector<cv::Point2d> cv_px;
  cv::projectPoints(pts, rvec, tvec, intrinsicMatrix(m), m.D, cv_px);
  for (size_t i = 0; i < pts.size(); ++i)
    EXPECT_LT(cv::norm(m.project({pts[i].x, pts[i].y, pts[i].z}) - cv_px[i]), 1e-6);
}

// The inverse (undistortion): round trip to 1e-6 px, and OpenCV's iterative
// undistortPoints (run to convergence) lands on the same normalised point.
TEST(CameraModel, UndistortionInvertsEveryModel)
{
  for (DistortionModel dm :
       {DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial, DistortionModel::kEquidistant})
  {
    const CameraModel m = lens(dm);
    const std::string name = CameraModel::distortionModelName(dm);
    std::vector<cv::Point2d> px;
    std::vector<Eigen::Vector2d> truth;
    for (const cv::Point3d& p : gridPoints())
    {
      px.push_back(m.project({p.x, p.y, p.z}));
      truth.emplace_back(p.x / p.z, p.y / p.z);
    }
    std::vector<cv::Point2d> cv_norm;
    if (dm == DistortionModel::kEquidistant)
      cv::fisheye::undistortPoints(px, cv_norm, intrinsicMatrix(m), m.D, cv::noArray(), cv::noArray(),
                                   cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-14));
    else
      cv::undistortPoints(px, cv_norm, intrinsicMatrix(m), m.D, cv::noArray(), cv::noArray(),
                          cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-14));
    double worst = 0.0, worst_cv = 0.0;
    for (size_t i = 0; i < px.size(); ++i)
    {
      const Eigen::Vector2d n = m.normalize(px[i]);
      worst = std::max(worst, (n - truth[i]).norm() * m.fx);
      worst_cv = std::max(worst_cv, (n - Eigen::Vector2d(cv_norm[i].x, cv_norm[i].y)).norm() * m.fx);
    }
    EXPECT_LT(worst, 1e-6) << name << " (px)";
    EXPECT_LT(worst_cv, 1e-3) << name << " vs OpenCV (px)";
  }
}

// Beyond a rational model's fold (denominator <= 0) there is no pixel, and a
// pixel whose inversion does not converge has no ray: NaN, never a wrong ray.
TEST(CameraModel, RationalModelOutsideItsDomainGivesNaN)
{
  CameraModel m = lens(DistortionModel::kRationalPolynomial);
  m.D = {0.0, 0.0, 0.0, 0.0, 0.0, -4.0, 0.0, 0.0};  // denominator 1 - 4 r^2: fold at r = 0.5
  ASSERT_TRUE(m.validate().empty());
  EXPECT_TRUE(std::isfinite(m.project({0.3, 0.0, 1.0}).x));
  EXPECT_TRUE(std::isnan(m.project({0.6, 0.0, 1.0}).x));
  m.D = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
  EXPECT_TRUE(m.validate().empty());
  m.D.resize(5);
  EXPECT_NE(m.validate().find("8 coefficients"), std::string::npos);
}

// The sensor window against physics: a Gaussian dot rendered on the full
// sensor and binned by averaging b x b blocks (what the camera does) has its
// intensity centroid where SensorWindow::toImage() puts the true position;
// image_geometry's mapping (no (b - 1) / 2 term) would be 0.25 px off at 2x2.
TEST(SensorWindow, BinnedDotCentroidFollowsTheWindow)
{
  const cv::Point2d dot(301.37, 218.81);  // full-resolution pixels
  const double sigma = 2.5;
  cv::Mat full(512, 640, CV_64F);
  for (int r = 0; r < full.rows; ++r)
    for (int c = 0; c < full.cols; ++c)
      full.at<double>(r, c) =
          std::exp(-0.5 * ((c - dot.x) * (c - dot.x) + (r - dot.y) * (r - dot.y)) / (sigma * sigma));
  for (const SensorWindow w : {SensorWindow{2, 2, 0, 0, 0, 0}, SensorWindow{2, 2, 128, 64, 384, 320},
                               SensorWindow{3, 2, 33, 17, 600, 400}, SensorWindow{1, 1, 100, 50, 300, 300}})
  {
    ASSERT_TRUE(w.validate(full.cols, full.rows).empty()) << w.validate(full.cols, full.rows);
    const cv::Rect roi = w.roi(full.cols, full.rows);
    const cv::Size size = w.imageSize(full.cols, full.rows);
    cv::Mat binned;
    cv::resize(full(cv::Rect(roi.x, roi.y, size.width * w.binning_x, size.height * w.binning_y)), binned, size, 0, 0,
               cv::INTER_AREA);  // integer factors: the mean of each block
    const cv::Moments mo = cv::moments(binned);
    const cv::Point2d centroid(mo.m10 / mo.m00, mo.m01 / mo.m00);
    const cv::Point2d expected = w.toImage(dot);
    EXPECT_LT(cv::norm(centroid - expected), 1e-3) << "binning " << w.binning_x << "x" << w.binning_y;
    EXPECT_LT(cv::norm(w.toFull(expected) - dot), 1e-12);
    if (w.binning_x == 2)
    {
      const cv::Point2d image_geometry((dot.x - roi.x) / 2.0, (dot.y - roi.y) / 2.0);
      EXPECT_NEAR(cv::norm(centroid - image_geometry), 0.25 * std::sqrt(2.0), 1e-3);
    }
  }
}

// The windowed model projects every point where the full model's pixel goes
// through the window, for every distortion model, and its rays are the same.
TEST(SensorWindow, WindowedModelEqualsFullModelThroughTheWindow)
{
  const SensorWindow w{2, 2, 128, 96, 768, 832};
  for (DistortionModel dm : {DistortionModel::kNone, DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial,
                             DistortionModel::kEquidistant})
  {
    const CameraModel full = lens(dm);
    const CameraModel win = full.windowed(w);
    ASSERT_TRUE(win.validate().empty());
    EXPECT_EQ(win.width, 384);
    EXPECT_EQ(win.height, 416);
    for (const cv::Point3d& p : gridPoints())
    {
      const Eigen::Vector3d X(p.x, p.y, p.z);
      EXPECT_LT(cv::norm(win.project(X) - w.toImage(full.project(X))), 1e-9);
      const cv::Point2d px = win.project(X);
      EXPECT_LT((win.ray(px) - X.normalized()).norm(), 1e-9);
    }
  }
}

TEST(SensorWindow, RefusesWindowsThatDoNotFit)
{
  EXPECT_TRUE((SensorWindow{}).validate(1024, 1024).empty());
  EXPECT_TRUE((SensorWindow{}).isFullSensor(1024, 1024));
  EXPECT_FALSE((SensorWindow{2, 2, 0, 0, 0, 0}).isFullSensor(1024, 1024));
  EXPECT_NE((SensorWindow{0, 1, 0, 0, 0, 0}).validate(1024, 1024).find("at least 1x1"), std::string::npos);
  EXPECT_NE((SensorWindow{1, 1, 900, 0, 200, 100}).validate(1024, 1024).find("exceeds"), std::string::npos);
  EXPECT_NE((SensorWindow{1, 1, 10, 10, 0, 0}).validate(1024, 1024).find("both be set"), std::string::npos);
  EXPECT_NE((SensorWindow{1, 1, -1, 0, 10, 10}).validate(1024, 1024).find("negative"), std::string::npos);
  EXPECT_NE((SensorWindow{4, 4, 0, 0, 3, 3}).validate(1024, 1024).find("smaller than one binned pixel"),
            std::string::npos);
}

TEST(CameraModel, RejectsBadIntrinsics)
{
  CameraModel m = CameraModel::studyDesign();
  m.fx = 0;
  EXPECT_NE(m.validate().find("focal length"), std::string::npos);
  m = CameraModel::studyDesign();
  m.cx = std::nan("");
  EXPECT_NE(m.validate().find("NaN"), std::string::npos);
  m = CameraModel::studyDesign();
  m.distortion = DistortionModel::kEquidistant;
  m.D = {0.1, 0.2};
  EXPECT_NE(m.validate().find("4 coefficients"), std::string::npos);
  EXPECT_TRUE(std::isnan(CameraModel::studyDesign().project({0, 0, -1}).x));
}

TEST(ProjectorCalibration, SaveLoadRoundTrip)
{
  const ProjectorCalibration cal = makeGridProjector(10, 10, {0.25, 0, 0}, {-0.25, 0, 1.5}, 0.035, 0.035, 0.087);
  ASSERT_TRUE(cal.validate().empty()) << cal.validate();
  const std::string path = ::testing::TempDir() + "/cal_roundtrip.yaml";
  std::string error;
  ASSERT_TRUE(saveProjectorCalibration(path, cal, &error)) << error;
  ProjectorCalibration back;
  ASSERT_TRUE(loadProjectorCalibration(path, &back, &error)) << error;
  ASSERT_EQ(back.beams.size(), 100u);
  for (size_t i = 0; i < cal.beams.size(); ++i)
  {
    EXPECT_LT((back.beams[i].origin - cal.beams[i].origin).norm(), 1e-11);
    EXPECT_LT((back.beams[i].direction - cal.beams[i].direction).norm(), 1e-11);
  }
  // The central beam of an odd grid would hit the convergence point; for a
  // 10x10 grid the centre lies between beams, so check symmetry instead.
  EXPECT_NEAR(cal.beams[0].direction.y(), -cal.beams[90 + 9].direction.y(), 0.05);
}

TEST(ProjectorCalibration, StudyFormConvertsToRays)
{
  // One beam, the study's experiment 3.3: d = 30 cm, alpha = 12.75 deg.
  const double ta = std::tan(12.75 * M_PI / 180.0);
  ProjectorCalibration cal;
  std::string error;
  ASSERT_TRUE(parseProjectorCalibration(
      "rows: 1\ncols: 1\nbeams:\n  - {tan_alpha: " + precise(ta) + ", tan_beta: 0.0, d_x: 0.30, d_y: 0.0}\n", &cal,
      &error))
      << error;
  // x = z tan(alpha) - d_x at z = 1.37 m: the ray passes through (1.37 ta - 0.3, 0, 1.37).
  const BeamRay& b = cal.beams[0];
  const double s = 1.37 / b.direction.z();
  EXPECT_NEAR(b.pointAt(s).x(), 1.37 * ta - 0.30, 1e-12);
}

TEST(ProjectorCalibration, RefusesMalformedFilesNamingTheFault)
{
  struct Case
  {
    const char* yaml;
    const char* expect;
  };
  const Case cases[] = {
      {"rows: 2\ncols: 2\nbeams: []\n", "4 but 'beams' has 0"},
      {"rows: 1\ncols: 1\nbeams:\n  - origin: [0, 0, 0]\n    direction: [0, 0, 0]\n", "beam 0 direction is zero"},
      {"rows: 1\ncols: 1\nbeams:\n  - origin: [0, 0]\n    direction: [0, 0, 1]\n", "beam 0 origin must be a list of 3"},
      {"rows: 1\ncols: 1\nbeams:\n  - origin: [0, x, 0]\n    direction: [0, 0, 1]\n", "line 4"},
      {"rows: -3\ncols: 1\nbeams: []\n", "out of range"},
      {"cols: 1\nbeams: []\n", "missing key 'rows'"},
      {"rows: [1\n", "not valid YAML"},
      {"rows: 1\ncols: 1\nbeams:\n  - origin: [0, 0, 0]\n    direction: [0, 0, -1]\n", "points away"},
  };
  for (const Case& c : cases)
  {
    ProjectorCalibration cal;
    std::string error;
    EXPECT_FALSE(parseProjectorCalibration(c.yaml, &cal, &error)) << c.yaml;
    EXPECT_NE(error.find(c.expect), std::string::npos) << "got: " << error;
  }
  std::string error;
  ProjectorCalibration cal;
  EXPECT_FALSE(loadProjectorCalibration("/nonexistent/cal.yaml", &cal, &error));
  EXPECT_NE(error.find("cannot open"), std::string::npos);
}
