// CameraDriver source "sim": the built-in simulator (docs/simulator.md)
// renders the rock, the dots, the sun and the arm's motion, and publishes its
// ground truth beside each frame, stamped like it: the true beam points
// (sim/ground_truth/points, the layout of `points`), the true camera motion
// (sim/ground_truth/pose_delta) and the true dots (sim/ground_truth/spots).
//
// Scene parameters are read once at start-up (README, "Parameters of the
// simulator"); lighting, noise and jitter are live (cfg/CameraDriver.cfg).
// Simulated time advances by 1 / ~rate per frame, deterministically, also
// across rate changes and while ~lazy skips the rendering; the stamps are
// spaced like it (stampAt).
#include <cmath>
#include <functional>
#include <mutex>
#include <utility>
#include <vector>

#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>
#include <sensor_msgs/PointCloud2.h>

#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/PoseDelta.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/nodelets/conversions.h"
#include "nodelets/frame_sources/frame_source.h"
#include "nodelets/common/param_reader.h"
#include "nodelets/frame_sources/sim/sim_closed_loop.h"

namespace structured_light_stabilizer
{

namespace
{

// ~radiometry's default: the physics of the recommended daylight rig (or ~rig's).
constexpr const char* kDefaultRadiometry = "corrected";

bool radiometryModel(const std::string& name, RadiometryModel* model)
{
  if (name == "study")
    *model = RadiometryModel::kStudyAsStated;
  else if (name == "corrected")
    *model = RadiometryModel::kCorrected;
  else
    return false;
  return true;
}

// The scene parameters, read over the defaults of SimulatorParams in this
// order (the order of the error messages for wrongly typed ones).
void readSceneParams(const ParamReader& read, SimulatorParams* c)
{
  read.integer("seed", &c->rock.seed);
  read.integer("noise_seed", &c->noise_seed);
  read.integer("projector_rows", &c->projector.rows);
  read.integer("projector_cols", &c->projector.cols);
  read.integer("rock_subsample", &c->rock_subsample);
  read.integer("clutter_specks", &c->clutter.green_specks);
  read.integer("clutter_olive", &c->clutter.olive_minerals);
  read.integer("clutter_blobs", &c->clutter.green_blobs);
  const std::pair<const char*, double*> numbers[] = {
      {"rock_distance", &c->rock.distance_m},
      {"rock_width", &c->rock.width_m},
      {"rock_height", &c->rock.height_m},
      {"rock_relief", &c->rock.relief_m},
      {"rock_tilt_x", &c->rock.tilt_x_rad},
      {"rock_tilt_y", &c->rock.tilt_y_rad},
      {"texture_scale", &c->rock.texture_scale_m},
      {"fine_texture_period", &c->rock.fine_texture_period_m},
      {"fine_texture_amplitude", &c->rock.fine_texture_amplitude},
      {"nir_to_red", &c->rock.nir_to_red_ratio},
      {"albedo_min", &c->rock.albedo_min},
      {"albedo_max", &c->rock.albedo_max},
      {"green_to_red", &c->rock.green_to_red},
      {"blue_to_red", &c->rock.blue_to_red},
      {"rock_step_height", &c->rock.step_height_m},
      {"rock_step_x", &c->rock.step_x_m},
      {"projector_roll", &c->projector.roll_rad},
      {"projector_converge_distance", &c->projector.converge_distance_m},
      {"beam_sigma", &c->projector.beam_sigma_rad},
      {"power_scale", &c->projector.power_scale},
      {"sun_level", &c->lighting.sun_level},
      {"exposure", &c->lighting.exposure},
      {"jitter_translation", &c->motion.jitter_translation_m},
      {"jitter_rotation", &c->motion.jitter_rotation_rad},
      {"jitter_frequency", &c->motion.jitter_frequency_hz},
      {"step_period", &c->motion.step_period_s},
      {"return_period", &c->motion.return_period_s},
      {"read_noise", &c->sensor.read_noise_dn},
      {"gain", &c->sensor.gain_dn_per_electron},
      {"focus_distance", &c->sensor.focus_distance_m},
      {"aperture", &c->sensor.aperture_diameter_m},
  };
  for (const auto& p : numbers)
    read.number(p.first, p.second);
  read.boolean("shot_noise", &c->sensor.shot_noise);
  read.boolean("vignetting", &c->sensor.natural_vignetting);
  // ~projector_pitch sets both pitches; ~projector_pitch_x/_y override one.
  double pitch = c->projector.pitch_x_rad;
  read.number("projector_pitch", &pitch);
  c->projector.pitch_x_rad = c->projector.pitch_y_rad = pitch;
  read.number("projector_pitch_x", &c->projector.pitch_x_rad);
  read.number("projector_pitch_y", &c->projector.pitch_y_rad);
  read.vector3("projector_origin", &c->projector.origin_m);
  read.vector3("drift_velocity", &c->motion.drift_velocity_mps);
  read.vector3("drift_angular_velocity", &c->motion.drift_angular_velocity_radps);
  read.vector3("step_translation", &c->motion.step_translation_m);
  std::vector<double> D;
  if (read.numbers("distortion_coeffs", 5, &D) && !D.empty())
  {
    c->sensor.camera.distortion = DistortionModel::kPlumbBob;
    c->sensor.camera.D = D;
  }
}

// The projector's colour and the sensor's output (docs/simulator.md,
// "Colours and sensor outputs"): ~projector_color (green | red | blue | nir |
// white; its nominal wavelength unless ~projector_wavelength), ~sensor_output
// (an image encoding) and ~sensor_output_bits (16-bit outputs: the
// converter's bits), ~blooming (none | column), ~full_well (DN), and the
// motion blur's ~exposure_time (s, 0 = off) and ~exposure_samples.
void readColourAndSensorParams(const ros::NodeHandle& pnh, const ParamReader& read,
                               const std::function<void(const std::string&)>& error, SimulatorParams* c)
{
  const std::string color = pnh.param<std::string>("projector_color", "green");
  if (!projectorColorFromName(color, &c->projector.color))
    error("unknown ~projector_color '" + color + "' (green | red | blue | nir | white); using 'green'");
  c->projector.wavelength_nm = nominalWavelengthNm(c->projector.color);
  read.number("projector_wavelength", &c->projector.wavelength_nm);
  const std::string output = pnh.param<std::string>("sensor_output", "bgr8");
  if (!sensorOutputFromEncoding(output, &c->sensor.output))
    error("unknown ~sensor_output '" + output +
          "' (bgr8 | rgb8 | bgr16 | rgb16 | mono8 | mono16 | bayer_rggb8 | bayer_bggr8 | bayer_gbrg8 | "
          "bayer_grbg8); using 'bgr8'");
  read.integer("sensor_output_bits", &c->sensor.output_bits);
  const std::string blooming = pnh.param<std::string>("blooming", "none");
  if (blooming == "column")
    c->sensor.blooming = Blooming::kColumn;
  else if (blooming != "none")
    error("unknown ~blooming '" + blooming + "' (none | column); using 'none'");
  read.number("full_well", &c->sensor.full_well_dn);
  read.number("exposure_time", &c->sensor.exposure_time_s);
  read.integer("exposure_samples", &c->sensor.exposure_samples);
}

// The named (string) scene settings and the chessboard target: ~target
// (rock | chessboard) and its ~board_* keys. An unknown name is an error
// naming the choices, and the default stays.
void readNamedSceneParams(const ros::NodeHandle& pnh, const ParamReader& read,
                          const std::function<void(const std::string&)>& error, SimulatorParams* c)
{
  readColourAndSensorParams(pnh, read, error, c);
  const std::string target = pnh.param<std::string>("target", "rock");
  if (target == "chessboard")
    c->target.kind = TargetKind::kChessboard;
  else if (target != "rock")
    error("unknown ~target '" + target + "' (rock | chessboard); using 'rock'");
  ChessboardParams& b = c->target.chessboard;
  read.integer("board_cols", &b.cols);
  read.integer("board_rows", &b.rows);
  const std::pair<const char*, double*> numbers[] = {
      {"board_square", &b.square_m},       {"board_margin", &b.margin_m},     {"board_black", &b.black},
      {"board_white", &b.white},           {"board_distance", &b.distance_m}, {"board_tilt_x", &b.tilt_x_rad},
      {"board_tilt_y", &b.tilt_y_rad},     {"board_roll", &b.roll_rad},       {"board_offset_x", &b.offset_m.x()},
      {"board_offset_y", &b.offset_m.y()},
  };
  for (const auto& p : numbers)
    read.number(p.first, p.second);
}

// ---- dynamic_reconfigure <-> the simulator's live settings, one function each way.

// model_ratio: the dot/sun ratio of the chosen radiometry (the rig's when
// one is loaded), used when the config's is negative.
void liveSettingsFromConfig(const CameraDriverConfig& config, double model_ratio, SimulatorParams* c)
{
  c->lighting.sun_level = config.sun_level;
  c->lighting.dot_to_sun_ratio = config.dot_to_sun_ratio >= 0.0 ? config.dot_to_sun_ratio : model_ratio;
  c->lighting.exposure = config.exposure;
  c->projector.power_scale = config.power_scale;
  c->motion.jitter_translation_m = config.jitter_translation;
  c->motion.jitter_rotation_rad = config.jitter_rotation;
  c->motion.jitter_frequency_hz = config.jitter_frequency;
  c->sensor.read_noise_dn = config.read_noise;
  c->sensor.shot_noise = config.shot_noise;
}

void configFromLiveSettings(const SimulatorParams& c, CameraDriverConfig* config)
{
  config->sun_level = c.lighting.sun_level;
  config->dot_to_sun_ratio = c.lighting.dot_to_sun_ratio;
  config->exposure = c.lighting.exposure;
  config->power_scale = c.projector.power_scale;
  config->jitter_translation = c.motion.jitter_translation_m;
  config->jitter_rotation = c.motion.jitter_rotation_rad;
  config->jitter_frequency = c.motion.jitter_frequency_hz;
  config->read_noise = c.sensor.read_noise_dn;
  config->shot_noise = c.sensor.shot_noise;
}

class SimSource : public FrameSource
{
public:
  explicit SimSource(const SourceContext& ctx) : ctx_(ctx) {}

  // Builds the simulator from the parameters; false (said why) when they
  // are invalid: the driver then publishes nothing.
  bool setUp()
  {
    SimulatorParams c;
    readSceneParams(ParamReader(ctx_.pnh, ctx_.error), &c);
    strobe_ = ctx_.pnh.param("strobe", false);
    readNamedSceneParams(ctx_.pnh, ParamReader(ctx_.pnh, ctx_.error), ctx_.error, &c);
    const std::string ratio_source = readLighting(&c);
    duration_s_ = ctx_.pnh.param("duration", 0.0);
    readDisturbanceParams(ctx_.pnh, ctx_.error, &c.motion);  // the closed loop's (sim_closed_loop.h)
    useUrlCalibration(&c);
    const CameraModel full = c.sensor.camera;
    renderWindow(&c);
    if (!build(c, ratio_source))
      return false;
    sim_info_ = cameraInfoFromModel(full, std_msgs::Header());
    pub_gt_points_ = ctx_.nh.advertise<sensor_msgs::PointCloud2>("sim/ground_truth/points", 5);
    pub_gt_pose_ = ctx_.nh.advertise<PoseDelta>("sim/ground_truth/pose_delta", 5);
    pub_gt_spots_ = ctx_.nh.advertise<CentroidArray>("sim/ground_truth/spots", 5);
    lazy_ = ctx_.pnh.param("lazy", true);
    if (lazy_)
      ctx_.info(
          "~lazy: frames are rendered only while someone subscribes to the image or the ground truth "
          "(simulated time runs on regardless)");
    if (strobe_)
      ctx_.info(
          "~strobe: every second frame has the projector off and goes to camera/image_ambient (its own stamp, "
          "no ground truth); the projector-on frames go to camera/image_raw");
    writeProjectorCalibration();
    // Without a usable arm the camera just ignores commands.
    closed_loop_.setUp(ctx_, [this] { return simulator()->params().motion; });
    return true;
  }

  bool open(std::string* /*why*/) override { return true; }
  // Lockstep: simulated time runs at the pipeline's pace, not the wall's.
  bool paced() const override { return !closed_loop_.lockstep(); }
  std::string describe(double /*rate*/) const override { return ""; }  // said by setUp()
  bool rendered() const override { return true; }
  const sensor_msgs::CameraInfo* cameraInfo() const override { return &sim_info_; }

  GrabResult grab(double rate, Frame* frame) override
  {
    if (rate != rate_base_)
    {
      // A rate change keeps simulated time continuous.
      if (index_ > index_base_)
        t_base_ += (index_ - index_base_) / rate_base_;
      index_base_ = index_;
      rate_base_ = rate;
    }
    const double t = t_base_ + (index_ - index_base_) / rate;
    if (duration_s_ > 0.0 && t >= duration_s_)
      return {GrabStatus::kEnd, stringf("~duration %.1f s of simulated time reached; no more frames", duration_s_)};
    if (closed_loop_.lockstep())
    {
      if (!closed_loop_.lockstepTo(t))
        return {GrabStatus::kSkip, ""};  // stopping
      frame->stamp = closed_loop_.lockstepStamp(t);
    }
    else
    {
      ros::Time now;
      if (!ctx_.stamp(&now))
        return {GrabStatus::kSkip, ""};
      frame->stamp = stampAt(t, now);
    }
    ++index_;
    // The arm moves whether or not this frame is rendered.
    FrameRequest request;
    request.arm_correction = closed_loop_.correctionAt(t, frame->stamp);
    if (lazy_ && !closed_loop_.lockstep() && ctx_.image_subscribers() == 0 &&
        pub_gt_points_.getNumSubscribers() == 0 && pub_gt_pose_.getNumSubscribers() == 0 &&
        pub_gt_spots_.getNumSubscribers() == 0)
      return {GrabStatus::kSkip, ""};
    rendered_by_ = simulator();
    // Strobed: odd frames are the ambient ones (index_ counts this frame).
    request.projector_on = !(strobe_ && index_ % 2 == 0);
    const auto t0 = std::chrono::steady_clock::now();
    rendered_ = rendered_by_->render(t, request);
    frame->ambient = last_ambient_ = !request.projector_on;
    frame->encoding = rendered_.encoding;
    if (window_rendered_)
    {
      // The ROI was rendered; the binning is the camera's.
      std::string why;
      if (!applyWindow(rendered_.image, rendered_.encoding, bin_only_, &frame->image, &why))
        return {GrabStatus::kSkip, why};
      frame->windowed = true;
    }
    else
      frame->image = rendered_.image;
    frame->processing_ms = millisecondsSince(t0);
    return {GrabStatus::kFrame, ""};
  }

  // The driver's schedule gave up `ticks` frames (the worker fell more than a
  // period behind): the scene moves on by as many frames, as the world does
  // while a camera's host cannot keep up, so that the stamps stay on the
  // schedule's clock. Before, each such frame left simulated time behind for
  // good and the stamps drifted up to kMaxSlipS into the past (58 ms median at
  // 30 Hz in one benchmark run), past the StabilizationController's 0.2 s
  // ~timeout at times. Strobed, the frames keep their slots: a lost slot
  // leaves two frames of one kind in a row, as with a triggered camera.
  void skipped(int64_t ticks) override
  {
    index_ += static_cast<uint64_t>(ticks);
    frames_lost_ += ticks;
    ROS_INFO_THROTTLE(30.0,
                      "CameraDriver (sim): %lld frame periods lost so far to a worker that fell behind ~rate (the "
                      "scene moves on, as with a camera whose host cannot keep up)",
                      static_cast<long long>(frames_lost_));
  }

  void published(const std_msgs::Header& header) override;
  void reconfigure(CameraDriverConfig& config) override;

private:
  std::string readLighting(SimulatorParams* c);
  SimRadiometry rigRadiometry();
  std::string applyRadiometry(const SimRadiometry& r, SimulatorParams* c);
  double modelRatio(RadiometryModel model) const;
  void useUrlCalibration(SimulatorParams* c) const;
  void renderWindow(SimulatorParams* c);
  bool build(const SimulatorParams& c, const std::string& ratio_source);
  void writeProjectorCalibration() const;

  // The stamp of simulated instant t: ROS time at the first frame plus the
  // simulated time since, so that the stamps are spaced exactly like the
  // scene's motion. Stamping each frame with the time it was grabbed bent
  // them wherever the worker woke late (20-58 ms apart at 30 Hz on a loaded
  // machine, for a scene moved by 33 ms each): the ambient compensation and
  // PoseDelta read motion per second from the stamps. Re-anchored, with a
  // warning, when ROS time and the stamps part by more than kMaxSlipS (a
  // machine too slow for ~rate, a jump in ROS time).
  static constexpr double kMaxSlipS = 0.25;
  ros::Time stampAt(double t, const ros::Time& now)
  {
    const double slip = now.toSec() - (anchor_s_ + t);
    if (!anchored_ || std::abs(slip) > kMaxSlipS)
    {
      if (anchored_)
        ROS_WARN_THROTTLE(10.0,
                          "CameraDriver (sim): the stamps of simulated time were %.0f ms %s ROS time; re-anchored "
                          "(one gap in the stamps; the machine may be too slow for ~rate)",
                          1e3 * std::abs(slip), slip > 0.0 ? "behind" : "ahead of");
      anchor_s_ = now.toSec() - t;
      anchored_ = true;
      return now;
    }
    return ros::Time(anchor_s_ + t);
  }

  std::shared_ptr<const Simulator> simulator() const
  {
    std::lock_guard<std::mutex> lock(mutex_);
    return simulator_;
  }

  SourceContext ctx_;
  double duration_s_ = 0.0;  // s of simulated time; 0 = no end
  bool lazy_ = true;
  sensor_msgs::CameraInfo sim_info_;
  ros::Publisher pub_gt_points_, pub_gt_pose_, pub_gt_spots_;

  mutable std::mutex mutex_;
  std::shared_ptr<const Simulator> simulator_;  // under mutex_; replaced, never modified
  std::string radiometry_ = "study";            // reconfigure() only (dynamic_reconfigure's thread)
  // Daylight (docs/daylight.md): ~strobe publishes every second frame with
  // the projector off on camera/image_ambient; ~rig sets the corrected
  // radiometry from a rig's YAML. Set in setUp(), read-only after.
  bool strobe_ = false;
  double rig_ratio_ = 0.0;     // the corrected radiometry's rig's dot/sun ratio (live radiometry switches)
  std::string rig_note_;       // the rig, for the start-up line
  bool last_ambient_ = false;  // worker thread: the last frame grabbed was a projector-off frame

  // Worker thread: simulated time, the last frame and the simulator that rendered it.
  uint64_t index_ = 0, index_base_ = 0;
  double t_base_ = 0.0, rate_base_ = 0.0;
  bool anchored_ = false;    // stampAt(): ROS time (s) of simulated time 0
  int64_t frames_lost_ = 0;  // skipped()
  double anchor_s_ = 0.0;
  SimFrame rendered_;
  std::shared_ptr<const Simulator> rendered_by_;
  // ~render_window: the simulator renders only the driver's ROI (at full
  // resolution; the binning follows), its pixels offset by roi_offset_.
  bool window_rendered_ = false;
  SensorWindow bin_only_;
  cv::Point2d roi_offset_;
  SimClosedLoop closed_loop_;  // the arm driven by stabilizer/cmd_twist, the truth offsets
};

// The dot-versus-sun brightness comes from the scene analysis unless
// ~dot_to_sun_ratio overrides it (negative = not set). Returns where it came
// from, for the start-up line.
std::string SimSource::readLighting(SimulatorParams* c)
{
  radiometry_ = ctx_.pnh.param<std::string>("radiometry", kDefaultRadiometry);
  RadiometryModel model = RadiometryModel::kStudyAsStated;
  if (!radiometryModel(radiometry_, &model))
  {
    ctx_.error(
        stringf("unknown ~radiometry '%s' (study | corrected); using '%s'", radiometry_.c_str(), kDefaultRadiometry));
    radiometry_ = kDefaultRadiometry;
    radiometryModel(radiometry_, &model);
    ctx_.pnh.setParam("radiometry", radiometry_);  // dynamic_reconfigure starts from it
  }
  std::string note = ", " + radiometry_ + " radiometry";
  const SimRadiometry rig = rigRadiometry();  // also for a live switch to 'corrected'
  if (model == RadiometryModel::kCorrected)
    note += applyRadiometry(rig, c);
  else
    applyRadiometry(studySimRadiometry(), c);
  double ratio = -1.0;
  ParamReader(ctx_.pnh, ctx_.error).number("dot_to_sun_ratio", &ratio);
  c->lighting.dot_to_sun_ratio = ratio >= 0.0 ? ratio : modelRatio(model);
  return ratio >= 0.0 ? " from ~dot_to_sun_ratio" : note;
}

double SimSource::modelRatio(RadiometryModel model) const
{
  return model == RadiometryModel::kCorrected ? rig_ratio_ : studySimRadiometry().dot_to_sun_ratio;
}

// The corrected radiometry's rig (radiometry.h): ~rig's file, else the
// recommended one; pulsed for the frames ~strobe lights. Sets rig_ratio_
// and rig_note_; a bad file is said and the recommended rig used.
SimRadiometry SimSource::rigRadiometry()
{
  const std::string path = ctx_.pnh.param<std::string>("rig", "");
  const SceneAnalysis analysis = analyseScene(SceneInputs());
  RigParams rig = RigParams::recommendedDaylight();
  try
  {
    if (!path.empty())
      rig = loadRig(analysis, path);
  }
  catch (const std::exception& e)
  {
    ctx_.error(stringf("~rig: %s; using the recommended daylight rig", e.what()));
  }
  rig.strobe = strobe_;  // the projector fires on the frames this driver lights
  const SimRadiometry r = simulatorRadiometry(analysis, rig);
  rig_ratio_ = r.dot_to_sun_ratio;
  rig_note_ = stringf(", rig '%s' (%s, %.2f ms, %.0f e-/DN)", rig.name.c_str(),
                      path.empty() ? "built in" : path.c_str(), rig.exposure_s * 1e3, 1.0 / r.gain_dn_per_electron);
  return r;
}

// The radiometry's exposure, gain, read noise, beam and wavelength; the
// parameters given explicitly keep their values (read before), the others
// are written back so that dynamic_reconfigure starts from them.
std::string SimSource::applyRadiometry(const SimRadiometry& r, SimulatorParams* c)
{
  const SimulatorParams explicit_values = *c;
  applySimRadiometry(r, c);
  if (ctx_.pnh.hasParam("exposure"))
    c->lighting.exposure = explicit_values.lighting.exposure;
  else
    ctx_.pnh.setParam("exposure", c->lighting.exposure);
  if (ctx_.pnh.hasParam("read_noise"))
    c->sensor.read_noise_dn = explicit_values.sensor.read_noise_dn;
  else
    ctx_.pnh.setParam("read_noise", c->sensor.read_noise_dn);
  if (ctx_.pnh.hasParam("gain"))
    c->sensor.gain_dn_per_electron = explicit_values.sensor.gain_dn_per_electron;
  if (ctx_.pnh.hasParam("beam_sigma"))
    c->projector.beam_sigma_rad = explicit_values.projector.beam_sigma_rad;
  // The rig's emitter is green (520 nm); another ~projector_color keeps its own wavelength (a red or NIR
  // projector at 520 nm is refused by the simulator's validation).
  if (ctx_.pnh.hasParam("projector_color") || ctx_.pnh.hasParam("projector_wavelength"))
    c->projector.wavelength_nm = explicit_values.projector.wavelength_nm;
  return rig_note_;
}

// A calibration file for the simulated camera replaces its intrinsics (and
// distortion) when it is of the simulator's size.
void SimSource::useUrlCalibration(SimulatorParams* c) const
{
  if (!ctx_.url_calibration)
    return;
  const sensor_msgs::CameraInfo& info = *ctx_.url_calibration;
  const char* url = ctx_.camera_info_url.c_str();
  CameraModel model;
  std::string why;
  if (static_cast<int>(info.width) != c->sensor.camera.width ||
      static_cast<int>(info.height) != c->sensor.camera.height)
    ctx_.error(
        stringf("~camera_info_url '%s' is for %ux%u images but the simulator renders %dx%d; using the "
                "simulator's own intrinsics",
                url, info.width, info.height, c->sensor.camera.width, c->sensor.camera.height));
  else if (!cameraModelFromInfo(info, &model, &why))
    ctx_.error(
        stringf("~camera_info_url '%s' is unusable (%s); using the simulator's own intrinsics", url, why.c_str()));
  else
    c->sensor.camera = model;
}

// With a sensor window (~roi_*, ~binning_*) the simulator renders only the
// ROI, at full resolution: the same physics for those pixels (its camera is
// the full one with the principal point moved), at the cost of the ROI's
// area (a 512 x 512 ROI renders 4 x faster, for 60-120 Hz). A Bayer mosaic
// keeps the full frame (its phase and its binning are the driver's), and so
// does ~render_window:=false.
void SimSource::renderWindow(SimulatorParams* c)
{
  const SensorWindow& w = ctx_.window;
  const CameraModel& full = c->sensor.camera;
  bool enabled = true;
  ParamReader(ctx_.pnh, ctx_.error).boolean("render_window", &enabled);
  const bool bayer = c->sensor.output == SensorOutput::kBayerRggb8 || c->sensor.output == SensorOutput::kBayerBggr8 ||
                     c->sensor.output == SensorOutput::kBayerGbrg8 || c->sensor.output == SensorOutput::kBayerGrbg8;
  if (!enabled || bayer || w.isFullSensor(full.width, full.height) || !w.validate(full.width, full.height).empty())
    return;
  const cv::Rect roi = w.roi(full.width, full.height);
  SensorWindow roi_only;
  roi_only.x_offset = roi.x;
  roi_only.y_offset = roi.y;
  roi_only.width = roi.width;
  roi_only.height = roi.height;
  c->sensor.camera = full.windowed(roi_only);
  bin_only_ = SensorWindow();
  bin_only_.binning_x = w.binning_x;
  bin_only_.binning_y = w.binning_y;
  roi_offset_ = cv::Point2d(roi.x, roi.y);
  window_rendered_ = true;
  ctx_.info(stringf("rendering only the ROI %dx%d+%d+%d, then binning it %dx%d", roi.width, roi.height, roi.x, roi.y,
                    w.binning_x, w.binning_y));
}

bool SimSource::build(const SimulatorParams& c, const std::string& ratio_source)
{
  try
  {
    const auto t0 = std::chrono::steady_clock::now();
    simulator_ = std::make_shared<const Simulator>(c);
    ctx_.info(
        stringf("simulator ready in %.0f ms (rock at %.2f m, relief %.2f m, %dx%d beams, sun %.2f, dot/sun "
                "ratio %.4g%s)",
                millisecondsSince(t0), c.rock.distance_m, c.rock.relief_m, c.projector.rows, c.projector.cols,
                c.lighting.sun_level, c.lighting.dot_to_sun_ratio, ratio_source.c_str()));
    return true;
  }
  catch (const std::exception& e)
  {
    ctx_.error(stringf("the simulator parameters are invalid, publishing nothing: %s", e.what()));
    return false;
  }
}

// ~write_projector_calibration: the simulator's exact projector, as a
// calibration file for the Triangulator.
void SimSource::writeProjectorCalibration() const
{
  const std::string path = ctx_.pnh.param<std::string>("write_projector_calibration", "");
  if (path.empty())
    return;
  std::string why;
  if (saveProjectorCalibration(path, simulator_->projector(), &why))
    ctx_.info("wrote the simulator's exact projector calibration to " + path);
  else
    ctx_.error("cannot write the projector calibration to '" + path + "': " + why);
}

void SimSource::published(const std_msgs::Header& header)
{
  if (last_ambient_)
    return;  // the ground truth goes with the frames that show the dots
  const ProjectorCalibration& projector = rendered_by_->projector();
  const SimFrame& frame = rendered_;
  std::vector<float> intensity(frame.peak_dn.begin(), frame.peak_dn.end());
  uint32_t visible = 0;
  auto spots = boost::make_shared<CentroidArray>();
  spots->header = header;
  // In the pixels of the published image: the driver's sensor window
  // (binning, ROI) applies to the truth as to the frame.
  const SensorWindow& window = ctx_.window;
  const cv::Size published_size = window.imageSize(frame.image.cols, frame.image.rows);
  spots->image_width = published_size.width;
  spots->image_height = published_size.height;
  for (int b = 0; b < projector.beamCount(); ++b)
  {
    if (!frame.visible[b])
      continue;
    const cv::Point2d px = window.toImage(frame.pixels[b] + roi_offset_);
    if (!(px.x >= -0.5 && px.y >= -0.5 && px.x < published_size.width - 0.5 && px.y < published_size.height - 0.5))
      continue;  // outside the ROI
    ++visible;
    Centroid c;
    c.x = px.x;
    c.y = px.y;
    // Area of the 2-sigma disc of the rendered dot, the size a detector
    // thresholding at ~14 % of the peak would find.
    c.area = static_cast<float>(M_PI * 4.0 * frame.blur_sigma_px[b] * frame.blur_sigma_px[b] /
                                (window.binning_x * window.binning_y));
    c.intensity = static_cast<float>(frame.peak_dn[b]);
    c.beam = b;
    spots->centroids.push_back(c);
  }
  pub_gt_points_.publish(makeBeamCloud(header, projector.rows, projector.cols, frame.points, intensity));
  auto pose = boost::make_shared<PoseDelta>();
  pose->header = header;
  pose->transform = transformFromIsometry(frame.delta);
  pose->rms_residual = 0.0;
  pose->points_used = visible;
  pose->valid = true;
  pose->status = "ground truth, simulated t = " + std::to_string(frame.t) + " s";
  pub_gt_pose_.publish(pose);
  pub_gt_spots_.publish(spots);
  closed_loop_.published(header, frame.t, frame.delta, rendered_by_->motion(frame.t));
}

void SimSource::reconfigure(CameraDriverConfig& config)
{
  const std::shared_ptr<const Simulator> current = simulator();
  RadiometryModel model = RadiometryModel::kStudyAsStated;
  if (!radiometryModel(config.radiometry, &model))
  {
    ctx_.warn(stringf("unknown radiometry '%s' (study | corrected); keeping '%s'", config.radiometry.c_str(),
                      radiometry_.c_str()));
    config.radiometry = radiometry_;
    radiometryModel(radiometry_, &model);
  }
  radiometry_ = config.radiometry;
  SimulatorParams c = current->params();
  liveSettingsFromConfig(config, modelRatio(model), &c);
  try
  {
    auto updated = std::make_shared<Simulator>(*current);
    updated->updateLive(c);
    std::lock_guard<std::mutex> lock(mutex_);
    simulator_ = updated;
  }
  catch (const std::exception& e)
  {
    ctx_.error(stringf("rejected simulator settings (%s); keeping the previous ones", e.what()));
    // Show the values in force, not the rejected ones, in rqt_reconfigure.
    configFromLiveSettings(current->params(), &config);
  }
}

}  // namespace

// The plugin (frame_source_plugins.xml): ~source:=sim.
class SimSourceFactory : public FrameSourceFactory
{
public:
  std::unique_ptr<FrameSource> make(const SourceContext& ctx) override
  {
    auto source = std::make_unique<SimSource>(ctx);
    if (!source->setUp())
      return nullptr;
    return source;
  }
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::SimSourceFactory, structured_light_stabilizer::FrameSourceFactory)
