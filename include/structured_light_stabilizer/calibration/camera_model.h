// Pinhole camera with optional lens distortion, and the sensor window (binning
// and region of interest) an image was taken with; ROS-free.
//
// Contract: pixel coordinates follow OpenCV (pixel centres at integer
// coordinates, x = column, y = row). Points are in the camera optical frame
// (REP-103: x right, y down, z forward), metres. The distortion models and
// coefficient orders are those of sensor_msgs/CameraInfo (OpenCV's):
//   "plumb_bob"            k1 k2 p1 p2 k3                  (4 or 5 values)
//   "rational_polynomial"  k1 k2 p1 p2 k3 k4 k5 k6         (8 values; 12 adds
//                          OpenCV's thin-prism s1 s2 s3 s4)
//   "equidistant"          k1 k2 k3 k4 (fisheye, of the angle theta)
// A CameraModel describes the pixels of the images it is used with: for a
// binned or cropped image that is CameraModel::windowed() of the full-sensor
// calibration. Nothing here throws; a model that fails validate() gives
// meaningless (possibly NaN) results. All members are const-safe to share
// between threads.
#pragma once

#include <array>
#include <string>
#include <tuple>
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
  kRationalPolynomial,
};

// Which part of the sensor an image shows and how it was binned, as
// sensor_msgs/CameraInfo says it (REP 104): the region of interest (x_offset,
// y_offset, width, height) in full-resolution pixels of the calibrated
// sensor, then binned by binning_x x binning_y (each image pixel is the
// mean or sum of binning_x x binning_y sensor pixels). The image is
// width / binning_x x height / binning_y pixels (integer division).
//
// A binned pixel's centre lies at the centre of the sensor pixels it merges,
// so with pixel centres at integer coordinates:
//   x_full = binning_x * x_image + (binning_x - 1) / 2 + x_offset.
// (image_geometry's toFullResolution() leaves out the (b - 1) / 2 term: its
// binned principal point is off by (b - 1) / (2 b) binned pixels, 0.25 px for
// 2 x 2 binning.)
struct SensorWindow
{
  int binning_x = 1;
  int binning_y = 1;
  int x_offset = 0;
  int y_offset = 0;
  int width = 0;  // full-resolution pixels; 0 with height 0 = the whole sensor
  int height = 0;

  // True when the image is the whole sensor at full resolution.
  bool isFullSensor(int sensor_width, int sensor_height) const;
  // Empty when the window fits a sensor of that size, otherwise why not.
  std::string validate(int sensor_width, int sensor_height) const;
  // The ROI, with width/height 0 replaced by the sensor's size.
  cv::Rect roi(int sensor_width, int sensor_height) const;
  // Image size (pixels) for a sensor of that size.
  cv::Size imageSize(int sensor_width, int sensor_height) const;

  cv::Point2d toImage(const cv::Point2d& full) const;
  cv::Point2d toFull(const cv::Point2d& image) const;
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

  // Every field, for comparisons (one list: a new field goes here too).
  auto fields() const { return std::tie(width, height, fx, fy, cx, cy, distortion, D); }
  bool operator==(const CameraModel& o) const { return fields() == o.fields(); }
  bool operator!=(const CameraModel& o) const { return !(*this == o); }

  // The camera of the study (docs/study.md §2.1.1): 1024 x 1024 pixels of
  // 12 um and the focal length f = 12.14 mm, so fx = fy = 12.14 mm / 12 um =
  // 1011.67 px, principal point at the image centre, no distortion.
  static CameraModel studyDesign();

  // Empty when the model is usable, otherwise why not (zero or NaN focal
  // length, non-positive size, unknown or malformed distortion, ...).
  std::string validate() const;

  // Whether any distortion coefficient is non-zero.
  bool hasDistortion() const;

  // The model of the images taken through `window` by the sensor this model
  // describes at full resolution: focal lengths divided by the binning, the
  // principal point moved as SensorWindow::toImage() moves pixels, the size
  // of the binned ROI; the distortion (a function of normalised coordinates)
  // is unchanged. Call it on a full-sensor model only.
  CameraModel windowed(const SensorWindow& window) const;

  // Projects a point of the camera frame to a (distorted) pixel. Points with
  // z <= 0, or beyond where the distortion model is monotonic (a rational
  // denominator <= 0), give NaN.
  cv::Point2d project(const Eigen::Vector3d& p_camera) const;

  // Undistorted normalised coordinates (x/z, y/z) of a distorted pixel,
  // by iterative inversion of the distortion model; NaN where the inversion
  // does not converge (beyond where the lens model is invertible).
  Eigen::Vector2d normalize(const cv::Point2d& pixel) const;

  // Unit direction of the camera ray through a (distorted) pixel.
  Eigen::Vector3d ray(const cv::Point2d& pixel) const;

  // Applies the distortion to normalised undistorted coordinates (NaN where
  // a rational denominator is not positive).
  Eigen::Vector2d distortNormalized(const Eigen::Vector2d& xy) const;

  // Parses the distortion_model string of a CameraInfo ("" and "none" count
  // as none; "fisheye" as equidistant).
  static bool parseDistortionModel(const std::string& name, DistortionModel* model);
  // The CameraInfo name of a model ("plumb_bob" for none: CameraInfo has no
  // name for "no distortion", plumb_bob with zero coefficients says it).
  static std::string distortionModelName(DistortionModel model);
};

}  // namespace structured_light_stabilizer
