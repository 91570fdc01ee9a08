// CameraDriver nodelet: publishes camera/image_raw + camera/camera_info from
// the built-in simulator, a V4L2 device, a video file or a folder of images
// (SPEC §2, §4). One worker thread acquires and publishes; it is joined in
// the destructor. Every failure of a source is logged (throttled) with what
// to fix and retried; nothing here may take the manager down.
#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <boost/filesystem.hpp>
#include <boost/make_shared.hpp>
#include <boost/thread/recursive_mutex.hpp>
#include <camera_info_manager/camera_info_manager.h>
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <diagnostic_updater/update_functions.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>

#include "structured_light_stabilizer/CameraDriverConfig.h"
#include "structured_light_stabilizer/CentroidArray.h"
#include "structured_light_stabilizer/PoseDelta.h"
#include "conversions.h"
#include "structured_light_stabilizer/projector_calibration.h"
#include "structured_light_stabilizer/simulator.h"

namespace structured_light_stabilizer
{

namespace
{

constexpr double kRetryPeriodS = 2.0;

bool isImageFile(const boost::filesystem::path& p)
{
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  static const std::vector<std::string> known = {".png",  ".jpg", ".jpeg", ".bmp", ".tif",
                                                 ".tiff", ".ppm", ".pgm",  ".pnm", ".webp"};
  return std::find(known.begin(), known.end(), ext) != known.end();
}

}  // namespace

class CameraDriverNodelet : public nodelet::Nodelet
{
public:
  ~CameraDriverNodelet() override
  {
    running_ = false;
    if (worker_.joinable())
      worker_.join();
  }

private:
  using Config = structured_light_stabilizer::CameraDriverConfig;

  void onInit() override
  {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    source_ = pnh.param<std::string>("source", "sim");
    frame_id_ = pnh.param<std::string>("frame_id", "camera_optical_frame");
    camera_info_url_ = pnh.param<std::string>("camera_info_url", "");
    const std::string camera_name = pnh.param<std::string>("camera_name", "camera");
    rate_ = pnh.param("rate", 30.0);
    if (!(rate_ > 0.0))
    {
      NODELET_ERROR("~rate = %g Hz is not positive; using 30 Hz", rate_);
      rate_ = 30.0;
      pnh.setParam("rate", rate_);
    }

    if (source_ == "none")
    {
      NODELET_INFO("CameraDriver: ~source is 'none': publishing nothing (images come from a bag or another driver)");
      return;
    }
    if (source_ != "sim" && source_ != "device" && source_ != "video" && source_ != "images")
    {
      NODELET_ERROR(
          "CameraDriver: unknown ~source '%s' (expected sim, device, video, images or none); publishing nothing",
          source_.c_str());
      return;
    }

    it_.reset(new image_transport::ImageTransport(nh));
    camera_pub_ = it_->advertiseCamera("camera/image_raw", 2);
    camera_info_manager_.reset(new camera_info_manager::CameraInfoManager(ros::NodeHandle(nh, "camera"), camera_name));
    if (!camera_info_url_.empty())
      loadCameraInfoUrl();

    if (source_ == "sim" && !setUpSimulator(pnh))
      return;

    diagnostics_.reset(new diagnostic_updater::Updater(nh, pnh, getName()));
    diagnostics_->setHardwareID(source_);
    diagnostics_->add("CameraDriver", this, &CameraDriverNodelet::diagnose);
    frequency_.reset(new diagnostic_updater::FrequencyStatus(
        diagnostic_updater::FrequencyStatusParam(&min_frequency_, &max_frequency_, 0.1, 10)));
    diagnostics_->add(*frequency_);
    setExpectedRate(rate_);
    diagnostics_timer_ =
        nh.createWallTimer(ros::WallDuration(1.0),
                           [this](const ros::WallTimerEvent&)
                           {
                             try
                             {
                               diagnostics_->update();
                             }
                             catch (const std::exception& e)
                             {
                               NODELET_ERROR_THROTTLE(10.0, "CameraDriver: diagnostics failed: %s", e.what());
                             }
                           });

    reconfigure_server_.reset(new dynamic_reconfigure::Server<Config>(config_mutex_, pnh));
    reconfigure_server_->setCallback([this](Config& config, uint32_t level) { reconfigure(config, level); });

    running_ = true;
    worker_ = std::thread(&CameraDriverNodelet::run, this);
  }

  // ---------------------------------------------------------------------
  // Parameters

  void loadCameraInfoUrl()
  {
    // What is published instead: the simulator knows its own intrinsics.
    const char* instead = source_ == "sim" ? "using the simulator's own intrinsics" :
                                             "publishing an uncalibrated camera_info (K = 0) until it is fixed";
    if (!camera_info_manager_->validateURL(camera_info_url_))
    {
      NODELET_ERROR(
          "CameraDriver: ~camera_info_url '%s' is not a valid camera_info_manager URL (file:///path.yaml or "
          "package://pkg/path.yaml); %s",
          camera_info_url_.c_str(), instead);
      return;
    }
    if (!camera_info_manager_->loadCameraInfo(camera_info_url_))
    {
      NODELET_ERROR("CameraDriver: ~camera_info_url '%s' could not be loaded (missing or malformed file, see the "
                    "parser's message above); %s",
                    camera_info_url_.c_str(), instead);
      return;
    }
    if (!camera_info_manager_->isCalibrated())
    {
      NODELET_ERROR("CameraDriver: ~camera_info_url '%s' has no intrinsics (camera_matrix K[0] = 0); %s",
                    camera_info_url_.c_str(), instead);
      return;
    }
    calibrated_from_url_ = true;
  }

  bool readVector(ros::NodeHandle& pnh, const std::string& name, size_t n, std::vector<double>* v)
  {
    if (!pnh.hasParam(name))
      return true;
    std::vector<double> value;
    if (!pnh.getParam(name, value) || value.size() != n)
    {
      NODELET_ERROR("CameraDriver: ~%s must be a list of %zu numbers; keeping the default", name.c_str(), n);
      return false;
    }
    *v = value;
    return true;
  }

  void readVector3(ros::NodeHandle& pnh, const std::string& name, Eigen::Vector3d* v)
  {
    std::vector<double> value(v->data(), v->data() + 3);
    if (readVector(pnh, name, 3, &value))
      *v = Eigen::Vector3d(value[0], value[1], value[2]);
  }

  // A number parameter: unset keeps *v; set but not a number is an error
  // (roscpp's param() would silently keep the default).
  void readNumber(ros::NodeHandle& pnh, const std::string& name, double* v)
  {
    XmlRpc::XmlRpcValue value;
    if (!pnh.getParam(name, value))
      return;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeDouble)
      *v = static_cast<double>(value);
    else if (value.getType() == XmlRpc::XmlRpcValue::TypeInt)
      *v = static_cast<int>(value);
    else
      NODELET_ERROR("CameraDriver: ~%s must be a number, got '%s'; keeping the default %g", name.c_str(),
                    value.toXml().c_str(), *v);
  }

  void readBool(ros::NodeHandle& pnh, const std::string& name, bool* v)
  {
    XmlRpc::XmlRpcValue value;
    if (!pnh.getParam(name, value))
      return;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeBoolean)
      *v = static_cast<bool>(value);
    else
      NODELET_ERROR("CameraDriver: ~%s must be true or false, got '%s'; keeping the default %s", name.c_str(),
                    value.toXml().c_str(), *v ? "true" : "false");
  }

  template <typename Int>
  void readInteger(ros::NodeHandle& pnh, const std::string& name, Int* v)
  {
    XmlRpc::XmlRpcValue value;
    if (!pnh.getParam(name, value))
      return;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeInt && static_cast<int>(value) >= 0)
      *v = static_cast<Int>(static_cast<int>(value));
    else
      NODELET_ERROR("CameraDriver: ~%s must be a non-negative integer, got '%s'; keeping the default %lld",
                    name.c_str(), value.toXml().c_str(), static_cast<long long>(*v));
  }

  bool setUpSimulator(ros::NodeHandle& pnh)
  {
    SimulatorConfig c;
    // The simulator's parameters (README, "Parameters of the simulator"),
    // read over the defaults of SimulatorConfig.
    readInteger(pnh, "seed", &c.rock.seed);
    readInteger(pnh, "noise_seed", &c.noise_seed);
    readInteger(pnh, "projector_rows", &c.projector.rows);
    readInteger(pnh, "projector_cols", &c.projector.cols);
    readInteger(pnh, "rock_subsample", &c.rock_subsample);
    readInteger(pnh, "clutter_specks", &c.clutter.green_specks);
    readInteger(pnh, "clutter_olive", &c.clutter.olive_minerals);
    readInteger(pnh, "clutter_blobs", &c.clutter.green_blobs);
    const std::pair<const char*, double*> numbers[] = {
        {"rock_distance", &c.rock.distance_m},
        {"rock_width", &c.rock.width_m},
        {"rock_height", &c.rock.height_m},
        {"rock_relief", &c.rock.relief_m},
        {"rock_tilt_x", &c.rock.tilt_x_rad},
        {"rock_tilt_y", &c.rock.tilt_y_rad},
        {"texture_scale", &c.rock.texture_scale_m},
        {"albedo_min", &c.rock.albedo_min},
        {"albedo_max", &c.rock.albedo_max},
        {"rock_step_height", &c.rock.step_height_m},
        {"rock_step_x", &c.rock.step_x_m},
        {"projector_roll", &c.projector.roll_rad},
        {"projector_converge_distance", &c.projector.converge_distance_m},
        {"beam_sigma", &c.projector.beam_sigma_rad},
        {"power_scale", &c.projector.power_scale},
        {"sun_level", &c.lighting.sun_level},
        {"exposure", &c.lighting.exposure},
        {"jitter_translation", &c.motion.jitter_translation_m},
        {"jitter_rotation", &c.motion.jitter_rotation_rad},
        {"jitter_frequency", &c.motion.jitter_frequency_hz},
        {"step_period", &c.motion.step_period_s},
        {"return_period", &c.motion.return_period_s},
        {"read_noise", &c.sensor.read_noise_dn},
        {"gain", &c.sensor.gain_dn_per_electron},
        {"focus_distance", &c.sensor.focus_distance_m},
        {"aperture", &c.sensor.aperture_diameter_m},
    };
    for (const auto& p : numbers)
      readNumber(pnh, p.first, p.second);
    readBool(pnh, "shot_noise", &c.sensor.shot_noise);
    readBool(pnh, "vignetting", &c.sensor.natural_vignetting);
    // ~projector_pitch sets both pitches; ~projector_pitch_x/_y override one.
    double pitch = c.projector.pitch_x_rad;
    readNumber(pnh, "projector_pitch", &pitch);
    c.projector.pitch_x_rad = c.projector.pitch_y_rad = pitch;
    readNumber(pnh, "projector_pitch_x", &c.projector.pitch_x_rad);
    readNumber(pnh, "projector_pitch_y", &c.projector.pitch_y_rad);
    readVector3(pnh, "projector_origin", &c.projector.origin_m);
    readVector3(pnh, "drift_velocity", &c.motion.drift_velocity_mps);
    readVector3(pnh, "drift_angular_velocity", &c.motion.drift_angular_velocity_radps);
    readVector3(pnh, "step_translation", &c.motion.step_translation_m);
    std::vector<double> D;
    if (readVector(pnh, "distortion_coeffs", 5, &D) && !D.empty())
    {
      c.sensor.camera.distortion = DistortionModel::kPlumbBob;
      c.sensor.camera.D = D;
    }
    // The dot-versus-sun brightness comes from the scene analysis unless
    // ~dot_to_sun_ratio overrides it (negative = not set).
    radiometry_ = pnh.param<std::string>("radiometry", "study");
    RadiometryModel model = RadiometryModel::kStudyAsStated;
    if (!radiometryModel(radiometry_, &model))
    {
      NODELET_ERROR("CameraDriver: unknown ~radiometry '%s' (study | corrected); using 'study'",
                    radiometry_.c_str());
      radiometry_ = "study";
      model = RadiometryModel::kStudyAsStated;
      pnh.setParam("radiometry", radiometry_);
    }
    double ratio = -1.0;
    readNumber(pnh, "dot_to_sun_ratio", &ratio);
    c.lighting.dot_to_sun_ratio = ratio >= 0.0 ? ratio : LightingConfig::sceneDotToSunRatio(model);
    const std::string ratio_source = ratio >= 0.0 ? " from ~dot_to_sun_ratio" : ", " + radiometry_ + " radiometry";
    duration_s_ = pnh.param("duration", 0.0);

    // A calibration file for the simulated camera replaces its intrinsics
    // (and distortion) when it is of the simulator's size.
    if (calibrated_from_url_)
    {
      const sensor_msgs::CameraInfo info = camera_info_manager_->getCameraInfo();
      CameraModel model;
      std::string why;
      if (static_cast<int>(info.width) != c.sensor.camera.width ||
          static_cast<int>(info.height) != c.sensor.camera.height)
        NODELET_ERROR(
            "CameraDriver: ~camera_info_url '%s' is for %ux%u images but the simulator renders %dx%d; using "
            "the simulator's own intrinsics",
            camera_info_url_.c_str(), info.width, info.height, c.sensor.camera.width, c.sensor.camera.height);
      else if (!cameraModelFromInfo(info, &model, &why))
        NODELET_ERROR("CameraDriver: ~camera_info_url '%s' is unusable (%s); using the simulator's own intrinsics",
                      camera_info_url_.c_str(), why.c_str());
      else
        c.sensor.camera = model;
    }

    try
    {
      const auto t0 = std::chrono::steady_clock::now();
      simulator_ = std::make_shared<const Simulator>(c);
      NODELET_INFO(
          "CameraDriver: simulator ready in %.0f ms (rock at %.2f m, relief %.2f m, %dx%d beams, sun %.2f, dot/sun "
          "ratio %.4g%s)",
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(), c.rock.distance_m,
          c.rock.relief_m, c.projector.rows, c.projector.cols, c.lighting.sun_level, c.lighting.dot_to_sun_ratio,
          ratio_source.c_str());
    }
    catch (const std::exception& e)
    {
      NODELET_ERROR("CameraDriver: the simulator parameters are invalid, publishing nothing: %s", e.what());
      return false;
    }
    sim_info_ = cameraInfoFromModel(simulator_->camera(), std_msgs::Header());

    ros::NodeHandle& nh = getNodeHandle();
    gt_points_pub_ = nh.advertise<sensor_msgs::PointCloud2>("sim/ground_truth/points", 2);
    gt_pose_pub_ = nh.advertise<PoseDelta>("sim/ground_truth/pose_delta", 2);
    gt_spots_pub_ = nh.advertise<CentroidArray>("sim/ground_truth/spots", 2);
    lazy_ = pnh.param("lazy", true);
    if (lazy_)
      NODELET_INFO(
          "CameraDriver: ~lazy: frames are rendered only while someone subscribes to the image or the "
          "ground truth (simulated time runs on regardless)");

    const std::string calibration_path = pnh.param<std::string>("write_projector_calibration", "");
    if (!calibration_path.empty())
    {
      std::string why;
      if (saveProjectorCalibration(calibration_path, simulator_->projector(), &why))
        NODELET_INFO("CameraDriver: wrote the simulator's exact projector calibration to %s", calibration_path.c_str());
      else
        NODELET_ERROR("CameraDriver: cannot write the projector calibration to '%s': %s", calibration_path.c_str(),
                      why.c_str());
    }
    return true;
  }

  void reconfigure(Config& config, uint32_t /*level*/)
  {
    // Called with config_mutex_ held.
    if (simulator_)
    {
      SimulatorConfig c = simulator_->config();
      c.lighting.sun_level = config.sun_level;
      RadiometryModel model = RadiometryModel::kStudyAsStated;
      if (!radiometryModel(config.radiometry, &model))
      {
        NODELET_WARN("CameraDriver: unknown radiometry '%s' (study | corrected); keeping '%s'",
                      config.radiometry.c_str(), radiometry_.c_str());
        config.radiometry = radiometry_;
        radiometryModel(radiometry_, &model);
      }
      radiometry_ = config.radiometry;
      c.lighting.dot_to_sun_ratio =
          config.dot_to_sun_ratio >= 0.0 ? config.dot_to_sun_ratio : LightingConfig::sceneDotToSunRatio(model);
      c.lighting.exposure = config.exposure;
      c.projector.power_scale = config.power_scale;
      c.motion.jitter_translation_m = config.jitter_translation;
      c.motion.jitter_rotation_rad = config.jitter_rotation;
      c.motion.jitter_frequency_hz = config.jitter_frequency;
      c.sensor.read_noise_dn = config.read_noise;
      c.sensor.shot_noise = config.shot_noise;
      try
      {
        auto updated = std::make_shared<Simulator>(*simulator_);
        updated->updateLive(c);
        simulator_ = updated;
      }
      catch (const std::exception& e)
      {
        NODELET_ERROR("CameraDriver: rejected simulator settings (%s); keeping the previous ones", e.what());
        // Show the values in force, not the rejected ones, in rqt_reconfigure.
        const SimulatorConfig& kept = simulator_->config();
        config.sun_level = kept.lighting.sun_level;
        config.dot_to_sun_ratio = kept.lighting.dot_to_sun_ratio;
        config.exposure = kept.lighting.exposure;
        config.power_scale = kept.projector.power_scale;
        config.jitter_translation = kept.motion.jitter_translation_m;
        config.jitter_rotation = kept.motion.jitter_rotation_rad;
        config.jitter_frequency = kept.motion.jitter_frequency_hz;
        config.read_noise = kept.sensor.read_noise_dn;
        config.shot_noise = kept.sensor.shot_noise;
      }
    }
    rate_ = config.rate;
    setExpectedRate(rate_);
  }

  static bool radiometryModel(const std::string& name, RadiometryModel* model)
  {
    if (name == "study")
      *model = RadiometryModel::kStudyAsStated;
    else if (name == "corrected")
      *model = RadiometryModel::kCorrected;
    else
      return false;
    return true;
  }

  void setExpectedRate(double rate)
  {
    // The tolerance of FrequencyStatus applies on top of these bounds.
    min_frequency_ = 0.9 * rate;
    max_frequency_ = 1.1 * rate;
  }

  double currentRate()
  {
    boost::recursive_mutex::scoped_lock lock(config_mutex_);
    return rate_;
  }

  // ---------------------------------------------------------------------
  // Worker

  // Sleeps until `t`, waking every 50 ms to honour shutdown.
  bool sleepUntil(const ros::WallTime& t)
  {
    while (running_ && ros::ok())
    {
      const ros::WallTime now = ros::WallTime::now();
      if (now >= t)
        return true;
      const double left = (t - now).toSec();
      ros::WallDuration(std::min(left, 0.05)).sleep();
    }
    return false;
  }

  bool sleepFor(double seconds) { return sleepUntil(ros::WallTime::now() + ros::WallDuration(seconds)); }

  void noteError(const std::string& what)
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    last_error_ = what;
    last_error_time_ = ros::WallTime::now();
  }

  void run()
  {
    while (running_ && ros::ok())
    {
      try
      {
        if (source_ == "sim")
          runSimulator();
        else if (source_ == "device")
          runDevice();
        else if (source_ == "video")
          runVideo();
        else if (source_ == "images")
          runImages();
        return;
      }
      catch (const std::exception& e)
      {
        // Nothing may escape the thread (it would terminate the manager).
        noteError(e.what());
        NODELET_ERROR_THROTTLE(5.0, "CameraDriver: %s source failed: %s; restarting it in %.0f s", source_.c_str(),
                               e.what(), kRetryPeriodS);
        sleepFor(kRetryPeriodS);
      }
    }
  }

  // Acquisition time of a frame; waits while ROS time is not running yet
  // (use_sim_time without a clock).
  bool acquisitionStamp(ros::Time* stamp)
  {
    *stamp = ros::Time::now();
    if (stamp->isZero())
    {
      NODELET_WARN_THROTTLE(10.0, "CameraDriver: ROS time is zero (use_sim_time without /clock?); waiting");
      return false;
    }
    return true;
  }

  // Paces the loop: next tick one period later, no burst after a stall.
  void advance(ros::WallTime* next, double rate)
  {
    *next += ros::WallDuration(1.0 / rate);
    const ros::WallTime now = ros::WallTime::now();
    if (*next < now - ros::WallDuration(1.0 / rate))
      *next = now;
  }

  void runSimulator()
  {
    ros::WallTime next = ros::WallTime::now();
    // Simulated time advances by 1 / rate per frame, deterministically; a
    // rate change keeps it continuous.
    uint64_t index = 0, index_base = 0;
    double t_base = 0.0, rate_base = currentRate();
    bool announced_end = false;
    // Publish rate actually reached (rendering may not keep up): mean period
    // between frames published on consecutive ticks.
    ros::WallTime previous_publish;
    bool consecutive = false;
    while (running_ && ros::ok())
    {
      const double rate = currentRate();
      if (rate != rate_base)
      {
        t_base += (index - index_base) / rate_base;
        index_base = index;
        rate_base = rate;
      }
      if (!sleepUntil(next))
        return;
      advance(&next, rate);
      const double t = t_base + (index - index_base) / rate;
      if (duration_s_ > 0.0 && t >= duration_s_)
      {
        if (!announced_end)
          NODELET_INFO("CameraDriver: ~duration %.1f s of simulated time reached; no more frames", duration_s_);
        announced_end = true;
        continue;
      }
      ros::Time stamp;
      if (!acquisitionStamp(&stamp))
        continue;
      ++index;
      if (lazy_ && camera_pub_.getNumSubscribers() == 0 && gt_points_pub_.getNumSubscribers() == 0 &&
          gt_pose_pub_.getNumSubscribers() == 0 && gt_spots_pub_.getNumSubscribers() == 0)
      {
        consecutive = false;
        continue;
      }

      std::shared_ptr<const Simulator> sim;
      {
        boost::recursive_mutex::scoped_lock lock(config_mutex_);
        sim = simulator_;
      }
      const auto t0 = std::chrono::steady_clock::now();
      SimFrame frame = sim->render(t);
      const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();

      std_msgs::Header header;
      header.stamp = stamp;
      header.frame_id = frame_id_;
      auto info = boost::make_shared<sensor_msgs::CameraInfo>(sim_info_);
      info->header = header;
      publishImage(header, frame.image, info, ms);

      const ProjectorCalibration& projector = sim->projector();
      std::vector<float> intensity(frame.peak_dn.begin(), frame.peak_dn.end());
      uint32_t visible = 0;
      auto spots = boost::make_shared<CentroidArray>();
      spots->header = header;
      spots->image_width = frame.image.cols;
      spots->image_height = frame.image.rows;
      for (int b = 0; b < projector.beamCount(); ++b)
      {
        if (!frame.visible[b])
          continue;
        ++visible;
        Centroid c;
        c.x = frame.pixels[b].x;
        c.y = frame.pixels[b].y;
        // Area of the 2-sigma disc of the rendered dot, the size a detector
        // thresholding at ~14 % of the peak would find.
        c.area = static_cast<float>(M_PI * 4.0 * frame.blur_sigma_px[b] * frame.blur_sigma_px[b]);
        c.intensity = static_cast<float>(frame.peak_dn[b]);
        c.beam = b;
        spots->centroids.push_back(c);
      }
      gt_points_pub_.publish(makeBeamCloud(header, projector.rows, projector.cols, frame.points, intensity));
      auto pose = boost::make_shared<PoseDelta>();
      pose->header = header;
      pose->transform = transformFromIsometry(frame.delta);
      pose->rms_residual = 0.0;
      pose->points_used = visible;
      pose->valid = true;
      pose->status = "ground truth, simulated t = " + std::to_string(t) + " s";
      gt_pose_pub_.publish(pose);
      gt_spots_pub_.publish(spots);

      const ros::WallTime now = ros::WallTime::now();
      if (consecutive)
        noteFramePeriod((now - previous_publish).toSec(), rate, ms);
      previous_publish = now;
      consecutive = true;
    }
  }

  // Keeps a running mean of the publish period; when rendering cannot keep
  // up, the loop publishes as fast as it can (no catch-up burst, see
  // advance()) and says so.
  void noteFramePeriod(double period_s, double rate, double render_ms)
  {
    double hz;
    {
      std::lock_guard<std::mutex> lock(status_mutex_);
      mean_period_s_ = mean_period_s_ > 0.0 ? 0.9 * mean_period_s_ + 0.1 * period_s : period_s;
      hz = 1.0 / mean_period_s_;
    }
    if (hz < 0.9 * rate)
      NODELET_WARN_THROTTLE(30.0, "CameraDriver: rendering at %.1f Hz < requested %.1f Hz (%.1f ms per render)", hz,
                            rate, render_ms);
  }

  // camera_info for a frame of a real source: the loaded calibration when it
  // fits the frame, otherwise an uncalibrated one (K = 0) of the frame's size.
  sensor_msgs::CameraInfoPtr infoFor(const std_msgs::Header& header, const cv::Mat& image)
  {
    auto info = boost::make_shared<sensor_msgs::CameraInfo>(camera_info_manager_->getCameraInfo());
    if (calibrated_from_url_ &&
        (static_cast<int>(info->width) != image.cols || static_cast<int>(info->height) != image.rows))
    {
      const std::string why = "~camera_info_url '" + camera_info_url_ + "' is for " + std::to_string(info->width) +
                              "x" + std::to_string(info->height) + " images but the " + source_ + " source gives " +
                              std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                              "; publishing an uncalibrated camera_info (K = 0)";
      noteError(why);
      NODELET_ERROR_THROTTLE(10.0, "CameraDriver: %s", why.c_str());
      info = boost::make_shared<sensor_msgs::CameraInfo>();
    }
    info->header = header;
    info->width = image.cols;
    info->height = image.rows;
    return info;
  }

  void publishImage(const std_msgs::Header& header, const cv::Mat& bgr, const sensor_msgs::CameraInfoPtr& info,
                    double processing_ms)
  {
    sensor_msgs::ImagePtr msg = cv_bridge::CvImage(header, "bgr8", bgr).toImageMsg();
    camera_pub_.publish(msg, info);
    frequency_->tick();
    std::lock_guard<std::mutex> lock(status_mutex_);
    ++frames_published_;
    processing_ms_ = processing_ms;
    last_size_ = cv::Size(bgr.cols, bgr.rows);
  }

  // Converts whatever a capture or a file gives to bgr8.
  static cv::Mat toBgr(const cv::Mat& in)
  {
    cv::Mat out;
    if (in.type() == CV_8UC3)
      return in;
    cv::Mat eight = in;
    if (in.depth() != CV_8U)
    {
      double lo, hi;
      cv::minMaxLoc(in.reshape(1), &lo, &hi);
      const double scale = in.depth() == CV_16U ? 255.0 / 65535.0 : (hi > 0 ? 255.0 / hi : 1.0);
      in.convertTo(eight, CV_8U, scale);
    }
    if (eight.channels() == 1)
      cv::cvtColor(eight, out, cv::COLOR_GRAY2BGR);
    else if (eight.channels() == 4)
      cv::cvtColor(eight, out, cv::COLOR_BGRA2BGR);
    else
      out = eight;
    return out;
  }

  void publishCaptured(const cv::Mat& raw, const ros::Time& stamp, double processing_ms)
  {
    const cv::Mat bgr = toBgr(raw);
    std_msgs::Header header;
    header.stamp = stamp;
    header.frame_id = frame_id_;
    publishImage(header, bgr, infoFor(header, bgr), processing_ms);
  }

  void runDevice()
  {
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    std::string device = "0";
    XmlRpc::XmlRpcValue value;
    if (pnh.getParam("device", value))
    {
      if (value.getType() == XmlRpc::XmlRpcValue::TypeInt)
        device = std::to_string(static_cast<int>(value));
      else if (value.getType() == XmlRpc::XmlRpcValue::TypeString)
        device = static_cast<std::string>(value);
    }
    const int width = pnh.param("width", 0), height = pnh.param("height", 0);
    const double fps = pnh.param("fps", 0.0);
    const bool numeric = !device.empty() && std::all_of(device.begin(), device.end(), ::isdigit);
    cv::VideoCapture capture;
    while (running_ && ros::ok())
    {
      if (!capture.isOpened())
      {
        const bool opened =
            numeric ? capture.open(std::stoi(device), cv::CAP_V4L2) : capture.open(device, cv::CAP_V4L2);
        if (!opened || !capture.isOpened())
        {
          const std::string why = "cannot open V4L2 device '" + device +
                                  "' (not connected, busy, or no permission on /dev/video*); retrying every 2 s";
          noteError(why);
          NODELET_ERROR_THROTTLE(10.0, "CameraDriver: %s", why.c_str());
          capture.release();
          sleepFor(kRetryPeriodS);
          continue;
        }
        if (width > 0)
          capture.set(cv::CAP_PROP_FRAME_WIDTH, width);
        if (height > 0)
          capture.set(cv::CAP_PROP_FRAME_HEIGHT, height);
        if (fps > 0)
          capture.set(cv::CAP_PROP_FPS, fps);
        NODELET_INFO("CameraDriver: opened device '%s' (%gx%g at %g Hz)", device.c_str(),
                     capture.get(cv::CAP_PROP_FRAME_WIDTH), capture.get(cv::CAP_PROP_FRAME_HEIGHT),
                     capture.get(cv::CAP_PROP_FPS));
      }
      cv::Mat frame;
      const auto t0 = std::chrono::steady_clock::now();
      const bool ok = capture.read(frame);
      ros::Time stamp;
      if (!ok || frame.empty())
      {
        const std::string why = "device '" + device + "' stopped delivering frames (unplugged?); reopening in 2 s";
        noteError(why);
        NODELET_ERROR_THROTTLE(10.0, "CameraDriver: %s", why.c_str());
        capture.release();
        sleepFor(kRetryPeriodS);
        continue;
      }
      if (!acquisitionStamp(&stamp))
        continue;
      publishCaptured(frame, stamp,
                      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
  }

  void runVideo()
  {
    const std::string file = getPrivateNodeHandle().param<std::string>("video_file", "");
    const bool loop = getPrivateNodeHandle().param("loop", true);
    cv::VideoCapture capture;
    ros::WallTime next = ros::WallTime::now();
    int frames_in_pass = 0;
    bool finished = false;
    while (running_ && ros::ok())
    {
      if (finished)
      {
        sleepFor(0.5);
        continue;
      }
      if (!capture.isOpened())
      {
        std::string why;
        if (file.empty())
          why = "~video_file is empty; set it to the video to play";
        else if (!boost::filesystem::is_regular_file(file))
          why = "video file '" + file + "' does not exist";
        else if (!capture.open(file) || !capture.isOpened())
          why = "cannot decode video file '" + file + "' (unknown container or codec)";
        if (!why.empty())
        {
          noteError(why);
          NODELET_ERROR_THROTTLE(10.0, "CameraDriver: %s; retrying every 2 s", why.c_str());
          capture.release();
          sleepFor(kRetryPeriodS);
          continue;
        }
        NODELET_INFO("CameraDriver: playing '%s' at %g Hz%s", file.c_str(), currentRate(), loop ? ", looping" : "");
        frames_in_pass = 0;
        next = ros::WallTime::now();
      }
      if (!sleepUntil(next))
        return;
      advance(&next, currentRate());
      cv::Mat frame;
      const auto t0 = std::chrono::steady_clock::now();
      if (!capture.read(frame) || frame.empty())
      {
        capture.release();
        if (frames_in_pass == 0)
        {
          const std::string why = "video file '" + file + "' has no readable frames";
          noteError(why);
          NODELET_ERROR_THROTTLE(10.0, "CameraDriver: %s; retrying every 2 s", why.c_str());
          sleepFor(kRetryPeriodS);
        }
        else if (!loop)
        {
          NODELET_INFO("CameraDriver: end of '%s' after %d frames (~loop is false)", file.c_str(), frames_in_pass);
          finished = true;
        }
        continue;
      }
      ++frames_in_pass;
      ros::Time stamp;
      if (!acquisitionStamp(&stamp))
        continue;
      publishCaptured(frame, stamp,
                      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
  }

  std::vector<std::string> listImages(const std::string& dir, std::string* why)
  {
    std::vector<std::string> files;
    boost::system::error_code ec;
    if (dir.empty())
    {
      *why = "~image_dir is empty; set it to a folder of images";
      return files;
    }
    if (!boost::filesystem::is_directory(dir, ec))
    {
      *why = "image folder '" + dir + "' does not exist or is not a folder";
      return files;
    }
    for (boost::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
      if (boost::filesystem::is_regular_file(it->path(), ec) && isImageFile(it->path()))
        files.push_back(it->path().string());
    std::sort(files.begin(), files.end());
    if (files.empty())
      *why = "image folder '" + dir + "' contains no images (png, jpg, bmp, tif, ppm, pgm, webp)";
    return files;
  }

  void runImages()
  {
    const std::string dir = getPrivateNodeHandle().param<std::string>("image_dir", "");
    const bool loop = getPrivateNodeHandle().param("loop", true);
    ros::WallTime next = ros::WallTime::now();
    bool announced = false;
    while (running_ && ros::ok())
    {
      std::string why;
      const std::vector<std::string> files = listImages(dir, &why);
      if (files.empty())
      {
        noteError(why);
        NODELET_ERROR_THROTTLE(10.0, "CameraDriver: %s; retrying every 2 s", why.c_str());
        sleepFor(kRetryPeriodS);
        continue;
      }
      if (!announced)
        NODELET_INFO("CameraDriver: playing %zu images from '%s' at %g Hz%s", files.size(), dir.c_str(), currentRate(),
                     loop ? ", looping" : "");
      announced = true;
      int published = 0;
      for (const std::string& path : files)
      {
        if (!sleepUntil(next))
          return;
        advance(&next, currentRate());
        const auto t0 = std::chrono::steady_clock::now();
        cv::Mat image;
        try
        {
          image = cv::imread(path, cv::IMREAD_UNCHANGED);
        }
        catch (const cv::Exception& e)
        {
          image.release();
        }
        if (image.empty())
        {
          const std::string what = "cannot read image '" + path + "' (unreadable or not an image); skipped";
          noteError(what);
          NODELET_ERROR_THROTTLE(5.0, "CameraDriver: %s", what.c_str());
          continue;
        }
        ros::Time stamp;
        if (!acquisitionStamp(&stamp))
          continue;
        publishCaptured(image, stamp,
                        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
        ++published;
      }
      if (published == 0)
        sleepFor(kRetryPeriodS);  // every file failed: do not spin on them
      if (!loop)
      {
        NODELET_INFO("CameraDriver: published the %zu images of '%s' once (~loop is false)", files.size(), dir.c_str());
        while (running_ && ros::ok())
          sleepFor(0.5);
        return;
      }
    }
  }

  // ---------------------------------------------------------------------
  // Diagnostics

  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat)
  {
    const double rate = currentRate();  // before status_mutex_: one lock at a time
    std::lock_guard<std::mutex> lock(status_mutex_);
    const bool recent_error = !last_error_.empty() && (ros::WallTime::now() - last_error_time_).toSec() < 10.0;
    const double reached_hz = mean_period_s_ > 0.0 ? 1.0 / mean_period_s_ : 0.0;
    char slow[128];
    std::snprintf(slow, sizeof(slow), "rendering at %.1f Hz < requested %.1f Hz", reached_hz, rate);
    if (recent_error)
      stat.summary(diagnostic_msgs::DiagnosticStatus::ERROR, last_error_);
    else if (frames_published_ == 0)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "no frame published yet");
    else if (source_ == "sim" && reached_hz > 0.0 && reached_hz < 0.9 * rate)
      stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, slow);
    else
      stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "publishing");
    if (source_ == "sim")
      stat.add("publish rate reached (Hz)", reached_hz);
    stat.add("source", source_);
    stat.add("frame_id", frame_id_);
    stat.add("frames published", frames_published_);
    stat.add("image size", std::to_string(last_size_.width) + "x" + std::to_string(last_size_.height));
    stat.add(source_ == "sim" ? "render time (ms)" : "acquisition time (ms)", processing_ms_);
    stat.add("camera_info",
             calibrated_from_url_ ? camera_info_url_ : (source_ == "sim" ? "simulator" : "uncalibrated"));
    stat.add("last error", last_error_);
  }

  std::string source_, frame_id_, camera_info_url_;
  std::string radiometry_ = "study";  // under config_mutex_ once running
  double rate_ = 30.0, duration_s_ = 0.0;
  bool lazy_ = true;
  bool calibrated_from_url_ = false;

  boost::recursive_mutex config_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<Config>> reconfigure_server_;
  std::shared_ptr<const Simulator> simulator_;  // replaced, never modified, under config_mutex_
  sensor_msgs::CameraInfo sim_info_;

  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::CameraPublisher camera_pub_;
  std::unique_ptr<camera_info_manager::CameraInfoManager> camera_info_manager_;
  ros::Publisher gt_points_pub_, gt_pose_pub_, gt_spots_pub_;

  std::unique_ptr<diagnostic_updater::Updater> diagnostics_;
  std::unique_ptr<diagnostic_updater::FrequencyStatus> frequency_;
  double min_frequency_ = 27.0, max_frequency_ = 33.0;
  ros::WallTimer diagnostics_timer_;

  std::mutex status_mutex_;
  std::string last_error_;
  ros::WallTime last_error_time_;
  uint64_t frames_published_ = 0;
  double processing_ms_ = 0.0;
  double mean_period_s_ = 0.0;  // sim: running mean of the publish period
  cv::Size last_size_;

  std::atomic<bool> running_{false};
  std::thread worker_;
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::CameraDriverNodelet, nodelet::Nodelet)
