// The ROS conversions (src/nodelets/conversions.h, resource_url.h), no master
// needed: camera_info -> CameraModel for every distortion model, binning and
// ROI, checked against image_geometry (an independent reading of CameraInfo;
// it differs from ours only by the documented (b - 1) / 2 binned-pixel centre
// term); the PoseDelta -> PoseWithCovariance conversion checked against a
// Monte Carlo propagation of the covariance; the resource URLs of
// ~projector_calibration.
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <random>

#include <gtest/gtest.h>
#include <image_geometry/pinhole_camera_model.h>
#include <ros/package.h>

#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/resource_url.h"

using namespace structured_light_stabilizer;

namespace
{

sensor_msgs::CameraInfo rationalInfo()
{
  CameraModel m = CameraModel::studyDesign();
  m.distortion = DistortionModel::kRationalPolynomial;
  m.fx = 1011.7;
  m.fy = 1009.2;
  m.cx = 515.3;
  m.cy = 507.6;
  m.D = {0.8, -0.2, 0.0008, -0.0004, 0.01, 0.95, -0.05, 0.02};
  return cameraInfoFromModel(m, std_msgs::Header());
}

}  // namespace

// Full resolution: our model projects exactly as image_geometry's raw
// (unrectified) pixels, for plumb_bob and rational_polynomial.
TEST(CameraInfoConversion, MatchesImageGeometryAtFullResolution)
{
  for (const bool rational : {false, true})
  {
    sensor_msgs::CameraInfo info = rationalInfo();
    if (!rational)
    {
      info.distortion_model = "plumb_bob";
      info.D = {-0.12, 0.03, 0.001, -0.0005, 0.002};
    }
    CameraModel model;
    std::string error;
    ASSERT_TRUE(cameraModelFromInfo(info, &model, &error)) << error;
    image_geometry::PinholeCameraModel ig;
    ig.fromCameraInfo(info);
    double worst = 0.0;
    for (double x = -0.4; x <= 0.41; x += 0.1)
      for (double y = -0.4; y <= 0.41; y += 0.1)
      {
        const cv::Point2d raw = ig.unrectifyPoint(ig.project3dToPixel(cv::Point3d(x, y, 1.0)));
        worst = std::max(worst, cv::norm(model.project({x, y, 1.0}) - raw));
      }
    EXPECT_LT(worst, 1e-6) << info.distortion_model;
  }
}

// Binning and ROI: same focal lengths and image size as image_geometry's
// reduced camera; principal point (b - 1) / (2 b) binned pixels lower (the
// centre of a binned pixel is the centre of the sensor pixels it merges:
// camera_model.h, SensorWindow); projection through the window agrees once
// that shift is added back.
TEST(CameraInfoConversion, BinnedRoiMatchesImageGeometryUpToTheBinCentre)
{
  sensor_msgs::CameraInfo info = rationalInfo();
  info.binning_x = 2;
  info.binning_y = 4;
  info.roi.x_offset = 128;
  info.roi.y_offset = 96;
  info.roi.width = 768;
  info.roi.height = 832;
  CameraModel model;
  std::string error;
  ASSERT_TRUE(cameraModelFromInfo(info, &model, &error)) << error;
  image_geometry::PinholeCameraModel ig;
  ig.fromCameraInfo(info);
  EXPECT_EQ(model.width, ig.reducedResolution().width);
  EXPECT_EQ(model.height, ig.reducedResolution().height);
  EXPECT_EQ(model.width, 384);
  EXPECT_EQ(model.height, 208);
  EXPECT_NEAR(model.fx, ig.fx(), 1e-12);
  EXPECT_NEAR(model.fy, ig.fy(), 1e-12);
  EXPECT_NEAR(model.cx, ig.cx() - 1.0 / 4.0, 1e-12);
  EXPECT_NEAR(model.cy, ig.cy() - 3.0 / 8.0, 1e-12);
  const cv::Point2d shift(1.0 / 4.0, 3.0 / 8.0);
  for (double x = -0.2; x <= 0.21; x += 0.1)
    for (double y = -0.1; y <= 0.11; y += 0.05)
    {
      const cv::Point2d raw = ig.unrectifyPoint(ig.project3dToPixel(cv::Point3d(x, y, 1.0)));
      EXPECT_LT(cv::norm(model.project({x, y, 1.0}) - (raw - shift)), 1e-6);
    }
  // Back to a CameraInfo: the window survives the round trip.
  const SensorWindow w = sensorWindowFromInfo(info);
  CameraModel full;
  info.binning_x = info.binning_y = 0;
  info.roi = sensor_msgs::RegionOfInterest();
  ASSERT_TRUE(cameraModelFromInfo(info, &full, &error)) << error;
  const sensor_msgs::CameraInfo again = cameraInfoFromModel(full, std_msgs::Header(), w);
  EXPECT_EQ(again.binning_x, 2u);
  EXPECT_EQ(again.binning_y, 4u);
  EXPECT_EQ(again.roi.x_offset, 128u);
  EXPECT_EQ(again.roi.height, 832u);
  EXPECT_EQ(again.width, 1024u);
  EXPECT_EQ(again.distortion_model, "rational_polynomial");
}

TEST(CameraInfoConversion, RefusesWhatItCannotUseNamingIt)
{
  struct Case
  {
    std::function<void(sensor_msgs::CameraInfo*)> change;
    const char* expect;
  };
  const Case cases[] = {
      {[](sensor_msgs::CameraInfo* i) { i->roi.x_offset = 900, i->roi.width = 300, i->roi.height = 10; }, "exceeds"},
      {[](sensor_msgs::CameraInfo* i) { i->D.resize(5); }, "8 coefficients"},
      {[](sensor_msgs::CameraInfo* i) { i->distortion_model = "kannala"; }, "unsupported distortion_model"},
      {[](sensor_msgs::CameraInfo* i) { i->K[0] = 0; }, "focal length"},
      {[](sensor_msgs::CameraInfo* i) { i->roi.x_offset = 8; }, "both be set"},
      {[](sensor_msgs::CameraInfo* i) { i->distortion_model = ""; }, "no distortion_model"},
  };
  for (const Case& c : cases)
  {
    sensor_msgs::CameraInfo info = rationalInfo();
    c.change(&info);
    CameraModel model;
    std::string error;
    EXPECT_FALSE(cameraModelFromInfo(info, &model, &error)) << c.expect;
    EXPECT_NE(error.find(c.expect), std::string::npos) << "got: " << error;
  }
}

// One camera, one model: all-zero coefficients are no distortion whatever
// the model's name (PoseDelta drops its texture features on a model change).
TEST(CameraInfoConversion, ZeroDistortionIsNoDistortion)
{
  for (const char* name : {"plumb_bob", "rational_polynomial", "equidistant", ""})
  {
    sensor_msgs::CameraInfo info = rationalInfo();
    info.distortion_model = name;
    info.D.assign(std::string(name) == "equidistant" ? 4 : std::string(name).empty() ? 0 : 8, 0.0);
    if (std::string(name) == "plumb_bob")
      info.D.resize(5);
    CameraModel model;
    std::string error;
    ASSERT_TRUE(cameraModelFromInfo(info, &model, &error)) << name << ": " << error;
    EXPECT_EQ(model.distortion, DistortionModel::kNone) << name;
    EXPECT_TRUE(model.D.empty()) << name;
  }
}

// pose_delta/pose: the pose is T^-1; its covariance is checked by sampling
// left increments with the PoseDelta covariance, inverting each perturbed
// transform, and measuring the spread of position (reference frame) and of
// the left rotation error, independently of the Jacobian in conversions.cpp.
TEST(PoseConversion, CurrentPoseInReferenceCarriesTheCovariance)
{
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(0.35, Eigen::Vector3d(0.3, -0.8, 0.5).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.04, -0.02, 0.07);
  Matrix6d L = Matrix6d::Zero();
  std::mt19937 rng(7);
  std::normal_distribution<double> n01;
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j <= i; ++j)
      L(i, j) = (i == j ? 1.0 : 0.3 * n01(rng)) * (i < 3 ? 1e-3 : 2e-3);
  const Matrix6d C = L * L.transpose();
  const geometry_msgs::PoseWithCovariance out = currentPoseInReference(T, C);

  const Eigen::Isometry3d inv = T.inverse();
  EXPECT_NEAR(out.pose.position.x, inv.translation().x(), 1e-12);
  EXPECT_NEAR(out.pose.position.z, inv.translation().z(), 1e-12);
  const Eigen::Quaterniond q(out.pose.orientation.w, out.pose.orientation.x, out.pose.orientation.y,
                             out.pose.orientation.z);
  EXPECT_LT((q.toRotationMatrix() - inv.linear()).norm(), 1e-12);

  const int samples = 40000;
  Matrix6d S = Matrix6d::Zero();
  for (int k = 0; k < samples; ++k)
  {
    Vector6d z;
    for (int i = 0; i < 6; ++i)
      z(i) = n01(rng);
    const Eigen::Isometry3d P = applyIncrement(L * z, T).inverse();
    Vector6d e;
    e.head<3>() = P.translation() - inv.translation();
    e.tail<3>() = logSO3(P.linear() * inv.linear().transpose());
    S += e * e.transpose();
  }
  S /= samples;
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j)
    {
      const double scale = std::sqrt(S(i, i) * S(j, j));
      EXPECT_NEAR(out.covariance[i * 6 + j], S(i, j), 0.03 * scale) << i << "," << j;
    }
}

TEST(PoseConversion, TransformRoundTripAndZeroQuaternion)
{
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(1.1, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(1, -2, 3);
  EXPECT_LT((isometryFromTransform(transformFromIsometry(T)).matrix() - T.matrix()).norm(), 1e-12);
  geometry_msgs::Transform zero;
  EXPECT_TRUE(isometryFromTransform(zero).linear().isIdentity(1e-15));
}

TEST(ResourceUrl, PackageFileAndPlainPaths)
{
  std::string path, error;
  ASSERT_TRUE(resolveResourceUrl("package://structured_light_stabilizer/config/projector_sim.yaml", &path, &error))
      << error;
  EXPECT_EQ(path, ros::package::getPath("structured_light_stabilizer") + "/config/projector_sim.yaml");
  EXPECT_TRUE(std::ifstream(path).good()) << path;
  ASSERT_TRUE(resolveResourceUrl("file:///tmp/p.yaml", &path, &error));
  EXPECT_EQ(path, "/tmp/p.yaml");
  ASSERT_TRUE(resolveResourceUrl("relative/p.yaml", &path, &error));
  EXPECT_EQ(path, "relative/p.yaml");
  setenv("ROS_HOME", "/var/ros_home", 1);
  ASSERT_TRUE(resolveResourceUrl("file://${ROS_HOME}/p.yaml", &path, &error));
  EXPECT_EQ(path, "/var/ros_home/p.yaml");
  EXPECT_FALSE(resolveResourceUrl("package://no_such_package_here/p.yaml", &path, &error));
  EXPECT_NE(error.find("no_such_package_here"), std::string::npos);
  EXPECT_FALSE(resolveResourceUrl("http://example.org/p.yaml", &path, &error));
  EXPECT_FALSE(resolveResourceUrl("file://relative", &path, &error));
  EXPECT_FALSE(resolveResourceUrl("", &path, &error));
}
