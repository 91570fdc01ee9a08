// Synthetic dot frames with exact truth, for the SpotDetector gtests and its
// benchmark, written independently of the scene simulator: a reddish rock
// lit by the sun, with a coarse albedo (texture_px features), optionally a
// fine multiplicative texture (1-3 cm period, +-25 %) with a
// little hue of its own per channel; a grid of dots whose light is the
// beam's footprint (a Gaussian, integrated over each pixel) times the albedo
// under each pixel at the projector's wavelength, then blurred by the optics
// (psf_sigma_px) like the rock itself; the sensor's response to the
// projector's colour in each channel; shot and read noise per sample;
// clipping at the full well, optionally with blooming along the columns
// (charge conserved); outputs in the encodings a ROS camera driver sends
// (bgr8, rgb8, Bayer, mono8/mono16, yuv422); optional clutter (green
// specks, olive minerals, dot-sized green mineral blobs) and a projector-off
// frame of the same scene with its own noise (the strobed ambient).
//
// The truth of a dot is the centre of its footprint (the beam's hit point).
// With every option at its default the frames are those of the generator's
// first version (same draws), so earlier figures stay comparable.
#pragma once

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace synthetic_dots
{

enum class Output
{
  kBgr8,
  kRgb8,
  kBayerRggb8,
  kBayerBggr8,
  kBayerGbrg8,
  kBayerGrbg8,
  kMono8,
  kMono16,
  kUyvy,
  kYuyv,
};

// green 520 nm, red 650 nm, blue 450 nm on a colour sensor; nir 850 nm (with
// a colour output: a sensor without IR cut, all channels alike).
enum class Projector
{
  kGreen,
  kRed,
  kBlue,
  kNir,
};

struct Config
{
  int width = 1024, height = 1024;
  int rows = 10, cols = 10;
  double pitch_px = 35.0;
  double roll_rad = 0.087;
  double position_jitter_px = 4.0;  // relief-like displacement of each dot
  double sigma_px = 2.0;            // the dot's image sigma (footprint and optics together)
  double sun = 0.3;                 // 0 = night, 1 = brightest
  double albedo_min = 0.05, albedo_max = 0.45;
  double texture_px = 13.0;       // coarse albedo feature size (2 cm at 1.5 m with fx = 1012 px)
  double dn_per_albedo = 400.0;   // red DN of albedo 1 at sun = 1
  double dot_to_sun_ratio = 4.0;  // dot peak radiance / sunlit radiance at sun = 1
  double read_noise_dn = 1.0;
  double dn_per_electron = 0.01;
  int green_specks = 0, olive_minerals = 0, green_blobs = 0;
  double clutter_clearance_px = 20.0;
  unsigned seed = 1;

  // Fine texture: albedo x (1 + fine_texture_amplitude n(p)), n band-limited
  // to fine_texture_px features, in [-1, 1]; 0 = off.
  double fine_texture_px = 0.0;
  double fine_texture_amplitude = 0.25;
  double hue_amplitude = 0.0;  // independent part per channel (relative)
  // Optics: the footprint is sqrt(sigma^2 - psf^2) wide, the albedo under it
  // is sharp, the optics blur both (0 = no blur, the first version).
  double psf_sigma_px = 0.0;
  // Full well in 8-bit DN: above it a sample clips; with blooming the charge
  // above it spills to the neighbours in its column (conserved). 0 = 255.
  double full_well_dn = 0.0;
  bool blooming = false;
  Projector projector = Projector::kGreen;
  Output output = Output::kBgr8;
  // Mono/nir: the rock's reflectance at 850 nm over red's, and the sun in a
  // NIR band-pass filter relative to the visible channels.
  double nir_rock_ratio = 1.2;
  double nir_sun_scale = 0.3;
  bool ambient_frame = false;  // also render the projector-off frame
};

struct Frame
{
  cv::Mat image;                  // in cfg.output's encoding (CV_8UC3 bgr8/rgb8, 8UC1, 16UC1, 8UC2)
  cv::Mat ambient;                // projector off, same encoding, own noise (with ambient_frame)
  std::string encoding;           // the sensor_msgs name
  std::vector<cv::Point2d> dots;  // true centres (footprint centres)
  std::vector<uint8_t> clipped;   // per dot: its noise-free peak reaches the full well
  // Per dot: the centroid of its light (first moment of footprint x albedo;
  // the optics' blur keeps it), which the albedo pulls off the hit point: the
  // bias left when nothing tells the albedo (by night).
  std::vector<cv::Point2d> light_centroids;
  std::vector<cv::Point2d> clutter;  // centres of green clutter (specks, blobs)
};

inline const char* encodingOf(Output o)
{
  static const char* kNames[] = {"bgr8",        "rgb8",  "bayer_rggb8", "bayer_bggr8", "bayer_gbrg8",
                                 "bayer_grbg8", "mono8", "mono16",      "yuv422",      "yuv422_yuy2"};
  return kNames[static_cast<int>(o)];
}

inline double pixelFraction(int i, double c, double sigma)
{
  const double k = 1.0 / (std::sqrt(2.0) * sigma);
  return 0.5 * (std::erf((i + 0.5 - c) * k) - std::erf((i - 0.5 - c) * k));
}

namespace detail
{
// Band-limited noise in [0, 1] with features of `cell` px: random values on a
// grid, cubic interpolation (the first version's coarse albedo).
inline cv::Mat smoothNoise(std::mt19937& rng, int W, int H, double feature_px)
{
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int cell = std::max(1, static_cast<int>(std::lround(feature_px)));
  cv::Mat coarse(H / cell + 3, W / cell + 3, CV_32F);
  for (int y = 0; y < coarse.rows; ++y)
    for (int x = 0; x < coarse.cols; ++x)
      coarse.at<float>(y, x) = static_cast<float>(uni(rng));
  cv::Mat out;
  cv::resize(coarse, out, cv::Size(coarse.cols * cell, coarse.rows * cell), 0, 0, cv::INTER_CUBIC);
  return out(cv::Rect(cell, cell, W, H)).clone();
}

// Albedo per channel (b, g, r) at each pixel: the coarse albedo with grain
// (first version), times the fine texture and the hue.
inline cv::Mat albedoMap(const Config& cfg, std::mt19937& rng)
{
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int W = cfg.width, H = cfg.height;
  cv::Mat albedo = smoothNoise(rng, W, H, cfg.texture_px);
  for (int y = 0; y < H; ++y)
  {
    float* a = albedo.ptr<float>(y);
    for (int x = 0; x < W; ++x)
    {
      const double u = std::min(1.0, std::max(0.0, a[x] + 0.05 * (uni(rng) - 0.5)));
      a[x] = static_cast<float>(cfg.albedo_min + (cfg.albedo_max - cfg.albedo_min) * u);
    }
  }
  cv::Mat out(H, W, CV_32FC3);
  std::mt19937 fine_rng(cfg.seed * 7919u + 17u);  // a stream of its own: default frames unchanged
  cv::Mat fine, hue[3];
  if (cfg.fine_texture_px > 0)
    fine = smoothNoise(fine_rng, W, H, cfg.fine_texture_px);
  for (int k = 0; k < 3 && cfg.hue_amplitude > 0; ++k)
    hue[k] = smoothNoise(fine_rng, W, H, std::max(2.0, cfg.fine_texture_px > 0 ? cfg.fine_texture_px : cfg.texture_px));
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
    {
      double a = albedo.at<float>(y, x);
      if (!fine.empty())
        a *= 1.0 + cfg.fine_texture_amplitude * (2.0 * fine.at<float>(y, x) - 1.0);
      cv::Vec3f& o = out.at<cv::Vec3f>(y, x);
      for (int k = 0; k < 3; ++k)
        o[k] = static_cast<float>(
            a * (hue[k].empty() ? 1.0 : 1.0 + cfg.hue_amplitude * (2.0 * hue[k].at<float>(y, x) - 1.0)));
    }
  return out;
}

// Reflectance of the rock per channel (b, g, r) relative to red; for a nir
// projector the red slot holds the 850 nm band.
inline cv::Vec3d rockColour(const Config& cfg)
{
  if (cfg.projector == Projector::kNir)
    return cv::Vec3d(0.35, 0.55, cfg.nir_rock_ratio * cfg.nir_sun_scale);
  return cv::Vec3d(0.35, 0.55, 1.0);
}

// The sensor's response (b, g, r) to the projector's light; the channel of
// the projector's own colour is 1.
inline cv::Vec3d projectorResponse(Projector p)
{
  switch (p)
  {
    case Projector::kRed:
      return cv::Vec3d(0.04, 0.10, 1.0);
    case Projector::kBlue:
      return cv::Vec3d(1.0, 0.20, 0.03);
    case Projector::kNir:
      return cv::Vec3d(0.0, 0.0, 1.0);
    default:
      return cv::Vec3d(0.22, 1.0, 0.08);  // 520 nm (as the scene simulator's)
  }
}

// The albedo channel that reflects the projector's wavelength.
inline int projectorChannel(Projector p)
{
  return p == Projector::kBlue ? 0 : p == Projector::kGreen ? 1 : 2;
}

inline std::vector<cv::Point2d> dotPositions(const Config& cfg, std::mt19937& rng)
{
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::vector<cv::Point2d> dots;
  const double cr = std::cos(cfg.roll_rad), sr = std::sin(cfg.roll_rad);
  for (int r = 0; r < cfg.rows; ++r)
    for (int c = 0; c < cfg.cols; ++c)
    {
      const double u = (c - 0.5 * (cfg.cols - 1)) * cfg.pitch_px, v = (r - 0.5 * (cfg.rows - 1)) * cfg.pitch_px;
      const double jy = uni(rng), jx = uni(rng);  // sequenced draws (docs/testing.md)
      dots.emplace_back(0.5 * (cfg.width - 1) + cr * u - sr * v + cfg.position_jitter_px * (jx - 0.5) * 2,
                        0.5 * (cfg.height - 1) + sr * u + cr * v + cfg.position_jitter_px * (jy - 0.5) * 2);
    }
  return dots;
}

// Clutter painted into the rock's radiance (it reflects sunlight only),
// between the dots (a speck right on a dot is an occlusion, another problem).
inline void paintClutter(const Config& cfg, std::mt19937& rng, cv::Mat* radiance, Frame* f)
{
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const int W = cfg.width, H = cfg.height;
  auto paint = [&](double cx, double cy, double radius, const cv::Vec3d& refl, bool soft)
  {
    const int r = static_cast<int>(std::ceil(radius * 2.5)) + 1;
    for (int y = std::max(0, int(cy) - r); y <= std::min(H - 1, int(cy) + r); ++y)
      for (int x = std::max(0, int(cx) - r); x <= std::min(W - 1, int(cx) + r); ++x)
      {
        const double d2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
        const double m = soft ? std::exp(-d2 / (2 * radius * radius)) : (d2 <= radius * radius ? 1.0 : 0.0);
        const cv::Vec3d mineral = refl * (cfg.sun * cfg.dn_per_albedo);
        radiance->at<cv::Vec3d>(y, x) = radiance->at<cv::Vec3d>(y, x) * (1.0 - m) + mineral * m;
      }
  };
  auto random_point = [&]()
  {
    for (;;)
    {
      const double fy = uni(rng), fx = uni(rng);  // sequenced draws (docs/testing.md)
      const cv::Point2d c(20 + fx * (W - 40), 20 + fy * (H - 40));
      bool clear = true;
      for (const cv::Point2d& d : f->dots)
        clear = clear && std::hypot(c.x - d.x, c.y - d.y) > cfg.clutter_clearance_px;
      if (clear)
        return c;
    }
  };
  for (int i = 0; i < cfg.green_specks; ++i)
  {
    const cv::Point2d c = random_point();  // a speck of 1-3 px seen through the optics (PSF sigma 0.7 px)
    paint(c.x, c.y, std::hypot(0.25 + 0.5 * uni(rng), 0.7), cv::Vec3d(0.10, 0.40, 0.10), true);
    f->clutter.push_back(c);
  }
  for (int i = 0; i < cfg.olive_minerals; ++i)
  {
    const cv::Point2d c = random_point();
    const double v = 0.10 + 0.08 * uni(rng);
    paint(c.x, c.y, 3 + 6 * uni(rng), cv::Vec3d(0.55 * v, 1.05 * v, 0.90 * v), false);
  }
  for (int i = 0; i < cfg.green_blobs; ++i)
  {
    const cv::Point2d c = random_point();
    paint(c.x, c.y, cfg.sigma_px, cv::Vec3d(0.14, 0.60, 0.08), true);
    f->clutter.push_back(c);
  }
}

// Adds the dots' light (footprint x albedo at the projector's wavelength,
// blurred by the optics) to the radiance; the centroid of each dot's light
// into *light.
inline void addDots(const Config& cfg, const cv::Mat& albedo, const std::vector<cv::Point2d>& dots, cv::Mat* radiance,
                    std::vector<cv::Point2d>* light_centroids)
{
  const double psf = std::min(cfg.psf_sigma_px, 0.95 * cfg.sigma_px);
  const double foot = std::sqrt(cfg.sigma_px * cfg.sigma_px - psf * psf);
  const double peak_dn = cfg.dot_to_sun_ratio * cfg.dn_per_albedo;  // per unit albedo
  const cv::Vec3d response = projectorResponse(cfg.projector);
  const int ch = projectorChannel(cfg.projector);
  for (const cv::Point2d& p : dots)
  {
    const double flux_scale = 2 * M_PI * foot * foot * peak_dn;
    const int R = static_cast<int>(std::ceil(5 * cfg.sigma_px)) + 1;
    const cv::Rect box =
        cv::Rect(int(p.x) - R, int(p.y) - R, 2 * R + 1, 2 * R + 1) & cv::Rect(0, 0, cfg.width, cfg.height);
    cv::Mat light(box.size(), CV_64F);
    for (int y = 0; y < box.height; ++y)
    {
      const double fy = pixelFraction(box.y + y, p.y, foot);
      for (int x = 0; x < box.width; ++x)
        light.at<double>(y, x) =
            flux_scale * fy * pixelFraction(box.x + x, p.x, foot) * albedo.at<cv::Vec3f>(box.y + y, box.x + x)[ch];
    }
    const cv::Moments m = cv::moments(light);
    light_centroids->emplace_back(m.m00 > 0 ? box.x + m.m10 / m.m00 : p.x, m.m00 > 0 ? box.y + m.m01 / m.m00 : p.y);
    if (psf > 0)
      cv::GaussianBlur(light, light, cv::Size(0, 0), psf, psf, cv::BORDER_CONSTANT);
    for (int y = 0; y < box.height; ++y)
      for (int x = 0; x < box.width; ++x)
        radiance->at<cv::Vec3d>(box.y + y, box.x + x) += response * light.at<double>(y, x);
  }
}

// The rock's sunlit radiance (b, g, r), blurred by the optics.
inline cv::Mat rockRadiance(const Config& cfg, const cv::Mat& albedo)
{
  const cv::Vec3d rock = rockColour(cfg);
  cv::Mat radiance(cfg.height, cfg.width, CV_64FC3);
  for (int y = 0; y < cfg.height; ++y)
  {
    const cv::Vec3f* a = albedo.ptr<cv::Vec3f>(y);
    cv::Vec3d* r = radiance.ptr<cv::Vec3d>(y);
    for (int x = 0; x < cfg.width; ++x)
      for (int k = 0; k < 3; ++k)
        r[x][k] = rock[k] * cfg.sun * cfg.dn_per_albedo * a[x][k];
  }
  if (cfg.psf_sigma_px > 0)
    cv::GaussianBlur(radiance, radiance, cv::Size(0, 0), cfg.psf_sigma_px, cfg.psf_sigma_px, cv::BORDER_REFLECT);
  return radiance;
}
}  // namespace detail
}  // namespace synthetic_dots

#include "synthetic_dots_sensor.h"
