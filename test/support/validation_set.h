// The path-traced validation set (test/data/validation/README.md): scenes
// rendered once with Blender's Cycles (tools/validation/), independent of
// the package's simulator, with exact truth; the camera's own effects are
// applied here, seeded, so that each frame can be read with many noise seeds.
//
// Contract: loadValidationSet(dir) reads dir/index.yaml (the cases, the
// sensor) and each scene's dir/<scene>/truth.yaml; it throws
// std::runtime_error naming the file on anything missing or malformed.
// Images are the scene's region of interest (SceneTruth::roi(), full-frame
// pixels, even offsets: the RGGB phase of the full frame); SceneTruth::camera
// is the full sensor's model and roiCamera() the one of the ROI images
// (CameraModel::windowed, as a camera_info with that ROI). Truth pixels are
// full-frame, OpenCV convention (pixel centres at integers); points in
// metres, camera optical frame. The ambient passes are stored as the colour
// sensor's RGGB mosaic; bgr8 and bgr16 frames are demosaiced from it after
// the noise (OpenCV's bilinear), as a colour camera's driver does. Light
// levels: DN of the 8-bit scale (255 = the full well). ROS-free: OpenCV,
// Eigen, yaml-cpp.
#pragma once

#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <yaml-cpp/yaml.h>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "structured_light_stabilizer/detection/spot_detector.h"

namespace structured_light_stabilizer
{
namespace test
{
namespace validation
{

struct BeamTruth
{
  int beam = -1;
  bool hit = false;                                        // the beam meets the scene
  bool visible = false;                                    // its hit point is seen by the camera (nothing in between)
  Eigen::Vector3d point = Eigen::Vector3d::Constant(NAN);  // hit point, camera frame (m)
  cv::Point2d pixel{NAN, NAN};                             // the hit point's pixel
  bool has_light = false;                                  // some of its light reaches the image
  cv::Point2d light_centroid{NAN, NAN};                    // intensity-weighted centroid of this beam's light alone
  double light_sum = 0, light_peak = 0, light_sigma_px = 0;
  bool window_cut = false;  // the centroid's window was cut by the ROI's edge
  // The sun's and the sky's passes under the dot (where its light is at
  // least half its peak): linear units, as light_peak.
  double sun_under_dot = NAN, sky_under_dot = NAN;
};

struct FrameTruth
{
  int index = 0;
  double t = 0;                                                         // s
  bool projector = false;                                               // the projector lights this frame
  Eigen::Isometry3d camera_from_world = Eigen::Isometry3d::Identity();  // world = the rock's (or board's) scene
  bool has_board = false;
  Eigen::Isometry3d camera_from_board = Eigen::Isometry3d::Identity();
  // Linear units per PNG count of each stored pass: "sun", "sky" and "proj"
  // on projector frames, "day" (the sun and the day's sky) on projector-off
  // frames, "sun" and "proj" on board views.
  std::map<std::string, double> scale;
  std::vector<BeamTruth> beams;
};

// DN (8-bit scale) per linear unit of each pass: a lighting case of a scene
// ("day", "dusk", "night"; "board" for board views). A projector-off frame's
// "day" pass reads at `sun` (only the day's lighting has it).
struct Lighting
{
  std::string name;
  double sun = 0, sky = 0, proj = 0;
};

struct SceneTruth
{
  std::string name, kind, dir;
  CameraModel camera;  // the full sensor
  SensorWindow window;
  double centroid_window_px = 0;
  std::vector<FrameTruth> frames;
  std::map<std::string, Lighting> lighting;
  // Board scenes: the print (inner corners, square and white margin, m).
  int board_cols = 0, board_rows = 0;
  double square_m = 0, margin_m = 0;
  cv::Rect roi() const { return window.roi(camera.width, camera.height); }
  CameraModel roiCamera() const { return camera.windowed(window); }
  const FrameTruth& frame(int index) const
  {
    for (const FrameTruth& f : frames)
      if (f.index == index)
        return f;
    throw std::runtime_error("validation set: scene " + name + " has no frame " + std::to_string(index));
  }
};

// The camera applied at load time: a linear sensor of `full_well_e`
// electrons at 255 DN, Poisson shot noise, Gaussian read noise, clipping at
// the full well, then 8-bit (or 12-bit, MSB-aligned in 16) quantisation.
// The renders' channels are the sensor's own under sunlight; the green
// projector's light is seen with `projector_rgb` (R, G, B relative to G).
struct Sensor
{
  double full_well_e = 10000;
  double read_noise_e = 6;
  cv::Vec3d projector_rgb{0.09, 1.0, 0.28};
  PixelFormat output = PixelFormat::kBgr8;  // kBgr8, kBayerRggb8 or kBgr16
  int bits = 8;                             // kBgr16: 12 (the converter's bits)
  bool noise = true;
};

struct CaseSpec
{
  std::string name, scene, lighting;
  bool strobe = false;
  std::string half;             // "tuning" or "heldout"
  double min_dot_to_sun = 0.0;  // beams scored: the dot at least this x the rock under it (day single frame)
  std::vector<int> on_frames;   // the projector frames of the sequence, in order (the first is locked)
};

struct ValidationSet
{
  std::string dir;
  Sensor sensor;
  std::vector<CaseSpec> cases;
  std::map<std::string, SceneTruth> scenes;
  const SceneTruth& scene(const std::string& name) const
  {
    auto it = scenes.find(name);
    if (it == scenes.end())
      throw std::runtime_error("validation set: no scene " + name);
    return it->second;
  }
};

namespace detail
{

inline std::string where(const std::string& file, const YAML::Node& n)
{
  return file + ":" + std::to_string(n.Mark().line + 1);
}

inline YAML::Node need(const YAML::Node& n, const char* key, const std::string& file)
{
  const YAML::Node v = n[key];
  if (!v)
    throw std::runtime_error("validation set: " + where(file, n) + ": missing '" + key + "'");
  return v;
}

inline Eigen::Isometry3d isometry(const YAML::Node& rows, const std::string& file)
{
  Eigen::Matrix4d m;
  if (!rows.IsSequence() || rows.size() != 4)
    throw std::runtime_error("validation set: " + where(file, rows) + ": not a 4 x 4 matrix");
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c)
      m(r, c) = rows[r][c].as<double>();
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = m.topLeftCorner<3, 3>();
  T.translation() = m.topRightCorner<3, 1>();
  return T;
}

inline BeamTruth beam(const YAML::Node& n)
{
  BeamTruth b;
  b.beam = n["beam"].as<int>();
  b.hit = n["hit"].as<bool>();
  if (!b.hit)
    return b;
  b.visible = n["visible"].as<bool>();
  for (int i = 0; i < 3; ++i)
    b.point[i] = n["point_camera"][i].as<double>();
  b.pixel = {n["pixel"][0].as<double>(), n["pixel"][1].as<double>()};
  if (n["light_centroid"])
  {
    b.has_light = true;
    b.light_centroid = {n["light_centroid"][0].as<double>(), n["light_centroid"][1].as<double>()};
    b.light_sum = n["light_sum"].as<double>();
    b.light_peak = n["light_peak"].as<double>();
    b.light_sigma_px = n["light_sigma_px"].as<double>();
    b.window_cut = n["window_cut"].as<bool>();
    b.sun_under_dot = n["sun_under_dot"].as<double>();
    b.sky_under_dot = n["sky_under_dot"].as<double>();
  }
  return b;
}

inline SceneTruth scene(const std::string& dir, const std::string& name)
{
  SceneTruth s;
  s.name = name;
  s.dir = dir + "/" + name;
  const std::string file = s.dir + "/truth.yaml";
  YAML::Node root;
  try
  {
    root = YAML::LoadFile(file);
  }
  catch (const YAML::Exception& e)
  {
    throw std::runtime_error("validation set: " + file + ": " + e.what());
  }
  s.kind = need(root, "kind", file).as<std::string>();
  const YAML::Node cam = need(root, "camera", file);
  s.camera.width = cam["width"].as<int>();
  s.camera.height = cam["height"].as<int>();
  s.camera.fx = cam["K"][0][0].as<double>();
  s.camera.fy = cam["K"][1][1].as<double>();
  s.camera.cx = cam["K"][0][2].as<double>();
  s.camera.cy = cam["K"][1][2].as<double>();
  s.centroid_window_px = need(root, "centroid_window_px", file).as<double>();
  const YAML::Node roi = need(root, "roi", file);
  s.window.x_offset = roi[0].as<int>();
  s.window.y_offset = roi[1].as<int>();
  s.window.width = roi[2].as<int>();
  s.window.height = roi[3].as<int>();
  for (const auto& kv : need(root, "lighting", file))
  {
    Lighting l;
    l.name = kv.first.as<std::string>();
    l.sun = kv.second["sun"].as<double>();
    l.sky = kv.second["sky"].as<double>();
    l.proj = kv.second["proj"].as<double>();
    s.lighting[kv.first.as<std::string>()] = l;
  }
  if (root["board"])
  {
    s.board_cols = root["board"]["inner_corners"][0].as<int>();
    s.board_rows = root["board"]["inner_corners"][1].as<int>();
    s.square_m = root["board"]["square_m"].as<double>();
    s.margin_m = root["board"]["margin_m"].as<double>();
  }
  for (const YAML::Node& fn : need(root, "frames", file))
  {
    FrameTruth f;
    f.index = fn["index"].as<int>();
    f.t = fn["t"].as<double>();
    f.projector = fn["projector"].as<bool>();
    f.camera_from_world = isometry(need(fn, "T_camera_world", file), file);
    if (fn["T_camera_board"])
    {
      f.has_board = true;
      f.camera_from_board = isometry(fn["T_camera_board"], file);
    }
    for (const auto& kv : need(fn, "scale", file))
      f.scale[kv.first.as<std::string>()] = kv.second.as<double>();
    if (f.projector)
      for (const YAML::Node& bn : need(fn, "beams", file))
        f.beams.push_back(beam(bn));
    s.frames.push_back(f);
  }
  return s;
}

inline cv::Mat readPng(const std::string& path, double scale)
{
  const cv::Mat raw = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (raw.empty() || raw.depth() != CV_16U || raw.channels() != 1)
    throw std::runtime_error("validation set: cannot read " + path + " as a 16-bit, one-channel PNG");
  cv::Mat f;
  raw.convertTo(f, CV_32F, scale);
  return f;
}

// The mosaic from its stored quadrants [R, G(odd x); G(odd y), B].
inline cv::Mat interleave(const cv::Mat& q)
{
  const int h = q.rows / 2, w = q.cols / 2;
  cv::Mat m(q.size(), CV_32F);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
    {
      m.at<float>(2 * y, 2 * x) = q.at<float>(y, x);
      m.at<float>(2 * y, 2 * x + 1) = q.at<float>(y, w + x);
      m.at<float>(2 * y + 1, 2 * x) = q.at<float>(h + y, x);
      m.at<float>(2 * y + 1, 2 * x + 1) = q.at<float>(h + y, w + x);
    }
  return m;
}

// Channel (0 = B, 1 = G, 2 = R) of RGGB site (x, y) of an even-offset ROI.
inline int rggbChannel(int x, int y)
{
  return (y & 1) == 0 ? ((x & 1) == 0 ? 2 : 1) : ((x & 1) == 0 ? 1 : 0);
}

}  // namespace detail

inline ValidationSet loadValidationSet(const std::string& dir)
{
  ValidationSet set;
  set.dir = dir;
  const std::string file = dir + "/index.yaml";
  YAML::Node root;
  try
  {
    root = YAML::LoadFile(file);
  }
  catch (const YAML::Exception& e)
  {
    throw std::runtime_error("validation set: " + file + ": " + e.what());
  }
  const YAML::Node sensor = detail::need(root, "sensor", file);
  set.sensor.full_well_e = sensor["full_well_e"].as<double>();
  set.sensor.read_noise_e = sensor["read_noise_e"].as<double>();
  for (int c = 0; c < 3; ++c)
    set.sensor.projector_rgb[c] = sensor["projector_rgb"][c].as<double>();
  for (const YAML::Node& cn : detail::need(root, "cases", file))
  {
    CaseSpec c;
    c.name = cn["name"].as<std::string>();
    c.scene = cn["scene"].as<std::string>();
    c.lighting = cn["lighting"].as<std::string>();
    c.strobe = cn["strobe"] && cn["strobe"].as<bool>();
    c.half = cn["half"].as<std::string>();
    if (c.half != "tuning" && c.half != "heldout")
      throw std::runtime_error("validation set: " + detail::where(file, cn) + ": half is tuning or heldout");
    if (cn["min_dot_to_sun"])
      c.min_dot_to_sun = cn["min_dot_to_sun"].as<double>();
    if (!set.scenes.count(c.scene))
      set.scenes[c.scene] = detail::scene(dir, c.scene);
    const SceneTruth& s = set.scenes[c.scene];
    if (!s.lighting.count(c.lighting))
      throw std::runtime_error("validation set: " + detail::where(file, cn) + ": scene " + c.scene +
                               " has no lighting " + c.lighting);
    for (const FrameTruth& f : s.frames)
      if (f.projector)
        c.on_frames.push_back(f.index);
    set.cases.push_back(c);
  }
  return set;
}

// The noise-free linear passes of one frame (ROI size, CV_32FC1): the
// ambient passes as RGGB mosaics (sun, sky; or day), the projector's light
// on the rock's green albedo at every pixel (empty off the projector frames).
struct Passes
{
  std::map<std::string, cv::Mat> mosaic;
  cv::Mat proj;
};

inline Passes loadPasses(const SceneTruth& s, const FrameTruth& f)
{
  Passes p;
  const std::string base = s.dir + "/f" + std::to_string(f.index) + "_";
  for (const auto& kv : f.scale)
  {
    cv::Mat m = detail::readPng(base + kv.first + ".png", kv.second);
    if (m.size() != s.roi().size())
      throw std::runtime_error("validation set: " + base + kv.first + ".png is not the scene's ROI size");
    if (kv.first == "proj")
      p.proj = m;
    else
      p.mosaic[kv.first] = detail::interleave(m);
  }
  return p;
}

// The mean signal of a frame under a lighting case (DN of the 8-bit scale,
// an RGGB mosaic, CV_32FC1), with or without the projector.
inline cv::Mat exposeFrame(const SceneTruth& s, const Passes& p, const Lighting& l, bool projector_on,
                           const Sensor& sensor)
{
  cv::Mat dn = cv::Mat::zeros(s.roi().size(), CV_32F);
  if (p.mosaic.count("day"))
  {
    const Lighting& day = s.lighting.at("day");
    if (l.sun <= 0 || std::abs(l.sky / l.sun - day.sky / day.sun) > 1e-9 * day.sky / day.sun)
      throw std::runtime_error("validation set: the projector-off frames of " + s.name +
                               " are the day's light only (lighting " + l.name + " asked)");
    dn += p.mosaic.at("day") * l.sun;
  }
  if (p.mosaic.count("sun"))
    dn += p.mosaic.at("sun") * l.sun;
  if (p.mosaic.count("sky") && l.sky > 0)
    dn += p.mosaic.at("sky") * l.sky;
  if (projector_on && !p.proj.empty())
  {
    const double bgr[3] = {sensor.projector_rgb[2], sensor.projector_rgb[1], sensor.projector_rgb[0]};
    for (int y = 0; y < dn.rows; ++y)
      for (int x = 0; x < dn.cols; ++x)
        dn.at<float>(y, x) += static_cast<float>(l.proj * bgr[detail::rggbChannel(x, y)] * p.proj.at<float>(y, x));
  }
  return dn;
}

// The dot's peak over the rock under it (sun and sky, green) for a beam
// under a lighting case; +inf where no ambient light reaches the rock.
inline double dotToRock(const BeamTruth& b, const Lighting& l)
{
  const double rock = l.sun * b.sun_under_dot + l.sky * b.sky_under_dot;
  return rock > 0 ? l.proj * b.light_peak / rock : INFINITY;
}

// The camera's image of a mean signal (an RGGB mosaic, DN): photon shot
// noise (Poisson) and read noise drawn from `seed`, clipped at the full
// well, quantised; sensor.output bayer_rggb8 as it is, bgr8 and bgr16 (at
// sensor.bits, MSB-aligned) demosaiced (OpenCV's bilinear).
inline cv::Mat capture(const cv::Mat& mean_dn, const Sensor& sensor, uint64_t seed)
{
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 12345);
  std::normal_distribution<double> gauss(0.0, 1.0);
  const double e_per_dn = sensor.full_well_e / 255.0;
  const bool wide = sensor.output == PixelFormat::kBgr16;
  const double levels = wide ? std::pow(2.0, sensor.bits) - 1.0 : 255.0;
  cv::Mat raw(mean_dn.size(), wide ? CV_16UC1 : CV_8UC1);
  for (int y = 0; y < mean_dn.rows; ++y)
    for (int x = 0; x < mean_dn.cols; ++x)
    {
      double e = std::max(0.0, static_cast<double>(mean_dn.at<float>(y, x))) * e_per_dn;
      if (sensor.noise)
      {
        e = e < 50.0 ? std::poisson_distribution<int>(e)(rng) : e + std::sqrt(e) * gauss(rng);
        e = std::min(std::max(e, 0.0), sensor.full_well_e) + sensor.read_noise_e * gauss(rng);
      }
      const double v =
          std::min(levels, std::max(0.0, std::round(std::min(e, sensor.full_well_e) / sensor.full_well_e * levels)));
      if (wide)
        raw.at<uint16_t>(y, x) = static_cast<uint16_t>(v * std::pow(2.0, 16 - sensor.bits));
      else
        raw.at<uint8_t>(y, x) = static_cast<uint8_t>(v);
    }
  if (sensor.output == PixelFormat::kBayerRggb8)
    return raw;
  cv::Mat bgr;
  cv::cvtColor(raw, bgr, cv::COLOR_BayerBG2BGR);  // OpenCV's name of RGGB (R at (0, 0))
  return bgr;
}

}  // namespace validation
}  // namespace test
}  // namespace structured_light_stabilizer
