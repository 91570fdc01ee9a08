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

#include "structured_light_stabilizer/camera_model.h"
#include "structured_light_stabilizer/chessboard.h"
#include "structured_light_stabilizer/projector_calibration.h"

namespace sls_test
{

using namespace structured_light_stabilizer;

struct ChessboardSceneParams
{
  BoardParams board;             // 10 x 8 inner corners of 8 cm by default
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
  std::vector<cv::Point2d> corners;                         // exact distorted pixels
  std::vector<Eigen::Vector3d> hits;                        // per beam, camera frame; NaN = not on the board / hidden
  std::vector<cv::Point2d> hit_pixels;                      // per beam, distorted pixel of the hit; NaN likewise
};

// Board -> camera pose looking at the board's centre from `distance` metres
// (the board's centre on the optical axis, shifted by `offset` in the camera
// frame), tilted by `tilt_x`, `tilt_y` (rad, about the camera's x and y axes)
// and rolled by `roll` about the optical axis.
inline Eigen::Isometry3d boardPoseFacing(const BoardParams& b, double distance, double tilt_x, double tilt_y,
                                         double roll = 0.0, const Eigen::Vector3d& offset = Eigen::Vector3d::Zero())
{
  const Eigen::Vector3d centre(0.5 * (b.cols - 1) * b.square_m, 0.5 * (b.rows - 1) * b.square_m, 0.0);
  const Eigen::Matrix3d R = (Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()) *
                             Eigen::AngleAxisd(tilt_y, Eigen::Vector3d::UnitY()) *
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

inline cv::Mat renderChessboardScene(const CameraModel& cam, const ProjectorCalibration& proj,
                                     const ChessboardSceneParams& p, const Eigen::Isometry3d& pose,
                                     ChessboardSceneTruth* truth)
{
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const int S = std::max(1, p.supersample), W = cam.width, H = cam.height;
  const Eigen::Vector3d n = pose.linear().col(2), t = pose.translation();
  const Eigen::Isometry3d inv = pose.inverse();
  // Undistorted ray directions on an exact grid every 4 px (pixel coords).
  const int step = 4, gw = W / step + 2, gh = H / step + 2;
  std::vector<Eigen::Vector2d> grid(static_cast<size_t>(gw) * gh);
  for (int j = 0; j < gh; ++j)
    for (int i = 0; i < gw; ++i)
      grid[static_cast<size_t>(j) * gw + i] = cam.normalize(cv::Point2d(i * step - 0.5, j * step - 0.5));
  const auto rayAt = [&](double u, double v) {
    const double gu = (u + 0.5) / step, gv = (v + 0.5) / step;
    const int i = std::min(gw - 2, std::max(0, static_cast<int>(gu))), j = std::min(gh - 2, std::max(0, static_cast<int>(gv)));
    const double fu = gu - i, fv = gv - j;
    const auto& a = grid[static_cast<size_t>(j) * gw + i];
    const auto& b = grid[static_cast<size_t>(j) * gw + i + 1];
    const auto& c = grid[static_cast<size_t>(j + 1) * gw + i];
    const auto& d = grid[static_cast<size_t>(j + 1) * gw + i + 1];
    const Eigen::Vector2d xy = (1 - fv) * ((1 - fu) * a + fu * b) + fv * ((1 - fu) * c + fu * d);
    return Eigen::Vector3d(xy.x(), xy.y(), 1.0);
  };
  // Truth: hits of the beams on the board (inside the print).
  const int nb = proj.beamCount();
  truth->pose = pose;
  truth->hits.assign(nb, Eigen::Vector3d::Constant(nan));
  truth->hit_pixels.assign(nb, cv::Point2d(nan, nan));
  truth->corners.clear();
  for (int k = 0; k < p.board.cornerCount(); ++k)
    truth->corners.push_back(cam.project(pose * p.board.corner(k)));
  for (int b = 0; b < nb; ++b)
  {
    const BeamRay& r = proj.beams[b];
    const double s = n.dot(t - r.origin) / n.dot(r.direction);
    const Eigen::Vector3d hit = r.pointAt(s);
    const Eigen::Vector3d hb = inv * hit;
    const bool hidden = b < static_cast<int>(p.hidden_beams.size()) && p.hidden_beams[b];
    const double s_b = p.board.square_m;
    const bool on_print = hb.x() > -s_b - p.board.margin_m && hb.y() > -s_b - p.board.margin_m &&
                          hb.x() < p.board.cols * s_b + p.board.margin_m && hb.y() < p.board.rows * s_b + p.board.margin_m;
    const cv::Point2d px = cam.project(hit);
    if (hidden || !on_print || !(px.x > 0 && px.y > 0 && px.x < W - 1 && px.y < H - 1))
      continue;
    truth->hits[b] = hit;
    truth->hit_pixels[b] = px;
  }
  // Radiance at the sub-pixels: ambient and dot light, per channel.
  cv::Mat amb(H * S, W * S, CV_32F), dot(H * S, W * S, CV_32F, cv::Scalar(0));
  cv::Mat alb(H * S, W * S, CV_32F);
  const double fx = cam.fx;
  // Albedo (white = 1) at a point of the image (pixel coordinates).
  const auto albedoAtPixel = [&](double x, double y) {
    const Eigen::Vector3d ray = rayAt(x, y);
    const double s = n.dot(t) / n.dot(ray);
    const Eigen::Vector3d hb = inv * (s * ray);
    return s > 0 ? detail_board::albedoAt(p, hb.x(), hb.y()) / p.white : 0.0;
  };
  for (int v = 0; v < H * S; ++v)
    for (int u = 0; u < W * S; ++u)
    {
      const double x = (u + 0.5) / S - 0.5, y = (v + 0.5) / S - 0.5, h = 0.5 / S;
      double a = albedoAtPixel(x, y);
      // A sub-pixel crossed by an edge gets its covered fraction (8 x 8
      // samples), not the value at its centre: point samples would put
      // every edge on the sub-pixel lattice.
      if (albedoAtPixel(x - h, y - h) != a || albedoAtPixel(x + h, y - h) != a || albedoAtPixel(x - h, y + h) != a ||
          albedoAtPixel(x + h, y + h) != a)
      {
        a = 0.0;
        for (int j = 0; j < 8; ++j)
          for (int i = 0; i < 8; ++i)
            a += albedoAtPixel(x - h + (i + 0.5) * 2 * h / 8, y - h + (j + 0.5) * 2 * h / 8) / 64.0;
      }
      const Eigen::Vector3d ray = rayAt(x, y);
      const double cos4 = p.vignetting ? std::pow(1.0 / ray.squaredNorm(), 2.0) : 1.0;
      alb.at<float>(v, u) = static_cast<float>(a * cos4);
      amb.at<float>(v, u) = static_cast<float>(p.ambient_dn * a * cos4);
    }
  std::mt19937 rng(p.seed);
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> sources;  // (origin, direction) of lit spots
  // Every beam not blocked at the projector lights the plane, on the print or beyond it.
  for (int b = 0; b < nb; ++b)
    if (!(b < static_cast<int>(p.hidden_beams.size()) && p.hidden_beams[b]) &&
        n.dot(t - proj.beams[b].origin) / n.dot(proj.beams[b].direction) > 0.0)
      sources.push_back({proj.beams[b].origin, proj.beams[b].direction});
  std::uniform_real_distribution<double> uni(0.1, 0.9);
  for (int k = 0; k < p.reflections; ++k)
  {
    // A glint: a dot-like spot at a random place on the print, lit from the projector's direction.
    const Eigen::Vector3d on_board(uni(rng) * p.board.cols * p.board.square_m, uni(rng) * p.board.rows * p.board.square_m, 0);
    const Eigen::Vector3d hit = pose * on_board;
    sources.push_back({proj.beams[0].origin, (hit - proj.beams[0].origin).normalized()});
  }
  for (const auto& src : sources)
  {
    const Eigen::Vector3d& o = src.first;
    const Eigen::Vector3d d = src.second.normalized();
    const double sh = n.dot(t - o) / n.dot(d);
    const Eigen::Vector3d hit = o + sh * d;
    const cv::Point2d c = cam.project(hit);
    const double cos_inc = std::abs(n.dot(d));
    const double gain = p.dot_peak_dn * cos_inc * std::pow(1.5 / sh, 2.0);
    const double half = 6.0 * p.beam_sigma_rad * sh * fx / hit.z() + 3.0;  // px
    for (int v = std::max(0, static_cast<int>((c.y - half) * S)); v < std::min(H * S, static_cast<int>((c.y + half) * S)); ++v)
      for (int u = std::max(0, static_cast<int>((c.x - half) * S)); u < std::min(W * S, static_cast<int>((c.x + half) * S)); ++u)
      {
        const Eigen::Vector3d ray = rayAt((u + 0.5) / S - 0.5, (v + 0.5) / S - 0.5);
        const Eigen::Vector3d q = ray * (n.dot(t) / n.dot(ray));
        const Eigen::Vector3d w = q - o;
        const double along = w.dot(d);
        const double ang2 = (w - along * d).squaredNorm() / (along * along);
        dot.at<float>(v, u) += static_cast<float>(gain * std::exp(-0.5 * ang2 / (p.beam_sigma_rad * p.beam_sigma_rad)) *
                                                  alb.at<float>(v, u));
      }
  }
  // Lens blur, pixel box, noise, quantisation.
  if (p.psf_sigma_px > 0.0)
  {
    cv::GaussianBlur(amb, amb, cv::Size(0, 0), p.psf_sigma_px * S);
    cv::GaussianBlur(dot, dot, cv::Size(0, 0), p.psf_sigma_px * S);
  }
  cv::Mat amb_px, dot_px;
  cv::resize(amb, amb_px, cv::Size(W, H), 0, 0, cv::INTER_AREA);
  cv::resize(dot, dot_px, cv::Size(W, H), 0, 0, cv::INTER_AREA);
  cv::Mat out(H, W, CV_8UC3);
  std::normal_distribution<double> gauss(0.0, 1.0);
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u)
      for (int ch = 0; ch < 3; ++ch)
      {
        const double signal = amb_px.at<float>(v, u) + p.dot_bgr_ratio(ch) * dot_px.at<float>(v, u);
        const double sigma = std::sqrt(p.read_noise_dn * p.read_noise_dn + std::max(0.0, signal) * p.gain_dn_per_electron);
        const double value = std::round(signal + sigma * gauss(rng));
        out.at<cv::Vec3b>(v, u)[ch] = static_cast<uint8_t>(std::min(255.0, std::max(0.0, value)));
      }
  return out;
}

}  // namespace sls_test
