// rostest checker: bad input to the Triangulator (no camera_info, camera_info
// of another size, K all zeros, NaN centroids, no projector calibration)
// publishes nothing and kills nothing; a good frame afterwards is published.
#include <atomic>
#include <limits>

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_srvs/Trigger.h>

#include "support/triangulator_scene.h"
#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/nodelets/conversions.h"

using namespace structured_light_stabilizer;

namespace
{

struct Target
{
  explicit Target(const std::string& ns) : nh(ns)
  {
    info_pub = nh.advertise<sensor_msgs::CameraInfo>("camera/camera_info", 1, true);
    spots_pub = nh.advertise<CentroidArray>("spots", 1);
    points_sub = nh.subscribe<sensor_msgs::PointCloud2>("points", 10,
                                                        [this](const sensor_msgs::PointCloud2ConstPtr&) { ++clouds; });
  }
  // Publishes `spots` a few times; returns the clouds received meanwhile.
  int feed(const CentroidArray& spots, double seconds = 1.5)
  {
    const int before = clouds;
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
    while (ros::WallTime::now() < end)
    {
      CentroidArrayPtr msg(new CentroidArray(spots));
      msg->header.stamp = ros::Time::now();
      spots_pub.publish(msg);
      ros::WallDuration(0.1).sleep();
    }
    return clouds - before;
  }
  bool waitConnected()
  {
    const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(20.0);
    while (ros::WallTime::now() < end)
    {
      if (spots_pub.getNumSubscribers() > 0 && points_sub.getNumPublishers() > 0)
        return true;
      ros::WallDuration(0.1).sleep();
    }
    return false;
  }
  ros::NodeHandle nh;
  ros::Publisher info_pub, spots_pub;
  ros::Subscriber points_sub;
  std::atomic<int> clouds{0};
};

CentroidArray goodSpots(const CameraModel& cam)
{
  ProjectorCalibration proj;
  std::string path, err;
  ros::NodeHandle("~").getParam("projector_calibration", path);
  EXPECT_TRUE(loadProjectorCalibration(path, &proj, &err)) << err;
  sls_test::Scene scene;
  const sls_test::Frame f = sls_test::makeFrame(cam, proj, scene, sls_test::FrameOptions());
  CentroidArray msg;
  msg.header.frame_id = "camera_optical_frame";
  msg.image_width = cam.width;
  msg.image_height = cam.height;
  spotsToMsg(f.spots, &msg);
  for (auto& c : msg.centroids)
    c.beam = -1;
  return msg;
}

}  // namespace

TEST(TriangulatorBadInput, NothingPublishedNothingKilled)
{
  const CameraModel cam = CameraModel::studyDesign();
  const CentroidArray good = goodSpots(cam);
  ASSERT_GT(good.centroids.size(), 90u);
  Target t("good");
  ASSERT_TRUE(t.waitConnected());

  // 1. No camera_info yet.
  EXPECT_EQ(t.feed(good), 0) << "published without camera_info";

  std_msgs::Header h;
  h.frame_id = "camera_optical_frame";
  // 2. camera_info of another size than the spots' image.
  CameraModel small = cam;
  small.width = 640;
  small.height = 480;
  t.info_pub.publish(cameraInfoFromModel(small, h));
  EXPECT_EQ(t.feed(good), 0) << "published with a 640x480 camera_info for 1024x1024 spots";

  // 3. Uncalibrated camera_info (K all zeros).
  sensor_msgs::CameraInfo zero = cameraInfoFromModel(cam, h);
  for (double& k : zero.K)
    k = 0.0;
  t.info_pub.publish(zero);
  EXPECT_EQ(t.feed(good), 0) << "published with K = 0";

  // 4. NaN centroids with a good camera_info.
  t.info_pub.publish(cameraInfoFromModel(cam, h));
  CentroidArray nan_spots = good;
  nan_spots.centroids[3].x = std::numeric_limits<double>::quiet_NaN();
  nan_spots.centroids[7].y = std::numeric_limits<double>::infinity();
  EXPECT_EQ(t.feed(nan_spots), 0) << "published a frame with NaN centroids";

  // 5. Still alive: a good frame is triangulated.
  EXPECT_GT(t.feed(good), 0) << "the Triangulator no longer publishes after bad input";

  // 6. No usable projector calibration: nothing, and the reload service
  // answers with the reason.
  Target nocal("nocal");
  nocal.info_pub.publish(cameraInfoFromModel(cam, h));
  ros::WallTime end = ros::WallTime::now() + ros::WallDuration(20.0);
  while (nocal.spots_pub.getNumSubscribers() == 0 && ros::WallTime::now() < end)
    ros::WallDuration(0.1).sleep();
  EXPECT_EQ(nocal.feed(good), 0) << "published without a projector calibration";
  ros::ServiceClient reload =
      ros::NodeHandle().serviceClient<std_srvs::Trigger>("nocal/triangulator/reload_calibration");
  ASSERT_TRUE(reload.waitForExistence(ros::Duration(10.0)));
  std_srvs::Trigger srv;
  ASSERT_TRUE(reload.call(srv));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.message.find("beam 2"), std::string::npos) << srv.response.message;
  std::cout << "[ MEASURE ] reload of a bad calibration answers: " << srv.response.message << "\n";
}

int main(int argc, char** argv)
{
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "check_triangulator_bad_input");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
