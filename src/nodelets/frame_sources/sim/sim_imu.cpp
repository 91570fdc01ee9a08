// The simulated IMU's parameters (sim_closed_loop.h, readImuParams): every
// field of ImuModelParams (sim/render/imu_model.h) under ~imu_*, SI units,
// vectors as [x, y, z], the rotation as a quaternion [x, y, z, w] of the IMU
// in the camera optical frame.
#include <vector>

#include "nodelets/common/param_reader.h"
#include "nodelets/frame_sources/sim/sim_closed_loop.h"

namespace structured_light_stabilizer
{

void readImuParams(const ros::NodeHandle& pnh, const std::function<void(const std::string&)>& error,
                   ImuModelParams* p)
{
  const ParamReader read(pnh, error);
  read.number("imu_rate", &p->rate_hz);
  std::vector<double> q;
  if (read.numbers("imu_rotation", 4, &q) && q.size() == 4)
    p->rotation_camera_imu = Eigen::Quaterniond(q[3], q[0], q[1], q[2]).normalized();
  read.vector3("imu_lever_arm", &p->lever_arm_m);
  read.vector3("imu_gravity", &p->gravity_m_s2);
  const std::pair<const char*, double*> numbers[] = {
      {"imu_gyro_noise_density", &p->gyro_noise_density},
      {"imu_gyro_bias_random_walk", &p->gyro_bias_random_walk},
      {"imu_accel_noise_density", &p->accel_noise_density},
      {"imu_accel_bias_random_walk", &p->accel_bias_random_walk},
      {"imu_time_offset", &p->time_offset_s},
      {"imu_silent_from", &p->silent_from_s},
      {"imu_silent_until", &p->silent_until_s},
      {"imu_bias_step_time", &p->bias_step_time_s},
  };
  for (const auto& n : numbers)
    read.number(n.first, n.second);
  read.vector3("imu_gyro_bias", &p->gyro_bias);
  read.vector3("imu_accel_bias", &p->accel_bias);
  read.vector3("imu_gyro_bias_step", &p->gyro_bias_step);
  read.vector3("imu_accel_bias_step", &p->accel_bias_step);
  read.integer("imu_seed", &p->seed);
}

}  // namespace structured_light_stabilizer
