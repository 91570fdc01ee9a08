// The sensor of the synthetic dot frames (synthetic_dots.h): samples per
// output encoding, shot and read noise, full well, blooming, quantisation,
// and render(), which chains the scene and the sensor.
#pragma once

#include "synthetic_dots.h"

namespace synthetic_dots
{
namespace detail
{
inline bool isBayer(Output o)
{
  return o == Output::kBayerRggb8 || o == Output::kBayerBggr8 || o == Output::kBayerGbrg8 || o == Output::kBayerGrbg8;
}

inline bool isMono(Output o)
{
  return o == Output::kMono8 || o == Output::kMono16;
}

// Channel (0 = b, 1 = g, 2 = r) of Bayer site (x, y).
inline int bayerChannel(Output o, int x, int y)
{
  static const int kCells[4][4] = {{2, 1, 1, 0}, {0, 1, 1, 2}, {1, 0, 2, 1}, {1, 2, 0, 1}};
  return kCells[static_cast<int>(o) - static_cast<int>(Output::kBayerRggb8)][(y & 1) * 2 + (x & 1)];
}

// Charge above the full well spills to both neighbours in the column, half
// each way, until no well overflows (what leaves the frame is lost): sweeps
// over the column's overflowing stretch until the excess left is below
// 1e-3 DN.
inline void bloomColumns(cv::Mat* q, double full_well)
{
  std::vector<double> col(q->rows), spill(q->rows);
  for (int x = 0; x < q->cols; ++x)
  {
    bool any = false;
    for (int y = 0; y < q->rows; ++y)
    {
      col[y] = q->at<double>(y, x);
      any = any || col[y] > full_well;
    }
    for (int sweep = 0; any && sweep < 100000; ++sweep)
    {
      any = false;
      std::fill(spill.begin(), spill.end(), 0.0);
      for (int y = 0; y < q->rows; ++y)
        if (col[y] > full_well + 1e-3)
        {
          const double e = col[y] - full_well;
          col[y] = full_well;
          if (y > 0)
            spill[y - 1] += 0.5 * e;
          if (y + 1 < q->rows)
            spill[y + 1] += 0.5 * e;
        }
      for (int y = 0; y < q->rows; ++y)
      {
        col[y] += spill[y];
        any = any || col[y] > full_well + 1e-3;
      }
    }
    for (int y = 0; y < q->rows; ++y)
      q->at<double>(y, x) = col[y];
  }
}

// BT.601 video range, as OpenCV's inverse (COLOR_YUV2BGR_UYVY) expects.
inline void bgrToYuv(const cv::Vec3b& p, double* y, double* u, double* v)
{
  const double b = p[0], g = p[1], r = p[2];
  *y = 16.0 + 0.256788 * r + 0.504129 * g + 0.097906 * b;
  *u = 128.0 - 0.148223 * r - 0.290993 * g + 0.439216 * b;
  *v = 128.0 + 0.439216 * r - 0.367788 * g - 0.071427 * b;
}

inline cv::Mat toYuv422(const cv::Mat& bgr, bool uyvy)
{
  cv::Mat out(bgr.rows, bgr.cols, CV_8UC2);
  for (int y = 0; y < bgr.rows; ++y)
    for (int x = 0; x + 1 < bgr.cols; x += 2)
    {
      double y0, u0, v0, y1, u1, v1;
      bgrToYuv(bgr.at<cv::Vec3b>(y, x), &y0, &u0, &v0);
      bgrToYuv(bgr.at<cv::Vec3b>(y, x + 1), &y1, &u1, &v1);
      uint8_t* o = out.ptr<uint8_t>(y) + 2 * x;
      const uint8_t Y0 = cv::saturate_cast<uint8_t>(y0), Y1 = cv::saturate_cast<uint8_t>(y1);
      const uint8_t U = cv::saturate_cast<uint8_t>(0.5 * (u0 + u1)), V = cv::saturate_cast<uint8_t>(0.5 * (v0 + v1));
      if (uyvy)
      {
        o[0] = U, o[1] = Y0, o[2] = V, o[3] = Y1;
      }
      else
      {
        o[0] = Y0, o[1] = U, o[2] = Y1, o[3] = V;
      }
    }
  return out;
}

// The noise-free value of one output sample of the radiance (8-bit DN).
inline double sampleOf(const Config& cfg, const cv::Vec3d& r, int x, int y)
{
  if (isBayer(cfg.output))
    return r[bayerChannel(cfg.output, x, y)];
  if (cfg.projector == Projector::kNir)
    return r[2];  // the 850 nm band
  return 0.1 * r[0] + 0.6 * r[1] + 0.3 * r[2];
}

// Noise (Gaussian approximation of shot noise + read noise) on one plane of
// charges in DN, then the full well (blooming or clipping).
inline void exposePlane(const Config& cfg, std::mt19937& rng, cv::Mat* q)
{
  std::normal_distribution<double> gauss(0.0, 1.0);
  for (int y = 0; y < q->rows; ++y)
    for (int x = 0; x < q->cols; ++x)
    {
      double& s = q->at<double>(y, x);
      s += std::sqrt(std::max(0.0, s) * cfg.dn_per_electron + cfg.read_noise_dn * cfg.read_noise_dn) * gauss(rng);
    }
  const double fw = cfg.full_well_dn > 0 ? cfg.full_well_dn : 255.0;
  if (cfg.blooming)
    bloomColumns(q, fw);
  cv::min(*q, fw, *q);
}

// One frame of the radiance in the output encoding.
inline cv::Mat expose(const Config& cfg, std::mt19937& rng, const cv::Mat& radiance)
{
  const int W = cfg.width, H = cfg.height;
  const double fw = cfg.full_well_dn > 0 ? cfg.full_well_dn : 255.0;
  const bool three = !isBayer(cfg.output) && !isMono(cfg.output);
  if (three && !cfg.blooming && cfg.full_well_dn <= 0)
  {
    // The first version's sampling (noise drawn pixel by pixel, channel by channel).
    std::normal_distribution<double> gauss(0.0, 1.0);
    cv::Mat out(H, W, CV_8UC3);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        for (int k = 0; k < 3; ++k)
        {
          const double s = radiance.at<cv::Vec3d>(y, x)[k];
          const double n = std::sqrt(std::max(0.0, s) * cfg.dn_per_electron + cfg.read_noise_dn * cfg.read_noise_dn);
          out.at<cv::Vec3b>(y, x)[k] = cv::saturate_cast<uint8_t>(s + n * gauss(rng));
        }
    return out;
  }
  std::vector<cv::Mat> planes(three ? 3 : 1);
  for (size_t k = 0; k < planes.size(); ++k)
  {
    planes[k].create(H, W, CV_64F);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x)
        planes[k].at<double>(y, x) =
            three ? radiance.at<cv::Vec3d>(y, x)[k] : sampleOf(cfg, radiance.at<cv::Vec3d>(y, x), x, y);
    exposePlane(cfg, rng, &planes[k]);
  }
  cv::Mat out;
  if (cfg.output == Output::kMono16)
  {
    planes[0].convertTo(out, CV_16U, 65535.0 / fw);
    return out;
  }
  // 8-bit outputs: the full well is the top of the range.
  for (cv::Mat& p : planes)
    p.convertTo(p, CV_8U, 255.0 / fw);
  if (!three)
    return planes[0];
  cv::merge(planes, out);
  return out;
}

// The encoding's own layout of a bgr8 frame (rgb8, yuv422).
inline cv::Mat encode(const Config& cfg, const cv::Mat& frame)
{
  cv::Mat out;
  switch (cfg.output)
  {
    case Output::kRgb8:
      cv::cvtColor(frame, out, cv::COLOR_BGR2RGB);
      return out;
    case Output::kUyvy:
      return toYuv422(frame, true);
    case Output::kYuyv:
      return toYuv422(frame, false);
    default:
      return frame;
  }
}
}  // namespace detail

inline Frame render(const Config& cfg)
{
  std::mt19937 rng(cfg.seed);
  Frame f;
  f.encoding = encodingOf(cfg.output);
  const cv::Mat albedo = detail::albedoMap(cfg, rng);
  cv::Mat radiance = detail::rockRadiance(cfg, albedo);
  f.dots = detail::dotPositions(cfg, rng);
  detail::paintClutter(cfg, rng, &radiance, &f);
  const cv::Mat ambient_radiance = cfg.ambient_frame ? radiance.clone() : cv::Mat();
  detail::addDots(cfg, albedo, f.dots, &radiance, &f.light_centroids);
  const double fw = cfg.full_well_dn > 0 ? cfg.full_well_dn : 255.0;
  // Clipped: the dot's peak plus the rock under it reach the full well in
  // the projector's channel.
  const int ch = detail::projectorChannel(cfg.projector);
  for (size_t i = 0; i < f.dots.size(); ++i)
  {
    const cv::Point p(std::min(cfg.width - 1, std::max(0, int(std::lround(f.dots[i].x)))),
                      std::min(cfg.height - 1, std::max(0, int(std::lround(f.dots[i].y)))));
    f.clipped.push_back(radiance.at<cv::Vec3d>(p)[ch] >= fw ? 1 : 0);
  }
  f.image = detail::encode(cfg, detail::expose(cfg, rng, radiance));
  if (cfg.ambient_frame)
  {
    std::mt19937 ambient_rng(cfg.seed * 104729u + 3u);
    f.ambient = detail::encode(cfg, detail::expose(cfg, ambient_rng, ambient_radiance));
  }
  return f;
}

}  // namespace synthetic_dots
