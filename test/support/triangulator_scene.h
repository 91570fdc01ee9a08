// Synthetic scenes for the triangulator and calibrator tests: exact beam
// hits on a surface (ray / height-field intersection, an optional
// fronto-parallel occluder), projected with the CameraModel, then noise,
// dropped dots and clutter. Independent of the simulator so that the core
// can be tested before (and apart from) it.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/common/spot.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace sls_test
{

using namespace structured_light_stabilizer;

struct Scene
{
  double distance = 1.5;  // mean depth of the surface (m)
  double relief = 0.0;    // peak-to-peak relief (m); 0 = flat board facing the camera
  double phase = 0.0;     // varies the relief between trials
  // Optional occluder: a fronto-parallel rectangle at depth occluder_z.
  bool occluder = false;
  double occluder_z = 1.0;
  double occ_x0 = 0.0, occ_x1 = 0.0, occ_y0 = 0.0, occ_y1 = 0.0;

  double surfaceZ(double x, double y) const
  {
    return distance + 0.5 * relief * std::sin(2.0 * M_PI * x / 0.7 + phase) * std::cos(2.0 * M_PI * y / 0.9 - phase);
  }

  bool inOccluder(const Eigen::Vector3d& p) const
  {
    return occluder && p.x() >= occ_x0 && p.x() <= occ_x1 && p.y() >= occ_y0 && p.y() <= occ_y1;
  }

  // First hit of a ray on the occluder or the surface.
  bool intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& u, Eigen::Vector3d* hit) const
  {
    if (occluder && u.z() > 0.0)
    {
      const double s = (occluder_z - o.z()) / u.z();
      const Eigen::Vector3d p = o + s * u;
      if (s > 0.0 && inOccluder(p))
      {
        *hit = p;
        return true;
      }
    }
    // Bisection on g(s) = z(s) - surface(x(s), y(s)), bracketed in depth.
    const auto g = [&](double s)
    {
      const Eigen::Vector3d p = o + s * u;
      return p.z() - surfaceZ(p.x(), p.y());
    };
    double lo = (0.05 - o.z()) / u.z(), hi = (distance + relief + 5.0 - o.z()) / u.z();
    if (g(lo) > 0.0 || g(hi) < 0.0)
      return false;
    for (int k = 0; k < 100; ++k)
    {
      const double mid = 0.5 * (lo + hi);
      (g(mid) > 0.0 ? hi : lo) = mid;
    }
    *hit = o + 0.5 * (lo + hi) * u;
    return true;
  }

  // Whether the camera (at the origin) sees p, i.e. the occluder is not in between.
  bool visibleFromCamera(const Eigen::Vector3d& p) const
  {
    if (!occluder || p.z() <= occluder_z)
      return true;
    const Eigen::Vector3d q = p * (occluder_z / p.z());
    return !inOccluder(q);
  }
};

struct Frame
{
  std::vector<Eigen::Vector3d> truth;  // per beam (NaN = not visible)
  std::vector<cv::Point2d> pixels;     // per beam, exact distorted pixel
  Spots spots;                         // shuffled, noisy, with clutter; spot.beam = true beam (-1 clutter)
};

struct FrameOptions
{
  double noise_px = 0.0;
  double drop_fraction = 0.0;
  int clutter = 0;
  int merge_pairs = 0;  // neighbouring visible dots (same row) merged into one blob
  uint32_t seed = 1;
};

// A frame of n beams with no hit yet (truth and pixels NaN).
inline Frame emptyFrame(int n)
{
  const double nan = std::numeric_limits<double>::quiet_NaN();
  Frame f;
  f.truth.assign(n, Eigen::Vector3d::Constant(nan));
  f.pixels.assign(n, cv::Point2d(nan, nan));
  return f;
}

inline bool inImage(const CameraModel& cam, const cv::Point2d& px)
{
  return px.x >= 0 && px.y >= 0 && px.x <= cam.width - 1 && px.y <= cam.height - 1;
}

inline Spot spotAt(const cv::Point2d& px, int beam)
{
  Spot s;
  s.x = px.x;
  s.y = px.y;
  s.area = 10.0f;
  s.intensity = 100.0f;
  s.beam = beam;
  return s;
}

inline Frame makeFrame(const CameraModel& cam, const ProjectorCalibration& proj, const Scene& scene,
                       const FrameOptions& opt)
{
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::mt19937 rng(opt.seed);
  std::normal_distribution<double> noise(0.0, opt.noise_px > 0.0 ? opt.noise_px : 1.0);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  Frame f;
  const int n = proj.beamCount();
  f.truth.assign(n, Eigen::Vector3d::Constant(nan));
  f.pixels.assign(n, cv::Point2d(nan, nan));
  for (int i = 0; i < n; ++i)
  {
    Eigen::Vector3d hit;
    if (!scene.intersect(proj.beams[i].origin, proj.beams[i].direction, &hit) || !scene.visibleFromCamera(hit))
      continue;
    const cv::Point2d px = cam.project(hit);
    if (!(px.x >= 0 && px.y >= 0 && px.x <= cam.width - 1 && px.y <= cam.height - 1))
      continue;
    f.truth[i] = hit;
    f.pixels[i] = px;
  }
  std::vector<char> merged(n, 0);
  int merges = 0;
  for (int i = 0; i + 1 < n && merges < opt.merge_pairs; i += 7)
  {
    if ((i + 1) % proj.cols == 0 || std::isnan(f.pixels[i].x) || std::isnan(f.pixels[i + 1].x))
      continue;
    merged[i] = merged[i + 1] = 1;
    Spot s;
    s.x = 0.5 * (f.pixels[i].x + f.pixels[i + 1].x);
    s.y = 0.5 * (f.pixels[i].y + f.pixels[i + 1].y);
    s.area = 20.0f;
    s.intensity = 200.0f;
    s.beam = -2;  // a merged blob: owned by no single beam
    f.spots.push_back(s);
    ++merges;
  }
  for (int i = 0; i < n; ++i)
  {
    if (std::isnan(f.pixels[i].x) || merged[i])
      continue;
    if (uni(rng) < opt.drop_fraction)
      continue;
    Spot s;
    s.x = f.pixels[i].x + (opt.noise_px > 0.0 ? noise(rng) : 0.0);
    s.y = f.pixels[i].y + (opt.noise_px > 0.0 ? noise(rng) : 0.0);
    s.area = 10.0f;
    s.intensity = 100.0f + static_cast<float>(i);
    s.beam = i;
    f.spots.push_back(s);
  }
  for (int k = 0; k < opt.clutter; ++k)
  {
    Spot s;
    s.x = uni(rng) * (cam.width - 1);
    s.y = uni(rng) * (cam.height - 1);
    s.area = 10.0f;
    s.intensity = 50.0f;
    s.beam = -1;
    f.spots.push_back(s);
  }
  std::shuffle(f.spots.begin(), f.spots.end(), rng);
  return f;
}

// Per spot: whether another spot lies within the gate of the true beam's
// epipolar segment and within half a beam pitch of the spot along it (both
// undistorted). Such a dot is not identifiable from geometry: the rival
// reads as a dot of the same beam at nearly the same depth (a difference the
// surface's relief can explain), so either may be the beam's dot; the
// triangulator leaves the beam unassigned (or, rarely, takes the rival: a
// wrong spot but a nearly right point). Spurious spots (beam < 0) get false.
inline std::vector<char> ambiguousDots(const Triangulator& tri, const Spots& spots)
{
  std::vector<Eigen::Vector2d> px(spots.size());
  for (size_t j = 0; j < spots.size(); ++j)
    px[j] = tri.undistortPixel(spots[j].x, spots[j].y);
  const double gate = tri.params().max_epipolar_distance_px;
  std::vector<char> out(spots.size(), 0);
  for (size_t j = 0; j < spots.size(); ++j)
  {
    if (spots[j].beam < 0 || !px[j].allFinite())
      continue;
    const EpipolarSegment& sg = tri.segments()[spots[j].beam];
    const Eigen::Vector2d ab = sg.far_px - sg.near_px;
    for (size_t o = 0; o < spots.size() && !out[j]; ++o)
    {
      if (o == j || !px[o].allFinite())
        continue;
      const double t = std::min(1.0, std::max(0.0, (px[o] - sg.near_px).dot(ab) / ab.squaredNorm()));
      const double off_line = (sg.near_px + t * ab - px[o]).norm();
      out[j] = off_line <= gate && (px[o] - px[j]).norm() <= 0.5 * tri.beamPitchPx();
    }
  }
  return out;
}

// The simulator's default rig (simulator.h): baseline 0.25 m along x, 10 x 10
// beams of 0.035 rad pitch converging on the optical axis at 1.5 m.
inline ProjectorCalibration simLikeProjector(double roll_rad, int rows = 10, int cols = 10,
                                             const Eigen::Vector3d& origin = Eigen::Vector3d(0.25, 0.0, 0.0))
{
  return makeGridProjector(rows, cols, origin, Eigen::Vector3d(0.0, 0.0, 1.5) - origin, 0.035, 0.035, roll_rad);
}

}  // namespace sls_test

namespace sls_test
{

// A rig moving over a fixed rock, frame after frame: the rock is the height
// field of `Scene` in a world frame (its camera frame at rest); the rig (the
// camera with its projector) sits at `rigPose(t)` in that frame: a slow
// approach and retreat between near_m and far_m over `period_s`, plus wind
// jitter of `jitter_m` / `jitter_rad` per axis (sums of sines, 0.7 Hz base).
struct SequenceOptions
{
  double near_m = 1.0, far_m = 2.0, period_s = 120.0;
  double jitter_m = 0.01, jitter_rad = 0.0175;
  double relief = 0.15;
  double drop_fraction = 0.1;  // dots missing at random in every frame
  int random_clutter = 10;     // projector-coloured spots anywhere, new every frame
  int rock_clutter = 10;       // projector-coloured spots fixed on the rock
  double noise_px = 0.04;
  uint32_t seed = 1;
};

inline Eigen::Isometry3d rigPose(const SequenceOptions& o, double t)
{
  const double mid = 0.5 * (o.near_m + o.far_m), amp = 0.5 * (o.far_m - o.near_m);
  // The rock's mean plane lies at mid: the rig moves along z so that the
  // distance goes mid + amp cos(...) (1.0 m .. 2.0 m).
  const double dz = mid - (mid + amp * std::cos(2.0 * M_PI * t / o.period_s));
  const auto s = [&](double f, double ph) { return std::sin(2.0 * M_PI * 0.7 * f * t + ph); };
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translation() = Eigen::Vector3d(o.jitter_m * (0.6 * s(1.0, 0.1) + 0.4 * s(2.3, 1.7)),
                                       o.jitter_m * (0.6 * s(1.3, 2.2) + 0.4 * s(2.9, 0.4)),
                                       dz + o.jitter_m * (0.6 * s(0.9, 1.1) + 0.4 * s(3.1, 2.9)));
  pose.linear() = (Eigen::AngleAxisd(o.jitter_rad * (0.6 * s(1.1, 0.7) + 0.4 * s(2.7, 1.3)), Eigen::Vector3d::UnitX()) *
                   Eigen::AngleAxisd(o.jitter_rad * (0.6 * s(0.8, 2.6) + 0.4 * s(2.1, 0.2)), Eigen::Vector3d::UnitY()) *
                   Eigen::AngleAxisd(o.jitter_rad * (0.6 * s(1.4, 1.9) + 0.4 * s(3.3, 2.4)), Eigen::Vector3d::UnitZ()))
                      .toRotationMatrix();
  return pose;
}

// Frame k at t = k / 15 s. Spots as makeFrame (beam = true beam, -1 clutter).
inline Frame sequenceFrame(const CameraModel& cam, const ProjectorCalibration& proj, const SequenceOptions& o, int k,
                           const std::vector<Eigen::Vector3d>& rock_points)
{
  Scene rock;
  rock.distance = 0.5 * (o.near_m + o.far_m);
  rock.relief = o.relief;
  const Eigen::Isometry3d pose = rigPose(o, k / 15.0), inv = pose.inverse();
  std::mt19937 rng(o.seed * 100003u + static_cast<uint32_t>(k));
  std::normal_distribution<double> noise(0.0, o.noise_px);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int n = proj.beamCount();
  Frame f = emptyFrame(n);
  for (int i = 0; i < n; ++i)
  {
    Eigen::Vector3d hit;
    if (!rock.intersect(pose * proj.beams[i].origin, pose.linear() * proj.beams[i].direction, &hit))
      continue;
    const Eigen::Vector3d p = inv * hit;
    const cv::Point2d px = cam.project(p);
    if (!inImage(cam, px))
      continue;
    f.truth[i] = p;
    f.pixels[i] = px;
    if (uni(rng) >= o.drop_fraction)
    {
      const double ny = noise(rng), nx = noise(rng);  // sequenced draws (docs/testing.md)
      f.spots.push_back(spotAt(cv::Point2d(px.x + nx, px.y + ny), i));
    }
  }
  const auto addClutter = [&](const cv::Point2d& px)
  {
    if (inImage(cam, px))
      f.spots.push_back(spotAt(px, -1));
  };
  for (const Eigen::Vector3d& w : rock_points)
    addClutter(cam.project(inv * w));
  for (int c = 0; c < o.random_clutter; ++c)
  {
    const double fy = uni(rng), fx = uni(rng);  // sequenced draws (docs/testing.md)
    addClutter(cv::Point2d(fx * (cam.width - 1), fy * (cam.height - 1)));
  }
  std::shuffle(f.spots.begin(), f.spots.end(), rng);
  return f;
}

// Points on the rock for fixed clutter: where camera rays through random
// pixels of the frame at rest meet the rock.
inline std::vector<Eigen::Vector3d> rockClutterPoints(const CameraModel& cam, const SequenceOptions& o, int count)
{
  Scene rock;
  rock.distance = 0.5 * (o.near_m + o.far_m);
  rock.relief = o.relief;
  std::mt19937 rng(o.seed * 7919u);
  std::uniform_real_distribution<double> uni(0.1, 0.9);
  std::vector<Eigen::Vector3d> out;
  while (static_cast<int>(out.size()) < count)
  {
    const double fy = uni(rng), fx = uni(rng);  // sequenced draws (docs/testing.md)
    const Eigen::Vector2d n = cam.normalize(cv::Point2d(fx * cam.width, fy * cam.height));
    Eigen::Vector3d hit;
    if (rock.intersect(Eigen::Vector3d::Zero(), Eigen::Vector3d(n.x(), n.y(), 1.0).normalized(), &hit))
      out.push_back(hit);
  }
  return out;
}

}  // namespace sls_test
