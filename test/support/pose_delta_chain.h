// Test-only full chain for PoseDelta accuracy: simulator image -> SpotDetector
// -> Triangulator (with the BeamTracker's prior) -> PoseDeltaEstimator, the
// way the nodelets chain them, with the accuracy scenes: a weakly
// textured rock, a rough rock with missing dots and clutter, the study's
// worst SNR, a flat textured plane, a textureless board. Shared by the gtest
// test_pose_delta_chain and the tool evaluate_pose_delta.
//
// Missing dots: after detection, each spot is removed with probability
// `drop_fraction`, independently per frame (the reference too), as dots lost
// on dark or oblique patches come and go while the rig moves.
#pragma once

#include <cmath>
#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "structured_light_stabilizer/pose/pose_delta.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "support/centroid_truth.h"
#include "support/stage_settings.h"

namespace sls_test
{

using namespace structured_light_stabilizer;

constexpr double kChainDeg = 3.14159265358979323846 / 180.0;

// One of the scenes, ready for a seed.
struct ChainScene
{
  std::string name;
  SimulatorParams sim;
  double drop_fraction = 0.0;  // spots removed after detection, per frame
  // Strobed operation: besides each frame at t, its projector-off
  // (ambient) partner exposed at t + strobe_gap_s; 0 = no strobing. With
  // strobe_both, also the one at t - strobe_gap_s (the frames around it).
  double strobe_gap_s = 0.0;
  bool strobe_both = false;
  // PoseDelta gets the frame as mono8 (luminance): dots as bright as the
  // rock's texture in the same channel, as on a monochrome camera.
  bool mono = false;
  // With a 16-bit camera (sim.sensor.output bgr16): PoseDelta gets the frame
  // converted to bgr8 (as its nodelet did before it read 16 bits).
  bool pose_reads_8bit = false;
  // Experiments (evaluate_pose_delta's flags). The reference surface from the
  // simulator's rock at the lock (PoseDeltaInput::surface_points: camera
  // rays every kTrueSurfaceStepPx pixels cast onto it) instead of the
  // surface through the dots: over the dots' box (what the registration
  // reads) or over the whole image (the texture features' depths too).
  enum class TrueSurface
  {
    kNone,
    kDotBox,
    kImage
  };
  TrueSurface true_surface = TrueSurface::kNone;
  // The lock's texture from a projector-off exposure of its instant
  // (PoseDeltaInput::lock_image): features on the dots too.
  bool projector_off_lock = false;
};

// Spacing (px) of the camera rays of a true reference surface: 1.8 cm at
// 1.5 m, a tenth of the rock's smallest relief features.
constexpr int kTrueSurfaceStepPx = 12;

// The rig jitter of the issue: +-10 mm, +-1 deg per axis.
inline SimulatorParams chainBase(uint32_t seed)
{
  SimulatorParams c = studySimulatorParams();  // the scenes were measured at the study's brightness
  c.rock.seed = seed;
  c.noise_seed = 1000 + 17 * seed;
  c.motion.jitter_translation_m = 0.010;
  c.motion.jitter_rotation_rad = 1.0 * kChainDeg;
  return c;
}

// The scenes by name: "weak_texture", "missing_dots", "worst_snr",
// "flat_textured", "textureless", "rough" (the default rock), "strobed" (the
// default rock with the ambient frames of 60 Hz strobing one field before and
// after each frame; "strobed_one_side": only the one before), "mono" (the
// default rock, PoseDelta given the frame as mono8), "bgr16" (the default
// rock from a 12-bit colour camera, PoseDelta reading its 16 bits) and
// "bgr16_as_bgr8" (the same frames, PoseDelta given them as bgr8). Unknown
// names give the default rock.
inline ChainScene chainScene(const std::string& name, uint32_t seed)
{
  ChainScene s;
  s.name = name;
  s.sim = chainBase(seed);
  if (name == "weak_texture")
    s.sim.rock.texture_scale_m = 0.10;  // albedo features 10-25 cm only (rock_surface.cpp)
  else if (name == "missing_dots")
  {
    s.drop_fraction = 0.10;
    s.sim.clutter.green_blobs = 6;
    s.sim.projector.beam_sigma_rad = 0.003;  // wider dots
  }
  else if (name == "worst_snr")
  {
    // The study's worst SNR (formula 2.26): full sun on 5-6 % albedo rock,
    // small dots (test_spot_detector_sim's condition).
    s.sim.lighting.sun_level = 1.0;
    s.sim.rock.albedo_min = 0.05;
    s.sim.rock.albedo_max = 0.06;
    s.sim.projector.beam_sigma_rad = 0.0014;
  }
  else if (name == "flat_textured")
    s.sim.rock.relief_m = 0.0;
  else if (name == "mono")
    s.mono = true;
  else if (name == "bgr16" || name == "bgr16_as_bgr8")
  {
    s.sim.sensor.output = SensorOutput::kBgr16;  // a 12-bit colour camera
    s.sim.sensor.output_bits = 12;
    s.pose_reads_8bit = name == "bgr16_as_bgr8";
  }
  else if (name == "strobed" || name == "strobed_one_side")
  {
    s.strobe_gap_s = -1.0 / 60.0;
    s.strobe_both = name == "strobed";
  }
  else if (name == "textureless")
  {
    s.sim.rock.relief_m = 0.0;
    s.sim.rock.albedo_min = s.sim.rock.albedo_max = 0.25;
  }
  return s;
}

// One frame through the chain, with its truth relative to t = 0.
struct ChainFrame
{
  PoseDeltaInput input;
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();  // p_cur = truth * p_ref(t = 0)
  int spots = 0;                                            // detected (before dropping)
  int points = 0;                                           // triangulated beams
  int wrong_beams = 0;                                      // points more than 5 mm from their beam's true hit point
  TruthErrors truths;       // the spots' centroids (with SimulatorParams::dot_centroid_truth)
  double depth_rel2 = 0.0;  // sum over the points of (depth error / depth)^2
};

class PoseChain
{
public:
  explicit PoseChain(const ChainScene& scene, const StageSettings& settings = StageSettings())
    : scene_(scene),
      sim_(scene.sim),
      detector_(settings.detector),
      triangulator_(std::make_shared<const Triangulator>(sim_.camera(), sim_.projector(), settings.triangulator)),
      tracker_(settings.tracker),
      rng_(scene.sim.rock.seed * 7919u + 13u)
  {
  }

  const Simulator& simulator() const { return sim_; }

  ChainFrame frame(double t)
  {
    const SimFrame f = sim_.render(t);
    ChainFrame out;
    out.truth = f.delta;
    PixelFormat format = PixelFormat::kBgr8;
    pixelFormatFromEncoding(f.encoding, &format);
    const SpotDetectionResult det = detector_.detect(f.image, format);
    Spots spots = det.ok ? det.spots : Spots();
    out.spots = static_cast<int>(spots.size());
    out.truths = truthErrors(spots, f, sim_);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    Spots kept;
    for (const Spot& s : spots)
      if (!(uni(rng_) < scene_.drop_fraction))
        kept.push_back(s);
    const TriangulationResult tri = tracker_.process(triangulator_, kept, t);
    out.input.rows = scene_.sim.projector.rows;
    out.input.cols = scene_.sim.projector.cols;
    out.input.points = tri.points;
    out.input.image = f.image;
    out.input.texture_channel = 2;  // bgr8: red carries the rock, not the green dots
    if (scene_.mono)
      cv::cvtColor(f.image, out.input.image, cv::COLOR_BGR2GRAY);
    if (scene_.pose_reads_8bit && f.image.depth() == CV_16U)
      f.image.convertTo(out.input.image, CV_8U, 1.0 / 257.0);
    out.input.stamp_s = t;
    if (scene_.strobe_gap_s != 0.0)
    {
      FrameRequest off;
      off.projector_on = false;
      out.input.ambient_image = sim_.render(t + scene_.strobe_gap_s, off).image;
      out.input.ambient_stamp_s = t + scene_.strobe_gap_s;
      if (scene_.strobe_both)
      {
        out.input.ambient_after_image = sim_.render(t - scene_.strobe_gap_s, off).image;
        out.input.ambient_after_stamp_s = t - scene_.strobe_gap_s;
      }
    }
    for (size_t b = 0; b < tri.points.size(); ++b)
    {
      if (!tri.points[b].allFinite())
        continue;
      ++out.points;
      const bool far = !f.points[b].allFinite() || (tri.points[b] - f.points[b]).norm() > 0.005;
      out.wrong_beams += far ? 1 : 0;
      if (!far)
      {
        const double rel = (tri.points[b].z() - f.points[b].z()) / f.points[b].z();
        out.depth_rel2 += rel * rel;
      }
    }
    return out;
  }

  // The frame at t that becomes the reference, with what the scene's
  // experiments add to a lock.
  ChainFrame lockFrame(double t)
  {
    ChainFrame f = frame(t);
    if (scene_.projector_off_lock)
    {
      FrameRequest off;
      off.projector_on = false;
      f.input.lock_image = sim_.render(t, off).image;
      if (scene_.mono)
        cv::cvtColor(f.input.lock_image, f.input.lock_image, cv::COLOR_BGR2GRAY);
      if (scene_.pose_reads_8bit && f.input.lock_image.depth() == CV_16U)
        f.input.lock_image.convertTo(f.input.lock_image, CV_8U, 1.0 / 257.0);
    }
    if (scene_.true_surface != ChainScene::TrueSurface::kNone)
      trueSurface(t, f.input.points, &f.input);
    return f;
  }

private:
  // The simulator's rock under a grid of camera rays at time t (camera
  // frame at t): over the dots' box (half a dot spacing around it) or the
  // whole image.
  void trueSurface(double t, const std::vector<Eigen::Vector3d>& dots, PoseDeltaInput* in) const
  {
    const CameraModel& cam = sim_.camera();
    cv::Rect2d box(0, 0, cam.width - 1, cam.height - 1);
    if (scene_.true_surface == ChainScene::TrueSurface::kDotBox)
    {
      std::vector<cv::Point2f> px;
      for (const Eigen::Vector3d& p : dots)
        if (p.allFinite())
        {
          const cv::Point2d q = cam.project(p);
          px.emplace_back(static_cast<float>(q.x), static_cast<float>(q.y));
        }
      if (px.size() < 4)
        return;
      const cv::Rect r = cv::boundingRect(px);
      const double margin = 0.5 * std::sqrt(static_cast<double>(r.area()) / px.size());
      box = cv::Rect2d(r.x - margin, r.y - margin, r.width + 2 * margin, r.height + 2 * margin) &
            cv::Rect2d(0, 0, cam.width - 1, cam.height - 1);
    }
    in->surface_cols = static_cast<int>(box.width / kTrueSurfaceStepPx) + 1;
    in->surface_rows = static_cast<int>(box.height / kTrueSurfaceStepPx) + 1;
    in->surface_points.assign(static_cast<size_t>(in->surface_rows) * in->surface_cols,
                              Eigen::Vector3d::Constant(std::nan("")));
    for (int r = 0; r < in->surface_rows; ++r)
      for (int c = 0; c < in->surface_cols; ++c)
      {
        const cv::Point2d px(box.x + c * kTrueSurfaceStepPx, box.y + r * kTrueSurfaceStepPx);
        Eigen::Vector3d hit;
        if (sim_.intersect(t, Eigen::Vector3d::Zero(), cam.ray(px).normalized(), &hit))
          in->surface_points[r * in->surface_cols + c] = hit;
      }
  }

  ChainScene scene_;
  Simulator sim_;
  SpotDetector detector_;
  std::shared_ptr<const Triangulator> triangulator_;
  BeamTracker tracker_;
  std::mt19937 rng_;
};

// Pose error of `estimate` against the truth relative to the reference
// frame: (tx, ty, tz) in mm, (rx, ry, rz) in degrees.
inline Eigen::Matrix<double, 6, 1> chainError(const Eigen::Isometry3d& estimate, const Eigen::Isometry3d& truth_cur,
                                              const Eigen::Isometry3d& truth_ref)
{
  const Eigen::Isometry3d E = estimate * (truth_cur * truth_ref.inverse()).inverse();
  Eigen::Matrix<double, 6, 1> e;
  e.head<3>() = E.translation() * 1e3;
  e.tail<3>() = logSO3(E.linear()) / kChainDeg;
  return e;
}

// Per-run tallies: RMS over the frames (all frames, valid or not, against
// truth) and over the valid ones, with the worst frame.
struct ChainTally
{
  double t2 = 0, r2 = 0, t2_valid = 0, r2_valid = 0;
  double worst_t_mm = 0, worst_r_deg = 0;  // over valid frames
  Eigen::Matrix<double, 6, 1> axis2 = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> sigma2 = Eigen::Matrix<double, 6, 1>::Zero();
  int frames = 0, valid = 0, in_plane_unobservable = 0, wrong_beams = 0, points = 0;
  double features = 0, sigma_texture_px = 0, sigma_geometry_mm = 0;  // sums over the frames
  TruthErrors truths;
  double depth_rel2 = 0.0;

  void add(const Eigen::Matrix<double, 6, 1>& e, const PoseDeltaResult& r, const ChainFrame& f)
  {
    const double t = e.head<3>().squaredNorm(), rr = e.tail<3>().squaredNorm();
    t2 += t;
    r2 += rr;
    axis2 += e.cwiseAbs2();
    for (int a = 0; a < 6; ++a)
      sigma2[a] += r.covariance(a, a) * (a < 3 ? 1e6 : 1.0 / (kChainDeg * kChainDeg));
    ++frames;
    wrong_beams += f.wrong_beams;
    points += f.points;
    truths.add(f.truths);
    depth_rel2 += f.depth_rel2;
    features += r.features_used;
    sigma_texture_px += r.sigma_texture_px;
    sigma_geometry_mm += r.sigma_geometry_m * 1e3;
    in_plane_unobservable += r.unobservable[0] && r.unobservable[1] && r.unobservable[5] ? 1 : 0;
    if (!r.valid)
      return;
    ++valid;
    t2_valid += t;
    r2_valid += rr;
    worst_t_mm = std::max(worst_t_mm, std::sqrt(t));
    worst_r_deg = std::max(worst_r_deg, std::sqrt(rr));
  }
  void add(const ChainTally& o)
  {
    t2 += o.t2;
    r2 += o.r2;
    t2_valid += o.t2_valid;
    r2_valid += o.r2_valid;
    worst_t_mm = std::max(worst_t_mm, o.worst_t_mm);
    worst_r_deg = std::max(worst_r_deg, o.worst_r_deg);
    axis2 += o.axis2;
    sigma2 += o.sigma2;
    frames += o.frames;
    valid += o.valid;
    in_plane_unobservable += o.in_plane_unobservable;
    wrong_beams += o.wrong_beams;
    points += o.points;
    truths.add(o.truths);
    depth_rel2 += o.depth_rel2;
    features += o.features;
    sigma_texture_px += o.sigma_texture_px;
    sigma_geometry_mm += o.sigma_geometry_mm;
  }
  // RMS over the valid frames (what a user of `valid` gets).
  double rmsTmm() const { return std::sqrt(t2_valid / std::max(valid, 1)); }
  double rmsRdeg() const { return std::sqrt(r2_valid / std::max(valid, 1)); }
  double validFraction() const { return frames > 0 ? static_cast<double>(valid) / frames : 0.0; }
  // RMS depth error of the right points, % of z.
  double depthPercent() const
  {
    return points > wrong_beams ? 100.0 * std::sqrt(depth_rel2 / (points - wrong_beams)) : NAN;
  }
};

// The instant a seed's run locks (not at rest: the rig is moving), the same
// in test_pose_delta_chain and evaluate_pose_delta so that the tool prints
// the test's runs.
inline double chainLockTime(uint32_t seed)
{
  return 0.37 * (static_cast<double>(seed) - 1.0);
}

// Locks at `t_lock` and runs `frames` frames dt apart through the chain.
// `log` (optional) gets one line per invalid frame.
inline ChainTally runChain(const ChainScene& scene, const StageSettings& settings, double t_lock, int frames,
                           double dt = 0.1, std::string* log = nullptr)
{
  PoseChain chain(scene, settings);
  PoseDeltaEstimator est(settings.pose);
  est.setCamera(chain.simulator().camera());
  const ChainFrame f0 = chain.lockFrame(t_lock);
  const PoseDeltaResult r0 = est.process(f0.input);
  ChainTally tally;
  if (log && !r0.locked_now)
    *log += "  lock failed: " + r0.status + "\n";
  for (int k = 1; k <= frames; ++k)
  {
    const ChainFrame f = chain.frame(t_lock + k * dt);
    const PoseDeltaResult r = est.process(f.input);
    const Eigen::Matrix<double, 6, 1> e = chainError(r.transform, f.truth, f0.truth);
    tally.add(e, r, f);
    if (log && !r.valid)
      *log += "  frame " + std::to_string(k) + ": " + r.status + "\n";
  }
  return tally;
}

inline ChainTally runChain(const ChainScene& scene, const PoseDeltaParams& params, double t_lock, int frames,
                           double dt = 0.1, std::string* log = nullptr)
{
  StageSettings settings;
  settings.pose = params;
  return runChain(scene, settings, t_lock, frames, dt, log);
}

}  // namespace sls_test
