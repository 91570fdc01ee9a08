// The Simulator: builds the scene once, then renders a frame stage by stage
// (rig pose, clutter and dots as splats, the rock's radiance, then per row
// the splats, the sensor's noise and quantisation).
#include "structured_light_stabilizer/sim/render/simulator.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <utility>

#include "sim/render/brightness.h"
#include "sim/render/clutter.h"
#include "sim/render/frame_geometry.h"
#include "sim/render/motion_blur.h"
#include "sim/render/noise.h"
#include "sim/render/optics.h"
#include "sim/render/projector_dots.h"
#include "sim/render/rig_motion.h"
#include "sim/render/rock_render.h"
#include "sim/render/rock_surface.h"
#include "sim/render/sensor.h"
#include "sim/render/spectral.h"
#include "sim/render/splat.h"
#include "sim/render/target_board.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

// The camera's pose at t = 0 in the rock frame: the rock's mean plane at
// distance_m along the optical axis, tilted about x then y.
Eigen::Isometry3d rockFromCamera0(const RockParams& rc)
{
  const Eigen::Matrix3d R_tilt = (Eigen::AngleAxisd(rc.tilt_x_rad, Eigen::Vector3d::UnitX()) *
                                  Eigen::AngleAxisd(rc.tilt_y_rad, Eigen::Vector3d::UnitY()))
                                     .toRotationMatrix();
  Eigen::Isometry3d T_cam0_rock = Eigen::Isometry3d::Identity();
  T_cam0_rock.linear() = R_tilt;
  T_cam0_rock.translation() = Eigen::Vector3d(0.0, 0.0, rc.distance_m);
  return T_cam0_rock.inverse();
}

// The grid projector of the params, its central beam crossing the optical
// axis at converge_distance_m. Throws std::invalid_argument.
ProjectorCalibration makeProjector(const ProjectorParams& pc)
{
  const Eigen::Vector3d centre = Eigen::Vector3d(0.0, 0.0, pc.converge_distance_m) - pc.origin_m;
  if (!(centre.z() > 0.0))
    throw std::invalid_argument("invalid simulator config: the projector's central beam must point forward");
  ProjectorCalibration projector =
      makeGridProjector(pc.rows, pc.cols, pc.origin_m, centre, pc.pitch_x_rad, pc.pitch_y_rad, pc.roll_rad);
  const std::string why = projector.validate();
  if (!why.empty())
    throw std::invalid_argument("invalid simulator config: projector: " + why);
  return projector;
}

// A dot's pixel, whose noise-free peak decides SimFrame::clipped.
struct ClipProbe
{
  int v, u, beam;
};

// Everything a row of the frame needs.
struct RowInputs
{
  const sim::RockSampling& sampling;
  const sim::RockSurface& rock;
  sim::RockSamples rock_samples;  // radiance nullptr without sun
  const sim::SplatRows& splats;
  const sim::SensorNoise& noise;
  const sim::SensorReadout& readout;
  const std::vector<ClipProbe>& probes;  // sorted by row
  Blooming blooming;
};

// Row v up to the recorded signal: the rock's radiance upsampled (black
// without sun), the splats, the noise-free copy on request, the clip
// probes, then the signal the sensor records (returned: L or S).
float* radianceRow(const RowInputs& in, int v, float* L, float* S, float* blend, SimFrame* frame)
{
  const int W = frame->image.cols;
  if (in.rock_samples.radiance)
  {
    in.sampling.upsampleRow(in.rock_samples.radiance, v, W, L, blend);
    if (in.rock_samples.hits)
      in.sampling.sharpenRow(in.rock, in.rock_samples.hits, v, W, L, blend);
  }
  else
    std::fill(L, L + 3 * W + 5, 0.0f);
  in.splats.applyRow(v, W, L);
  auto p =
      std::lower_bound(in.probes.begin(), in.probes.end(), v, [](const ClipProbe& a, int row) { return a.v < row; });
  for (; p != in.probes.end() && p->v == v; ++p)
    frame->clipped[p->beam] = in.readout.pixelPeak(p->u, L) > in.readout.fullWell();
  float* rec = in.readout.record(v, W, L, S);
  if (!frame->linear.empty())
    std::memcpy(frame->linear.ptr<float>(v), frame->linear.channels() == 3 ? L : rec,
                sizeof(float) * frame->linear.cols * frame->linear.channels());
  return rec;
}

// The frame's rows, in parallel (each row's noise is seeded by its index, so
// the result does not depend on the thread count). Without a charge path,
// shot and read noise at once, then the output; with one, the charge of
// every row (shot noise) first, the full well (clipping, blooming) over the
// frame, then read noise and the output.
void exposeRows(const RowInputs& in, SimFrame* frame)
{
  const int W = frame->image.cols, H = frame->image.rows;
  const int n = in.readout.samplesPerRow(W);
  const bool charge_path = in.readout.chargePath();
  // The charge image is kept per thread from frame to frame: a new 4-12 MB
  // buffer per frame cost its first-touch page faults, about 2000 a frame.
  cv::Mat charge;
  if (charge_path)
  {
    thread_local cv::Mat kept;
    kept.create(H, n, CV_32F);
    charge = kept;  // a plain local from here on: the row workers write the caller's buffer
  }
  cv::parallel_for_(cv::Range(0, H),
                    [&](const cv::Range& range)
                    {
                      std::vector<float> buf(3 * W + 5), rec(W + 5), normal(3 * W + 5), deviation(3 * W),
                          blend(3 * in.sampling.rw);
                      for (int v = range.start; v < range.end; ++v)
                      {
                        float* S = radianceRow(in, v, buf.data(), rec.data(), blend.data(), frame);
                        if (charge_path)
                        {
                          in.noise.applyShotRow(v, n, S, normal.data(), deviation.data());
                          std::memcpy(charge.ptr<float>(v), S, sizeof(float) * n);
                          continue;
                        }
                        if (in.noise.enabled())
                          in.noise.applyRow(v, n, S, normal.data(), deviation.data());
                        in.readout.write(v, S, &frame->image);
                      }
                    });
  if (!charge_path)
    return;
  sim::spillCharge(in.blooming, in.readout.fullWell(), &charge);
  cv::parallel_for_(cv::Range(0, H),
                    [&](const cv::Range& range)
                    {
                      std::vector<float> normal(n + 5);
                      for (int v = range.start; v < range.end; ++v)
                      {
                        float* S = charge.ptr<float>(v);
                        if (in.noise.enabled())
                          in.noise.applyReadRow(v, n, S, normal.data());
                        in.readout.write(v, S, &frame->image);
                      }
                    });
}

// SimFrame::light_centroids and footprint_centroids from the dots' splats
// (a blurred dot's sub-exposures add up).
void dotCentroids(const std::vector<sim::Splat>& splats, const std::vector<sim::DotAlbedo>& albedo,
                  const sim::RockSurface& rock, int channel, int width, SimFrame* frame)
{
  std::vector<sim::DotMoments> m(frame->visible.size());
  for (const sim::Splat& sp : splats)
    if (sp.albedo >= 0 && sp.beam >= 0 && sp.beam < static_cast<int>(m.size()))
      sim::addDotMoments(sp, albedo[sp.albedo], rock, channel, width, &m[sp.beam]);
  const cv::Point2d none(detail::kNaN, detail::kNaN);
  frame->light_centroids.assign(m.size(), none);
  frame->footprint_centroids.assign(m.size(), none);
  for (size_t b = 0; b < m.size(); ++b)
  {
    if (!frame->visible[b] || !(m[b].w > 0.0) || !(m[b].fw > 0.0))
      continue;
    frame->light_centroids[b] = cv::Point2d(m[b].wx / m[b].w, m[b].wy / m[b].w);
    frame->footprint_centroids[b] = cv::Point2d(m[b].fwx / m[b].fw, m[b].fwy / m[b].fw);
  }
}

}  // namespace

// The built scene, immutable after construction and shared by copies of the
// Simulator (updateLive() copies change only the params).
struct Simulator::Impl
{
  explicit Impl(const SimulatorParams& p)
    : board(p.target.kind == TargetKind::kChessboard),
      rock(board ? sim::boardSlab(p.target.chessboard, p.rock) : p.rock, p.lighting),
      // The board's sharp print is rendered per pixel.
      sampling(p.sensor.camera, board ? 1 : p.rock_subsample),
      clutter(sim::scatterClutter(p.clutter, rock, p.rock.seed)),
      T_rock_cam0(board ? sim::boardRockFromCamera0(p.target.chessboard) : rockFromCamera0(p.rock)),
      spectrum(sim::cameraSpectrum(p.projector.color, p.sensor.output))
  {
    if (board)
      rock.board = std::make_shared<const sim::ChessboardPattern>(p.target.chessboard);
  }

  bool board;
  sim::RockSurface rock;
  sim::RockSampling sampling;
  std::vector<sim::ClutterItem> clutter;
  Eigen::Isometry3d T_rock_cam0;
  sim::CameraSpectrum spectrum;
};

Simulator::Simulator(const SimulatorParams& params) : params_(params)
{
  const std::string why = params.validate();
  if (!why.empty())
    throw std::invalid_argument("invalid simulator config: " + why);
  projector_ = makeProjector(params.projector);
  impl_ = std::make_shared<const Impl>(params);
  sim::normalTable();  // built now rather than in the first frame
}

void Simulator::updateLive(const SimulatorParams& params)
{
  SimulatorParams c = params_;
  c.lighting = params.lighting;
  c.lighting.sun_direction = params_.lighting.sun_direction;  // baked into the rock's shading
  c.lighting.sky_ambient = params_.lighting.sky_ambient;
  c.motion = params.motion;
  c.sensor.read_noise_dn = params.sensor.read_noise_dn;
  c.sensor.shot_noise = params.sensor.shot_noise;
  c.sensor.gain_dn_per_electron = params.sensor.gain_dn_per_electron;
  c.noise_seed = params.noise_seed;
  c.keep_linear = params.keep_linear;
  c.dot_centroid_truth = params.dot_centroid_truth;
  c.projector.power_scale = params.projector.power_scale;
  const std::string why = c.validate();
  if (!why.empty())
    throw std::invalid_argument("invalid simulator config: " + why);
  params_ = c;
}

double Simulator::diameterOfConfusion(double r) const
{
  return sim::diameterOfConfusion(params_.sensor, r);
}

Eigen::Isometry3d Simulator::motion(double t) const
{
  return sim::rigMotion(params_.motion, t);
}

Eigen::Isometry3d Simulator::cameraPose(double t) const
{
  return impl_->T_rock_cam0 * motion(t).inverse();
}

double Simulator::surfaceOffset(const Eigen::Vector3d& p) const
{
  if (!impl_->rock.inside(p.x(), p.y()))
    return detail::kNaN;
  return p.z() - impl_->rock.height(p.x(), p.y());
}

bool Simulator::intersect(double t, const Eigen::Vector3d& origin, const Eigen::Vector3d& direction,
                          Eigen::Vector3d* hit) const
{
  const Eigen::Isometry3d T_rc = cameraPose(t);
  const Eigen::Vector3d o = T_rc * origin;
  const Eigen::Vector3d d = T_rc.linear() * direction;
  double s;
  bool wall;
  if (!impl_->rock.cast(o, d, &s, &wall) || wall)
    return false;
  *hit = T_rc.inverse() * (o + s * d);
  return true;
}

SimFrame Simulator::render(double t, const FrameRequest& request) const
{
  const Impl& im = *impl_;
  const SensorParams& sc = params_.sensor;
  SimFrame frame;
  frame.t = t;
  frame.delta = request.arm_correction * motion(t);
  const sim::FrameGeometry g(im.T_rock_cam0 * frame.delta.inverse());
  const double sun = sim::sunDn(params_);

  // Clutter patches and dots as splats, in the order they apply to a pixel.
  std::vector<sim::Splat> splats;
  std::vector<sim::DotAlbedo> dot_albedo;
  if (sun > 0.0)
    sim::addClutterSplats(im.clutter, im.rock, g, sc, sun, &splats);
  const size_t clutter_splats = splats.size();
  const bool blur = sc.exposure_time_s > 0.0;
  const sim::GeometryAt geometry = [&](double tau)
  { return sim::FrameGeometry(im.T_rock_cam0 * (request.arm_correction * motion(tau)).inverse()); };
  if (blur)
  {
    // The truth at t; the dots' light over the exposure. (Clutter patches
    // stay at t: they are blended reflectance, not added light.)
    std::vector<sim::Splat> unused;
    std::vector<sim::DotAlbedo> unused_albedo;
    sim::renderDots(params_, projector_, im.rock, g, &frame, &unused, &unused_albedo);
    sim::renderBlurredDots(params_, projector_, im.rock, geometry, t, &splats, &dot_albedo);
  }
  else
    sim::renderDots(params_, projector_, im.rock, g, &frame, &splats, &dot_albedo);
  if (im.board)
    sim::boardTruth(params_.target.chessboard, sc.camera, g, &frame.target_pose, &frame.target_corners);
  if (params_.dot_centroid_truth)
    dotCentroids(splats, dot_albedo, im.rock, im.spectrum.primary, sc.camera.width, &frame);
  if (!request.projector_on)
    splats.resize(clutter_splats);  // the truth stays; the light does not reach the rock
  const sim::SplatRows splat_rows(std::move(splats), std::move(dot_albedo), im.rock, sc.camera.height);

  sim::RockSamples rock_samples;
  if (sun > 0.0 && blur)
    rock_samples.radiance = sim::renderBlurredRock(im.rock, im.sampling, sc, geometry, t, sun);
  else if (sun > 0.0)
    rock_samples = sim::renderRockSamples(im.rock, im.sampling, sc, g, sun);
  const sim::SensorReadout readout(sc, im.spectrum.mono_weights);
  if (params_.keep_linear)
    frame.linear.create(sc.camera.height, sc.camera.width, readout.linearType());
  frame.image.create(sc.camera.height, sc.camera.width, readout.imageType());
  frame.encoding = encodingName(sc.output);
  frame.clipped.assign(frame.visible.size(), 0);
  std::vector<ClipProbe> probes;
  for (size_t b = 0; b < frame.visible.size(); ++b)
    if (frame.visible[b])
      probes.push_back({static_cast<int>(std::lround(frame.pixels[b].y)),
                        static_cast<int>(std::lround(frame.pixels[b].x)), static_cast<int>(b)});
  if (!request.projector_on)
    probes.clear();  // no dot, nothing clipped by it
  std::sort(probes.begin(), probes.end(), [](const ClipProbe& a, const ClipProbe& b) { return a.v < b.v; });
  const sim::SensorNoise noise(sc, params_.noise_seed, t, request.projector_on ? 0u : 1u);
  exposeRows({im.sampling, im.rock, rock_samples, splat_rows, noise, readout, probes, sc.blooming}, &frame);
  return frame;
}

}  // namespace structured_light_stabilizer
