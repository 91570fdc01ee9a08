// InertialFusion nodelet: the camera's offset from the locked reference at
// IMU rate (docs/stabilization.md, "Inertial fusion").
//
// Wiring only: imu/data (sensor_msgs/Imu, REP 145: gyro and accelerometer in
// the IMU's frame, ~imu_frame) and pose_delta (PoseDelta) -> InertialFusion
// (core, control/inertial_fusion.h) -> pose_fused (PoseDelta, one per IMU
// sample, for the StabilizationController) and pose_fused/frames (PoseDelta,
// one per camera estimate: the fused pose at its exposure stamp, for the
// stabilised image; invalid with the reason when it was not fused). The mount
// (~imu_rotation [x y z w] of the IMU in the camera optical frame,
// ~imu_lever_arm [x y z] m, ~imu_time_offset s) is read at start-up
// (calibrate_imu estimates it). Bad Imu messages (NaN, a frame_id other than
// ~imu_frame, stamps out of order) are dropped with a throttled error.
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <boost/make_shared.hpp>
#include <boost/thread/recursive_mutex.hpp>
#include <dynamic_reconfigure/server.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/Imu.h>

#include "structured_light_stabilizer/InertialFusionConfig.h"
#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/control/inertial_fusion.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/common/nodelet_base.h"
#include "nodelets/common/param_reader.h"

namespace structured_light_stabilizer
{

namespace
{

using Config = structured_light_stabilizer::InertialFusionConfig;

CameraMeasurement cameraFromMsg(const PoseDelta& msg)
{
  CameraMeasurement c;
  c.stamp = msg.header.stamp.toSec();
  c.transform = isometryFromTransform(msg.transform);
  for (int i = 0; i < 36; ++i)
    c.covariance(i / 6, i % 6) = msg.covariance[i];
  c.valid = msg.valid;
  c.status = msg.status;
  return c;
}

PoseDeltaPtr msgFromFused(const FusedEstimate& f, const std::string& frame, uint32_t points_used)
{
  auto msg = boost::make_shared<PoseDelta>();
  msg->header.stamp.fromSec(f.stamp);
  msg->header.frame_id = frame;
  msg->transform = transformFromIsometry(f.transform);
  for (int i = 0; i < 36; ++i)
    msg->covariance[i] = f.covariance(i / 6, i % 6);
  msg->points_used = points_used;
  msg->valid = f.valid;
  msg->status = f.status;
  return msg;
}

// Why an Imu message cannot be used (empty when it can).
std::string imuProblem(const sensor_msgs::Imu& msg, const std::string& expected_frame)
{
  const auto& w = msg.angular_velocity;
  const auto& a = msg.linear_acceleration;
  if (!std::isfinite(w.x) || !std::isfinite(w.y) || !std::isfinite(w.z))
    return "imu/data: NaN or infinite angular velocity; sample dropped";
  if (!std::isfinite(a.x) || !std::isfinite(a.y) || !std::isfinite(a.z))
    return "imu/data: NaN or infinite linear acceleration; sample dropped";
  if (msg.header.stamp.isZero())
    return "imu/data: zero stamp; sample dropped";
  if (!expected_frame.empty() && msg.header.frame_id != expected_frame)
    return "imu/data: frame_id '" + msg.header.frame_id + "' is not ~imu_frame '" + expected_frame +
           "' (the mount ~imu_rotation / ~imu_lever_arm is for that frame); sample dropped";
  return "";
}

}  // namespace

class InertialFusionNodelet : public NodeletBase
{
public:
  InertialFusionNodelet() : NodeletBase("InertialFusion") {}
  ~InertialFusionNodelet() override { stopCallbacks(); }

private:
  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    readLazyParam();
    readMount();
    pnh.param("diagnostic_min_rate", min_frequency_, 50.0);
    pnh.param("diagnostic_max_rate", max_frequency_, 2000.0);
    fusion_.reset(new InertialFusion(InertialFusionParams(), mount_));
    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { configCb(config, level); });

    setUpDiagnostics(imu_frame_.empty() ? "imu" : imu_frame_);
    addFrequencyStatus();
    diagnostics_->add("fusion", this, &InertialFusionNodelet::diagnose);
    startDiagnostics(1.0);

    pub_fused_ = advertise<PoseDelta>(nh, "pose_fused", 50);
    pub_frames_ = advertise<PoseDelta>(nh, "pose_fused/frames", 10);
    startSubscriptions("inputs (imu/data, pose_delta) are subscribed on demand, while pose_fused or "
                       "pose_fused/frames has subscribers");
  }

  void readMount()
  {
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    const ParamReader read(pnh, [this](const std::string& m) { NODELET_ERROR("InertialFusion: %s", m.c_str()); });
    pnh.param("imu_frame", imu_frame_, std::string("imu_link"));
    std::vector<double> q;
    if (read.numbers("imu_rotation", 4, &q) && q.size() == 4)
      mount_.rotation_camera_imu = Eigen::Quaterniond(q[3], q[0], q[1], q[2]);
    read.vector3("imu_lever_arm", &mount_.lever_arm_m);
    read.number("imu_time_offset", &mount_.time_offset_s);
    const std::string why = mount_.validate();
    if (!why.empty())
    {
      NODELET_ERROR("InertialFusion: %s; using the identity mount (fused poses will be wrong)", why.c_str());
      mount_ = ImuMount();
    }
    mount_.rotation_camera_imu.normalize();
    NODELET_INFO("InertialFusion: IMU '%s' at [%.3f %.3f %.3f] m, rotation [%.4f %.4f %.4f %.4f] (x y z w), time "
                 "offset %.1f ms",
                 imu_frame_.c_str(), mount_.lever_arm_m.x(), mount_.lever_arm_m.y(), mount_.lever_arm_m.z(),
                 mount_.rotation_camera_imu.x(), mount_.rotation_camera_imu.y(), mount_.rotation_camera_imu.z(),
                 mount_.rotation_camera_imu.w(), mount_.time_offset_s * 1e3);
  }

  void subscribe() override
  {
    // Deep queues: 400 Hz samples must not be lost while a camera estimate
    // replays the history.
    sub_imu_ = getNodeHandle().subscribe("imu/data", 200, &InertialFusionNodelet::imuCb, this,
                                         ros::TransportHints().tcpNoDelay());
    sub_pose_ = getNodeHandle().subscribe("pose_delta", 20, &InertialFusionNodelet::poseCb, this);
  }
  void unsubscribe() override
  {
    sub_imu_.shutdown();
    sub_pose_.shutdown();
  }

  void configCb(Config& config, uint32_t /*level*/)
  {
    InertialFusionParams params;
    params.fromConfig(config);
    const std::string why = params.validate();
    if (!why.empty())
    {
      NODELET_ERROR("InertialFusion: rejected parameters (%s); keeping the previous ones", why.c_str());
      return;
    }
    std::lock_guard<std::mutex> lock(mutex_);
    fusion_->setParams(params);
  }

  void imuCb(const sensor_msgs::ImuConstPtr& msg)
  {
    guarded(
        [&]
        {
          const std::string problem = imuProblem(*msg, imu_frame_);
          if (!problem.empty())
          {
            dropFrame(problem);
            return;
          }
          ImuMeasurement m;
          m.stamp = msg->header.stamp.toSec();
          m.angular_velocity = Eigen::Vector3d(msg->angular_velocity.x, msg->angular_velocity.y, msg->angular_velocity.z);
          m.linear_acceleration =
              Eigen::Vector3d(msg->linear_acceleration.x, msg->linear_acceleration.y, msg->linear_acceleration.z);
          FusedEstimate fused;
          std::string why;
          std::lock_guard<std::mutex> lock(mutex_);
          if (!fusion_->addImu(m, &fused, &why))
          {
            dropFrame("imu/data: " + why + "; sample dropped");
            return;
          }
          ++imu_samples_;
          last_status_ = fused.status;
          last_valid_ = fused.valid;
          pub_fused_.publish(msgFromFused(fused, camera_frame_, points_used_));
          frequency_->tick();
        });
  }

  void poseCb(const PoseDeltaConstPtr& msg)
  {
    guarded(
        [&]
        {
          std::lock_guard<std::mutex> lock(mutex_);
          if (!msg->header.frame_id.empty())
            camera_frame_ = msg->header.frame_id;
          points_used_ = msg->points_used;
          std::string why;
          const CameraUpdate u = fusion_->addCamera(cameraFromMsg(*msg), &why);
          ++camera_estimates_;
          camera_used_ += u.used;
          if (u.silent_imu)
            pub_fused_.publish(msgFromFused(u.fused, camera_frame_, points_used_));
          // One answer per estimate (the stabilised image and lockstep runs count on it).
          pub_frames_.publish(msgFromFused(u.frame, camera_frame_, points_used_));
        });
  }

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (last_valid_)
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, last_status_);
    else
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, last_status_.empty() ? "no IMU sample yet" : last_status_);
    stat.add("IMU samples fused", imu_samples_);
    stat.add("camera estimates", camera_estimates_);
    stat.add("camera estimates fused", camera_used_);
    stat.add("samples dropped", framesDropped());
    stat.add("last drop", lastDropReason());
    stat.add("last NIS", fusion_->lastNis());
    const Eigen::Vector3d bg = fusion_->gyroBias(), ba = fusion_->accelBias();
    stat.addf("gyro bias (deg/s)", "%.4f %.4f %.4f", bg.x() * 180 / M_PI, bg.y() * 180 / M_PI, bg.z() * 180 / M_PI);
    stat.addf("accelerometer bias (m/s^2)", "%.4f %.4f %.4f", ba.x(), ba.y(), ba.z());
  }

  std::string imu_frame_;
  ImuMount mount_;
  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  ros::Publisher pub_fused_, pub_frames_;
  ros::Subscriber sub_imu_, sub_pose_;

  std::mutex mutex_;  // the filter and what follows (callbacks and diagnostics)
  std::unique_ptr<InertialFusion> fusion_;
  std::string camera_frame_ = "camera_optical_frame";
  uint32_t points_used_ = 0;
  std::string last_status_;
  bool last_valid_ = false;
  int64_t imu_samples_ = 0, camera_estimates_ = 0, camera_used_ = 0;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::InertialFusionNodelet, nodelet::Nodelet)
