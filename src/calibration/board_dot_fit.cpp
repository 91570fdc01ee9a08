#include "calibration/board_dot_fit.h"

#include "calibration/calibration_geometry.h"

#include <array>
#include <cmath>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

namespace structured_light_stabilizer
{
namespace detail
{

DotWindow::DotWindow(const cv::Mat& img, const cv::Rect& rect, double psf_sigma_px, double clip_dn,
                     const BoardAlbedoSource& albedo)
  : rect_(rect)
{
  const int kr_sub = psf_sigma_px > 0.0 ? static_cast<int>(std::ceil(3.0 * psf_sigma_px * kSub)) : 0;
  pad_ = (kr_sub + kSub - 1) / kSub;
  const cv::Rect padded(rect.x - pad_, rect.y - pad_, rect.width + 2 * pad_, rect.height + 2 * pad_);
  if ((padded & cv::Rect(0, 0, img.cols, img.rows)) != padded)
    return;
  img_ = img(rect).clone();
  alb_sub_ = renderBoardAlbedoWindow(*albedo.camera, *albedo.board, albedo.pose, albedo.square00_white,
                                     albedo.black_ratio, padded, kSub, 16);
  if (cv::countNonZero(alb_sub_ != alb_sub_) > 0)
    return;
  if (kr_sub > 0)
    kernel_ = cv::getGaussianKernel(2 * kr_sub + 1, psf_sigma_px * kSub, CV_32F);
  amb_ = boxAverage(alb_sub_);
  use_ = img_ < static_cast<float>(clip_dn);
  usable_ = cv::countNonZero(use_);
  valid_ = true;
}

// Lens blur at sub-pixel resolution, then the mean over each pixel of rect_.
cv::Mat DotWindow::boxAverage(const cv::Mat& sub) const
{
  cv::Mat blurred;  // a new buffer: OpenCV's separable filter must not run in place
  if (!kernel_.empty())
    cv::sepFilter2D(sub, blurred, CV_32F, kernel_, kernel_, cv::Point(-1, -1), 0, cv::BORDER_CONSTANT);
  else
    blurred = sub;
  const cv::Mat inner = blurred(cv::Rect(pad_ * kSub, pad_ * kSub, rect_.width * kSub, rect_.height * kSub));
  cv::Mat out;
  cv::resize(inner, out, rect_.size(), 0, 0, cv::INTER_AREA);
  return out;
}

Eigen::VectorXd DotWindow::residuals(const DotVector& th, double noise, Eigen::MatrixXd* J) const
{
  double p = 0.0, q = 0.0, r = 0.0;
  footprintInverse(th, &p, &q, &r);
  const double dq_db = (1.0 - std::tanh(th(8)) * std::tanh(th(8))) * std::sqrt(p * r);
  const int nimg = J ? 6 : 1;
  std::array<cv::Mat, 6> P;
  for (int k = 0; k < nimg; ++k)
    P[k] = cv::Mat::zeros(alb_sub_.size(), CV_32F);
  const double x0 = rect_.x - pad_ - 0.5 + 0.5 / kSub, y0 = rect_.y - pad_ - 0.5 + 0.5 / kSub;
  for (int v = 0; v < alb_sub_.rows; ++v)
  {
    const double dy = y0 + static_cast<double>(v) / kSub - th(kDotY);
    for (int u = 0; u < alb_sub_.cols; ++u)
    {
      const double dx = x0 + static_cast<double>(u) / kSub - th(kDotX);
      const double e = -0.5 * (p * dx * dx + 2.0 * q * dx * dy + r * dy * dy);
      if (e < -14.0)
        continue;
      const double g = alb_sub_.at<float>(v, u) * std::exp(e);
      P[0].at<float>(v, u) = static_cast<float>(g);
      if (!J)
        continue;
      P[1].at<float>(v, u) = static_cast<float>(g * (p * dx + q * dy));
      P[2].at<float>(v, u) = static_cast<float>(g * (q * dx + r * dy));
      P[3].at<float>(v, u) = static_cast<float>(g * -0.5 * (p * dx * dx + q * dx * dy));
      P[4].at<float>(v, u) = static_cast<float>(g * -dq_db * dx * dy);
      P[5].at<float>(v, u) = static_cast<float>(g * -0.5 * (r * dy * dy + q * dx * dy));
    }
  }
  for (int k = 0; k < nimg; ++k)
    P[k] = boxAverage(P[k]);
  Eigen::VectorXd res(usable_ + 1);
  if (J)
    J->setZero(usable_ + 1, kDotParams);
  const double xc = rect_.x + 0.5 * (rect_.width - 1), yc = rect_.y + 0.5 * (rect_.height - 1);
  const double A = th(4);
  int i = 0;
  for (int v = 0; v < rect_.height; ++v)
    for (int u = 0; u < rect_.width; ++u)
    {
      if (!use_.at<uint8_t>(v, u))
        continue;
      const double ab = amb_.at<float>(v, u), p0 = P[0].at<float>(v, u);
      const double dx = rect_.x + u - xc, dy = rect_.y + v - yc;
      res(i) = img_.at<float>(v, u) - (th(0) + (th(1) + th(2) * dx + th(3) * dy) * ab + A * p0);
      if (J)
      {
        J->row(i) << -1.0, -ab, -ab * dx, -ab * dy, -p0, -A * P[1].at<float>(v, u), -A * P[2].at<float>(v, u),
            -A * P[3].at<float>(v, u), -A * P[4].at<float>(v, u), -A * P[5].at<float>(v, u);
      }
      ++i;
    }
  // The black level: a weak prior (5 DN); it only matters in windows that
  // hold a single albedo, where it and L are otherwise one unknown.
  res(i) = th(0) * noise / 5.0;
  if (J)
    (*J)(i, 0) = noise / 5.0;
  return res;
}

double DotWindow::blackFraction(const DotVector& th) const
{
  double p = 0.0, q = 0.0, r = 0.0;
  footprintInverse(th, &p, &q, &r);
  double on_black = 0.0, total = 0.0;
  for (int v = 0; v < alb_sub_.rows; ++v)
    for (int u = 0; u < alb_sub_.cols; ++u)
    {
      const double dx = rect_.x - pad_ - 0.5 + (u + 0.5) / kSub - th(kDotX);
      const double dy = rect_.y - pad_ - 0.5 + (v + 0.5) / kSub - th(kDotY);
      const double g = std::exp(-0.5 * (p * dx * dx + 2.0 * q * dx * dy + r * dy * dy));
      total += g;
      on_black += alb_sub_.at<float>(v, u) < 0.5f ? g : 0.0;
    }
  return total > 0.0 ? on_black / total : 0.0;
}

bool fitDotWindow(const DotWindow& w, double noise, DotVector* th, DotMatrix* cov, double* rms)
{
  Eigen::MatrixXd J;
  Eigen::VectorXd r = w.residuals(*th, noise, &J);
  double cost = r.squaredNorm(), lambda = 1e-3;
  for (int it = 0; it < 100; ++it)
  {
    const DotMatrix H = J.transpose() * J;
    const DotVector g = J.transpose() * r;
    DotVector candidate;
    bool converged = false;
    const bool accepted = levenbergMarquardtIteration(
        &cost, &lambda,
        [&](double l)
        {
          DotMatrix A = H;
          A.diagonal() *= 1.0 + l;
          A.diagonal().array() += 1e-12;
          return DotVector(-A.ldlt().solve(g));
        },
        [&](const DotVector& step, double* c)
        {
          candidate = *th + step;
          *c = w.residuals(candidate, noise, nullptr).squaredNorm();
          return true;
        },
        [&] { *th = candidate; }, &converged);
    if (!accepted || converged)
      break;
    r = w.residuals(*th, noise, &J);
  }
  r = w.residuals(*th, noise, &J);
  const int dof = std::max(1, static_cast<int>(r.size()) - kDotParams);
  *rms = std::sqrt(r.squaredNorm() / dof) / noise;
  *cov = (J.transpose() * J).inverse() * (r.squaredNorm() / dof);
  return th->allFinite() && cov->allFinite();
}

}  // namespace detail
}  // namespace structured_light_stabilizer
