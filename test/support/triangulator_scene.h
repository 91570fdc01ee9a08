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

#include "structured_light_stabilizer/camera_model.h"
#include "structured_light_stabilizer/projector_calibration.h"
#include "structured_light_stabilizer/spot.h"
#include "structured_light_stabilizer/triangulator.h"

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
    const auto g = [&](double s) {
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
