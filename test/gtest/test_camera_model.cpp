// Camera model and projector calibration: projection/back-projection round
// trips against analytic values, and the calibration loader's refusals.
#include <cmath>
#include <fstream>
#include <sstream>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/camera_model.h"
#include "structured_light_stabilizer/projector_calibration.h"

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
  for (DistortionModel dm : {DistortionModel::kPlumbBob, DistortionModel::kEquidistant})
  {
    CameraModel m = CameraModel::studyDesign();
    m.distortion = dm;
    m.D = dm == DistortionModel::kPlumbBob ? std::vector<double>{-0.12, 0.03, 0.001, -0.0005, 0.0}
                                           : std::vector<double>{0.05, -0.01, 0.002, 0.0};
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
  const ProjectorCalibration cal =
      makeGridProjector(10, 10, {0.25, 0, 0}, {-0.25, 0, 1.5}, 0.035, 0.035, 0.087);
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
      "rows: 1\ncols: 1\nbeams:\n  - {tan_alpha: " + precise(ta) + ", tan_beta: 0.0, d_x: 0.30, d_y: 0.0}\n",
      &cal, &error))
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
