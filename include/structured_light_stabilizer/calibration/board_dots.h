// Projector dots on a chessboard whose pose is known: found and fitted with
// the albedo under every pixel accounted for. ROS-free.
//
// Why: a dot on a print is the beam's irradiance times the print's
// reflectance. On a black square it is about 16x dimmer than on a white one,
// and a dot straddling a square's edge is cut by it: its plain centroid is
// pulled towards the white side by up to about a pixel. With the board's
// pose the reflectance under every pixel is known (renderBoardAlbedo), so
// each dot is fitted with the model
//   I(u) = b + L * A_blur(u) + A * [PSF * (a(u) G(u; c, S))](u)
// over a window: a(u) the print's albedo (white = 1) averaged over pixel u,
// A_blur the same seen through the lens blur PSF (a Gaussian whose sigma is
// measured on the board's own square edges), L the ambient light on white,
// b the black level, G an elliptical Gaussian of centre c and covariance S
// (the beam's footprint), A its peak on white. The centre c is the image of
// the beam's hit point. Clipped pixels are left out of the fit (the dot's
// unclipped flanks carry its centre).
//
// Input: the image channel that carries the dots (float or 8/16-bit, one
// channel: green for green dots), the camera, the board and its detection
// (chessboard.h). Output: the dots inside the print (margin included) with
// distorted sub-pixel centres (OpenCV convention), their fitted uncertainty
// and quality. Reentrant; no shared state.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/chessboard.h"

namespace structured_light_stabilizer
{

struct BoardDotParams
{
  // Reflectance of black relative to white. 0: measured from the board's
  // squares (needs an ambient light of at least min_ambient_dn on white),
  // else default_black_ratio.
  double black_ratio = 0.0;
  double default_black_ratio = 1.0 / 16.0;
  double min_ambient_dn = 8.0;
  // Lens blur sigma (px); < 0: measured from the square edges of the view.
  double psf_sigma_px = -1.0;
  // A candidate's matched-filter peak over the noise (both in the dot's own
  // light, DN on the print it lies on).
  double min_snr = 7.0;
  // Pixels at or above this fraction of the full scale are clipped and left out.
  double clip_fraction = 0.98;
  // Window half-size around a candidate (px); 0 = 4 x the dot's sigma + 2.
  int window_radius_px = 0;
  // Fitted footprint sigma bounds (px): outside them the spot is not a dot.
  double min_sigma_px = 0.5;
  double max_sigma_px = 8.0;

  std::string validate() const;
};

struct BoardDot
{
  double x = 0.0, y = 0.0;   // distorted px, the image of the beam's hit point
  double sigma_xy_px = 0.0;  // 1-sigma uncertainty of the centre from the fit (per axis, RMS of the two)
  double sigma_px = 0.0;     // footprint size: sqrt of the mean eigenvalue of S
  double amplitude = 0.0;    // peak DN on white
  double ambient_dn = 0.0;   // ambient light on white at the dot (DN)
  double snr = 0.0;          // candidate peak over the noise
  double fit_rms = 0.0;      // RMS residual of the window fit over its noise (about 1 for a clean dot)
  int clipped = 0;           // clipped pixels left out
  Eigen::Vector2d board_xy = Eigen::Vector2d::Zero();  // metres, board frame
  double black_fraction = 0.0;                         // share of the dot's light on black squares (0 = all on white)
};

struct BoardDotReport
{
  double black_ratio = 0.0;  // used
  bool black_ratio_measured = false;
  double psf_sigma_px = 0.0;    // used
  double noise_dn = 0.0;        // robust noise of the smoothed dot light on white squares (DN)
  double noise_black_dn = 0.0;  // same on black squares
  double pixel_noise_dn = 0.0;  // robust noise of one pixel of the dot channel
  int candidates = 0;           // peaks above min_snr
  int rejected = 0;             // candidates whose fit failed or that lie beyond the print
};

// Dots on the board of `detection` (found == true expected). `dots` is the
// channel of the projector's colour (CV_8U, CV_16U or CV_32F, one channel,
// the camera's size); full_scale is its clipping level (255 for 8-bit).
std::vector<BoardDot> findBoardDots(const cv::Mat& dots, double full_scale, const CameraModel& camera,
                                    const BoardParams& board, const ChessboardDetection& detection,
                                    const BoardDotParams& params, BoardDotReport* report);

// The same dots fitted again on a refined pose of the board (the blur, the
// black ratio and the noise of `report`, which must come from the
// findBoardDots of `previous`, are kept); dots whose fit fails are dropped.
// Cheaper than findBoardDots: no maps of the whole image.
std::vector<BoardDot> refitBoardDots(const cv::Mat& dots, double full_scale, const CameraModel& camera,
                                     const BoardParams& board, const ChessboardDetection& detection,
                                     const BoardDotParams& params, const std::vector<BoardDot>& previous,
                                     BoardDotReport* report);

}  // namespace structured_light_stabilizer
