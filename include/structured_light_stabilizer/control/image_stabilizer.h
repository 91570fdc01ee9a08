// The stabilised image, ROS-free (docs/stabilization.md, "The stabilised
// image"): the camera image warped into the locked reference view with the
// camera's pose at its exposure, so that the rock stands still in the
// picture; for what the arm cannot cancel (its delay and lag cap its
// bandwidth at a few Hz, a warp has no such cap).
//
// Contract. The reference: the rock's surface from the locked frame's beam
// map (organised rows x cols points in the reference camera optical frame,
// metres, NaN = missing; the `points` cloud of the lock) as a plane or the
// interpolated surface (pose/beam_surface.h), and the camera model of the
// images (calibration/camera_model.h: windowed to the published binned ROI,
// distortion included). A frame: its image and the pose T of its exposure
// (p_cur = T p_ref, the PoseDelta convention). The output is the reference
// view: output pixel u shows the current image at project(T X(u)), X(u) the
// surface point on the reference camera's ray through u; pixels whose
// source lies outside the image, or whose ray misses the surface, are 0.
// Any image cv::remap takes (8/16-bit, 1 or 3 channels; not a Bayer
// mosaic: demosaic first). Bilinear in the image.
//
// Thread-safety: warp() and sourcePixel() are const and may run
// concurrently; setReference() may not run concurrently with them. Nothing
// throws except the constructor (std::invalid_argument with the reason).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/common/params.h"
#include "structured_light_stabilizer/pose/beam_surface.h"

namespace structured_light_stabilizer
{

enum class StabilizerSurface
{
  kPlane,
  kSurface
};

struct ImageStabilizerParams
{
#define SLS_PARAMS_STRUCT ImageStabilizerParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/control/image_stabilizer_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  std::string validate() const;
};

// The locked rock in the reference camera frame.
class ReferenceSurface
{
public:
  // From the locked frame's beam map. False with *why when the points make
  // no plane (fewer than 3 usable, or all on a line).
  bool build(int rows, int cols, const std::vector<Eigen::Vector3d>& points, StabilizerSurface model,
             std::string* why);
  // The surface point on the reference camera's ray along `direction`
  // (from the optical centre); false when the ray misses. *uv: the
  // surface's parameters to start from and where it hit (NaN: none yet).
  bool intersect(const Eigen::Vector3d& direction, Eigen::Vector2d* uv, Eigen::Vector3d* point) const;
  // The plane n . X = d (n unit, towards the camera).
  const Eigen::Vector3d& normal() const { return normal_; }
  double offset() const { return offset_; }
  bool empty() const { return !built_; }

private:
  bool built_ = false;
  StabilizerSurface model_ = StabilizerSurface::kSurface;
  BeamSurface surface_;
  Eigen::Vector3d normal_ = Eigen::Vector3d::UnitZ();
  double offset_ = 0.0;
};

class ImageStabilizer
{
public:
  explicit ImageStabilizer(const ImageStabilizerParams& params = ImageStabilizerParams());

  // The reference view: the camera of the images and the locked surface;
  // the surface points of the warp's nodes are found here, once. False with
  // *why when the camera is unusable or no node hits the surface.
  bool setReference(const CameraModel& camera, const ReferenceSurface& surface, std::string* why);
  bool hasReference() const { return !nodes_.empty(); }
  const CameraModel& camera() const { return camera_; }
  const ImageStabilizerParams& params() const { return params_; }

  // The image of a frame at pose T warped into the reference view. False
  // with *why when there is no reference or the image is not of the
  // camera's size, or T is not finite.
  bool warp(const cv::Mat& image, const Eigen::Isometry3d& T, cv::Mat* out, std::string* why) const;
  // Where the warp reads reference pixel u in the current image (exact,
  // not interpolated); false when its ray misses the surface.
  bool sourcePixel(const cv::Point2d& u, const Eigen::Isometry3d& T, cv::Point2d* source) const;

private:
  ImageStabilizerParams params_;
  CameraModel camera_;
  ReferenceSurface surface_;
  int grid_cols_ = 0, grid_rows_ = 0;
  std::vector<int> node_x_, node_y_;        // pixel coordinates of the node columns and rows
  std::vector<Eigen::Vector3d> nodes_;      // surface point per node, NaN when the ray misses
};

}  // namespace structured_light_stabilizer
