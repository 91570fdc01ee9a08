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
#include <geometry_msgs/PoseWithCovariance.h>
#include <geometry_msgs/Transform.h>
#include <opencv2/core.hpp>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/Header.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/common/spot.h"
#include "structured_light_stabilizer/detection/spot_detector.h"

namespace structured_light_stabilizer
{

// Fills *model from a CameraInfo: the model of the images that come with it.
// K and D describe the full-resolution sensor (width x height); binning_x/y
// and roi say which binned window of it the images are (REP 104: the image
// is the ROI, in full-resolution pixels, binned; camera_model.h,
// SensorWindow), so *model is the full model windowed: its width x height is
// the image's. Distortion models: plumb_bob, rational_polynomial,
// equidistant, or none ("" with zero D; any model with all-zero D becomes
// kNone with an empty D). Returns false with the reason when
// the info is unusable (zero or NaN K, unknown distortion model, wrong D
// size, a window that does not fit the sensor).
bool cameraModelFromInfo(const sensor_msgs::CameraInfo& info, CameraModel* model, std::string* error);

// The binning and ROI of a CameraInfo (binning 0 counts as 1, an all-zero
// ROI as the whole sensor).
SensorWindow sensorWindowFromInfo(const sensor_msgs::CameraInfo& info);

// CameraInfo (K, P, R, D) of a full-resolution camera model, with `window`
// as binning_x/y and roi (width/height stay the full sensor's).
sensor_msgs::CameraInfo cameraInfoFromModel(const CameraModel& model, const std_msgs::Header& header,
                                            const SensorWindow& window = SensorWindow());

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

// Eigen <-> geometry_msgs through tf2_eigen; a zero or non-finite quaternion
// reads as the identity rotation.
geometry_msgs::Transform transformFromIsometry(const Eigen::Isometry3d& T);
Eigen::Isometry3d isometryFromTransform(const geometry_msgs::Transform& T);

// A PoseDelta estimate as a standard pose (pose_delta/pose): T maps
// reference-frame points into the current frame (p_cur = T p_ref) and
// `covariance` is that of a left increment (v, w) in the current camera
// frame (se3.h: T = Exp(v, w) * T_estimate). Returns the current camera's
// pose in the reference camera frame, T^-1, with its covariance in ROS
// order (x, y, z, rotation about x, y, z; position and rotation errors in
// the axes of the reference frame, the rotation applied on the left):
// T^-1 = T_est^-1 Exp(-(v, w)) gives dp = -R^T v, dtheta = -R^T w, so
// C' = J C J^T with J = -diag(R^T, R^T). Non-finite covariance entries stay
// non-finite.
geometry_msgs::PoseWithCovariance currentPoseInReference(const Eigen::Isometry3d& T, const Matrix6d& covariance);

// Why an image message cannot be read as `format` (empty when it can): empty,
// a step shorter than a row, data shorter than the rows, an odd step for
// 16-bit samples. Refuse with a clear message instead of an OpenCV abort.
std::string imageInconsistency(const sensor_msgs::Image& msg, PixelFormat format);

// A cv::Mat over a consistent message's buffer (zero copy, its step
// honoured): valid while the message lives; 16-bit big-endian data is
// byte-swapped into *swapped first (then valid while *swapped is).
cv::Mat imageView(const sensor_msgs::Image& msg, PixelFormat format, cv::Mat* swapped);

}  // namespace structured_light_stabilizer
