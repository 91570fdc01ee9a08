// Physically grounded scene simulator (docs/simulator.md), ROS-free and
// deterministic.
//
// Contract: render(t) gives a frame (bgr8 by default; SensorParams::output)
// of the rock as seen by the study's camera at time t (seconds), plus the ground truth for that frame: the hit
// point of every projector beam in the camera optical frame at t (NaN where
// the beam misses the rock or the hit point is hidden from the camera), its
// (distorted) pixel projection, and the true camera motion since t = 0 as
// p_cur = delta * p_ref (the PoseDelta convention). The camera and the
// projector form one rigid rig; the rock is fixed in the world. The same
// params (seed included) give byte-identical frames, whatever the number of
// threads.
//
// Frames: the rock (world) frame has its z axis along the normal of the
// rock's mean plane, pointing away from the camera; the surface is the height
// field z = h(x, y) over |x| <= width/2, |y| <= height/2 (a slab with vertical
// side walls), and the camera at t = 0 sits on the -z side, its optical axis
// through the rock origin at `distance_m`.
//
// Radiometry (linear sensor, 8-bit counts "DN"): a sunlit Lambertian surface
// of reflectance rho facing the sun gives rho * LightingParams::kSunFullScaleDn * sun_level
// in each channel (times cos(sun incidence) + sky); a dot's peak radiance on
// the rock is dot_to_sun_ratio times the sunlit radiance of the same surface
// facing the sun at sun_level = 1 (at 1.5 m from the projector, normal
// incidence, for the default 2 mrad beam; by default the ratio of the
// study's design, scene_analysis.h), falls
// with cos(incidence) / distance^2 and is spread in the image by the beam
// footprint, the defocus blur (DoC / 4 as a Gaussian sigma: the second moment
// of a uniform disc of diameter DoC), diffraction and the pixel box; each
// pixel of a dot takes the albedo, and on relief the incidence, of its own
// surface point.
//
// Where each part lives (src/sim/), and so where new physics goes:
//   rock_surface   height field, albedo (fine texture), baked shading
//   target_board   the chessboard target: print, pose, per-pixel rendering
//   ray_cast       rays against the height field
//   rock_render    the rock's radiance per pixel
//   brightness     the lighting as signal: sunDn(), dotGain() (the radiometric hook)
//   projector_dots beams, their footprints, brightness and ground truth
//   spectral       projector colours and camera channels (bands, responses, mono)
//   clutter        patches on the rock
//   splat          image-space Gaussians (dots with their per-pixel albedo and incidence, patches)
//   optics         defocus, diffraction, vignetting
//   sensor         noise, full well and blooming, the output encodings
//   motion_blur    sub-exposures over the exposure time
//   rig_motion     the camera's motion (an arm model)
//   simulator      the frame, stage by stage
//
// Thread-safety: render() and the other const members may run concurrently;
// updateLive() may not run concurrently with anything on the same object.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{

struct SimFrame
{
  double t = 0.0;
  // The sensor's output (SensorParams::output): encoding is its
  // sensor_msgs name; image is CV_8UC3 (bgr8, rgb8), CV_8UC1 (mono8, bayer_*)
  // or CV_16UC1 (mono16).
  std::string encoding = "bgr8";
  cv::Mat image;
  std::vector<Eigen::Vector3d> points;  // per beam, camera frame at t; NaN if not visible
  std::vector<cv::Point2d> pixels;      // per beam, distorted pixel of the hit point; NaN if not visible
  std::vector<double> blur_sigma_px;    // per beam, Gaussian sigma of the rendered dot
  std::vector<uint8_t> visible;         // per beam, 1 when the dot is in view and unoccluded
  // Per beam, noise-free peak of the dot (DN, 8-bit counts) in the
  // projector's own channel (green for green and white, red, blue; the one
  // channel of a monochrome camera); 0 if not visible.
  std::vector<double> peak_dn;
  // Per beam, 1 when the noise-free signal at the dot's pixel (dot and rock,
  // any channel) exceeds the full well: the dot is clipped.
  std::vector<uint8_t> clipped;
  // Only with SimulatorParams::dot_centroid_truth (NaN for beams without a
  // dot, empty otherwise): per beam, the centroid (distorted pixels) of the
  // dot's own noise-free light in the projector's channel (its image
  // position as rendered: the albedo under it, the relief's incidence across
  // the footprint, motion blur; what a detector can reach without knowing
  // the albedo), and of that light divided by the reflectance under each
  // pixel (the footprint: what a detector that divides the albedo out can
  // reach). `pixels` is the hit point's projection (what depth needs).
  std::vector<cv::Point2d> light_centroids;
  std::vector<cv::Point2d> footprint_centroids;
  // Noise-free radiance in DN before noise, clipping and quantisation, only
  // with keep_linear: CV_32FC3 (B, G, R) for colour and Bayer outputs (the
  // mosaic samples it), CV_32FC1 for monochrome.
  cv::Mat linear;
  Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();  // p_cur = delta * p_ref, ref = t=0
  // Chessboard target only (TargetKind::kChessboard; identity / empty
  // otherwise): the board frame (ChessboardParams) in the camera frame at t
  // (p_cam = target_pose * p_board), and the distorted pixel of every inner
  // corner, index j * cols + i for corner (i, j) (OpenCV's object-point
  // order), NaN when behind the camera or outside the image.
  Eigen::Isometry3d target_pose = Eigen::Isometry3d::Identity();
  std::vector<cv::Point2d> target_corners;
};

// What a frame is asked for besides its time (the CameraDriver's strobed and
// closed-loop modes).
struct FrameRequest
{
  // false: the projector is off during this exposure (the ambient frame of a
  // strobed pair): no dots in the image; the ground truth still says where
  // each beam would hit.
  bool projector_on = true;
  // Camera motion on top of the disturbance, applied on the current-frame
  // side: delta = arm_correction * motion(t) (p_cur = delta * p_ref). The
  // closed loop's arm model accumulates it from the velocity commands.
  Eigen::Isometry3d arm_correction = Eigen::Isometry3d::Identity();
};

class Simulator
{
public:
  // Throws std::invalid_argument with the reason when the params are invalid.
  explicit Simulator(const SimulatorParams& params);

  SimFrame render(double t) const { return render(t, FrameRequest()); }
  SimFrame render(double t, const FrameRequest& request) const;

  // Replaces the parts of the params that do not change the scene (lighting,
  // noise, motion, keep_linear) without rebuilding it; for live tuning.
  // Throws std::invalid_argument when the result would be invalid.
  void updateLive(const SimulatorParams& params);

  const SimulatorParams& params() const { return params_; }
  const CameraModel& camera() const { return params_.sensor.camera; }
  // The exact projector calibration in the camera frame (rig-fixed, constant).
  const ProjectorCalibration& projector() const { return projector_; }
  // True camera motion since t = 0 (p_cur = delta * p_ref).
  Eigen::Isometry3d motion(double t) const;
  // Pose of the camera in the rock (world) frame at time t.
  Eigen::Isometry3d cameraPose(double t) const;

  // Ray-casts a ray given in the camera frame at time t onto the rock.
  // Returns false when it misses. The hit point is in the camera frame at t.
  bool intersect(double t, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, Eigen::Vector3d* hit) const;
  // Signed distance along the rock normal of a world point from the surface (0 = on it).
  double surfaceOffset(const Eigen::Vector3d& p_world) const;

  // Diameter of confusion (m, on the sensor) of a point at distance r
  // (docs/study.md §2.1.1.4).
  double diameterOfConfusion(double distance_m) const;

private:
  SimulatorParams params_;
  ProjectorCalibration projector_;
  struct Impl;  // the built scene (rock, sample lattice, clutter), shared by copies
  std::shared_ptr<const Impl> impl_;
};

}  // namespace structured_light_stabilizer
