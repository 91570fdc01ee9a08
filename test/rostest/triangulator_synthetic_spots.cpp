// rostest helper node: publishes camera/camera_info and spots computed from
// a known scene (a rock with relief, exact beam hits projected with the
// camera model, centroid noise, missing dots and clutter), and the true beam
// hits on sim/ground_truth/points in the `points` layout, with the same stamp.
// Stands in for the simulator + detector so that the Triangulator's and the
// ProjectorCalibrator's rostests depend on nothing but the core.
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>

#include "support/triangulator_scene.h"
#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/nodelets/conversions.h"

using namespace structured_light_stabilizer;

int main(int argc, char** argv)
{
  ros::init(argc, argv, "triangulator_synthetic_spots");
  ros::NodeHandle nh, pnh("~");
  std::string calibration_path;
  pnh.param<std::string>("projector_calibration", calibration_path, "");
  double rate = 10.0, distance = 1.5, relief = 0.1, noise_px = 0.04, drop = 0.1, breathe = 0.1;
  int clutter = 10;
  pnh.param("rate", rate, rate);
  pnh.param("distance", distance, distance);
  pnh.param("relief", relief, relief);
  pnh.param("noise_px", noise_px, noise_px);
  pnh.param("drop_fraction", drop, drop);
  pnh.param("clutter", clutter, clutter);
  pnh.param("breathe_fraction", breathe, breathe);
  ProjectorCalibration proj;
  std::string err;
  if (!loadProjectorCalibration(calibration_path, &proj, &err))
  {
    ROS_FATAL("%s", err.c_str());
    return 1;
  }
  const CameraModel cam = CameraModel::studyDesign();
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>("camera/camera_info", 1);
  ros::Publisher spots_pub = nh.advertise<CentroidArray>("spots", 1);
  ros::Publisher truth_pub = nh.advertise<sensor_msgs::PointCloud2>("sim/ground_truth/points", 5);
  ros::Rate loop(rate);
  uint32_t seq = 0;
  while (ros::ok())
  {
    // ~distance may be changed while running (the calibration rostest moves the board).
    pnh.getParamCached("distance", distance);
    sls_test::Scene scene;
    // The rock breathes slowly by +-breathe_fraction around `distance`.
    scene.distance = distance * (1.0 + breathe * std::sin(0.3 * seq));
    scene.relief = relief;
    scene.phase = 0.1 * seq;
    sls_test::FrameOptions fo;
    fo.noise_px = noise_px;
    fo.drop_fraction = drop;
    fo.clutter = clutter;
    fo.seed = 1 + seq;
    const sls_test::Frame f = sls_test::makeFrame(cam, proj, scene, fo);
    std_msgs::Header header;
    header.stamp = ros::Time::now();
    header.frame_id = "camera_optical_frame";
    header.seq = seq++;
    sensor_msgs::CameraInfoPtr info(new sensor_msgs::CameraInfo(cameraInfoFromModel(cam, header)));
    CentroidArrayPtr spots(new CentroidArray);
    spots->header = header;
    spots->image_width = cam.width;
    spots->image_height = cam.height;
    Spots unlabelled = f.spots;
    for (Spot& s : unlabelled)
      s.beam = -1;  // the detector does not know the beams
    spotsToMsg(unlabelled, spots.get());
    std::vector<Eigen::Vector3d> truth = f.truth;
    truth_pub.publish(makeBeamCloud(header, proj.rows, proj.cols, truth, {}));
    info_pub.publish(info);
    spots_pub.publish(spots);
    ros::spinOnce();
    loop.sleep();
  }
  return 0;
}
