// rostest checker: compares the Triangulator's `points` with the truth of
// sim/ground_truth/points (same stamp): layout, header, depth RMS, and that
// no beam carries a point of another beam (identification).
#include <map>
#include <mutex>

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/PointCloud2.h>

#include "structured_light_stabilizer/nodelets/conversions.h"

using namespace structured_light_stabilizer;

namespace
{
std::mutex g_mutex;
std::map<ros::Time, sensor_msgs::PointCloud2ConstPtr> g_truth, g_points;

void truthCallback(const sensor_msgs::PointCloud2ConstPtr& msg)
{
  std::lock_guard<std::mutex> lock(g_mutex);
  g_truth[msg->header.stamp] = msg;
}
void pointsCallback(const sensor_msgs::PointCloud2ConstPtr& msg)
{
  std::lock_guard<std::mutex> lock(g_mutex);
  g_points[msg->header.stamp] = msg;
}
}  // namespace

TEST(TriangulatorRostest, PointsMatchTruth)
{
  ros::NodeHandle nh, pnh("~");
  int frames = 20;
  double max_rms_fraction = 0.001, min_identified = 0.95;
  pnh.param("frames", frames, frames);
  pnh.param("max_rms_fraction", max_rms_fraction, max_rms_fraction);
  pnh.param("min_identified", min_identified, min_identified);
  ros::Subscriber a = nh.subscribe("sim/ground_truth/points", 50, truthCallback);
  ros::Subscriber b = nh.subscribe("points", 50, pointsCallback);
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(40.0);
  int compared = 0, visible = 0, identified = 0, wrong = 0;
  double sum2_rel = 0.0, sum2 = 0.0;
  while (ros::ok() && ros::WallTime::now() < deadline && compared < frames)
  {
    ros::WallDuration(0.05).sleep();
    std::lock_guard<std::mutex> lock(g_mutex);
    for (auto it = g_points.begin(); it != g_points.end();)
    {
      const auto t = g_truth.find(it->first);
      if (t == g_truth.end())
      {
        ++it;
        continue;
      }
      const sensor_msgs::PointCloud2& got = *it->second;
      EXPECT_EQ(got.header.frame_id, "camera_optical_frame");
      EXPECT_FALSE(got.is_dense);
      int rows = 0, cols = 0, trows = 0, tcols = 0;
      std::vector<Eigen::Vector3d> p, q;
      std::vector<float> intensity, tint;
      std::string err;
      ASSERT_TRUE(readBeamCloud(got, &rows, &cols, &p, &intensity, &err)) << err;
      ASSERT_TRUE(readBeamCloud(*t->second, &trows, &tcols, &q, &tint, &err)) << err;
      ASSERT_EQ(rows, trows);
      ASSERT_EQ(cols, tcols);
      for (size_t i = 0; i < p.size(); ++i)
      {
        const bool has_truth = q[i].allFinite();
        visible += has_truth;
        if (!p[i].allFinite())
          continue;
        // A point where the beam has no dot, or 1 cm away from its own dot,
        // belongs to another dot.
        if (!has_truth || (p[i] - q[i]).norm() > 0.01)
        {
          ++wrong;
          continue;
        }
        ++identified;
        const double e = p[i].z() - q[i].z();
        sum2 += e * e;
        sum2_rel += e * e / (q[i].z() * q[i].z());
        EXPECT_GT(intensity[i], 0.0f);
      }
      ++compared;
      g_truth.erase(t);
      it = g_points.erase(it);
    }
  }
  ASSERT_GE(compared, frames) << "the Triangulator published too few clouds matching the truth";
  const double rms_rel = std::sqrt(sum2_rel / std::max(1, identified));
  std::cout << "[ MEASURE ] " << compared << " clouds: " << identified << " of " << visible
            << " beam hits with a dot triangulated (dots dropped upstream included), " << wrong << " wrong; depth RMS "
            << std::sqrt(sum2 / std::max(1, identified)) * 1e3 << " mm = " << rms_rel * 100 << " %\n";
  EXPECT_EQ(wrong, 0);
  EXPECT_LT(rms_rel, max_rms_fraction);
  EXPECT_GE(identified, min_identified * visible);
}

int main(int argc, char** argv)
{
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "check_triangulator_synthetic");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  return RUN_ALL_TESTS();
}
