// The IMU's rotation in the camera frame and the offset of its clock,
// estimated from a recording, ROS-free (docs/tools.md, "calibrate_imu"; the
// calibrate_imu tool reads a bag into it).
//
// Contract. Inputs: the gyro's samples (ImuMeasurement: the IMU's stamps and
// rates, rad/s, in its own frame) and the camera's orientations over the
// same time (CameraMeasurement: PoseDelta's estimates, p_cur = T p_ref, the
// exposure stamps; only valid ones are used) while the camera turns about
// all three axes (a few degrees at 0.5-5 Hz is plenty). The camera's body
// rate between consecutive estimates is matched with the gyro's mean rate
// over the same interval of the IMU's clock: the time offset (camera time =
// IMU stamp + offset, as ImuMount) is where the magnitudes of the two rates
// correlate best (searched over +-max_offset_s, then refined to a fraction
// of the IMU period), the rotation R_ci and the gyro bias b then solve
// w_camera = R_ci (w_imu - b) by least squares (Kabsch, alternated with the
// bias). The lever arm is not observable from rotations alone: measure it.
//
// Output: ImuCameraAlignment; `problem` is empty when the result is usable,
// else why not (too few pairs, too little rotation about some axis, a poor
// fit). Nothing throws. Thread-safe (no state).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/control/inertial_fusion.h"

namespace structured_light_stabilizer
{

struct ImuCameraAlignment
{
  Eigen::Quaterniond rotation_camera_imu = Eigen::Quaterniond::Identity();  // R_ci
  double time_offset_s = 0.0;                                               // camera time = IMU stamp + offset
  Eigen::Vector3d gyro_bias = Eigen::Vector3d::Zero();                      // rad/s, IMU frame
  double rms_residual = 0.0;  // of w_camera - R_ci (w_imu - b), rad/s
  double correlation = 0.0;   // of the rate magnitudes at the offset found
  int pairs = 0;              // camera intervals matched with the gyro
  // The smallest spread of the camera's rate over an axis (rad/s): how well
  // the rotation is determined.
  double weakest_excitation = 0.0;
  std::string problem;
};

ImuCameraAlignment estimateImuCameraAlignment(const std::vector<ImuMeasurement>& imu,
                                              const std::vector<CameraMeasurement>& camera,
                                              double max_offset_s = 0.1);

}  // namespace structured_light_stabilizer
