// Conversions between the ROS-free core types and ROS messages, for the
// nodelets and the C++ rostest checkers (kept here, out of the ROS-free
// include/ folder: the core must not depend on ROS).
//
// The organised cloud layout is the `points` contract of docs/interface.md:
// height = projector rows, width = projector cols, point (r, c) = beam
// r * cols + c, fields x y z intensity (float32, metres, camera optical
// frame) and beam (uint32); a beam without a valid point is NaN;
// is_dense = false.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <geometry_msgs/Transform.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/camera_model.h"
#include "structured_light_stabilizer/spot.h"

namespace structured_light_stabilizer
{

// Fills *model from a CameraInfo. Returns false with the reason when the
// info is unusable (zero or NaN K, unknown distortion model, wrong D size,
// binning or ROI that the package does not support).
bool cameraModelFromInfo(const sensor_msgs::CameraInfo& info, CameraModel* model, std::string* error);

// CameraInfo (K, P, R, D) of a camera model.
sensor_msgs::CameraInfo cameraInfoFromModel(const CameraModel& model, const std_msgs::Header& header);

// Builds the organised `points` cloud. `points` has rows * cols entries (NaN
// = no point); `intensity` may be empty (zeros).
sensor_msgs::PointCloud2Ptr makeBeamCloud(const std_msgs::Header& header, int rows, int cols,
                                          const std::vector<Eigen::Vector3d>& points,
                                          const std::vector<float>& intensity);

// Reads an organised `points` cloud back. Returns false with the reason when
// the layout or the fields are not the contract's.
bool readBeamCloud(const sensor_msgs::PointCloud2& cloud, int* rows, int* cols, std::vector<Eigen::Vector3d>* points,
                   std::vector<float>* intensity, std::string* error);

Spots spotsFromMsg(const CentroidArray& msg);
void spotsToMsg(const Spots& spots, CentroidArray* msg);

geometry_msgs::Transform transformFromIsometry(const Eigen::Isometry3d& T);
Eigen::Isometry3d isometryFromTransform(const geometry_msgs::Transform& T);

}  // namespace structured_light_stabilizer
