// The simulated IMU (sim/render/imu_model.h) against closed forms: at rest it
// reads -gravity and its biases; a constant rotation gives the gyro reading
// and the centripetal acceleration of its lever arm; a sinusoidal
// translation gives the mean acceleration over each period; the noise has
// its datasheet density and the biases walk at their rate; the mount, the
// time offset and the faults do what they say. cameraKinematics() against
// finite differences of the poses it composes (disturbance and arm).
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/sim/render/imu_model.h"

using namespace structured_light_stabilizer;

namespace
{

ImuModelParams noiseless()
{
  ImuModelParams p;
  p.gyro_noise_density = p.accel_noise_density = 0.0;
  p.gyro_bias_random_walk = p.accel_bias_random_walk = 0.0;
  return p;
}

CameraKinematics atRest(double t)
{
  CameraKinematics k;
  k.t = t;
  return k;
}

}  // namespace

TEST(ImuModel, AtRestReadsGravityAndBiases)
{
  const ImuModelParams p = noiseless();
  ImuModel imu(p);
  ImuSample s;
  EXPECT_FALSE(imu.sample(atRest(0.0), &s));  // primes
  ASSERT_TRUE(imu.sample(atRest(0.0025), &s));
  const Eigen::Matrix3d R_ci = p.rotation_camera_imu.toRotationMatrix();
  // REP 145: the specific force at rest points up, +g along the up axis.
  EXPECT_LT((s.linear_acceleration - (-(R_ci.transpose() * p.gravity_m_s2) + p.accel_bias)).norm(), 1e-12);
  EXPECT_LT((s.angular_velocity - p.gyro_bias).norm(), 1e-12);
  // The default mount: the IMU's z is up (camera -y), so gravity reads +3.711 on z.
  EXPECT_NEAR(s.linear_acceleration.z() - p.accel_bias.z(), 3.711, 0.01);
  EXPECT_DOUBLE_EQ(s.stamp, 0.0025);
}

TEST(ImuModel, ConstantRotationGivesRateAndCentripetalAcceleration)
{
  ImuModelParams p = noiseless();
  p.gyro_bias.setZero();
  p.accel_bias.setZero();
  p.gravity_m_s2.setZero();
  ImuModel imu(p);
  const Eigen::Vector3d w(0.3, -0.2, 0.5);  // rad/s, camera frame
  const Eigen::Matrix3d R_ci = p.rotation_camera_imu.toRotationMatrix();
  const Eigen::Vector3d r = p.lever_arm_m;
  ImuSample s;
  for (int i = 0; i <= 400; ++i)
  {
    CameraKinematics k;
    k.t = i / 400.0;
    k.pose.linear() = expSO3(w * k.t);
    k.angular_velocity = w;  // the optical centre still: a rotation about it
    if (!imu.sample(k, &s))
      continue;
    EXPECT_LT((s.angular_velocity - R_ci.transpose() * w).norm(), 1e-9);
    // a = w x (w x r) in the camera frame: the IMU's point circles the axis.
    const Eigen::Vector3d a_cam = w.cross(w.cross(r));
    EXPECT_LT((s.linear_acceleration - R_ci.transpose() * a_cam).norm(), 2e-6) << "t " << k.t;
  }
}

TEST(ImuModel, SinusoidalTranslationGivesTheMeanAcceleration)
{
  ImuModelParams p = noiseless();
  p.gyro_bias.setZero();
  p.accel_bias.setZero();
  p.gravity_m_s2.setZero();
  ImuModel imu(p);
  const double A = 0.003, f = 5.0, wf = 2.0 * M_PI * f, dt = 1.0 / p.rate_hz;
  const Eigen::Matrix3d R_ci = p.rotation_camera_imu.toRotationMatrix();
  ImuSample s;
  for (int i = 0; i <= 400; ++i)
  {
    CameraKinematics k;
    k.t = i * dt;
    k.pose.translation() = Eigen::Vector3d(A * std::sin(wf * k.t), 0.0, 0.0);
    k.velocity = Eigen::Vector3d(A * wf * std::cos(wf * k.t), 0.0, 0.0);
    if (!imu.sample(k, &s))
      continue;
    const double mean = A * wf * (std::cos(wf * k.t) - std::cos(wf * (k.t - dt))) / dt;
    EXPECT_LT((s.linear_acceleration - R_ci.transpose() * Eigen::Vector3d(mean, 0, 0)).norm(), 1e-9);
  }
}

TEST(ImuModel, NoiseHasItsDensityAndBiasesWalk)
{
  ImuModelParams p;
  p.gyro_bias_random_walk = p.accel_bias_random_walk = 0.0;
  ImuModel imu(p);
  const int n = 20000;
  Eigen::Vector3d sum_g = Eigen::Vector3d::Zero(), sq_g = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_a = Eigen::Vector3d::Zero(), sq_a = Eigen::Vector3d::Zero();
  ImuSample s;
  int got = 0;
  for (int i = 0; i <= n; ++i)
    if (imu.sample(atRest(i / p.rate_hz), &s))
    {
      sum_g += s.angular_velocity;
      sq_g += s.angular_velocity.cwiseProduct(s.angular_velocity);
      sum_a += s.linear_acceleration;
      sq_a += s.linear_acceleration.cwiseProduct(s.linear_acceleration);
      ++got;
    }
  ASSERT_EQ(got, n);
  const double sigma_g = p.gyro_noise_density * std::sqrt(p.rate_hz);
  const double sigma_a = p.accel_noise_density * std::sqrt(p.rate_hz);
  for (int a = 0; a < 3; ++a)
  {
    const double sd_g = std::sqrt(sq_g[a] / n - std::pow(sum_g[a] / n, 2));
    const double sd_a = std::sqrt(sq_a[a] / n - std::pow(sum_a[a] / n, 2));
    EXPECT_NEAR(sd_g / sigma_g, 1.0, 0.03) << "axis " << a;
    EXPECT_NEAR(sd_a / sigma_a, 1.0, 0.03) << "axis " << a;
    EXPECT_NEAR(sum_g[a] / n, p.gyro_bias[a], 4.0 * sigma_g / std::sqrt(n));
  }
  std::printf("[ MEASURE ] IMU noise per sample: gyro %.3g rad/s (expected %.3g), accel %.3g m/s^2 (expected %.3g)\n",
              std::sqrt(sq_g[0] / n - std::pow(sum_g[0] / n, 2)), sigma_g,
              std::sqrt(sq_a[0] / n - std::pow(sum_a[0] / n, 2)), sigma_a);

  // The biases walk: after 1 s their spread over many seeds is rw * sqrt(1 s).
  ImuModelParams w;
  double sq_bg = 0.0, sq_ba = 0.0;
  const int seeds = 300;
  for (int seed = 0; seed < seeds; ++seed)
  {
    w.seed = 1000 + seed;
    ImuModel walk(w);
    for (int i = 0; i <= 400; ++i)
      walk.sample(atRest(i / w.rate_hz), &s);
    sq_bg += (walk.gyroBias() - w.gyro_bias).squaredNorm() / 3.0;
    sq_ba += (walk.accelBias() - w.accel_bias).squaredNorm() / 3.0;
  }
  EXPECT_NEAR(std::sqrt(sq_bg / seeds) / w.gyro_bias_random_walk, 1.0, 0.1);
  EXPECT_NEAR(std::sqrt(sq_ba / seeds) / w.accel_bias_random_walk, 1.0, 0.1);
}

TEST(ImuModel, TimeOffsetSilenceAndBiasStep)
{
  ImuModelParams p = noiseless();
  p.time_offset_s = 0.007;
  p.silent_from_s = 0.1;
  p.silent_until_s = 0.2;
  p.bias_step_time_s = 0.3;
  p.gyro_bias_step = Eigen::Vector3d(0.05, 0, 0);
  p.accel_bias_step = Eigen::Vector3d(0, 0.5, 0);
  ImuModel imu(p);
  ImuSample s;
  int silent = 0;
  for (int i = 0; i <= 160; ++i)
  {
    const double t = i / p.rate_hz;
    const bool got = imu.sample(atRest(t), &s);
    if (i == 0)
      continue;
    if (t >= 0.1 && t < 0.2)
    {
      EXPECT_FALSE(got) << t;
      ++silent;
      continue;
    }
    ASSERT_TRUE(got) << t;
    EXPECT_NEAR(s.stamp, t - 0.007, 1e-12);
    const double bias_x = p.gyro_bias.x() + (t >= 0.3 ? 0.05 : 0.0);
    EXPECT_NEAR(s.angular_velocity.x(), bias_x, 1e-12) << t;
  }
  EXPECT_EQ(silent, 40);
  EXPECT_EQ(ImuModelParams().validate(), "");
  ImuModelParams bad;
  bad.rate_hz = 0.0;
  EXPECT_NE(bad.validate().find("rate_hz"), std::string::npos);
  EXPECT_THROW(ImuModel{bad}, std::invalid_argument);
}

TEST(ImuModel, KinematicsMatchFiniteDifferencesOfThePoses)
{
  RigMotionParams m = roverArmDisturbance();
  m.vibration_translation_rms_m = 0.003;
  m.vibration_rotation_rms_rad = 0.005;
  m.vibration_min_hz = 1.0;
  ArmModelParams ap;
  ArmModel arm(ap);
  Vector6d xi;
  xi << 0.01, -0.02, 0.005, 0.05, -0.03, 0.08;
  arm.command(0.0, xi);
  // After the arm reached a steady twist (a constant velocity over each step).
  const double t = 0.5, h = 1e-5;
  arm.advance(t - h);
  const Eigen::Isometry3d before = cameraKinematics(m, &arm, t - h).pose;
  arm.advance(t);
  const CameraKinematics k = cameraKinematics(m, &arm, t);
  arm.advance(t + h);
  const Eigen::Isometry3d after = cameraKinematics(m, &arm, t + h).pose;
  const Eigen::Vector3d v = (after.translation() - before.translation()) / (2.0 * h);
  const Eigen::Vector3d w = logSO3(before.linear().transpose() * after.linear()) / (2.0 * h);
  EXPECT_LT((k.velocity - v).norm(), 1e-6 + 1e-4 * v.norm()) << k.velocity.transpose() << " / " << v.transpose();
  EXPECT_LT((k.angular_velocity - w).norm(), 1e-6 + 1e-4 * w.norm());
  EXPECT_GT(v.norm(), 0.01);  // both the disturbance and the arm move it
  // Without the arm: the disturbance alone, T_W_C = D^-1.
  EXPECT_TRUE(cameraKinematics(m, nullptr, t).pose.isApprox(disturbanceMotion(m, t).inverse(), 1e-12));
}

TEST(ImuModel, NoSpikeAtTheStart)
{
  // The disturbance is defined from t = 0 on (its steps would count
  // backwards before): the first samples read gravity, not a jump.
  const RigMotionParams m = roverArmDisturbance();
  ImuModelParams p = noiseless();
  p.accel_bias.setZero();
  ImuModel imu(p);
  ImuSample s;
  imu.sample(cameraKinematics(m, nullptr, 0.0), &s);
  ASSERT_TRUE(imu.sample(cameraKinematics(m, nullptr, 0.0025), &s));
  EXPECT_NEAR(s.linear_acceleration.norm(), 3.711, 0.1);  // the motion's own, no jump
}
