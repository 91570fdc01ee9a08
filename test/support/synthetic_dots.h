// Synthetic dot frames with exact truth, for the SpotDetector gtest and its
// benchmark (independent of the scene simulator): a reddish textured rock lit
// by the sun, a grid of Gaussian dots integrated over the pixels (their
// radiance scales with the local albedo, like light on a real rock, and a
// little leaks into red and blue as on a Bayer sensor), shot and read noise,
// 8-bit clipping, and optional clutter (green specks, olive minerals,
// dot-sized green mineral blobs).
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace synthetic_dots
{

struct Config
{
  int width = 1024, height = 1024;
  int rows = 10, cols = 10;
  double pitch_px = 35.0;
  double roll_rad = 0.087;
  double position_jitter_px = 4.0;  // relief-like displacement of each dot
  double sigma_px = 2.0;
  double sun = 0.3;                  // 0 = night, 1 = brightest
  double albedo_min = 0.05, albedo_max = 0.45;
  double texture_px = 13.0;          // albedo feature size (2 cm at 1.5 m with fx = 1012 px)
  double dn_per_albedo = 400.0;      // red DN of albedo 1 at sun = 1
  double dot_to_sun_ratio = 4.0;     // dot peak radiance / sunlit radiance at sun = 1
  double read_noise_dn = 1.0;
  double dn_per_electron = 0.01;
  int green_specks = 0, olive_minerals = 0, green_blobs = 0;
  double clutter_clearance_px = 20.0;
  unsigned seed = 1;
};

struct Frame
{
  cv::Mat image;                        // bgr8
  std::vector<cv::Point2d> dots;        // true centres
  std::vector<cv::Point2d> clutter;     // centres of green clutter (specks, blobs)
};

inline double pixelFraction(int i, double c, double sigma)
{
  const double k = 1.0 / (std::sqrt(2.0) * sigma);
  return 0.5 * (std::erf((i + 0.5 - c) * k) - std::erf((i - 0.5 - c) * k));
}

inline Frame render(const Config& cfg)
{
  std::mt19937 rng(cfg.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int W = cfg.width, H = cfg.height;

  // Albedo: smooth random texture (features of texture_px) plus grain.
  const int cell = std::max(1, static_cast<int>(std::lround(cfg.texture_px)));
  cv::Mat coarse(H / cell + 3, W / cell + 3, CV_32F);
  for (int y = 0; y < coarse.rows; ++y)
    for (int x = 0; x < coarse.cols; ++x)
      coarse.at<float>(y, x) = static_cast<float>(uni(rng));
  cv::Mat albedo;
  cv::resize(coarse, albedo, cv::Size(coarse.cols * cell, coarse.rows * cell), 0, 0, cv::INTER_CUBIC);
  albedo = albedo(cv::Rect(cell, cell, W, H)).clone();
  for (int y = 0; y < H; ++y)
  {
    float* a = albedo.ptr<float>(y);
    for (int x = 0; x < W; ++x)
    {
      const double u = std::min(1.0, std::max(0.0, a[x] + 0.05 * (uni(rng) - 0.5)));
      a[x] = static_cast<float>(cfg.albedo_min + (cfg.albedo_max - cfg.albedo_min) * u);
    }
  }
  // Reflectance per channel (b, g, r) of the reddish rock, relative to red.
  const cv::Vec3d rock(0.35, 0.55, 1.0);
  cv::Mat radiance(H, W, CV_64FC3);
  for (int y = 0; y < H; ++y)
  {
    const float* a = albedo.ptr<float>(y);
    cv::Vec3d* r = radiance.ptr<cv::Vec3d>(y);
    for (int x = 0; x < W; ++x)
      r[x] = rock * (cfg.sun * cfg.dn_per_albedo * a[x]);
  }

  Frame f;
  // Dot positions: a rotated, jittered grid around the image centre.
  const double cr = std::cos(cfg.roll_rad), sr = std::sin(cfg.roll_rad);
  for (int r = 0; r < cfg.rows; ++r)
    for (int c = 0; c < cfg.cols; ++c)
    {
      const double u = (c - 0.5 * (cfg.cols - 1)) * cfg.pitch_px, v = (r - 0.5 * (cfg.rows - 1)) * cfg.pitch_px;
      f.dots.emplace_back(0.5 * (W - 1) + cr * u - sr * v + cfg.position_jitter_px * (uni(rng) - 0.5) * 2,
                          0.5 * (H - 1) + sr * u + cr * v + cfg.position_jitter_px * (uni(rng) - 0.5) * 2);
    }

  // Clutter painted into the rock (it reflects sunlight only).
  auto paint_patch = [&](double cx, double cy, double radius, const cv::Vec3d& refl, double albedo_v, bool soft) {
    const int r = static_cast<int>(std::ceil(radius * 2.5)) + 1;
    for (int y = std::max(0, int(cy) - r); y <= std::min(H - 1, int(cy) + r); ++y)
      for (int x = std::max(0, int(cx) - r); x <= std::min(W - 1, int(cx) + r); ++x)
      {
        const double d2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
        const double m = soft ? std::exp(-d2 / (2 * radius * radius)) : (d2 <= radius * radius ? 1.0 : 0.0);
        const cv::Vec3d mineral = refl * (cfg.sun * cfg.dn_per_albedo * albedo_v);
        radiance.at<cv::Vec3d>(y, x) = radiance.at<cv::Vec3d>(y, x) * (1.0 - m) + mineral * m;
      }
  };
  // Clutter lies between the dots (at least clutter_clearance_px from any):
  // a speck right on a dot is a different problem (an occlusion).
  auto random_point = [&]() {
    for (;;)
    {
      const cv::Point2d c(20 + uni(rng) * (W - 40), 20 + uni(rng) * (H - 40));
      bool clear = true;
      for (const cv::Point2d& d : f.dots)
        clear = clear && std::hypot(c.x - d.x, c.y - d.y) > cfg.clutter_clearance_px;
      if (clear)
        return c;
    }
  };
  // Clutter colours (b, g, r reflectance) as the scene simulator's.
  for (int i = 0; i < cfg.green_specks; ++i)
  {
    // A speck of 1-3 px seen through the optics (PSF sigma 0.7 px).
    const cv::Point2d c = random_point();
    paint_patch(c.x, c.y, std::hypot(0.25 + 0.5 * uni(rng), 0.7), cv::Vec3d(0.10, 0.40, 0.10), 1.0, true);
    f.clutter.push_back(c);
  }
  for (int i = 0; i < cfg.olive_minerals; ++i)
  {
    const cv::Point2d c = random_point();
    const double v = 0.10 + 0.08 * uni(rng);
    paint_patch(c.x, c.y, 3 + 6 * uni(rng), cv::Vec3d(0.55 * v, 1.05 * v, 0.90 * v), 1.0, false);
  }
  for (int i = 0; i < cfg.green_blobs; ++i)
  {
    const cv::Point2d c = random_point();
    paint_patch(c.x, c.y, cfg.sigma_px, cv::Vec3d(0.14, 0.60, 0.08), 1.0, true);
    f.clutter.push_back(c);
  }

  // Dots: light added on top of the rock, scaled by its albedo.
  const double peak_dn = cfg.dot_to_sun_ratio * cfg.dn_per_albedo;  // per unit albedo
  const cv::Vec3d leak(0.22, 1.0, 0.08);  // b, g, r response to 520 nm (as the simulator's)
  for (const cv::Point2d& p : f.dots)
  {
    const double flux_scale = 2 * M_PI * cfg.sigma_px * cfg.sigma_px * peak_dn;
    const int R = static_cast<int>(std::ceil(5 * cfg.sigma_px)) + 1;
    const int x0 = std::max(0, int(p.x) - R), x1 = std::min(W - 1, int(p.x) + R);
    const int y0 = std::max(0, int(p.y) - R), y1 = std::min(H - 1, int(p.y) + R);
    for (int y = y0; y <= y1; ++y)
    {
      const double fy = pixelFraction(y, p.y, cfg.sigma_px);
      for (int x = x0; x <= x1; ++x)
      {
        const double e = flux_scale * fy * pixelFraction(x, p.x, cfg.sigma_px) * albedo.at<float>(y, x);
        radiance.at<cv::Vec3d>(y, x) += leak * e;
      }
    }
  }

  // Shot noise (Gaussian approximation) + read noise, 8-bit quantisation.
  std::normal_distribution<double> gauss(0.0, 1.0);
  f.image.create(H, W, CV_8UC3);
  for (int y = 0; y < H; ++y)
  {
    const cv::Vec3d* r = radiance.ptr<cv::Vec3d>(y);
    cv::Vec3b* o = f.image.ptr<cv::Vec3b>(y);
    for (int x = 0; x < W; ++x)
      for (int k = 0; k < 3; ++k)
      {
        const double s = r[x][k];
        const double noise =
            std::sqrt(std::max(0.0, s) * cfg.dn_per_electron + cfg.read_noise_dn * cfg.read_noise_dn) * gauss(rng);
        o[x][k] = cv::saturate_cast<uint8_t>(s + noise);
      }
  }
  return f;
}

}  // namespace synthetic_dots
