// The chessboard target (TargetKind::kChessboard): its printed pattern,
// its slab for the ray caster (a flat RockSurface of the board's size), its
// pose, and its pixels rendered analytically (a plane: no height field, and
// sharp printed edges that a vertex grid would blur). The rock code only
// forwards to it (RockSurface::board).
#pragma once

#include <vector>

#include <Eigen/Geometry>

#include "sim/render/frame_geometry.h"
#include "sim/render/rock_surface.h"
#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace structured_light_stabilizer
{
namespace sim
{

struct RockSampling;

// The printed pattern in the rock frame of the board's slab: rock (x, y) =
// board (x, y) - centre of the inner corners.
class ChessboardPattern
{
public:
  explicit ChessboardPattern(const ChessboardParams& params);

  // Reflectance at rock-frame (x, y), every band alike, blurred by a Gaussian
  // of standard deviation blur_x, blur_y (m, along the board's axes; exact
  // for straight edges, blurs of up to a quarter square).
  double reflectance(double x, double y, double blur_x, double blur_y) const;

  // Rock-frame offset of the board frame: p_rock = p_board - centre().
  Eigen::Vector3d centre() const { return Eigen::Vector3d(cx_, cy_, 0.0); }

private:
  // The checker's "darkness" along one axis, blurred: the square wave of the
  // squares' parity (+-1) inside [-square, n * square], 0 outside; and the
  // inside indicator alone.
  void blurredAxis(double b, double sigma, int n, double* wave, double* inside) const;

  ChessboardParams p_;
  double cx_, cy_;
};

// The slab that stands for the board in the ray caster: flat, the board's
// outer size.
RockParams boardSlab(const ChessboardParams& board, const RockParams& rock);

// The camera's pose at t = 0 in the board's rock frame (ChessboardParams).
Eigen::Isometry3d boardRockFromCamera0(const ChessboardParams& board);

// Fills `rows` (sampling.rh rows of sampling.stride() floats, B, G, R) with
// the board's sunlit radiance; sun: DN of a white surface facing the sun.
// Each pixel is the print blurred by the pixel's box, the defocus at its
// depth and diffraction (white light), as Gaussians. Sampling must be one
// sample per pixel.
void renderBoardSamples(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor,
                        const FrameGeometry& g, double sun, float* rows);

// The ground truth of a board frame: its pose in the camera frame and its
// corners' pixels (SimFrame::target_pose, target_corners).
void boardTruth(const ChessboardParams& board, const CameraModel& cam, const FrameGeometry& g, Eigen::Isometry3d* pose,
                std::vector<cv::Point2d>* corners);

}  // namespace sim
}  // namespace structured_light_stabilizer
