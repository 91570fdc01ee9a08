// calibrate_imu: the IMU's rotation in the camera frame and its clock offset,
// from a bag of imu/data (sensor_msgs/Imu) and pose_delta (PoseDelta)
// recorded while the camera turns about all three axes (docs/stabilization.md,
// docs/tools.md). Prints the InertialFusion's mount parameters as the YAML
// of config/imu.yaml (imu_frame, imu_rotation [x y z w], imu_lever_arm,
// imu_time_offset; the lever arm is measured, not estimated: kept from
// --lever-arm), and writes it to --output if given.
//
// Usage: rosrun structured_light_stabilizer calibrate_imu --bag REC.bag
//          [--imu-topic imu/data] [--pose-topic pose_delta] [--max-offset 0.1]
//          [--lever-arm X,Y,Z] [--imu-frame imu_link] [--output FILE]
// Exit status: 0 printed (and written), 1 the data cannot determine the mount (the reason
// is printed), 2 bad arguments or an unreadable bag.
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/Imu.h>

#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/control/imu_camera_alignment.h"
#include "structured_light_stabilizer/nodelets/conversions.h"

using namespace structured_light_stabilizer;

namespace
{

// The topic as recorded: with or without its leading slash.
bool sameTopic(const std::string& a, const std::string& b)
{
  const auto strip = [](const std::string& s) { return s.empty() || s[0] != '/' ? s : s.substr(1); };
  return strip(a) == strip(b);
}

int usage(const char* why)
{
  std::fprintf(stderr, "calibrate_imu: %s\nusage: calibrate_imu --bag REC.bag [--imu-topic imu/data] [--pose-topic "
                       "pose_delta] [--max-offset 0.1] [--lever-arm X,Y,Z] [--imu-frame imu_link] [--output FILE]\n",
               why);
  return 2;
}

}  // namespace

int main(int argc, char** argv)
{
  std::string bag_path, imu_topic = "imu/data", pose_topic = "pose_delta", output;
  std::string imu_frame = "imu_link", lever_arm = "0,0,0";
  double max_offset = 0.1;
  for (int i = 1; i < argc; ++i)
  {
    const std::string a = argv[i];
    if (i + 1 >= argc)
      return usage(("missing value after " + a).c_str());
    const std::string v = argv[++i];
    if (a == "--bag")
      bag_path = v;
    else if (a == "--imu-topic")
      imu_topic = v;
    else if (a == "--pose-topic")
      pose_topic = v;
    else if (a == "--output")
      output = v;
    else if (a == "--imu-frame")
      imu_frame = v;
    else if (a == "--lever-arm")
      lever_arm = v;
    else if (a == "--max-offset")
      max_offset = std::atof(v.c_str());
    else
      return usage(("unknown argument " + a).c_str());
  }
  if (bag_path.empty() || !(max_offset > 0.0))
    return usage("--bag is required and --max-offset must be > 0");
  std::vector<ImuMeasurement> imu;
  std::vector<CameraMeasurement> camera;
  try
  {
    rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
    for (const rosbag::MessageInstance& m : rosbag::View(bag))
    {
      if (sameTopic(m.getTopic(), imu_topic))
        if (const auto msg = m.instantiate<sensor_msgs::Imu>())
          imu.push_back({msg->header.stamp.toSec(),
                         Eigen::Vector3d(msg->angular_velocity.x, msg->angular_velocity.y, msg->angular_velocity.z),
                         Eigen::Vector3d(msg->linear_acceleration.x, msg->linear_acceleration.y,
                                         msg->linear_acceleration.z)});
      if (sameTopic(m.getTopic(), pose_topic))
        if (const auto msg = m.instantiate<PoseDelta>())
        {
          CameraMeasurement c;
          c.stamp = msg->header.stamp.toSec();
          c.transform = isometryFromTransform(msg->transform);
          c.valid = msg->valid;
          camera.push_back(c);
        }
    }
  }
  catch (const std::exception& e)
  {
    std::fprintf(stderr, "calibrate_imu: cannot read %s: %s\n", bag_path.c_str(), e.what());
    return 2;
  }
  const ImuCameraAlignment a = estimateImuCameraAlignment(imu, camera, max_offset);
  std::fprintf(stderr, "calibrate_imu: %zu IMU samples, %zu camera estimates; %d intervals matched, rate residual %.4f "
              "rad/s, correlation %.3f, weakest excitation %.3f rad/s, gyro bias [%.5f %.5f %.5f] rad/s\n",
              imu.size(), camera.size(), a.pairs, a.rms_residual, a.correlation, a.weakest_excitation,
              a.gyro_bias.x(), a.gyro_bias.y(), a.gyro_bias.z());
  if (!a.problem.empty())
  {
    std::fprintf(stderr, "calibrate_imu: no mount estimated: %s\n", a.problem.c_str());
    return 1;
  }
  const Eigen::Quaterniond& q = a.rotation_camera_imu;
  std::ostringstream yaml;
  yaml.precision(9);
  yaml << "# calibrate_imu from " << bag_path << ": " << a.pairs << " intervals, rate residual " << a.rms_residual
       << " rad/s\nimu_frame: " << imu_frame << "\nimu_rotation: [" << q.x() << ", " << q.y() << ", " << q.z()
       << ", " << q.w() << "]\nimu_lever_arm: [" << lever_arm << "]\nimu_time_offset: " << a.time_offset_s << "\n";
  std::fputs(yaml.str().c_str(), stdout);
  if (!output.empty())
  {
    std::ofstream out(output);
    out << yaml.str();
    if (!out)
    {
      std::fprintf(stderr, "calibrate_imu: cannot write %s\n", output.c_str());
      return 2;
    }
  }
  return 0;
}
