// Pinhole camera with optional lens distortion, ROS-free.
//
// Contract: pixel coordinates follow OpenCV (pixel centres at integer
// coordinates, x = column, y = row). Points are in the camera optical frame
// (REP-103: x right, y down, z forward), metres. The distortion models and
// coefficient orders are those of sensor_msgs/CameraInfo: "plumb_bob"
// (k1, k2, p1, p2, k3) and "equidistant" (k1, k2, k3, k4, fisheye).
#pragma once

#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace structured_light_stabilizer
{

enum class DistortionModel
{
  kNone,
  kPlumbBob,
  kEquidistant,
};

struct CameraModel
{
  int width = 0;
  int height = 0;
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;
  DistortionModel distortion = DistortionModel::kNone;
  std::vector<double> D;  // coefficients in the CameraInfo order of the model

  // The camera of the study (docs/study.md §2.1.1): 1024 x 1024 pixels of
  // 12 um and the focal length f = 12.14 mm, so fx = fy = 12.14 mm / 12 um =
  // 1011.67 px, principal point at the image centre, no distortion.
  static CameraModel studyDesign();

  // Empty when the model is usable, otherwise why not (zero or NaN focal
  // length, non-positive size, unknown or malformed distortion, ...).
  std::string validate() const;

  // Whether any distortion coefficient is non-zero.
  bool hasDistortion() const;

  // Projects a point of the camera frame to a (distorted) pixel. Points with
  // z <= 0 give NaN.
  cv::Point2d project(const Eigen::Vector3d& p_camera) const;

  // Undistorted normalised coordinates (x/z, y/z) of a distorted pixel,
  // by iterative inversion of the distortion model.
  Eigen::Vector2d normalize(const cv::Point2d& pixel) const;

  // Unit direction of the camera ray through a (distorted) pixel.
  Eigen::Vector3d ray(const cv::Point2d& pixel) const;

  // Applies the distortion to normalised undistorted coordinates.
  Eigen::Vector2d distortNormalized(const Eigen::Vector2d& xy) const;

  // Parses the distortion_model string of a CameraInfo ("" counts as none).
  static bool parseDistortionModel(const std::string& name, DistortionModel* model);
  static std::string distortionModelName(DistortionModel model);
};

}  // namespace structured_light_stabilizer
