// The core pipeline (detector, Triangulator, PoseDelta) on simulated
// daylight against the simulator's truth (docs/daylight.md, "Measured"):
// what tools/evaluate_daylight prints and test_daylight_rig asserts. Per case
// (a distance and a rock seed): recall (spots within 3 px of their true pixel,
// one to one) pooled and its worst frame; the centroid against two truths,
// the beam's hit point (what depth needs; also its part along the epipolar
// line, the only part that moves the depth) and the dot's own light (what a
// detector can reach: SimFrame::light_centroids, and footprint_centroids
// for the light over the albedo), with how far the light itself lies from
// the hit point; wrong beams, depth RMS (mm and % of z), pose RMS against
// the truth and the share of valid poses.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/detection/ambient_compensation.h"
#include "structured_light_stabilizer/pose/pose_delta.h"
#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "support/centroid_truth.h"
#include "support/scene_ablations.h"
#include "support/spot_score.h"
#include "support/stage_settings.h"

namespace structured_light_stabilizer
{
namespace test
{
namespace daylight
{

constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Options
{
  std::string rig;
  double ratio = -1.0;  // < 0: the rig's (or the study's corrected without a rig)
  bool strobe = true;
  double sun = 1.0;
  std::vector<double> distances = {1.0, 1.5, 2.0};
  std::vector<uint32_t> seeds = {7, 8};  // held out: the bounds were never tuned on them
  int frames = 40;                       // dot frames per case
  double texture_period = 0.02;
  double motion = 1.0;  // scale of the jitter (2 mm, 1 mrad at 0.7 Hz)
  std::vector<double> sweep;
  bool normalise = false;     // --difference: divide the difference by the ambient (the albedo under the dot)
  bool difference = false;    // strobed: the difference image into the detector (the emulation before the
                              // SpotDetector had its strobed mode); default: detect(on, ambient) as the nodelet
  double albedo = -1.0;       // > 0: a uniform rock of this albedo (no texture at all)
  double camera_rate = 30.0;  // Hz, every frame (strobed: on and off alternate)
  bool extrapolate = false;   // strobed: the ambient from the two frames before (a nodelet that does not wait)
  bool full_resolution_tracking = false;  // strobed: track the ambient frames' motion at full resolution
  bool true_ambient = false;  // strobed: the projector-off render at the on-frame's own time (the upper bound)
  // The camera's encoding (SensorOutput) and a 16-bit output's converter
  // bits; empty: the rig's camera as designed (bgr16 at its output_bits when
  // more than 8), bgr8 without a rig.
  std::string output;
  int output_bits = 16;
  double focus_m = -1.0;       // > 0: the lens's focus distance (default: the simulator's, 1 m)
  int rock_subsample = 0;      // > 0: SimulatorParams::rock_subsample
  bool unrounded = true;       // strobed: the ambient estimate unrounded (CV_32F)
  double relief = 0.15;        // the rock's peak-to-peak relief (m; 0: a flat rock)
  bool noise_free = false;     // no shot nor read noise (quantisation stays): what the geometry alone leaves
  sls_test::StageSettings settings;    // the detector's, Triangulator's and PoseDelta's (--param)
  sls_test::SceneAblations ablations;  // vignetting, grid, noise, relief (applied last)
};

struct Stats
{
  Score spots;  // against the hit points
  sls_test::TruthErrors truths;
  double worst_frame_recall = 1.0;
  double worst_frame_rms = 0.0;  // the largest centroid RMS of one frame (px)
  int wrong_beams = 0, beams = 0;
  double depth2 = 0.0, depth_rel2 = 0.0;  // 3D error (m^2); depth error over depth, squared
  int depth_n = 0;
  double t2 = 0.0, r2 = 0.0;
  int poses = 0, valid = 0;

  void add(const Stats& o)
  {
    spots.add(o.spots);
    truths.add(o.truths);
    worst_frame_recall = std::min(worst_frame_recall, o.worst_frame_recall);
    worst_frame_rms = std::max(worst_frame_rms, o.worst_frame_rms);
    wrong_beams += o.wrong_beams;
    beams += o.beams;
    depth2 += o.depth2;
    depth_rel2 += o.depth_rel2;
    depth_n += o.depth_n;
    t2 += o.t2;
    r2 += o.r2;
    poses += o.poses;
    valid += o.valid;
  }
  double depthPercent() const { return depth_n ? 100.0 * std::sqrt(depth_rel2 / depth_n) : NAN; }
  std::string line() const
  {
    char buf[600];
    std::snprintf(buf, sizeof(buf),
                  "recall %.4f (worst frame %.3f), centroid %.4f px (worst frame %.4f; along the epipolar line "
                  "%.4f; against the light %.4f, its footprint %.4f; light from hit %.4f), false %.2f/frame, wrong "
                  "beams %d of %d, depth %.2f mm (%.4f %% of z), pose %.3f mm / %.4f deg RMS, valid %.1f %%",
                  spots.recall(), worst_frame_recall, spots.rms(), worst_frame_rms, truths.rms(truths.along2),
                  truths.rms(truths.light2), truths.rms(truths.footprint2), truths.rms(truths.light_hit2),
                  spots.falsePerFrame(), wrong_beams, beams, depth_n ? 1e3 * std::sqrt(depth2 / depth_n) : NAN,
                  depthPercent(), poses ? std::sqrt(t2 / poses) : NAN, poses ? std::sqrt(r2 / poses) : NAN,
                  poses ? 100.0 * valid / poses : NAN);
    return buf;
  }
};

inline SimulatorParams sceneFor(const Options& o, double distance, uint32_t seed)
{
  SimulatorParams p;
  p.rock.seed = seed;
  p.noise_seed = 1000 + seed;
  p.rock.distance_m = distance;
  p.rock.relief_m = o.relief;
  p.lighting.sun_level = o.sun;
  p.motion.jitter_translation_m = 0.002 * o.motion;
  p.motion.jitter_rotation_rad = 0.001 * o.motion;
  p.motion.jitter_frequency_hz = 0.7;
  if (!o.rig.empty())
  {
    const SceneAnalysis a = analyseScene(SceneInputs());
    RigParams rig = loadRig(a, o.rig);
    rig.strobe = o.strobe;
    applySimRadiometry(simulatorRadiometry(a, rig), &p);
  }
  else
    applySimRadiometry(studySimRadiometry(), &p);  // the historical camera; --ratio sets the dots
  if (o.ratio >= 0.0)
    p.lighting.dot_to_sun_ratio = o.ratio;
  p.rock.fine_texture_period_m = o.texture_period;  // +-25 % (RockParams' default amplitude)
  if (!sensorOutputFromEncoding(o.output, &p.sensor.output))
    throw std::invalid_argument("--output: unknown encoding " + o.output);
  p.sensor.output_bits = o.output_bits;
  if (o.focus_m > 0.0)
    p.sensor.focus_distance_m = o.focus_m;
  if (o.rock_subsample > 0)
    p.rock_subsample = o.rock_subsample;
  if (o.noise_free)
  {
    p.sensor.read_noise_dn = 0.0;
    p.sensor.shot_noise = false;
  }
  if (o.albedo > 0.0)
  {
    p.rock.albedo_min = p.rock.albedo_max = o.albedo;
    p.rock.fine_texture_period_m = 0.0;
  }
  o.ablations.apply(&p);
  p.dot_centroid_truth = true;
  return p;
}

// On-frame minus the compensated ambient, as an image the detector reads
// (negative differences clipped: the detector subtracts its own background).
inline cv::Mat difference(const cv::Mat& on, const cv::Mat& ambient, bool normalise)
{
  cv::Mat d;
  if (!normalise)
  {
    cv::subtract(on, ambient, d);
    return d;
  }
  // The dot's light over the albedo under it (the ambient frame carries the
  // albedo), rescaled by the ambient's local mean so that the level stays
  // that of the rock around the dot: the albedo texture leaves the dot.
  cv::Mat fo, fa, local;
  on.convertTo(fo, CV_32F);
  ambient.convertTo(fa, CV_32F);
  cv::GaussianBlur(fa, local, cv::Size(0, 0), 15.0);
  cv::Mat ratio = (fo - fa) / cv::max(fa, 1.0f);
  ratio = ratio.mul(local);
  ratio.convertTo(d, CV_8U);
  return d;
}

// Beams whose assigned spot is the true dot of another beam.
inline int wrongBeams(const Spots& spots, const TriangulationResult& tri, const SimFrame& f)
{
  int wrong = 0;
  for (size_t b = 0; b < tri.spot_of_beam.size(); ++b)
  {
    const int s = tri.spot_of_beam[b];
    if (s < 0)
      continue;
    double best = 1e9;
    size_t best_b = b;
    for (size_t k = 0; k < f.pixels.size(); ++k)
    {
      if (!f.visible[k])
        continue;
      const double d = std::hypot(spots[s].x - f.pixels[k].x, spots[s].y - f.pixels[k].y);
      if (d < best)
      {
        best = d;
        best_b = k;
      }
    }
    wrong += best < 3.0 && best_b != b ? 1 : 0;
  }
  return wrong;
}

inline Stats runCase(const Options& o, double distance, uint32_t seed)
{
  const Simulator sim(sceneFor(o, distance, seed));
  SpotDetectorParams dp = o.settings.detector;
  dp.projector_rows = sim.projector().rows;
  dp.projector_cols = sim.projector().cols;
  SpotDetector detector(dp);
  const Triangulator tri(sim.camera(), sim.projector(), o.settings.triangulator);
  PoseDeltaEstimator pose(o.settings.pose);
  pose.setCamera(sim.camera());
  Stats st;
  FrameRequest off;
  off.projector_on = false;
  const double period = 1.0 / o.camera_rate;
  Eigen::Isometry3d ref = Eigen::Isometry3d::Identity();
  for (int k = 0; k < o.frames; ++k)
  {
    // Dot frames at 15 Hz when strobing (the frames between are ambient), 30 Hz otherwise.
    const double t = 0.3 + (o.strobe ? 2.0 : 1.0) * period * k;
    const SimFrame f = sim.render(t);
    cv::Mat image = f.image, texture = f.image, ambient;
    if (o.strobe)
    {
      const double t2 = o.extrapolate ? t - 3.0 * period : t + period;
      AmbientCompensationParams ap;
      ap.half_resolution_tracking = !o.full_resolution_tracking;
      ap.unrounded = o.unrounded;
      const AmbientEstimate amb =
          compensateAmbient(t, {sim.render(t - period, off).image, t - period}, {sim.render(t2, off).image, t2}, ap);
      ambient = o.true_ambient ? sim.render(t, off).image : amb.image;
      texture = cv::Mat();                         // not into the frame's own pixels
      ambient.convertTo(texture, f.image.type());  // PoseDelta reads the frame's type
      if (o.difference)
        image = difference(f.image, texture, o.normalise);
    }
    PixelFormat format = PixelFormat::kBgr8;
    pixelFormatFromEncoding(o.output, &format);
    const SpotDetectionResult det =
        o.strobe && !o.difference ? detector.detect(image, ambient, format) : detector.detect(image, format);
    if (!det.ok)
      std::fprintf(stderr, "detector: %s\n", det.error.c_str());
    std::vector<cv::Point2d> truth;
    for (size_t b = 0; b < f.pixels.size(); ++b)
      if (f.visible[b])
        truth.push_back(f.pixels[b]);
    const Score sc = score(det.spots, truth);
    st.spots.add(sc);
    st.worst_frame_recall = std::min(st.worst_frame_recall, sc.recall());
    if (sc.matched > 0)
      st.worst_frame_rms = std::max(st.worst_frame_rms, sc.rms());
    st.truths.add(sls_test::truthErrors(det.spots, f, sim));
    const TriangulationResult tr = tri.process(det.spots);
    st.wrong_beams += wrongBeams(det.spots, tr, f);
    for (size_t b = 0; b < tr.points.size(); ++b)
      if (tr.points[b].allFinite() && f.points[b].allFinite())
      {
        ++st.beams;
        st.depth2 += (tr.points[b] - f.points[b]).squaredNorm();
        const double rel = (tr.points[b].z() - f.points[b].z()) / f.points[b].z();
        st.depth_rel2 += rel * rel;
        ++st.depth_n;
      }
    PoseDeltaInput in;
    in.rows = sim.projector().rows;
    in.cols = sim.projector().cols;
    in.points = tr.points;
    if (texture.depth() == CV_16U)
      texture.convertTo(in.image, CV_8U, 1.0 / 257.0);  // as the PoseDelta nodelet converts it (cv_bridge)
    else
      in.image = texture;
    const PoseDeltaResult r = pose.process(in);
    if (k == 0)
    {
      ref = f.delta;
      continue;
    }
    const Eigen::Isometry3d E = r.transform * (f.delta * ref.inverse()).inverse();
    ++st.poses;
    st.valid += r.valid ? 1 : 0;
    if (r.valid)
    {
      st.t2 += (E.translation() * 1e3).squaredNorm();
      st.r2 += (logSO3(E.linear()) / kDeg).squaredNorm();
    }
  }
  return st;
}

inline Stats runAll(const Options& o, bool print)
{
  Stats all;
  for (double d : o.distances)
    for (uint32_t s : o.seeds)
    {
      const Stats one = runCase(o, d, s);
      if (print)
        std::printf("  %.1f m seed %u: %s\n", d, s, one.line().c_str());
      all.add(one);
    }
  return all;
}

}  // namespace daylight
}  // namespace test
}  // namespace structured_light_stabilizer
