// The window fit of one projector dot on a chessboard (board_dots.h gives
// the model and why). Not a public API.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/chessboard.h"

namespace structured_light_stabilizer
{
namespace detail
{

// b (black level), L0, Lx, Ly (ambient on white at the window's centre and
// its gradient per px: vignetting and the light's falloff), A (dot peak on
// white), cx, cy (px), and the inverse footprint covariance as (log p,
// atanh(q / sqrt(p r)), log r) so that any value is a valid ellipse.
constexpr int kDotParams = 10;
constexpr int kDotX = 5, kDotY = 6;
using DotVector = Eigen::Matrix<double, kDotParams, 1>;
using DotMatrix = Eigen::Matrix<double, kDotParams, kDotParams>;

struct BoardAlbedoSource
{
  const CameraModel* camera = nullptr;
  const BoardParams* board = nullptr;
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  bool square00_white = true;
  double black_ratio = 1.0 / 16.0;
};

// A window of the dot channel around a dot and its model
//   I(u) = b + L(u) * [box * PSF * a](u) + A * [box * PSF * (a G)](u):
// the print's albedo a and the footprint G are multiplied on `kSub` x
// `kSub` sub-pixels (a dot straddling an edge varies a lot within one
// pixel), blurred by the lens (Gaussian PSF) at that resolution, then
// averaged over each pixel (box). A blur applied to pixel averages instead
// would misplace a blurred edge by a few hundredths of a pixel, which is
// what moves a dot cut by that edge.
class DotWindow
{
public:
  static constexpr int kSub = 4;

  // `img`: the dot channel (CV_32F); `rect` inside the image.
  DotWindow(const cv::Mat& img, const cv::Rect& rect, double psf_sigma_px, double clip_dn,
            const BoardAlbedoSource& albedo);

  // Whether the window, blur margin included, lies within the print.
  bool valid() const { return valid_; }
  int usable() const { return usable_; }
  int clipped() const { return static_cast<int>(img_.total()) - usable_; }
  const cv::Rect& rect() const { return rect_; }
  // The blurred albedo at a window pixel (white = 1).
  double ambientAlbedo(int u, int v) const { return amb_.at<float>(v, u); }

  // Residuals I - model over the usable pixels (+ one prior row on b), and
  // their Jacobian d(residual)/d(theta) when J is not null.
  Eigen::VectorXd residuals(const DotVector& th, double noise, Eigen::MatrixXd* J) const;

  // Share of the footprint's light on black (albedo < 0.5) sub-pixels.
  double blackFraction(const DotVector& th) const;

private:
  cv::Mat boxAverage(const cv::Mat& sub) const;

  cv::Rect rect_;
  int pad_ = 0;  // blur margin (px) around rect_
  bool valid_ = false;
  int usable_ = 0;
  cv::Mat img_, amb_, use_, kernel_;
  cv::Mat alb_sub_;  // (rect + pad) * kSub sub-pixels
};

// Levenberg-Marquardt with the analytic Jacobian; *cov is the parameters'
// covariance scaled by the residual variance, *rms the residual over `noise`.
bool fitDotWindow(const DotWindow& w, double noise, DotVector* th, DotMatrix* cov, double* rms);

// Inverse footprint covariance (p, q, r) of the parameters.
inline void footprintInverse(const DotVector& th, double* p, double* q, double* r)
{
  *p = std::exp(th(7));
  *r = std::exp(th(9));
  *q = std::tanh(th(8)) * std::sqrt(*p * *r);
}

}  // namespace detail
}  // namespace structured_light_stabilizer
