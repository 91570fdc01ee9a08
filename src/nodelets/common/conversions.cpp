#include "structured_light_stabilizer/nodelets/conversions.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>

#include <geometry_msgs/TransformStamped.h>
#include <sensor_msgs/point_cloud2_iterator.h>
#include <tf2_eigen/tf2_eigen.h>

namespace structured_light_stabilizer
{

bool cameraModelFromInfo(const sensor_msgs::CameraInfo& info, CameraModel* model, std::string* error)
{
  CameraModel full;
  full.width = static_cast<int>(info.width);
  full.height = static_cast<int>(info.height);
  full.fx = info.K[0];
  full.fy = info.K[4];
  full.cx = info.K[2];
  full.cy = info.K[5];
  if (!CameraModel::parseDistortionModel(info.distortion_model, &full.distortion))
  {
    *error =
        "unsupported distortion_model '" + info.distortion_model + "' (plumb_bob, rational_polynomial or equidistant)";
    return false;
  }
  full.D = info.D;
  if (full.distortion == DistortionModel::kNone &&
      std::any_of(full.D.begin(), full.D.end(), [](double d) { return d != 0.0; }))
  {
    *error = "camera_info has distortion coefficients but no distortion_model";
    return false;
  }
  std::string why = full.validate();
  if (!why.empty())
  {
    *error = "camera_info unusable: " + why;
    return false;
  }
  // All-zero coefficients are no distortion whatever the model's name: one
  // camera, one model (a consumer that compares models sees no change).
  if (!full.hasDistortion())
  {
    full.distortion = DistortionModel::kNone;
    full.D.clear();
  }
  const SensorWindow window = sensorWindowFromInfo(info);
  why = window.validate(full.width, full.height);
  if (!why.empty())
  {
    *error = "camera_info binning/ROI unusable: " + why;
    return false;
  }
  *model = full.windowed(window);
  return true;
}

SensorWindow sensorWindowFromInfo(const sensor_msgs::CameraInfo& info)
{
  SensorWindow w;
  w.binning_x = std::max<int>(1, static_cast<int>(info.binning_x));
  w.binning_y = std::max<int>(1, static_cast<int>(info.binning_y));
  w.x_offset = static_cast<int>(info.roi.x_offset);
  w.y_offset = static_cast<int>(info.roi.y_offset);
  w.width = static_cast<int>(info.roi.width);
  w.height = static_cast<int>(info.roi.height);
  return w;
}

sensor_msgs::CameraInfo cameraInfoFromModel(const CameraModel& model, const std_msgs::Header& header,
                                            const SensorWindow& window)
{
  sensor_msgs::CameraInfo info;
  info.header = header;
  info.width = static_cast<uint32_t>(model.width);
  info.height = static_cast<uint32_t>(model.height);
  info.distortion_model = CameraModel::distortionModelName(model.distortion);
  info.D = model.D;
  if (info.D.empty() && (model.distortion == DistortionModel::kNone || model.distortion == DistortionModel::kPlumbBob))
    info.D.assign(5, 0.0);
  info.K = {model.fx, 0, model.cx, 0, model.fy, model.cy, 0, 0, 1};
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info.P = {model.fx, 0, model.cx, 0, 0, model.fy, model.cy, 0, 0, 0, 1, 0};
  if (!window.isFullSensor(model.width, model.height))
  {
    info.binning_x = static_cast<uint32_t>(window.binning_x);
    info.binning_y = static_cast<uint32_t>(window.binning_y);
    const cv::Rect roi = window.roi(model.width, model.height);
    info.roi.x_offset = static_cast<uint32_t>(roi.x);
    info.roi.y_offset = static_cast<uint32_t>(roi.y);
    info.roi.width = static_cast<uint32_t>(roi.width);
    info.roi.height = static_cast<uint32_t>(roi.height);
  }
  return info;
}

sensor_msgs::PointCloud2Ptr makeBeamCloud(const std_msgs::Header& header, int rows, int cols,
                                          const std::vector<Eigen::Vector3d>& points,
                                          const std::vector<float>& intensity)
{
  sensor_msgs::PointCloud2Ptr cloud(new sensor_msgs::PointCloud2);
  cloud->header = header;
  cloud->height = static_cast<uint32_t>(rows);
  cloud->width = static_cast<uint32_t>(cols);
  cloud->is_dense = false;
  cloud->is_bigendian = false;
  sensor_msgs::PointCloud2Modifier modifier(*cloud);
  modifier.setPointCloud2Fields(5, "x", 1, sensor_msgs::PointField::FLOAT32, "y", 1, sensor_msgs::PointField::FLOAT32,
                                "z", 1, sensor_msgs::PointField::FLOAT32, "intensity", 1,
                                sensor_msgs::PointField::FLOAT32, "beam", 1, sensor_msgs::PointField::UINT32);
  modifier.resize(static_cast<size_t>(rows) * cols);
  // resize() flattens the cloud to one row: restore the organised layout.
  cloud->height = static_cast<uint32_t>(rows);
  cloud->width = static_cast<uint32_t>(cols);
  cloud->row_step = cloud->width * cloud->point_step;
  sensor_msgs::PointCloud2Iterator<float> it_x(*cloud, "x");
  sensor_msgs::PointCloud2Iterator<float> it_i(*cloud, "intensity");
  sensor_msgs::PointCloud2Iterator<uint32_t> it_b(*cloud, "beam");
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const size_t n = static_cast<size_t>(rows) * cols;
  for (size_t i = 0; i < n; ++i, ++it_x, ++it_i, ++it_b)
  {
    const bool ok = i < points.size() && points[i].allFinite();
    it_x[0] = ok ? static_cast<float>(points[i].x()) : nan;
    it_x[1] = ok ? static_cast<float>(points[i].y()) : nan;
    it_x[2] = ok ? static_cast<float>(points[i].z()) : nan;
    *it_i = ok && i < intensity.size() ? intensity[i] : (ok ? 0.0f : nan);
    *it_b = static_cast<uint32_t>(i);
  }
  return cloud;
}

bool readBeamCloud(const sensor_msgs::PointCloud2& cloud, int* rows, int* cols, std::vector<Eigen::Vector3d>* points,
                   std::vector<float>* intensity, std::string* error)
{
  bool has_xyz[3] = {false, false, false};
  bool has_intensity = false;
  for (const auto& f : cloud.fields)
  {
    const bool f32 = f.datatype == sensor_msgs::PointField::FLOAT32 && f.count == 1;
    if (f.name == "x")
      has_xyz[0] = f32;
    if (f.name == "y")
      has_xyz[1] = f32;
    if (f.name == "z")
      has_xyz[2] = f32;
    if (f.name == "intensity")
      has_intensity = f32;
  }
  if (!has_xyz[0] || !has_xyz[1] || !has_xyz[2])
  {
    *error = "cloud lacks float32 x, y, z fields";
    return false;
  }
  const size_t n = static_cast<size_t>(cloud.width) * cloud.height;
  if (cloud.height == 0 || cloud.width == 0 || cloud.point_step == 0 ||
      cloud.row_step < static_cast<size_t>(cloud.width) * cloud.point_step ||
      cloud.data.size() < static_cast<size_t>(cloud.row_step) * cloud.height)
  {
    *error = "cloud is empty or its data is shorter than width*height*point_step";
    return false;
  }
  *rows = static_cast<int>(cloud.height);
  *cols = static_cast<int>(cloud.width);
  points->assign(n, Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  if (intensity)
    intensity->assign(n, 0.0f);
  sensor_msgs::PointCloud2ConstIterator<float> it_x(cloud, "x");
  for (size_t i = 0; i < n; ++i, ++it_x)
    (*points)[i] = Eigen::Vector3d(it_x[0], it_x[1], it_x[2]);
  if (intensity && has_intensity)
  {
    sensor_msgs::PointCloud2ConstIterator<float> it_i(cloud, "intensity");
    for (size_t i = 0; i < n; ++i, ++it_i)
      (*intensity)[i] = *it_i;
  }
  return true;
}

Spots spotsFromMsg(const CentroidArray& msg)
{
  Spots spots;
  spots.reserve(msg.centroids.size());
  for (const auto& c : msg.centroids)
  {
    Spot s;
    s.x = c.x;
    s.y = c.y;
    s.area = c.area;
    s.intensity = c.intensity;
    s.beam = c.beam;
    spots.push_back(s);
  }
  return spots;
}

void spotsToMsg(const Spots& spots, CentroidArray* msg)
{
  msg->centroids.resize(spots.size());
  for (size_t i = 0; i < spots.size(); ++i)
  {
    auto& c = msg->centroids[i];
    c.x = spots[i].x;
    c.y = spots[i].y;
    c.area = spots[i].area;
    c.intensity = spots[i].intensity;
    c.beam = spots[i].beam;
  }
}

geometry_msgs::Transform transformFromIsometry(const Eigen::Isometry3d& T)
{
  return tf2::eigenToTransform(T).transform;
}

Eigen::Isometry3d isometryFromTransform(const geometry_msgs::Transform& T)
{
  const double n = std::sqrt(T.rotation.x * T.rotation.x + T.rotation.y * T.rotation.y + T.rotation.z * T.rotation.z +
                             T.rotation.w * T.rotation.w);
  geometry_msgs::TransformStamped stamped;
  stamped.transform = T;
  if (!(n > 1e-9) || !std::isfinite(n))
  {
    stamped.transform.rotation = geometry_msgs::Quaternion();
    stamped.transform.rotation.w = 1.0;
  }
  else
  {
    stamped.transform.rotation.x /= n;
    stamped.transform.rotation.y /= n;
    stamped.transform.rotation.z /= n;
    stamped.transform.rotation.w /= n;
  }
  return tf2::transformToEigen(stamped);
}

geometry_msgs::PoseWithCovariance currentPoseInReference(const Eigen::Isometry3d& T, const Matrix6d& covariance)
{
  geometry_msgs::PoseWithCovariance out;
  out.pose = tf2::toMsg(Eigen::Isometry3d(T.inverse()));
  Matrix6d J = Matrix6d::Zero();
  const Eigen::Matrix3d Rt = T.linear().transpose();
  J.topLeftCorner<3, 3>() = -Rt;
  J.bottomRightCorner<3, 3>() = -Rt;
  const Matrix6d C = J * covariance * J.transpose();
  for (int i = 0; i < 36; ++i)
    out.covariance[i] = C(i / 6, i % 6);
  return out;
}

// Why an image message cannot be read as `format` (empty when it can):
// style weak spot 2, refuse with a clear message instead of an OpenCV abort.
std::string imageInconsistency(const sensor_msgs::Image& msg, PixelFormat format)
{
  const size_t bytes = static_cast<size_t>(channelCount(format)) * (matDepth(format) == CV_16U ? 2 : 1);
  const size_t row_bytes = static_cast<size_t>(msg.width) * bytes;
  const std::string what = std::to_string(msg.width) + "x" + std::to_string(msg.height) + " " + msg.encoding;
  if (msg.width == 0 || msg.height == 0)
    return "inconsistent image (" + what + "): empty";
  if (msg.step < row_bytes)
    return "inconsistent image (" + what + "): step " + std::to_string(msg.step) +
           " < width * channels * bytes per sample " + std::to_string(row_bytes);
  const size_t needed = static_cast<size_t>(msg.step) * (msg.height - 1) + row_bytes;
  if (msg.data.size() < needed)
    return "inconsistent image (" + what + ", step " + std::to_string(msg.step) + "): truncated, " +
           std::to_string(msg.data.size()) + " data bytes of the " + std::to_string(needed) + " needed";
  if (matDepth(format) == CV_16U && msg.step % 2 != 0)
    return "inconsistent image (" + what + "): odd step " + std::to_string(msg.step) + " for 16-bit samples";
  return "";
}

// A cv::Mat over the message's buffer (zero copy, its step honoured); 16-bit
// big-endian data is byte-swapped into *swapped first.
cv::Mat imageView(const sensor_msgs::Image& msg, PixelFormat format, cv::Mat* swapped)
{
  const cv::Mat view(static_cast<int>(msg.height), static_cast<int>(msg.width), matType(format),
                     const_cast<uint8_t*>(msg.data.data()), msg.step);
  const uint16_t one = 1;
  const bool host_big_endian = *reinterpret_cast<const uint8_t*>(&one) == 0;
  if (matDepth(format) != CV_16U || bool(msg.is_bigendian) == host_big_endian)
    return view;
  view.copyTo(*swapped);
  for (int y = 0; y < swapped->rows; ++y)
  {
    uint16_t* row = swapped->ptr<uint16_t>(y);
    for (int x = 0; x < swapped->cols * swapped->channels(); ++x)
      row[x] = static_cast<uint16_t>((row[x] >> 8) | (row[x] << 8));
  }
  return *swapped;
}

}  // namespace structured_light_stabilizer
