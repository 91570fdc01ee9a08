// The Simulator: builds the scene once, then renders a frame stage by stage
// (rig pose, clutter and dots as splats, the rock's radiance, then per row
// the splats, the sensor's noise and quantisation).
#include "structured_light_stabilizer/sim/simulator.h"

#include <algorithm>
#include <cstring>
#include <stdexcept>
#include <utility>

#include "brightness.h"
#include "clutter.h"
#include "frame_geometry.h"
#include "noise.h"
#include "optics.h"
#include "projector_dots.h"
#include "rig_motion.h"
#include "rock_render.h"
#include "rock_surface.h"
#include "sensor.h"
#include "splat.h"
#include "target_board.h"
#include "structured_light_stabilizer/detail/math.h"

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

// The frame's rows, in parallel (each row's noise is seeded by its index, so
// the result does not depend on the thread count): the rock's radiance
// upsampled (black without sun), the splats, the noise-free copy on request,
// the sensor's noise and quantisation.
void exposeRows(const sim::RockSampling& sampling, const float* rock_samples, const sim::SplatRows& splats,
                const sim::SensorNoise& noise, SimFrame* frame)
{
  const int W = frame->image.cols, H = frame->image.rows;
  const int n3 = 3 * W, nr3 = 3 * sampling.rw;
  const bool keep_linear = !frame->linear.empty();
  cv::parallel_for_(cv::Range(0, H),
                    [&](const cv::Range& range)
                    {
                      std::vector<float> buf(n3 + 5), normal(n3 + 5), deviation(n3), blend(nr3);
                      float* L = buf.data();
                      for (int v = range.start; v < range.end; ++v)
                      {
                        if (rock_samples)
                          sampling.upsampleRow(rock_samples, v, W, L, blend.data());
                        else
                          std::fill(buf.begin(), buf.end(), 0.0f);
                        splats.applyRow(v, W, L);
                        if (keep_linear)
                          std::memcpy(frame->linear.ptr<float>(v), L, sizeof(float) * n3);
                        if (noise.enabled())
                          noise.applyRow(v, n3, L, normal.data(), deviation.data());
                        sim::quantizeRow(L, n3, frame->image.ptr<uint8_t>(v));
                      }
                    });
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
      T_rock_cam0(board ? sim::boardRockFromCamera0(p.target.chessboard) : rockFromCamera0(p.rock))
  {
    if (board)
      rock.board = std::make_shared<const sim::ChessboardPattern>(p.target.chessboard);
  }

  bool board;
  sim::RockSurface rock;
  sim::RockSampling sampling;
  std::vector<sim::ClutterItem> clutter;
  Eigen::Isometry3d T_rock_cam0;
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
  sim::renderDots(params_, projector_, im.rock, g, &frame, &splats, &dot_albedo);
  if (im.board)
    sim::boardTruth(params_.target.chessboard, sc.camera, g, &frame.target_pose, &frame.target_corners);
  if (!request.projector_on)
    splats.resize(clutter_splats);  // the truth stays; the light does not reach the rock
  const sim::SplatRows splat_rows(std::move(splats), std::move(dot_albedo), im.rock, sc.camera.height);

  const float* rock_samples = sun > 0.0 ? sim::renderRockSamples(im.rock, im.sampling, sc, g, sun) : nullptr;
  if (params_.keep_linear)
    frame.linear.create(sc.camera.height, sc.camera.width, CV_32FC3);
  frame.image.create(sc.camera.height, sc.camera.width, CV_8UC3);
  exposeRows(im.sampling, rock_samples, splat_rows, sim::SensorNoise(sc, params_.noise_seed, t), &frame);
  return frame;
}

}  // namespace structured_light_stabilizer
