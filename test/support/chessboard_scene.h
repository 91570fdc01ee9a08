// An independent renderer of chessboard views with projector dots on them,
// for the calibration tests (written apart from the simulator and from the
// core's renderBoardAlbedo so that each checks the other).
//
// Physics, per sub-pixel (supersample x supersample per pixel): the camera
// ray meets the board plane (exact ray/plane intersection; the undistorted
// ray directions are interpolated from an exact grid every 4 px); the
// radiance is albedo(point) * (ambient + beam irradiance(point)), the beams
// being Gaussian cones of angular sigma `beam_sigma_rad` from their own
// origins (so a dot straddling a square edge is cut by the edge as on a real
// print); natural vignetting cos^4; then the lens blur (Gaussian, sigma
// `psf_sigma_px`) at sub-pixel resolution, the pixel box, shot and read
// noise, clipping at 255 and 8-bit quantisation. Colour: the ambient light
// is grey; the dots add (blue, green, red) = dot_rgb_ratio * their green.
// Truth: the board pose, the exact corner pixels and every beam's hit point
// on the board (the calibration's target).
#pragma once

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/calibration/chessboard.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"

namespace sls_test
{

using namespace structured_light_stabilizer;

struct ChessboardSceneParams
{
  BoardParams board;                 // 10 x 8 inner corners of 8 cm by default
  double white = 0.5, black = 0.03;  // reflectances of the print (black ~16x dimmer)
  double ambient_dn = 120.0;         // DN of the white print under the ambient light (0 = night)
  double dot_peak_dn = 150.0;        // peak DN a dot adds on the white print at 1.5 m, normal incidence
  double beam_sigma_rad = 0.002;     // angular sigma of each beam (3 mm at 1.5 m)
  double psf_sigma_px = 0.5;         // lens blur
  double read_noise_dn = 1.0;
  double gain_dn_per_electron = 0.01;  // shot noise variance = signal * gain
  bool vignetting = true;
  int supersample = 3;
  Eigen::Vector3d dot_bgr_ratio = Eigen::Vector3d(0.22, 1.0, 0.08);
  std::vector<char> hidden_beams;  // per beam: 1 = blocked at the projector (no dot)
  int reflections = 0;             // extra dot-like spots off the lattice (glints), on the board
  uint32_t seed = 1;
};

struct ChessboardSceneTruth
{
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  // board -> camera
  std::vector<cv::Point2d> corners;                        // exact distorted pixels
  std::vector<Eigen::Vector3d> hits;                       // per beam, camera frame; NaN = not on the board / hidden
  std::vector<cv::Point2d> hit_pixels;                     // per beam, distorted pixel of the hit; NaN likewise
};

// Board -> camera pose looking at the board's centre from `distance` metres
// (the board's centre on the optical axis, shifted by `offset` in the camera
// frame), tilted by `tilt_x`, `tilt_y` (rad, about the camera's x and y axes)
// and rolled by `roll` about the optical axis.
inline Eigen::Isometry3d boardPoseFacing(const BoardParams& b, double distance, double tilt_x, double tilt_y,
                                         double roll = 0.0, const Eigen::Vector3d& offset = Eigen::Vector3d::Zero())
{
  const Eigen::Vector3d centre(0.5 * (b.cols - 1) * b.square_m, 0.5 * (b.rows - 1) * b.square_m, 0.0);
  const Eigen::Matrix3d R =
      (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
       Eigen::AngleAxisd(tilt_x, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = R;
  pose.translation() = Eigen::Vector3d(0.0, 0.0, distance) + offset - R * centre;
  return pose;
}

namespace detail_board
{

inline double albedoAt(const ChessboardSceneParams& p, double x, double y)
{
  const BoardParams& b = p.board;
  const double s = b.square_m, m = b.margin_m;
  const double beyond_m = 0.25;  // the rest of the plane: a mid-grey wall
  if (x < -s - m - beyond_m || y < -s - m - beyond_m || x > b.cols * s + m + beyond_m || y > b.rows * s + m + beyond_m)
    return 0.0;
  if (x < -s - m || y < -s - m || x > b.cols * s + m || y > b.rows * s + m)
    return 0.2;
  if (x < -s || y < -s || x > b.cols * s || y > b.rows * s)
    return p.white;
  const long i = static_cast<long>(std::floor(x / s)), j = static_cast<long>(std::floor(y / s));
  // Square (0, 0) is black in this print.
  return ((i + j) % 2 + 2) % 2 == 0 ? p.black : p.white;
}

}  // namespace detail_board

// The renderer's stages (see the file's header for the physics).
class BoardRenderer
{
public:
  BoardRenderer(const CameraModel& cam, const ChessboardSceneParams& p, const Eigen::Isometry3d& pose)
    : cam_(cam),
      p_(p),
      pose_(pose),
      inv_(pose.inverse()),
      n_(pose.linear().col(2)),
      t_(pose.translation()),
      S_(std::max(1, p.supersample)),
      W_(cam.width),
      H_(cam.height)
  {
    // Undistorted ray directions on an exact grid every 4 px (pixel coords).
    gw_ = W_ / kStep + 2;
    gh_ = H_ / kStep + 2;
    grid_.resize(static_cast<size_t>(gw_) * gh_);
    for (int j = 0; j < gh_; ++j)
      for (int i = 0; i < gw_; ++i)
        grid_[static_cast<size_t>(j) * gw_ + i] = cam.normalize(cv::Point2d(i * kStep - 0.5, j * kStep - 0.5));
  }

  // Camera ray (x/z, y/z, 1) through a point of the image (pixel coordinates).
  Eigen::Vector3d rayAt(double u, double v) const
  {
    const double gu = (u + 0.5) / kStep, gv = (v + 0.5) / kStep;
    const int i = std::min(gw_ - 2, std::max(0, static_cast<int>(gu)));
    const int j = std::min(gh_ - 2, std::max(0, static_cast<int>(gv)));
    const double fu = gu - i, fv = gv - j;
    const auto at = [&](int di, int dj) { return grid_[static_cast<size_t>(j + dj) * gw_ + i + di]; };
    const Eigen::Vector2d xy =
        (1 - fv) * ((1 - fu) * at(0, 0) + fu * at(1, 0)) + fv * ((1 - fu) * at(0, 1) + fu * at(1, 1));
    return Eigen::Vector3d(xy.x(), xy.y(), 1.0);
  }

  // Albedo (white = 1) where a camera ray (x/z, y/z, 1) meets the plane.
  double albedoOnRay(const Eigen::Vector3d& ray) const
  {
    const double s = n_.dot(t_) / n_.dot(ray);
    if (!(s > 0))
      return 0.0;
    const Eigen::Vector3d p = s * ray;  // on the plane, camera frame; to the board's frame:
    const double bx = inv_.linear().row(0).dot(p) + inv_.translation().x();
    const double by = inv_.linear().row(1).dot(p) + inv_.translation().y();
    return detail_board::albedoAt(p_, bx, by) / p_.white;
  }

  // Albedo (white = 1) at a point of the image.
  double albedoAtPixel(double x, double y) const { return albedoOnRay(rayAt(x, y)); }

  void truth(const ProjectorCalibration& proj, ChessboardSceneTruth* truth) const
  {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const int nb = proj.beamCount();
    const BoardParams& b = p_.board;
    truth->pose = pose_;
    truth->hits.assign(nb, Eigen::Vector3d::Constant(nan));
    truth->hit_pixels.assign(nb, cv::Point2d(nan, nan));
    truth->corners.clear();
    for (int k = 0; k < b.cornerCount(); ++k)
      truth->corners.push_back(cam_.project(pose_ * b.corner(k)));
    for (int i = 0; i < nb; ++i)
    {
      const BeamRay& r = proj.beams[i];
      const Eigen::Vector3d hit = r.pointAt(n_.dot(t_ - r.origin) / n_.dot(r.direction));
      const Eigen::Vector3d hb = inv_ * hit;
      const double lo = -b.square_m - b.margin_m;
      const bool on_print = hb.x() > lo && hb.y() > lo && hb.x() < b.cols * b.square_m + b.margin_m &&
                            hb.y() < b.rows * b.square_m + b.margin_m;
      const cv::Point2d px = cam_.project(hit);
      if (hidden(i) || !on_print || !(px.x > 0 && px.y > 0 && px.x < W_ - 1 && px.y < H_ - 1))
        continue;
      truth->hits[i] = hit;
      truth->hit_pixels[i] = px;
    }
  }

  // The print's albedo times vignetting on the sub-pixels; a sub-pixel
  // crossed by an edge gets its covered fraction (8 x 8 samples), not the
  // value at its centre: point samples would put every edge on the
  // sub-pixel lattice. A sub-pixel is crossed when one of its corners sees
  // another albedo than its centre; the corners are evaluated once, a row of
  // them at a time (each is shared by four sub-pixels).
  cv::Mat albedo() const
  {
    const int w = W_ * S_, hgt = H_ * S_;
    cv::Mat alb(hgt, w, CV_32F);
    const double h = 0.5 / S_;
    std::vector<double> upper(w + 1), lower(w + 1);
    const auto cornerRow = [&](int v, std::vector<double>* row)
    {
      for (int u = 0; u <= w; ++u)
        (*row)[u] = albedoAtPixel(double(u) / S_ - 0.5, double(v) / S_ - 0.5);
    };
    cornerRow(0, &upper);
    for (int v = 0; v < hgt; ++v)
    {
      cornerRow(v + 1, &lower);
      for (int u = 0; u < w; ++u)
      {
        const double x = (u + 0.5) / S_ - 0.5, y = (v + 0.5) / S_ - 0.5;
        const Eigen::Vector3d ray = rayAt(x, y);
        double a = albedoOnRay(ray);
        if (upper[u] != a || upper[u + 1] != a || lower[u] != a || lower[u + 1] != a)
        {
          a = 0.0;
          for (int j = 0; j < 8; ++j)
            for (int i = 0; i < 8; ++i)
              a += albedoAtPixel(x - h + (i + 0.5) * 2 * h / 8, y - h + (j + 0.5) * 2 * h / 8) / 64.0;
        }
        const double cos4 = p_.vignetting ? std::pow(1.0 / ray.squaredNorm(), 2.0) : 1.0;
        alb.at<float>(v, u) = static_cast<float>(a * cos4);
      }
      upper.swap(lower);
    }
    return alb;
  }

  // The light sources: every beam not blocked at the projector that meets
  // the plane (on the print or beyond it), and the glints.
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> sources(const ProjectorCalibration& proj,
                                                                   std::mt19937* rng) const
  {
    std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> out;  // (origin, direction)
    for (int b = 0; b < proj.beamCount(); ++b)
      if (!hidden(b) && n_.dot(t_ - proj.beams[b].origin) / n_.dot(proj.beams[b].direction) > 0.0)
        out.push_back({proj.beams[b].origin, proj.beams[b].direction});
    std::uniform_real_distribution<double> uni(0.1, 0.9);
    for (int k = 0; k < p_.reflections; ++k)
    {
      // A glint: a dot-like spot at a random place on the print.
      const double fy = uni(*rng), fx = uni(*rng);  // sequenced draws (docs/testing.md)
      const Eigen::Vector3d on_board(fx * p_.board.cols * p_.board.square_m, fy * p_.board.rows * p_.board.square_m, 0);
      out.push_back({proj.beams[0].origin, (pose_ * on_board - proj.beams[0].origin).normalized()});
    }
    return out;
  }

  // One beam's light on the sub-pixels: a Gaussian cone from its origin,
  // falling as cos(incidence) / distance^2, times the print under each.
  void addDot(const Eigen::Vector3d& o, const Eigen::Vector3d& dir, const cv::Mat& alb, cv::Mat* dot) const
  {
    const Eigen::Vector3d d = dir.normalized();
    const double sh = n_.dot(t_ - o) / n_.dot(d);
    const Eigen::Vector3d hit = o + sh * d;
    const cv::Point2d c = cam_.project(hit);
    const double gain = p_.dot_peak_dn * std::abs(n_.dot(d)) * std::pow(1.5 / sh, 2.0);
    const double half = 6.0 * p_.beam_sigma_rad * sh * cam_.fx / hit.z() + 3.0;  // px
    const double s2 = p_.beam_sigma_rad * p_.beam_sigma_rad;
    for (int v = std::max(0, static_cast<int>((c.y - half) * S_));
         v < std::min(H_ * S_, static_cast<int>((c.y + half) * S_)); ++v)
      for (int u = std::max(0, static_cast<int>((c.x - half) * S_));
           u < std::min(W_ * S_, static_cast<int>((c.x + half) * S_)); ++u)
      {
        const Eigen::Vector3d ray = rayAt((u + 0.5) / S_ - 0.5, (v + 0.5) / S_ - 0.5);
        const Eigen::Vector3d w = ray * (n_.dot(t_) / n_.dot(ray)) - o;
        const double along = w.dot(d);
        const double ang2 = (w - along * d).squaredNorm() / (along * along);
        dot->at<float>(v, u) += static_cast<float>(gain * std::exp(-0.5 * ang2 / s2) * alb.at<float>(v, u));
      }
  }

  // Lens blur and pixel box of the sub-pixel radiance, then shot and read
  // noise, clipping and 8 bits, per channel.
  cv::Mat sensor(cv::Mat amb, cv::Mat dot, std::mt19937* rng) const
  {
    if (p_.psf_sigma_px > 0.0)
    {
      cv::GaussianBlur(amb, amb, cv::Size(0, 0), p_.psf_sigma_px * S_);
      cv::GaussianBlur(dot, dot, cv::Size(0, 0), p_.psf_sigma_px * S_);
    }
    cv::Mat amb_px, dot_px;
    cv::resize(amb, amb_px, cv::Size(W_, H_), 0, 0, cv::INTER_AREA);
    cv::resize(dot, dot_px, cv::Size(W_, H_), 0, 0, cv::INTER_AREA);
    cv::Mat out(H_, W_, CV_8UC3);
    std::normal_distribution<double> gauss(0.0, 1.0);
    for (int v = 0; v < H_; ++v)
      for (int u = 0; u < W_; ++u)
        for (int ch = 0; ch < 3; ++ch)
        {
          const double signal = amb_px.at<float>(v, u) + p_.dot_bgr_ratio(ch) * dot_px.at<float>(v, u);
          const double sigma =
              std::sqrt(p_.read_noise_dn * p_.read_noise_dn + std::max(0.0, signal) * p_.gain_dn_per_electron);
          const double value = std::round(signal + sigma * gauss(*rng));
          out.at<cv::Vec3b>(v, u)[ch] = static_cast<uint8_t>(std::min(255.0, std::max(0.0, value)));
        }
    return out;
  }

private:
  static constexpr int kStep = 4;
  bool hidden(int b) const { return b < static_cast<int>(p_.hidden_beams.size()) && p_.hidden_beams[b]; }

  const CameraModel& cam_;
  const ChessboardSceneParams& p_;
  Eigen::Isometry3d pose_, inv_;
  Eigen::Vector3d n_, t_;
  int S_, W_, H_, gw_ = 0, gh_ = 0;
  std::vector<Eigen::Vector2d> grid_;
};

inline cv::Mat renderChessboardScene(const CameraModel& cam, const ProjectorCalibration& proj,
                                     const ChessboardSceneParams& p, const Eigen::Isometry3d& pose,
                                     ChessboardSceneTruth* truth)
{
  const BoardRenderer r(cam, p, pose);
  r.truth(proj, truth);
  const cv::Mat alb = r.albedo();
  const cv::Mat amb = alb * p.ambient_dn;
  cv::Mat dot(alb.size(), CV_32F, cv::Scalar(0));
  std::mt19937 rng(p.seed);
  for (const auto& src : r.sources(proj, &rng))
    r.addDot(src.first, src.second, alb, &dot);
  return r.sensor(amb, dot, &rng);
}

}  // namespace sls_test
