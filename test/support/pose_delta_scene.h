// Test-only synthetic scene for the PoseDelta gtests: an analytic height-field
// rock fixed in the world (= the reference camera frame), a grid projector
// rigid with the camera, beams ray-cast by bisection, and an optional
// textured image of the rock with green dots. Independent of the simulator so
// that the estimator is checked against a second, simple implementation.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"

namespace sls_test
{

using structured_light_stabilizer::CameraModel;
using structured_light_stabilizer::ProjectorCalibration;

constexpr double kPi = 3.14159265358979323846;

struct Rock
{
  double distance = 1.5;
  double relief = 0.15;  // about peak-to-peak

  double height(double x, double y) const
  {
    if (relief == 0.0)
      return distance;
    // A few smooth undulations from 0.25 m to 0.8 m wavelength plus a small
    // finer one; the normalisation makes the sum about `relief` peak-to-peak.
    const double h = 0.30 * std::sin(2 * kPi * x / 0.62 + 0.3) + 0.25 * std::sin(2 * kPi * y / 0.78 + 1.1) +
                     0.20 * std::sin(2 * kPi * (x + 0.7 * y) / 0.41 + 2.0) +
                     0.15 * std::sin(2 * kPi * (0.8 * x - y) / 0.29 + 0.4) +
                     0.05 * std::sin(2 * kPi * (x - 0.3 * y) / 0.19 + 1.7);
    return distance + relief * h / 1.9;
  }

  // Albedo 0.05 - 0.45: multi-octave value noise, features of 1 - 4 cm.
  double albedo(double x, double y) const
  {
    double a = 0.0, amp = 0.5, scale = 0.04;
    for (int o = 0; o < 3; ++o)
    {
      a += amp * valueNoise(x / scale, y / scale, o);
      amp *= 0.55;
      scale *= 0.5;
    }
    a /= (0.5 + 0.275 + 0.15125);
    return 0.05 + 0.40 * std::min(1.0, std::max(0.0, a));
  }

  static double hash(int ix, int iy, int o)
  {
    uint32_t h = static_cast<uint32_t>(ix) * 374761393u + static_cast<uint32_t>(iy) * 668265263u +
                 static_cast<uint32_t>(o) * 2246822519u;
    h = (h ^ (h >> 13)) * 1274126177u;
    h ^= h >> 16;
    return (h & 0xffffff) / static_cast<double>(0xffffff);
  }

  static double valueNoise(double x, double y, int o)
  {
    const double fx = std::floor(x), fy = std::floor(y);
    const int ix = static_cast<int>(fx), iy = static_cast<int>(fy);
    const double sx = x - fx, sy = y - fy;
    const double ux = sx * sx * (3 - 2 * sx), uy = sy * sy * (3 - 2 * sy);
    const double a = hash(ix, iy, o), b = hash(ix + 1, iy, o), c = hash(ix, iy + 1, o), d = hash(ix + 1, iy + 1, o);
    return (a * (1 - ux) + b * ux) * (1 - uy) + (c * (1 - ux) + d * ux) * uy;
  }

  // First crossing of the ray with the height field, world frame.
  bool intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d, Eigen::Vector3d* hit) const
  {
    auto f = [&](double s)
    {
      const Eigen::Vector3d p = o + s * d;
      return p.z() - height(p.x(), p.y());
    };
    double lo = 0.2, hi = 4.0;
    if (f(lo) >= 0.0 || f(hi) <= 0.0)
      return false;
    for (int i = 0; i < 70; ++i)
    {
      const double mid = 0.5 * (lo + hi);
      (f(mid) < 0.0 ? lo : hi) = mid;
    }
    *hit = o + 0.5 * (lo + hi) * d;
    return true;
  }
};

// The simulator's default projector: baseline 0.25 m, pitch 0.035 rad, 5 deg
// roll, central beam crossing the optical axis at 1.5 m.
inline ProjectorCalibration defaultProjector()
{
  const Eigen::Vector3d origin(0.25, 0.0, 0.0);
  return structured_light_stabilizer::makeGridProjector(10, 10, origin, Eigen::Vector3d(0, 0, 1.5) - origin, 0.035,
                                                        0.035, 0.087);
}

// Beam hit points in the camera frame of pose `delta` (p_cur = delta * p_ref,
// ref = world). `noise_m`: Gaussian noise along the camera ray, the way
// triangulation errors mostly fall.
inline std::vector<Eigen::Vector3d> beamPoints(const Rock& rock, const ProjectorCalibration& proj,
                                               const Eigen::Isometry3d& delta, double noise_m = 0.0,
                                               std::mt19937* rng = nullptr)
{
  const Eigen::Isometry3d inv = delta.inverse();
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<Eigen::Vector3d> out;
  for (const auto& b : proj.beams)
  {
    Eigen::Vector3d hit;
    if (!rock.intersect(inv * b.origin, inv.linear() * b.direction, &hit))
    {
      out.push_back(Eigen::Vector3d::Constant(NAN));
      continue;
    }
    Eigen::Vector3d q = delta * hit;
    if (noise_m > 0.0 && rng)
      q += noise_m * n01(*rng) * q.normalized();
    out.push_back(q);
  }
  return out;
}

// A random rig pose within +-t_max per axis and +-r_max per axis.
inline Eigen::Isometry3d randomDelta(std::mt19937& rng, double t_max, double r_max)
{
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  // Sequenced draws (docs/testing.md): the order gcc evaluated them in.
  const double rz = u(rng), ry = u(rng), rx = u(rng);
  T.linear() = (Eigen::AngleAxisd(r_max * rx, Eigen::Vector3d::UnitX()) *
                Eigen::AngleAxisd(r_max * ry, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(r_max * rz, Eigen::Vector3d::UnitZ()))
                   .toRotationMatrix();
  const double tz = u(rng), ty = u(rng), tx = u(rng);
  T.translation() = Eigen::Vector3d(t_max * tx, t_max * ty, t_max * tz);
  return T;
}

// Renders the rock (bgr8, reddish texture) with green Gaussian dots at the
// projected beam points, a mild defocus and 1 DN of read noise. Only the
// central `half_size` pixels around the principal point are rendered; the
// rest stays black (enough for the texture tracker, fast in a test).
inline cv::Mat renderImage(const Rock& rock, const CameraModel& cam, const Eigen::Isometry3d& delta,
                           const std::vector<Eigen::Vector3d>& dots_cam, uint32_t seed, int half_size = 260)
{
  cv::Mat img(cam.height, cam.width, CV_32FC3, cv::Scalar(0, 0, 0));
  const Eigen::Isometry3d inv = delta.inverse();
  const Eigen::Vector3d c_w = inv.translation();
  const int x0 = std::max(0, static_cast<int>(cam.cx) - half_size),
            x1 = std::min(cam.width, static_cast<int>(cam.cx) + half_size);
  const int y0 = std::max(0, static_cast<int>(cam.cy) - half_size),
            y1 = std::min(cam.height, static_cast<int>(cam.cy) + half_size);
  for (int y = y0; y < y1; ++y)
  {
    cv::Vec3f* row = img.ptr<cv::Vec3f>(y);
    for (int x = x0; x < x1; ++x)
    {
      const Eigen::Vector3d d_w = inv.linear() * cam.ray(cv::Point2d(x, y));
      // Fixed-point iteration on the height field from the mean plane.
      double s = (rock.distance - c_w.z()) / d_w.z();
      for (int k = 0; k < 6; ++k)
      {
        const Eigen::Vector3d p = c_w + s * d_w;
        s = (rock.height(p.x(), p.y()) - c_w.z()) / d_w.z();
      }
      const Eigen::Vector3d p = c_w + s * d_w;
      const double a = rock.albedo(p.x(), p.y());
      row[x] = cv::Vec3f(static_cast<float>(60 * a), static_cast<float>(140 * a), static_cast<float>(420 * a));
    }
  }
  // Dots: green Gaussians of sigma 2 px, a little red/blue cross-talk.
  for (const Eigen::Vector3d& q : dots_cam)
  {
    if (!q.allFinite())
      continue;
    const cv::Point2d c = cam.project(q);
    for (int y = static_cast<int>(c.y) - 8; y <= static_cast<int>(c.y) + 8; ++y)
      for (int x = static_cast<int>(c.x) - 8; x <= static_cast<int>(c.x) + 8; ++x)
      {
        if (x < 0 || y < 0 || x >= cam.width || y >= cam.height)
          continue;
        const double r2 = (x - c.x) * (x - c.x) + (y - c.y) * (y - c.y);
        const float g = static_cast<float>(400.0 * std::exp(-0.5 * r2 / 4.0));
        img.at<cv::Vec3f>(y, x) += cv::Vec3f(0.05f * g, g, 0.05f * g);
      }
  }
  cv::GaussianBlur(img, img, cv::Size(0, 0), 0.8);
  cv::Mat noise(img.size(), CV_32FC3);
  cv::theRNG().state = seed;
  cv::randn(noise, 0.0, 1.0);
  img += noise;
  cv::Mat out;
  img.convertTo(out, CV_8UC3);
  return out;
}

inline double rotationErrorDeg(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b)
{
  return Eigen::AngleAxisd(a.linear() * b.linear().transpose()).angle() * 180.0 / kPi;
}

}  // namespace sls_test
