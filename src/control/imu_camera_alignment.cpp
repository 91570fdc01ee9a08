#include "structured_light_stabilizer/control/imu_camera_alignment.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "structured_light_stabilizer/common/se3.h"

namespace structured_light_stabilizer
{

namespace
{

// Fewest matched intervals, and the least rotation rate spread per axis
// (rad/s) for a usable rotation.
constexpr int kMinPairs = 50;
constexpr double kMinExcitation = 0.005;

struct CameraRate
{
  double t0, t1;    // the interval (camera clock)
  Eigen::Vector3d w;  // mean body rate over it, camera frame
};

// The camera's body rate between consecutive valid estimates.
std::vector<CameraRate> cameraRates(const std::vector<CameraMeasurement>& camera)
{
  std::vector<const CameraMeasurement*> valid;
  for (const CameraMeasurement& c : camera)
    if (c.valid && c.transform.matrix().allFinite())
      valid.push_back(&c);
  std::sort(valid.begin(), valid.end(), [](const CameraMeasurement* a, const CameraMeasurement* b) { return a->stamp < b->stamp; });
  std::vector<CameraRate> rates;
  for (size_t k = 1; k < valid.size(); ++k)
  {
    const double dt = valid[k]->stamp - valid[k - 1]->stamp;
    if (!(dt > 0.0) || dt > 0.2)
      continue;
    // The camera's orientation in the reference frame is R^T (p_cur = R p_ref + t).
    const Eigen::Matrix3d a = valid[k - 1]->transform.linear().transpose(), b = valid[k]->transform.linear().transpose();
    rates.push_back({valid[k - 1]->stamp, valid[k]->stamp, logSO3(a.transpose() * b) / dt});
  }
  return rates;
}

// The gyro's mean rate over [t0, t1] of the IMU's clock (each sample is the
// mean over the period that ends at its stamp); false when not covered.
bool gyroMean(const std::vector<ImuMeasurement>& imu, double t0, double t1, Eigen::Vector3d* w)
{
  auto it = std::lower_bound(imu.begin(), imu.end(), t0, [](const ImuMeasurement& m, double t) { return m.stamp < t; });
  if (it == imu.begin() || it == imu.end())
    return false;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double covered = 0.0, from = t0;
  for (; it != imu.end() && from < t1; ++it)
  {
    const double to = std::min(it->stamp, t1);
    sum += it->angular_velocity * (to - from);
    covered += to - from;
    from = to;
  }
  if (from < t1 - 1e-9 || !(covered > 0.0))
    return false;
  *w = sum / covered;
  return true;
}

struct Pairs
{
  std::vector<Eigen::Vector3d> camera, gyro;
};

Pairs pairsAt(const std::vector<CameraRate>& rates, const std::vector<ImuMeasurement>& imu, double offset)
{
  Pairs p;
  for (const CameraRate& r : rates)
  {
    Eigen::Vector3d w;
    if (gyroMean(imu, r.t0 - offset, r.t1 - offset, &w))
    {
      p.camera.push_back(r.w);
      p.gyro.push_back(w);
    }
  }
  return p;
}

// Pearson correlation of the rate magnitudes (independent of the rotation).
double magnitudeCorrelation(const Pairs& p)
{
  const size_t n = p.camera.size();
  if (n < 3)
    return -1.0;
  double ma = 0, mb = 0;
  for (size_t i = 0; i < n; ++i)
    ma += p.camera[i].norm() / n, mb += p.gyro[i].norm() / n;
  double sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < n; ++i)
  {
    const double a = p.camera[i].norm() - ma, b = p.gyro[i].norm() - mb;
    sab += a * b, saa += a * a, sbb += b * b;
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : -1.0;
}

// w_camera = R (w_gyro - b): Kabsch for R, the mean for b, alternated.
void solveRotation(const Pairs& p, Eigen::Matrix3d* R, Eigen::Vector3d* b)
{
  b->setZero();
  R->setIdentity();
  for (int iteration = 0; iteration < 10; ++iteration)
  {
    Eigen::Vector3d mc = Eigen::Vector3d::Zero(), mg = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < p.camera.size(); ++i)
      mc += p.camera[i], mg += p.gyro[i] - *b;
    mc /= p.camera.size(), mg /= p.camera.size();
    Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
    for (size_t i = 0; i < p.camera.size(); ++i)
      H += (p.gyro[i] - *b - mg) * (p.camera[i] - mc).transpose();
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
    *R = svd.matrixV() * D * svd.matrixU().transpose();
    Eigen::Vector3d bias = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < p.camera.size(); ++i)
      bias += p.gyro[i] - R->transpose() * p.camera[i];
    *b = bias / static_cast<double>(p.camera.size());
  }
}

}  // namespace

ImuCameraAlignment estimateImuCameraAlignment(const std::vector<ImuMeasurement>& imu_in,
                                              const std::vector<CameraMeasurement>& camera, double max_offset_s)
{
  ImuCameraAlignment out;
  std::vector<ImuMeasurement> imu;
  for (const ImuMeasurement& m : imu_in)
    if (std::isfinite(m.stamp) && m.angular_velocity.allFinite())
      imu.push_back(m);
  std::sort(imu.begin(), imu.end(), [](const ImuMeasurement& a, const ImuMeasurement& b) { return a.stamp < b.stamp; });
  const std::vector<CameraRate> rates = cameraRates(camera);
  if (imu.size() < 10 || rates.size() < static_cast<size_t>(kMinPairs))
  {
    out.problem = "too few samples: " + std::to_string(imu.size()) + " IMU, " + std::to_string(rates.size()) +
                  " camera intervals (need " + std::to_string(kMinPairs) + ")";
    return out;
  }
  // The offset: a coarse search at a fraction of the IMU period, then the
  // parabola through the best and its neighbours.
  const double period = (imu.back().stamp - imu.front().stamp) / std::max<size_t>(1, imu.size() - 1);
  const double step = std::max(1e-4, 0.25 * period);
  double best = -2.0, best_offset = 0.0;
  std::vector<std::pair<double, double>> scores;
  for (double d = -max_offset_s; d <= max_offset_s + 1e-12; d += step)
  {
    const double c = magnitudeCorrelation(pairsAt(rates, imu, d));
    scores.emplace_back(d, c);
    if (c > best)
      best = c, best_offset = d;
  }
  for (size_t i = 1; i + 1 < scores.size(); ++i)
    if (scores[i].first == best_offset)
    {
      const double a = scores[i - 1].second, b = scores[i].second, c = scores[i + 1].second;
      const double denominator = a - 2.0 * b + c;
      if (denominator < 0.0)
        best_offset += 0.5 * step * (a - c) / denominator;
    }
  const Pairs p = pairsAt(rates, imu, best_offset);
  out.time_offset_s = best_offset;
  out.correlation = magnitudeCorrelation(p);
  out.pairs = static_cast<int>(p.camera.size());
  Eigen::Matrix3d R;
  solveRotation(p, &R, &out.gyro_bias);
  out.rotation_camera_imu = Eigen::Quaterniond(R).normalized();
  if (out.rotation_camera_imu.w() < 0.0)  // one sign for the YAML: w >= 0
    out.rotation_camera_imu.coeffs() *= -1.0;
  double sq = 0.0;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < p.camera.size(); ++i)
  {
    sq += (p.camera[i] - R * (p.gyro[i] - out.gyro_bias)).squaredNorm();
    mean += p.camera[i] / static_cast<double>(p.camera.size());
  }
  out.rms_residual = std::sqrt(sq / std::max<size_t>(1, p.camera.size()));
  Eigen::Matrix3d spread = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& w : p.camera)
    spread += (w - mean) * (w - mean).transpose() / static_cast<double>(p.camera.size());
  out.weakest_excitation = std::sqrt(std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(spread).eigenvalues()[0]));
  std::ostringstream why;
  if (out.pairs < kMinPairs)
    why << "only " << out.pairs << " camera intervals matched the IMU's clock; ";
  // An axis the camera did not turn about shows only the rates' noise.
  if (out.weakest_excitation < std::max(kMinExcitation, 3.0 * out.rms_residual / std::sqrt(3.0)))
    why << "too little rotation about one axis (" << out.weakest_excitation
        << " rad/s spread): turn the camera about all three axes; ";
  if (out.correlation < 0.5)
    why << "the rates hardly correlate (" << out.correlation << "): wrong topics or no common motion; ";
  out.problem = why.str();
  if (!out.problem.empty())
    out.problem.resize(out.problem.size() - 2);
  return out;
}

}  // namespace structured_light_stabilizer
