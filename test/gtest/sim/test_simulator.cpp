// Tests of the scene simulator against its own geometric ground truth and the
// study's formulas. Frames are 1024 x 1024 as everywhere in the package.
#include <algorithm>
#include <cmath>
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/sim/design/scene_analysis.h"
#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "support/sim_measure.h"

namespace sls = structured_light_stabilizer;
using sim_measure::channelMoments;
using sim_measure::Moments;
using sim_measure::nightNoNoise;

namespace
{

bool isIdentity(const Eigen::Isometry3d& T, double tol)
{
  return (T.matrix() - Eigen::Matrix4d::Identity()).cwiseAbs().maxCoeff() <= tol;
}

}  // namespace

TEST(Simulator, RejectsInvalidConfig)
{
  sls::SimulatorParams c;
  c.rock.albedo_min = 0.5;
  c.rock.albedo_max = 0.2;
  EXPECT_FALSE(c.validate().empty());
  EXPECT_THROW(sls::Simulator{c}, std::invalid_argument);
  c = sls::SimulatorParams();
  c.rock.distance_m = -1.0;
  EXPECT_THROW(sls::Simulator{c}, std::invalid_argument);
  c = sls::SimulatorParams();
  c.rock.fine_texture_period_m = 0.001;  // finer than the 2 mm grid can hold
  EXPECT_NE(c.validate().find("fine_texture_period_m"), std::string::npos) << c.validate();
  c = sls::SimulatorParams();
  c.rock.fine_texture_amplitude = std::nan("");
  EXPECT_NE(c.validate().find("fine_texture_amplitude"), std::string::npos) << c.validate();
  EXPECT_TRUE(sls::SimulatorParams().validate().empty());
}

TEST(Simulator, MotionStartsAtIdentityAndReturnsWithThePeriod)
{
  sls::SimulatorParams c;
  c.motion.jitter_translation_m = 0.004;
  c.motion.jitter_rotation_rad = 0.003;
  c.motion.jitter_frequency_hz = 0.9;
  c.motion.drift_velocity_mps = Eigen::Vector3d(0.01, -0.005, 0.002);
  c.motion.drift_angular_velocity_radps = Eigen::Vector3d(0.001, 0.002, -0.001);
  c.motion.step_period_s = 0.7;
  c.motion.step_translation_m = Eigen::Vector3d(0.002, 0, 0);
  c.motion.return_period_s = 2.0;
  sls::Simulator sim(c);
  EXPECT_TRUE(isIdentity(sim.motion(0.0), 0.0)) << sim.motion(0.0).matrix();
  EXPECT_TRUE(isIdentity(sim.render(0.0).delta, 0.0));
  double worst = 0.0;
  for (int k = 1; k <= 5; ++k)
    worst = std::max(worst, (sim.motion(k * 2.0).matrix() - Eigen::Matrix4d::Identity()).cwiseAbs().maxCoeff());
  std::cout << "[ MEASURE ] |motion(k * return_period) - I|max = " << worst << "\n";
  EXPECT_LT(worst, 1e-12);
  // In between it really moves, by about the configured amounts.
  const Eigen::Isometry3d mid = sim.motion(0.9);
  EXPECT_GT(mid.translation().norm(), 1e-3);
  EXPECT_LT(mid.translation().norm(), 0.05);

  // Without a period the drift accumulates linearly.
  c.motion = sls::RigMotionParams();
  c.motion.drift_velocity_mps = Eigen::Vector3d(0.01, 0, 0);
  sls::Simulator drift(c);
  // delta = T_cur_ref: the camera moved +x, so rock points move -x in it.
  EXPECT_NEAR(drift.motion(3.0).translation().x(), -0.03, 1e-12);
  EXPECT_TRUE(isIdentity(drift.motion(0.0), 0.0));
  // Camera pose in the rock frame is consistent with delta.
  const Eigen::Isometry3d lhs = drift.cameraPose(3.0);
  const Eigen::Isometry3d rhs = drift.cameraPose(0.0) * drift.motion(3.0).inverse();
  EXPECT_LT((lhs.matrix() - rhs.matrix()).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(Simulator, HitPointsLieOnTheSurfaceAndOnTheirBeams)
{
  for (double relief : {0.0, 0.15, 0.5})
  {
    sls::SimulatorParams c;
    c.rock.relief_m = relief;
    c.rock.tilt_x_rad = 0.1;
    c.motion.jitter_translation_m = 0.01;
    c.motion.jitter_rotation_rad = 0.01;
    sls::Simulator sim(c);
    double worst_surface = 0.0, worst_beam = 0.0, worst_pixel = 0.0;
    int visible = 0;
    for (double t : {0.0, 0.37, 1.91})
    {
      const sls::SimFrame f = sim.render(t);
      for (int b = 0; b < sim.projector().beamCount(); ++b)
      {
        if (!f.visible[b])
        {
          EXPECT_TRUE(std::isnan(f.points[b].x()));
          continue;
        }
        ++visible;
        const Eigen::Vector3d p_rock = sim.cameraPose(t) * f.points[b];
        worst_surface = std::max(worst_surface, std::abs(sim.surfaceOffset(p_rock)));
        const sls::BeamRay& ray = sim.projector().beams[b];
        const Eigen::Vector3d rel = f.points[b] - ray.origin;
        worst_beam = std::max(worst_beam, (rel - rel.dot(ray.direction) * ray.direction).norm());
        const cv::Point2d px = sim.camera().project(f.points[b]);
        worst_pixel = std::max(worst_pixel, std::hypot(px.x - f.pixels[b].x, px.y - f.pixels[b].y));
      }
    }
    std::cout << "[ MEASURE ] relief " << relief << " m: " << visible
              << " visible hits, max |surface offset| = " << worst_surface
              << " m, max distance to beam = " << worst_beam << " m\n";
    EXPECT_GT(visible, 250);
    EXPECT_LT(worst_surface, 1e-6);
    EXPECT_LT(worst_beam, 1e-9);
    EXPECT_LT(worst_pixel, 1e-9);
  }
}

TEST(Simulator, NoiseFreeDotCentroidIsTheProjectedHitPoint)
{
  for (bool distorted : {false, true})
  {
    sls::SimulatorParams c = nightNoNoise();
    c.lighting.dot_to_sun_ratio = 1.5;  // peaks stay below saturation
    // Uniform albedo on a plane (tilted, so the footprints are sheared): each
    // pixel of a dot reflects the albedo under it, and on relief receives the
    // irradiance of its own incidence, so texture and relief bend centroids
    // (test_simulator_physics: DotOverAmbient..., DotOnRoughRock...).
    c.rock.albedo_min = c.rock.albedo_max = 0.3;
    c.rock.relief_m = 0.0;
    c.rock.tilt_x_rad = 0.25;
    c.rock.tilt_y_rad = -0.3;
    if (distorted)
    {
      c.sensor.camera.distortion = sls::DistortionModel::kPlumbBob;
      c.sensor.camera.D = {-0.15, 0.06, 0.0008, -0.0005, 0.0};
    }
    c.motion.jitter_translation_m = 0.005;
    sls::Simulator sim(c);
    const sls::SimFrame f = sim.render(0.41);
    double worst_lin = 0.0, worst_8bit = 0.0, sum2_8bit = 0.0, max_peak = 0.0;
    int n = 0;
    for (int b = 0; b < sim.projector().beamCount(); ++b)
    {
      if (!f.visible[b])
        continue;
      const int half = static_cast<int>(std::ceil(5.0 * f.blur_sigma_px[b])) + 1;
      const cv::Point2d p = f.pixels[b];
      if (p.x < half || p.y < half || p.x > 1023 - half || p.y > 1023 - half)
        continue;
      const Moments ml = channelMoments(f.linear, 1, p, half);
      const Moments mq = channelMoments(f.image, 1, p, half);
      worst_lin = std::max(worst_lin, std::hypot(ml.x - p.x, ml.y - p.y));
      const double e = std::hypot(mq.x - p.x, mq.y - p.y);
      worst_8bit = std::max(worst_8bit, e);
      sum2_8bit += e * e;
      max_peak = std::max(max_peak, f.peak_dn[b]);
      ++n;
    }
    std::cout << "[ MEASURE ] " << (distorted ? "plumb_bob" : "no distortion") << ": " << n
              << " dots, centroid error max " << worst_lin << " px (linear), max " << worst_8bit << " px / RMS "
              << std::sqrt(sum2_8bit / std::max(n, 1)) << " px (8-bit), brightest peak " << max_peak << " DN\n";
    EXPECT_GT(n, 80);
    EXPECT_LT(max_peak, 255.0);
    EXPECT_LT(worst_lin, 0.01);
    // 8-bit rounding of the tails costs a little more.
    EXPECT_LT(worst_8bit, 0.03);
  }
}

TEST(Simulator, SameSeedGivesIdenticalFramesWhateverTheThreadCount)
{
  sls::SimulatorParams c;
  c.motion.jitter_translation_m = 0.003;
  c.clutter.green_specks = 50;
  c.clutter.olive_minerals = 10;
  c.clutter.green_blobs = 5;
  const int threads = cv::getNumThreads();
  const sls::SimFrame a = sls::Simulator(c).render(0.5);
  cv::setNumThreads(1);
  const sls::SimFrame b = sls::Simulator(c).render(0.5);
  cv::setNumThreads(threads);
  EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0.0);
  // Another noise seed, another time, or another rock seed change the frame.
  sls::SimulatorParams c2 = c;
  c2.noise_seed = 7;
  EXPECT_GT(cv::norm(a.image, sls::Simulator(c2).render(0.5).image, cv::NORM_L1), 0.0);
  EXPECT_GT(cv::norm(a.image, sls::Simulator(c).render(0.6).image, cv::NORM_L1), 0.0);
  c2 = c;
  c2.rock.seed = 99;
  EXPECT_GT(cv::norm(a.image, sls::Simulator(c2).render(0.5).image, cv::NORM_L1), 0.0);
}

TEST(Simulator, SubsampledRockShadingMatchesTheExactOne)
{
  // rock_subsample 2 (the default) ray-casts the rock on every other pixel
  // and interpolates the surface point in between; compared with a cast per
  // pixel (1), noise-free, on the default rock, on a steep one, with lens
  // distortion, and with the fine texture (2 cm) at 2.0 m, where its 2 mm
  // albedo cells are 1 px (interpolating the radiance instead lost that
  // texture, which the dots' light keeps). The dots are identical by
  // construction (rendered per pixel), so this is the rock.
  for (int variant = 0; variant < 4; ++variant)
  {
    sls::SimulatorParams c;
    c.lighting.sun_level = 1.0;
    c.sensor.read_noise_dn = 0.0;
    c.sensor.shot_noise = false;
    c.keep_linear = true;
    c.projector.power_scale = 0.0;
    c.motion.jitter_translation_m = 0.004;
    if (variant == 1)
      c.rock.relief_m = 0.5;
    if (variant == 2)
    {
      c.sensor.camera.distortion = sls::DistortionModel::kPlumbBob;
      c.sensor.camera.D = {-0.12, 0.05, 0.0005, -0.0003, 0.0};
    }
    if (variant == 3)
    {
      c.rock.fine_texture_period_m = 0.02;
      c.rock.distance_m = 2.0;
    }
    sls::SimulatorParams exact = c;
    exact.rock_subsample = 1;
    const cv::Mat a = sls::Simulator(c).render(0.3).linear, b = sls::Simulator(exact).render(0.3).linear;
    cv::Mat diff, mean_level;
    cv::absdiff(a, b, diff);
    diff = diff.reshape(1);
    std::vector<float> v(diff.begin<float>(), diff.end<float>());
    std::nth_element(v.begin(), v.begin() + v.size() * 99 / 100, v.end());
    const double p99 = v[v.size() * 99 / 100];
    const double mean_diff = cv::mean(diff)[0], mean = cv::mean(b.reshape(1))[0];
    std::cout << "[ MEASURE ] "
              << (variant == 0   ? "default rock"
                  : variant == 1 ? "0.5 m relief"
                  : variant == 2 ? "plumb_bob"
                                 : "fine texture at 2.0 m")
              << ": |subsampled - exact| mean " << mean_diff << " DN, 99th percentile " << p99 << " DN (mean level "
              << mean << " DN)\n";
    // Measured: 0.01-0.1 % and 0.1-3.8 % (interpolating the radiance: 0.34-2.5 %
    // and 2.2-15 %, the fine texture failing both).
    EXPECT_LT(mean_diff, 0.005 * mean);  // below the sensor noise (>= 1 DN)
    EXPECT_LT(p99, 0.06 * mean);
  }
}

TEST(Simulator, DefocusFollowsTheDiameterOfConfusion)
{
  sls::SimulatorParams c;
  sls::Simulator study(c);
  // Study §2.1.1.4: DoC = 0.0117 mm for the chosen 1.9 mm aperture, at the far
  // end of the 1-2 m range.
  std::cout << "[ MEASURE ] DoC(2 m) = " << study.diameterOfConfusion(2.0) * 1e3 << " mm (study 0.0117 mm)\n";
  EXPECT_NEAR(study.diameterOfConfusion(2.0), 0.0117e-3, 0.0002e-3);
  EXPECT_EQ(study.diameterOfConfusion(1.0), 0.0);

  // A wide aperture and a pencil beam make the defocus dominate the dot size;
  // the measured second moment then follows DoC / 4 (uniform disc).
  c = nightNoNoise();
  c.sensor.aperture_diameter_m = 0.012;
  c.projector.beam_sigma_rad = 0.0;
  c.projector.rows = 3;
  c.projector.cols = 3;
  c.projector.pitch_x_rad = c.projector.pitch_y_rad = 0.08;
  c.rock.relief_m = 0.0;
  double previous = 0.0;
  for (double distance : {1.2, 1.5, 2.0})
  {
    c.rock.distance_m = distance;
    c.projector.converge_distance_m = distance;
    sls::Simulator sim(c);
    const sls::SimFrame f = sim.render(0.0);
    const int centre = 4;
    ASSERT_TRUE(f.visible[centre]);
    const double z = f.points[centre].z();
    const double expected = sim.diameterOfConfusion(z) / 4.0 / c.sensor.pixel_size_m;
    const Moments m = channelMoments(f.linear, 1, f.pixels[centre], 15);
    // Second moment of the rendered dot minus the pixel box and diffraction
    // terms (both known, both small).
    const double diff_px = 0.42 * 520e-9 * (1.0 / (1.0 / c.sensor.focal_length_m - 1.0)) /
                           c.sensor.aperture_diameter_m / c.sensor.pixel_size_m;
    const double measured = std::sqrt(0.5 * (m.sxx + m.syy) - 1.0 / 12.0 - diff_px * diff_px);
    std::cout << "[ MEASURE ] depth " << z << " m: defocus sigma measured " << measured << " px, DoC/4 = " << expected
              << " px\n";
    EXPECT_NEAR(measured, expected, 0.03 * expected + 0.01);
    EXPECT_GT(measured, previous);
    previous = measured;
  }
}

TEST(Simulator, StepOccludesAndShadowsDots)
{
  // Two flat planes and a step: analytic first hits to compare with.
  for (double step : {0.4, -0.4})
  {
    sls::SimulatorParams c = nightNoNoise();
    c.rock.relief_m = 0.0;
    c.rock.step_height_m = step;
    c.rock.step_x_m = step > 0 ? 0.12 : 0.05;
    c.projector.rows = 1;
    c.projector.cols = 100;
    c.projector.pitch_x_rad = 0.0024;
    c.projector.roll_rad = 0.0;
    sls::Simulator sim(c);
    const sls::SimFrame f = sim.render(0.0);
    const double D = c.rock.distance_m, xs = c.rock.step_x_m, half = 0.5 * std::abs(step);
    // In the rock frame (no tilt, t = 0) the camera sits at (0, 0, -D).
    auto depth_at = [&](double x) { return (x > xs) == (step > 0) ? half : -half; };
    // Camera line of sight to a far-plane point crosses the edge at depth
    // z_cross; it is blocked when that is inside the near part.
    int checked = 0, occluded = 0, shadowed = 0;
    for (int b = 0; b < 100; ++b)
    {
      const sls::BeamRay& ray = sim.projector().beams[b];
      const Eigen::Vector3d o = ray.origin - Eigen::Vector3d(0, 0, D);
      const Eigen::Vector3d d = ray.direction;
      // First analytic hit: the near plane if the ray meets it on its side,
      // else the far plane (or the step face in between).
      const double near_z = -half, far_z = half;
      const double x_near = o.x() + (near_z - o.z()) / d.z() * d.x();
      const double x_far = o.x() + (far_z - o.z()) / d.z() * d.x();
      const bool near_side_is_right = step < 0;
      const bool hits_near = near_side_is_right ? x_near > xs : x_near < xs;
      const bool hits_far = !hits_near && (near_side_is_right ? x_far < xs : x_far > xs);
      if (std::abs(x_near - xs) < 0.008 || std::abs(x_far - xs) < 0.008)
        continue;  // within the one-cell ramp of the step
      Eigen::Vector3d hit;
      if (hits_near)
      {
        hit = o + (near_z - o.z()) / d.z() * d;
        // Without the near part this beam would have reached the far plane:
        // it is the near part's edge that shadows that spot.
        shadowed += near_side_is_right ? x_far < xs : x_far > xs;
      }
      else if (hits_far)
        hit = o + (far_z - o.z()) / d.z() * d;
      else
      {
        continue;  // lands on the step face
      }
      // Camera line of sight crosses x = xs at depth z_cross; blocked when
      // that is inside the near part.
      // The step is a one-cell (<= 5 mm) ramp: skip beams whose answer
      // depends on where inside the ramp the edge is.
      auto blocked_by_edge_at = [&](double edge)
      {
        if (std::abs(depth_at(hit.x()) - far_z) > 1e-12 || (hit.x() > edge) == (0.0 > edge))
          return false;
        const double z_cross = -D + edge / hit.x() * (hit.z() + D);
        return z_cross > near_z;
      };
      const bool blocked = blocked_by_edge_at(xs);
      if (blocked != blocked_by_edge_at(xs - 0.005) || blocked != blocked_by_edge_at(xs + 0.005))
        continue;
      ++checked;
      occluded += blocked;
      EXPECT_EQ(static_cast<bool>(f.visible[b]), !blocked)
          << "beam " << b << " step " << step << " hit " << hit.transpose() << " pixel " << f.pixels[b];
      if (f.visible[b])
      {
        const Eigen::Vector3d p = sim.cameraPose(0.0) * f.points[b];
        EXPECT_LT((p - hit).norm(), 1e-6) << "beam " << b << " step " << step;
      }
    }
    std::cout << "[ MEASURE ] step " << step << " m: " << checked << " beams checked, " << occluded
              << " hidden from the camera, " << shadowed << " caught by the near part's edge\n";
    EXPECT_GT(checked, 80);
    if (step > 0)
      EXPECT_GE(occluded, 3);  // the 3.7 cm band behind the edge
    else
      EXPECT_GE(shadowed, 3);  // the shadow band behind the edge
  }
}

TEST(Simulator, BrightDotsSaturateToAYellowWhiteCoreOnBrightRock)
{
  sls::SimulatorParams c = sls::studySimulatorParams();  // the study's brightness
  c.lighting.sun_level = 1.0;
  c.projector.power_scale = 4.0;
  c.rock.albedo_min = 0.40;
  c.rock.albedo_max = 0.45;
  sls::Simulator sim(c);
  const sls::SimFrame f = sim.render(0.0);
  int saturated = 0, n = 0;
  for (int b = 0; b < sim.projector().beamCount(); ++b)
  {
    if (!f.visible[b])
      continue;
    ++n;
    const cv::Vec3b px =
        f.image.at<cv::Vec3b>(static_cast<int>(std::round(f.pixels[b].y)), static_cast<int>(std::round(f.pixels[b].x)));
    if (px[1] == 255 && px[2] >= 250 && px[0] > 150)
      ++saturated;
  }
  std::cout << "[ MEASURE ] " << saturated << " of " << n << " dots with a saturated yellow-white core\n";
  EXPECT_GT(saturated, n / 2);

  // And the rock itself is reddish (R > G > B) everywhere away from dots.
  sls::SimulatorParams d;
  d.lighting.sun_level = 1.0;
  const cv::Scalar mean = cv::mean(sls::Simulator(d).render(0.0).image);
  std::cout << "[ MEASURE ] mean B G R of a sunlit frame: " << mean[0] << " " << mean[1] << " " << mean[2] << "\n";
  EXPECT_GT(mean[2], mean[1]);
  EXPECT_GT(mean[1], mean[0]);
}

TEST(Simulator, DotToSunRatioInTheImageIsTheSceneAnalysis)
{
  // Study §2.1.3: the dot against the sun. The scene analysis gives the ratio
  // of the dot's peak photo-electrons to a sunlit surface's, with the sun and
  // the LED both at 10 deg incidence; the simulator must render that ratio.
  // Flat rock facing the camera at 1.5 m (the reference distance), the sun
  // at the study's 10 deg incidence and no sky light. Measured in the
  // noise-free linear green channel: the dot's energy and covariance from the
  // difference with a frame without dots, its covariance less the known blur
  // (pixel box, diffraction, defocus) gives its peak radiance on the rock,
  // divided by the sunlit background under it.
  const sls::SceneAnalysis scene = sls::analyseScene(sls::SceneInputs());
  const double dot_sigma_m = sls::LightingParams::kReferenceBeamSigmaRad * sls::LightingParams::kReferenceDistanceM;
  const double incidence = scene.inputs.sun_incidence_min_deg * M_PI / 180.0;
  // The weakest daylight sun (lowest F50, 50 deg incidence) as a sun_level,
  // which counts the sun at the study's brightest incidence (10 deg).
  const double weakest_sun = scene.irradiance_latitude.min *
                             std::cos(scene.inputs.sun_incidence_max_deg * M_PI / 180.0) /
                             (scene.irradiance_latitude.max * std::cos(incidence));
  struct Case
  {
    const char* name;
    double sun_level, albedo;
    sls::RadiometryModel model;
  };
  const Case cases[] = {
      {"study worst case (brightest sun, albedo 0.05)", 1.0, 0.05, sls::RadiometryModel::kStudyAsStated},
      {"study best daylight (weakest sun, albedo 0.45)", weakest_sun, 0.45, sls::RadiometryModel::kStudyAsStated},
      {"corrected physics, worst case", 1.0, 0.05, sls::RadiometryModel::kCorrected},
  };
  for (const Case& k : cases)
  {
    sls::SimulatorParams c = sls::studySimulatorParams();  // the study's brightness
    c.lighting.sun_level = k.sun_level;
    c.lighting.dot_to_sun_ratio = sls::LightingParams::sceneDotToSunRatio(k.model);
    c.lighting.sun_direction = Eigen::Vector3d(std::sin(incidence), 0.0, -std::cos(incidence));
    c.lighting.sky_ambient = 0.0;
    c.rock.albedo_min = c.rock.albedo_max = k.albedo;
    c.rock.relief_m = 0.0;
    c.keep_linear = true;
    sls::SimulatorParams dark = c;
    dark.projector.power_scale = 0.0;
    sls::Simulator sim(c);
    const sls::SimFrame f = sim.render(0.0);
    const sls::SimFrame bg = sls::Simulator(dark).render(0.0);
    const double expected_ratio =
        sls::dotAndSunElectrons(scene, k.albedo, k.sun_level, k.model, sls::Brdf::kLambertian, -1.0, dot_sigma_m)
            .ratio();

    // Background noise of the 8-bit frame in a corner without dots.
    const cv::Rect corner(0, 0, 200, 200);
    cv::Mat noisy, clean;
    cv::extractChannel(f.image(corner), noisy, 1);
    cv::extractChannel(f.linear(corner), clean, 1);
    noisy.convertTo(noisy, CV_32F);
    cv::Scalar mean_noise, sd_noise;
    cv::meanStdDev(noisy - clean, mean_noise, sd_noise);

    const double diff_px = 0.42 * 520e-9 * (1.0 / (1.0 / c.sensor.focal_length_m - 1.0 / c.sensor.focus_distance_m)) /
                           c.sensor.aperture_diameter_m / c.sensor.pixel_size_m;
    double worst = 0.0, sum_ratio = 0.0, sum_snr = 0.0;
    int n = 0;
    for (int b = 0; b < sim.projector().beamCount(); ++b)
    {
      const cv::Point2d p = f.pixels[b];
      if (!f.visible[b] || std::hypot(p.x - 511.5, p.y - 511.5) > 200)
        continue;
      double e = 0, sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
      for (int v = static_cast<int>(p.y) - 12; v <= static_cast<int>(p.y) + 12; ++v)
        for (int u = static_cast<int>(p.x) - 12; u <= static_cast<int>(p.x) + 12; ++u)
        {
          const double w = f.linear.at<cv::Vec3f>(v, u)[1] - bg.linear.at<cv::Vec3f>(v, u)[1];
          e += w;
          sx += w * u;
          sy += w * v;
          sxx += w * u * u;
          syy += w * v * v;
          sxy += w * u * v;
        }
      ASSERT_GT(e, 0.0);
      const double mx = sx / e, my = sy / e;
      const double blur = 1.0 / 12.0 + diff_px * diff_px +
                          std::pow(sim.diameterOfConfusion(f.points[b].z()) / 4.0 / c.sensor.pixel_size_m, 2);
      const double cxx = sxx / e - mx * mx, cyy = syy / e - my * my, cxy = sxy / e - mx * my;
      const double image_peak = e / (2.0 * M_PI * std::sqrt(cxx * cyy - cxy * cxy));
      const double rock_peak = e / (2.0 * M_PI * std::sqrt((cxx - blur) * (cyy - blur) - cxy * cxy));
      const double background =
          bg.linear.at<cv::Vec3f>(static_cast<int>(std::round(p.y)), static_cast<int>(std::round(p.x)))[1];
      // The dot meets the rock at its own incidence and distance from the
      // projector, the study's LED at 10 deg and the reference distance.
      const sls::BeamRay& beam = sim.projector().beams[b];
      const double cos_i = beam.direction.z();
      const double range = (f.points[b] - beam.origin).norm() / sls::LightingParams::kReferenceDistanceM;
      const double ratio = rock_peak / background * std::cos(incidence) / cos_i * range * range;
      worst = std::max(worst, std::abs(ratio / expected_ratio - 1.0));
      sum_ratio += ratio;
      sum_snr += image_peak / sd_noise[0];
      ++n;
    }
    ASSERT_GT(n, 10);
    const sls::DotSunElectrons el =
        sls::dotAndSunElectrons(scene, k.albedo, k.sun_level, k.model, sls::Brdf::kLambertian, -1.0, dot_sigma_m);
    std::cout << "[ MEASURE ] " << k.name << ", sun_level " << k.sun_level << ": dot/sun ratio in the image "
              << sum_ratio / n << " (scene analysis " << expected_ratio << ", worst deviation " << 100.0 * worst
              << " % over " << n << " dots); image SNR (blurred peak / background noise " << sd_noise[0] << " DN) "
              << sum_snr / n << "; the study's sensor: SNR " << el.snr() << "\n";
    EXPECT_LT(worst, 0.01);
  }
}

TEST(Simulator, OliveMineralsDoNotLookLikeDots)
{
  // Clutter pixels found as the difference with and without clutter (same
  // seed, no noise); compared in OpenCV's HSV hue (0-180).
  for (double sun : {0.3, 1.0})
  {
    sls::SimulatorParams c = sls::studySimulatorParams();  // the study's brightness
    c.lighting.sun_level = sun;
    c.sensor.read_noise_dn = 0.0;
    c.sensor.shot_noise = false;
    sls::SimulatorParams olive = c, nodots = c;
    olive.clutter.olive_minerals = 80;
    nodots.projector.power_scale = 0.0;
    const cv::Mat base = sls::Simulator(c).render(0.0).image;
    const cv::Mat with_olive = sls::Simulator(olive).render(0.0).image;
    const cv::Mat without_dots = sls::Simulator(nodots).render(0.0).image;
    auto changed = [](const cv::Mat& a, const cv::Mat& b, int threshold)
    {
      cv::Mat d, g;
      cv::absdiff(a, b, d);
      cv::cvtColor(d, g, cv::COLOR_BGR2GRAY);
      return cv::Mat(g > threshold);
    };
    cv::Mat hsv;
    cv::Scalar dot_mean, dot_sd, olive_mean, olive_sd;
    cv::cvtColor(base, hsv, cv::COLOR_BGR2HSV);
    cv::meanStdDev(hsv, dot_mean, dot_sd, changed(base, without_dots, 40));
    cv::cvtColor(with_olive, hsv, cv::COLOR_BGR2HSV);
    const cv::Mat olive_mask = changed(with_olive, base, 4);
    ASSERT_GT(cv::countNonZero(olive_mask), 1000);
    cv::meanStdDev(hsv, olive_mean, olive_sd, olive_mask);
    std::cout << "[ MEASURE ] sun " << sun << ": dot cores hue " << dot_mean[0] << " +- " << dot_sd[0] << ", V "
              << dot_mean[2] << "; olive minerals hue " << olive_mean[0] << " +- " << olive_sd[0] << ", V "
              << olive_mean[2] << "\n";
    // One standard deviation of each apart, plus a margin.
    EXPECT_GT(dot_mean[0] - olive_mean[0], dot_sd[0] + olive_sd[0] + 5.0);
    EXPECT_LT(olive_mean[2], 0.5 * dot_mean[2]);
  }
}

// Two exposures of one instant (the projector-on frame and a projector-off
// frame rendered at its time) draw their own noise, as two exposures of a
// camera do: away from the dots their noise residuals are uncorrelated
// (|r| < 0.05 over ~10^5 pixels; shared deviates gave r near 1), and each
// has the noise of the camera (within 10 % of each other).
namespace
{
// The projector-off frame of time t.
sls::SimFrame renderOff(const sls::Simulator& sim, double t)
{
  sls::FrameRequest off_request;
  off_request.projector_on = false;
  return sim.render(t, off_request);
}
}  // namespace

TEST(Simulator, ExposuresOfOneInstantHaveTheirOwnNoise)
{
  sls::SimulatorParams c = sls::studySimulatorParams();  // 1 DN read noise: the noise well above the rounding
  c.lighting.sun_level = 1.0;
  c.keep_linear = true;
  const sls::Simulator sim(c);
  const sls::SimFrame on = sim.render(0.4);
  const sls::SimFrame off = renderOff(sim, 0.4);
  cv::Mat mask(on.image.size(), CV_8U, cv::Scalar(255));
  for (size_t b = 0; b < on.points.size(); ++b)
    if (on.visible[b])
      cv::circle(mask, on.pixels[b], 16, cv::Scalar(0), -1);
  double sxy = 0.0, sxx = 0.0, syy = 0.0;
  int n = 0;
  for (int y = 40; y < on.image.rows - 40; y += 2)
    for (int x = 40; x < on.image.cols - 40; x += 2)
    {
      if (!mask.at<uint8_t>(y, x))
        continue;
      const double u = on.image.at<cv::Vec3b>(y, x)[2] - on.linear.at<cv::Vec3f>(y, x)[2];
      const double v = off.image.at<cv::Vec3b>(y, x)[2] - off.linear.at<cv::Vec3f>(y, x)[2];
      sxy += u * v;
      sxx += u * u;
      syy += v * v;
      ++n;
    }
  ASSERT_GT(n, 100000);
  const double r = sxy / std::sqrt(sxx * syy);
  std::cout << "[ MEASURE ] noise correlation of the on and off exposures of one instant: " << r << " over " << n
            << " pixels\n";
  EXPECT_LT(std::fabs(r), 0.05);
  EXPECT_NEAR(std::sqrt(syy / sxx), 1.0, 0.1);
}

TEST(Simulator, FrameRequestTurnsTheProjectorOffAndMovesTheCamera)
{
  sls::SimulatorParams c;
  c.sensor.read_noise_dn = 0.0;
  c.sensor.shot_noise = false;
  c.keep_linear = true;
  const sls::Simulator sim(c);
  const sls::SimFrame on = sim.render(0.2);
  const sls::SimFrame off = renderOff(sim, 0.2);
  // Same truth, same rock; the only light that differs is the projector's.
  int visible = 0;
  for (size_t b = 0; b < on.points.size(); ++b)
  {
    ASSERT_EQ(on.visible[b], off.visible[b]);
    if (!on.visible[b])
      continue;
    ++visible;
    EXPECT_EQ(on.pixels[b], off.pixels[b]);
    const cv::Point2d p = on.pixels[b];
    const Moments m_on = channelMoments(on.linear, 1, p, 1);
    const Moments m_off = channelMoments(off.linear, 1, p, 1);
    EXPECT_GT(m_on.sum - m_off.sum, 0.5 * on.peak_dn[b]) << "beam " << b;
  }
  EXPECT_GT(visible, 50);
  cv::Mat diff;
  cv::absdiff(on.linear, off.linear, diff);
  cv::Mat dot_free = diff.clone();
  for (size_t b = 0; b < on.points.size(); ++b)
    if (on.visible[b])
      cv::circle(dot_free, on.pixels[b], 16, cv::Scalar::all(0), -1);
  double worst = 0.0;
  cv::minMaxLoc(dot_free.reshape(1), nullptr, &worst);
  cv::Point where;
  cv::minMaxLoc(dot_free.reshape(1), nullptr, &worst, nullptr, &where);
  EXPECT_LT(worst, 1e-3) << "the projector-off frame differs away from the dots, at " << where.x / 3 << "," << where.y;

  // An arm correction moves the camera on top of the disturbance.
  sls::FrameRequest moved;
  moved.arm_correction.translation() = Eigen::Vector3d(0.01, 0.0, 0.0);
  const sls::SimFrame shifted = sim.render(0.2, moved);
  EXPECT_TRUE(isIdentity(shifted.delta * on.delta.inverse() * moved.arm_correction.inverse(), 1e-12));
  // Rock points move by +1 cm in x in the camera frame: the rock's texture
  // shifts by fx * 0.01 / z in the image (the dots ride with the rig).
  const cv::Rect centre(312, 312, 400, 400);
  cv::Mat a, b;
  cv::extractChannel(off.linear(centre), a, 2);
  sls::SimFrame shifted_off = sim.render(0.2,
                                         [&]
                                         {
                                           sls::FrameRequest r = moved;
                                           r.projector_on = false;
                                           return r;
                                         }());
  cv::extractChannel(shifted_off.linear(centre), b, 2);
  const cv::Point2d shift = cv::phaseCorrelate(a, b);
  const double expected = c.sensor.camera.fx * 0.01 / c.rock.distance_m;
  EXPECT_NEAR(shift.x, expected, 0.1 * expected);
  EXPECT_NEAR(shift.y, 0.0, 0.5);
}
