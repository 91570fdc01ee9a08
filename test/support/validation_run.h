// The core pipeline on the path-traced validation set (validation_set.h):
// what tools/evaluate_validation prints and test_validation_set asserts.
// Per frame of a case and noise seed: SpotDetector (the nodelet's defaults
// unless overridden) on the frame, or strobed on the frame and the
// projector-off frames around it (motion-compensated to its time, as the
// nodelet does); the Triangulator with the projector file; PoseDelta locked
// on the case's first projector frame. Scored against the truth:
//  - recall: truth dots (visible beams with light in the image; in a case
//    with min_dot_to_sun, only those whose dot is at least that x the rock
//    under it) with a spot within match_px of the light's own centroid (one
//    to one, closest first);
//  - false spots: spots near no visible dot's light (spots on the light of
//    an occluded beam, or of a dot left out by min_dot_to_sun, are counted
//    apart);
//  - wrong beams: spots the Triangulator gives a beam other than the truth's
//    (matched spots) or any beam (false spots);
//  - centroid error against the light's centroid and against the hit
//    point's pixel (matched spots); depth: |triangulated - hit point| of the
//    beams given their own spot;
//  - pose: valid or not, and its error against the true motion.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/common/se3.h"
#include "structured_light_stabilizer/detection/ambient_compensation.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/pose/pose_delta.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "support/validation_set.h"

namespace structured_light_stabilizer
{
namespace test
{
namespace validation
{

struct RunOptions
{
  std::vector<uint64_t> seeds = {1};
  PixelFormat output = PixelFormat::kBgr8;  // kBgr8, kBayerRggb8 or kBgr16 (12 bits)
  int strobe = -1;                          // -1: as the case says; 0 or 1 overrides it
  SpotDetectorParams detector;              // the nodelet's defaults (projector_color green)
  std::string projector_file;               // the projector's rays
  double match_px = 2.0;
  bool noise = true;
  FILE* dump = nullptr;  // when set: one CSV row per spot (case, seed, frame, beam or -1 if false, spot, light, hit)
};

struct Tally
{
  int frames = 0, refused = 0;
  int truth = 0, matched = 0, false_spots = 0, occluded_spots = 0, other_dots = 0;
  int wrong = 0, assigned = 0;
  double light2 = 0, hit2 = 0;  // squared centroid errors (px^2) of the matched spots
  double depth2 = 0;
  int depth_n = 0;
  int poses = 0, valid = 0;
  double pose_t2 = 0, pose_r2 = 0;  // over the valid poses (mm^2, deg^2)
  double worst_recall = 1.0, worst_light_rms = 0.0, worst_hit_rms = 0.0;

  double recall() const { return truth ? double(matched) / truth : NAN; }
  double lightRms() const { return matched ? std::sqrt(light2 / matched) : NAN; }
  double hitRms() const { return matched ? std::sqrt(hit2 / matched) : NAN; }
  void add(const Tally& o)
  {
    frames += o.frames;
    refused += o.refused;
    truth += o.truth;
    matched += o.matched;
    false_spots += o.false_spots;
    occluded_spots += o.occluded_spots;
    other_dots += o.other_dots;
    wrong += o.wrong;
    assigned += o.assigned;
    light2 += o.light2;
    hit2 += o.hit2;
    depth2 += o.depth2;
    depth_n += o.depth_n;
    poses += o.poses;
    valid += o.valid;
    pose_t2 += o.pose_t2;
    pose_r2 += o.pose_r2;
    worst_recall = std::min(worst_recall, o.worst_recall);
    worst_light_rms = std::max(worst_light_rms, o.worst_light_rms);
    worst_hit_rms = std::max(worst_hit_rms, o.worst_hit_rms);
  }
  std::string line() const
  {
    char buf[512];
    std::snprintf(buf, sizeof(buf),
                  "recall %.4f (%d/%d, worst frame %.3f), false %.2f/frame (+%d on occluded, %d on unscored dots), "
                  "wrong beams %d of %d assigned, centroid to light %.3f px (worst frame %.3f), to hit %.3f px "
                  "(worst frame %.3f), depth %.2f mm, pose valid %d/%d (%.3f mm, %.4f deg RMS), refused %d/%d",
                  recall(), matched, truth, worst_recall, frames ? double(false_spots) / frames : NAN, occluded_spots,
                  other_dots, wrong, assigned, lightRms(), worst_light_rms, hitRms(), worst_hit_rms,
                  depth_n ? 1e3 * std::sqrt(depth2 / depth_n) : NAN, valid, poses,
                  valid ? std::sqrt(pose_t2 / valid) : NAN, valid ? std::sqrt(pose_r2 / valid) : NAN, refused, frames);
    return buf;
  }
};

struct FrameScore
{
  int frame = 0;
  uint64_t seed = 0;
  Tally tally;
};

struct CaseResult
{
  std::vector<FrameScore> frames;
  Tally pooled;
};

namespace detail
{

inline uint64_t noiseSeed(uint64_t seed, const std::string& scene, int frame)
{
  uint64_t h = 1469598103934665603ull;
  for (char c : scene)
    h = (h ^ static_cast<unsigned char>(c)) * 1099511628211ull;
  return h ^ (seed * 1000003ull + static_cast<uint64_t>(frame));
}

// The projector-off frames nearest before and after frame `on` (by time).
inline void neighbours(const SceneTruth& s, const FrameTruth& on, const FrameTruth** before, const FrameTruth** after)
{
  *before = *after = nullptr;
  for (const FrameTruth& f : s.frames)
  {
    if (f.projector)
      continue;
    if (f.t < on.t && (!*before || f.t > (*before)->t))
      *before = &f;
    if (f.t > on.t && (!*after || f.t < (*after)->t))
      *after = &f;
  }
}

struct Match
{
  int spot, beam;
  double d;
};

// One-to-one matching of spots (ROI pixels) to points (full-frame pixels),
// closest pairs first, within max_px.
inline std::vector<Match> match(const Spots& spots, const cv::Point2d& offset, const std::vector<cv::Point2d>& pts,
                                const std::vector<int>& beams, double max_px)
{
  std::vector<Match> pairs;
  for (size_t s = 0; s < spots.size(); ++s)
    for (size_t k = 0; k < pts.size(); ++k)
    {
      const double d = std::hypot(spots[s].x + offset.x - pts[k].x, spots[s].y + offset.y - pts[k].y);
      if (d < max_px)
        pairs.push_back({static_cast<int>(s), static_cast<int>(k), d});
    }
  std::sort(pairs.begin(), pairs.end(), [](const Match& a, const Match& b) { return a.d < b.d; });
  std::vector<char> used_s(spots.size(), 0), used_k(pts.size(), 0);
  std::vector<Match> out;
  for (const Match& m : pairs)
    if (!used_s[m.spot] && !used_k[m.beam])
    {
      used_s[m.spot] = used_k[m.beam] = 1;
      out.push_back({m.spot, beams[m.beam], m.d});
    }
  return out;
}

}  // namespace detail

// Scores one frame's spots and their triangulation.
inline Tally scoreFrame(const SceneTruth& s, const FrameTruth& f, const Lighting& l, double min_dot_to_sun,
                        const Spots& spots, const TriangulationResult& tri, double match_px, FILE* dump = nullptr,
                        const std::string& label = "")
{
  Tally t;
  t.frames = 1;
  const cv::Point2d offset(s.roi().x, s.roi().y);
  std::vector<cv::Point2d> scored, other;
  std::vector<int> scored_beam, other_beam;
  for (const BeamTruth& b : f.beams)
  {
    if (!b.has_light)
      continue;
    const bool in = b.visible && !b.window_cut && dotToRock(b, l) >= min_dot_to_sun;
    (in ? scored : other).push_back(b.light_centroid);
    (in ? scored_beam : other_beam).push_back(b.beam);
  }
  const std::vector<detail::Match> m = detail::match(spots, offset, scored, scored_beam, match_px);
  std::vector<int> truth_of_spot(spots.size(), -2);  // -2: false, -1: another light, >= 0: its beam
  t.truth = static_cast<int>(scored.size());
  double l2 = 0, h2 = 0;
  for (const detail::Match& mm : m)
  {
    truth_of_spot[mm.spot] = mm.beam;
    const BeamTruth& b = f.beams[mm.beam];
    const cv::Point2d p(spots[mm.spot].x + offset.x, spots[mm.spot].y + offset.y);
    l2 += std::pow(p.x - b.light_centroid.x, 2) + std::pow(p.y - b.light_centroid.y, 2);
    h2 += std::pow(p.x - b.pixel.x, 2) + std::pow(p.y - b.pixel.y, 2);
    if (dump)
      std::fprintf(dump, "%s,%d,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f\n", label.c_str(), f.index, b.beam, p.x, p.y,
                   b.light_centroid.x, b.light_centroid.y, b.pixel.x, b.pixel.y);
  }
  t.matched = static_cast<int>(m.size());
  t.light2 = l2;
  t.hit2 = h2;
  for (size_t k = 0; k < spots.size(); ++k)
  {
    if (truth_of_spot[k] >= 0)
      continue;
    bool near_other = false;
    for (size_t j = 0; j < other.size(); ++j)
      if (std::hypot(spots[k].x + offset.x - other[j].x, spots[k].y + offset.y - other[j].y) < match_px)
      {
        near_other = true;
        const bool occluded = !f.beams[other_beam[j]].visible;
        ++(occluded ? t.occluded_spots : t.other_dots);
        truth_of_spot[k] = -1;
        break;
      }
    if (!near_other)
    {
      ++t.false_spots;
      if (dump)
        std::fprintf(dump, "%s,%d,-1,%.4f,%.4f,,,,\n", label.c_str(), f.index, spots[k].x + offset.x,
                     spots[k].y + offset.y);
    }
  }
  for (size_t k = 0; k < spots.size() && k < tri.beam_of_spot.size(); ++k)
  {
    const int beam = tri.beam_of_spot[k];
    if (beam < 0)
      continue;
    ++t.assigned;
    if (truth_of_spot[k] == -2 || (truth_of_spot[k] >= 0 && truth_of_spot[k] != beam))
      ++t.wrong;
    if (truth_of_spot[k] == beam && tri.points[beam].allFinite())
    {
      t.depth2 += (tri.points[beam] - f.beams[beam].point).squaredNorm();
      ++t.depth_n;
    }
  }
  t.worst_recall = t.recall();
  if (t.matched)
  {
    t.worst_light_rms = t.lightRms();
    t.worst_hit_rms = t.hitRms();
  }
  return t;
}

// Runs one case for every seed; `print` writes one line per frame.
inline CaseResult runCase(const ValidationSet& set, const CaseSpec& c, const RunOptions& o, bool print)
{
  const SceneTruth& s = set.scene(c.scene);
  const Lighting& l = s.lighting.at(c.lighting);
  const bool strobe = o.strobe < 0 ? c.strobe : o.strobe != 0;
  Sensor sensor = set.sensor;
  sensor.output = o.output;
  sensor.bits = o.output == PixelFormat::kBgr16 ? 12 : 8;
  sensor.noise = o.noise;
  const CameraModel camera = s.roiCamera();
  std::string why;
  ProjectorCalibration projector;
  if (!loadProjectorCalibration(o.projector_file, &projector, &why))
    throw std::runtime_error("projector file " + o.projector_file + ": " + why);
  CaseResult result;
  for (uint64_t seed : o.seeds)
  {
    SpotDetector detector(o.detector);
    const Triangulator tri(camera, projector);
    PoseDeltaEstimator pose((PoseDeltaParams()));
    pose.setCamera(camera);
    auto shot = [&](const FrameTruth& f, bool on) {
      return capture(exposeFrame(s, loadPasses(s, f), l, on, sensor), sensor, detail::noiseSeed(seed, s.name, f.index));
    };
    Eigen::Isometry3d ref = Eigen::Isometry3d::Identity();
    for (size_t k = 0; k < c.on_frames.size(); ++k)
    {
      const FrameTruth& f = s.frame(c.on_frames[k]);
      const cv::Mat image = shot(f, true);
      cv::Mat ambient, texture = image;
      if (strobe)
      {
        const FrameTruth *before, *after;
        detail::neighbours(s, f, &before, &after);
        if (!before || !after)
          throw std::runtime_error("case " + c.name + ": frame " + std::to_string(f.index) +
                                   " has no projector-off frame on both sides");
        AmbientCompensationParams ap;
        ap.layout = o.output == PixelFormat::kBayerRggb8 ? AmbientLayout::kBayerRggb : AmbientLayout::kInterleaved;
        ap.unrounded = true;  // as the nodelet (8-bit interleaved frames only)
        const AmbientEstimate amb =
            compensateAmbient(f.t, {shot(*before, false), before->t}, {shot(*after, false), after->t}, ap);
        ambient = amb.image;
        texture = cv::Mat();
        ambient.convertTo(texture, image.type());
      }
      const SpotDetectionResult det =
          strobe ? detector.detect(image, ambient, o.output) : detector.detect(image, o.output);
      const TriangulationResult tr = tri.process(det.spots);
      Tally t =
          scoreFrame(s, f, l, c.min_dot_to_sun, det.spots, tr, o.match_px, o.dump, c.name + "," + std::to_string(seed));
      if (!det.ok)
        ++t.refused;
      PoseDeltaInput in;
      in.rows = projector.rows;
      in.cols = projector.cols;
      in.points = tr.points;
      in.stamp_s = f.t;
      in.image = o.output == PixelFormat::kBayerRggb8 ? toBgr(texture, o.output) : texture;
      in.texture_channel = 2;
      const PoseDeltaResult r = pose.process(in);
      if (k == 0)
        ref = f.camera_from_world;
      else
      {
        const Eigen::Isometry3d truth = f.camera_from_world * ref.inverse();
        const Eigen::Isometry3d E = r.transform * truth.inverse();
        ++t.poses;
        if (r.valid)
        {
          ++t.valid;
          t.pose_t2 = (E.translation() * 1e3).squaredNorm();
          t.pose_r2 = (logSO3(E.linear()) * 180.0 / M_PI).squaredNorm();
        }
      }
      if (print)
        std::printf("  frame %d seed %llu: %s%s%s\n", f.index, static_cast<unsigned long long>(seed), t.line().c_str(),
                    det.ok ? "" : "; refused: ", det.ok ? "" : det.error.c_str());
      result.frames.push_back({f.index, seed, t});
      result.pooled.add(t);
    }
  }
  return result;
}

}  // namespace validation
}  // namespace test
}  // namespace structured_light_stabilizer
