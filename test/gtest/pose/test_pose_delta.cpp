// PoseDelta core on synthetic height-field rocks (test/support/pose_delta_scene.h):
// the surface model, geometric registration against ground truth, the
// beam-index trap, observability on a flat board, frame-to-frame chaining,
// texture on a flat textured board, and bad input.
#include <cmath>
#include <iostream>
#include <random>

#include <Eigen/SVD>
#include <gtest/gtest.h>

#include "support/pose_delta_scene.h"
#include "structured_light_stabilizer/pose/pose_delta.h"

using namespace structured_light_stabilizer;
using namespace sls_test;

namespace
{

PoseDeltaInput frameOf(const std::vector<Eigen::Vector3d>& pts, const cv::Mat& image = cv::Mat())
{
  PoseDeltaInput in;
  in.rows = 10;
  in.cols = 10;
  in.points = pts;
  in.image = image;
  return in;
}

// Error of an estimate in the PoseDelta axes: translation of E = est * truth^-1
// and its rotation vector.
Vector6d axisError(const Eigen::Isometry3d& est, const Eigen::Isometry3d& truth)
{
  const Eigen::Isometry3d E = est * truth.inverse();
  Vector6d e;
  e << E.translation(), logSO3(E.linear());
  return e;
}

// The trap: rigid fit of the two clouds pairing points by beam index.
Eigen::Isometry3d kabschByBeamIndex(const std::vector<Eigen::Vector3d>& ref, const std::vector<Eigen::Vector3d>& cur)
{
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> pairs;
  for (size_t i = 0; i < ref.size(); ++i)
    if (ref[i].allFinite() && cur[i].allFinite())
      pairs.emplace_back(ref[i], cur[i]);
  Eigen::Vector3d mp = Eigen::Vector3d::Zero(), mq = Eigen::Vector3d::Zero();
  for (const auto& p : pairs)
  {
    mp += p.first;
    mq += p.second;
  }
  mp /= pairs.size();
  mq /= pairs.size();
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  for (const auto& p : pairs)
    S += (p.second - mq) * (p.first - mp).transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(S, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = svd.matrixU() * D * svd.matrixV().transpose();
  T.translation() = mq - T.linear() * mp;
  return T;
}

struct Stats
{
  double sum_t2 = 0, sum_r2 = 0;
  Vector6d sum_axis2 = Vector6d::Zero();
  int n = 0, valid = 0;
  void add(const Eigen::Isometry3d& est, const Eigen::Isometry3d& truth, bool ok)
  {
    const Vector6d e = axisError(est, truth);
    sum_t2 += e.head<3>().squaredNorm();
    sum_r2 += std::pow(rotationErrorDeg(est, truth), 2);
    sum_axis2 += e.cwiseProduct(e);
    ++n;
    valid += ok ? 1 : 0;
  }
  double rmsTranslationMm() const { return 1e3 * std::sqrt(sum_t2 / n); }
  double rmsRotationDeg() const { return std::sqrt(sum_r2 / n); }
  double axisRms(int a) const { return std::sqrt(sum_axis2[a] / n) * (a < 3 ? 1e3 : 180.0 / kPi); }
  double validPercent() const { return 100.0 * valid / n; }
  void print(const char* name) const
  {
    std::cout << "[ MEASURE ] " << name << ": translation RMS " << rmsTranslationMm() << " mm, rotation RMS "
              << rmsRotationDeg() << " deg, valid " << validPercent() << " % of " << n
              << " frames; per axis (mm, deg):";
    for (int a = 0; a < 6; ++a)
      std::cout << " " << axisRms(a);
    std::cout << "\n";
  }
};

// Default settings (texture on), jitter +-10 mm / +-1 deg, 0.5 mm point
// noise, rendered images: locks on the first frame, then 15 random poses.
// Prints the statistics as `name` and returns them.
Stats trackWithTexture(const Rock& rock, uint32_t seed, int first_image_seed, const char* name)
{
  const ProjectorCalibration proj = defaultProjector();
  const CameraModel cam = CameraModel::studyDesign();
  std::mt19937 rng(seed);
  PoseDeltaEstimator est;
  est.setCamera(cam);
  {
    const auto pts = beamPoints(rock, proj, Eigen::Isometry3d::Identity(), 0.5e-3, &rng);
    const PoseDeltaResult r0 = est.process(frameOf(pts, renderImage(rock, cam, Eigen::Isometry3d::Identity(), pts, 1)));
    std::cout << "  lock: " << r0.status << "\n";
  }
  Stats s;
  std::string example;
  for (int k = 0; k < 15; ++k)
  {
    const Eigen::Isometry3d truth = randomDelta(rng, 0.010, 1.0 * kPi / 180);
    const auto pts = beamPoints(rock, proj, truth, 0.5e-3, &rng);
    const PoseDeltaResult r = est.process(frameOf(pts, renderImage(rock, cam, truth, pts, first_image_seed + k)));
    s.add(r.transform, truth, r.valid);
    example = r.status;
  }
  s.print(name);
  std::cout << "  status: " << example << "\n";
  return s;
}

}  // namespace

TEST(BeamSurface, InterpolatesTheRockBetweenTheDots)
{
  const Rock rock;
  const ProjectorCalibration proj = defaultProjector();
  const std::vector<Eigen::Vector3d> ref = beamPoints(rock, proj, Eigen::Isometry3d::Identity());
  BeamSurface surface;
  surface.build(10, 10, ref);
  ASSERT_EQ(surface.validCells(), 81);
  // Between the dots the interpolated surface must stay on the true rock.
  std::mt19937 rng(3);
  double sum2 = 0.0, worst = 0.0;
  int n = 0;
  for (int k = 0; k < 2000; ++k)
  {
    std::uniform_real_distribution<double> u(0.3, 8.7);
    const double v = u(rng), u_ = u(rng);  // sequenced draws (docs/testing.md)
    Eigen::Vector2d uv(u_, v);
    Eigen::Vector3d s;
    ASSERT_TRUE(surface.evaluate(uv.x(), uv.y(), &s));
    // Distance of the interpolated point from the true height field along z.
    const double dz = s.z() - rock.height(s.x(), s.y());
    sum2 += dz * dz;
    worst = std::max(worst, std::abs(dz));
    ++n;
  }
  const double rms = std::sqrt(sum2 / n);
  std::cout << "[ MEASURE ] bicubic surface vs true rock (relief 0.15 m): RMS " << rms * 1e3 << " mm, worst "
            << worst * 1e3 << " mm (dot spacing " << surface.medianSpacing() * 1e3 << " mm)\n";
  EXPECT_LT(rms, 1.0e-3);

  // The foot of a point off the surface is perpendicular.
  Eigen::Vector3d s, su, sv;
  ASSERT_TRUE(surface.evaluate(4.3, 5.6, &s, &su, &sv));
  const Eigen::Vector3d n_true = su.cross(sv).normalized();
  Eigen::Vector2d uv(4.0, 5.0);
  Eigen::Vector3d foot, normal;
  ASSERT_TRUE(surface.closestPoint(s + 0.004 * n_true, &uv, &foot, &normal));
  EXPECT_NEAR((foot - s).norm(), 0.0, 1e-7);
  EXPECT_NEAR(std::abs(normal.dot(n_true)), 1.0, 1e-9);

  // A ray through a surface point hits it.
  Eigen::Vector2d uv_ray(NAN, NAN);
  Eigen::Vector3d hit;
  ASSERT_TRUE(surface.intersectRay(s, &uv_ray, &hit));
  EXPECT_NEAR((hit - s).norm(), 0.0, 1e-7);
}

TEST(BeamSurface, DropsMissingPointsAndJumps)
{
  const Rock rock;
  std::vector<Eigen::Vector3d> ref = beamPoints(rock, defaultProjector(), Eigen::Isometry3d::Identity());
  ref[44] = Eigen::Vector3d::Constant(NAN);  // 4 cells around it go
  ref[77] += Eigen::Vector3d(0, 0, 0.4);     // an occlusion-like jump: 4 more
  BeamSurface surface;
  surface.build(10, 10, ref);
  EXPECT_EQ(surface.validCells(), 81 - 8);
  Eigen::Vector3d s;
  EXPECT_FALSE(surface.evaluate(4.5, 4.5, &s));
  EXPECT_FALSE(surface.evaluate(7.2, 6.8, &s));
  EXPECT_TRUE(surface.evaluate(1.5, 1.5, &s));
}

// The trap: rough rock, rig jitter +-10 mm / +-1 deg, geometry only, points
// with 0.5 mm triangulation noise, against a rigid fit that pairs the clouds
// by beam index (fed noise-free points, and still an order of magnitude off).
// Freezing of weak directions is off here to measure what geometry alone
// gives on every axis.
TEST(PoseDelta, RoughRockGeometryBeatsBeamIndexFit)
{
  const Rock rock;
  const ProjectorCalibration proj = defaultProjector();
  std::mt19937 rng(7);
  PoseDeltaParams cfg;
  cfg.use_texture = false;
  cfg.freeze_factor = 1e6;
  PoseDeltaEstimator est(cfg);
  PoseDeltaResult r0 = est.process(frameOf(beamPoints(rock, proj, Eigen::Isometry3d::Identity(), 0.5e-3, &rng)));
  ASSERT_TRUE(r0.locked_now);
  const std::vector<Eigen::Vector3d> ref_exact = beamPoints(rock, proj, Eigen::Isometry3d::Identity());

  Stats ours, kabsch;
  for (int k = 0; k < 60; ++k)
  {
    const Eigen::Isometry3d truth = randomDelta(rng, 0.010, 1.0 * kPi / 180);
    const std::vector<Eigen::Vector3d> cur = beamPoints(rock, proj, truth, 0.5e-3, &rng);
    const PoseDeltaResult r = est.process(frameOf(cur));
    ours.add(r.transform, truth, r.valid);
    kabsch.add(kabschByBeamIndex(ref_exact, beamPoints(rock, proj, truth)), truth, true);
    if (k < 3)
      std::cout << "  frame " << k << ": " << r.status << ", rms " << r.rms_residual_m * 1e3 << " mm, " << r.iterations
                << " iterations\n";
  }
  ours.print("rough rock, geometry only, 0.5 mm noise");
  kabsch.print("rough rock, beam-index Kabsch (noise-free points!)");
  // Geometry alone on this rock: distance and tilts at the bounds, the
  // in-plane axes within a few tenths (the texture pins them, see below).
  EXPECT_LT(ours.axisRms(2), 1.0);
  EXPECT_LT(std::hypot(ours.axisRms(3), ours.axisRms(4)), 0.1);
  EXPECT_LT(ours.rmsTranslationMm(), 1.5);
  EXPECT_LT(ours.rmsRotationDeg(), 0.2);
  // The beam-index fit is several times worse even without noise.
  EXPECT_GT(kabsch.rmsTranslationMm(), 5.0 * ours.rmsTranslationMm());
  EXPECT_GT(kabsch.rmsRotationDeg(), 3.0 * ours.rmsRotationDeg());
}

// The first accuracy case with the default settings (texture on):
// rough rock, jitter +-10 mm / +-1 deg, 0.5 mm point noise, rendered images.
TEST(PoseDelta, RoughRockWithTexture)
{
  const Stats s = trackWithTexture(Rock(), 17, 200, "rough rock, texture on");
  EXPECT_LT(s.rmsTranslationMm(), 1.0);
  EXPECT_LT(s.rmsRotationDeg(), 0.05);
  EXPECT_GE(s.validPercent(), 95.0);
}

TEST(PoseDelta, ReturnsToIdentityAtTheReferencePose)
{
  const Rock rock;
  const ProjectorCalibration proj = defaultProjector();
  std::mt19937 rng(11);
  PoseDeltaParams cfg;
  cfg.use_texture = false;
  PoseDeltaEstimator est(cfg);
  est.process(frameOf(beamPoints(rock, proj, Eigen::Isometry3d::Identity())));
  // Wander, then come back exactly.
  for (int k = 0; k < 5; ++k)
    est.process(frameOf(beamPoints(rock, proj, randomDelta(rng, 0.01, kPi / 180))));
  const PoseDeltaResult r = est.process(frameOf(beamPoints(rock, proj, Eigen::Isometry3d::Identity())));
  const double t_mm = r.transform.translation().norm() * 1e3;
  const double r_deg = rotationErrorDeg(r.transform, Eigen::Isometry3d::Identity());
  std::cout << "[ MEASURE ] back at the reference pose: " << t_mm << " mm, " << r_deg << " deg (" << r.status << ")\n";
  EXPECT_TRUE(r.valid);
  EXPECT_LT(t_mm, 0.2);
  EXPECT_LT(r_deg, 0.01);
}

TEST(PoseDelta, FlatBoardWithoutTextureNamesTheUnobservableAxes)
{
  Rock board;
  board.relief = 0.0;
  const ProjectorCalibration proj = defaultProjector();
  std::mt19937 rng(5);
  PoseDeltaParams cfg;
  cfg.use_texture = false;
  PoseDeltaEstimator est(cfg);
  est.process(frameOf(beamPoints(board, proj, Eigen::Isometry3d::Identity(), 0.5e-3, &rng)));
  Stats s;
  int named = 0;
  std::string example;
  for (int k = 0; k < 40; ++k)
  {
    const Eigen::Isometry3d truth = randomDelta(rng, 0.010, 1.0 * kPi / 180);
    const PoseDeltaResult r = est.process(frameOf(beamPoints(board, proj, truth, 0.5e-3, &rng)));
    s.add(r.transform, truth, r.valid);
    EXPECT_FALSE(r.valid);
    const bool ok = r.unobservable[0] && r.unobservable[1] && r.unobservable[5] && !r.unobservable[2] &&
                    !r.unobservable[3] && !r.unobservable[4];
    named += ok && r.status.find("unobservable: tx ty rz") != std::string::npos ? 1 : 0;
    // Honest covariance: the in-plane axes are far less certain than the bounds.
    EXPECT_GT(std::sqrt(r.covariance(0, 0)), 2 * cfg.max_sigma_translation_m);
    EXPECT_GT(std::sqrt(r.covariance(35)), 2 * cfg.maxSigmaRotationRad());
    example = r.status;
  }
  s.print("flat board, texture off");
  std::cout << "  status: " << example << "\n";
  EXPECT_EQ(named, 40);
  // The three observable axes meet the bounds.
  EXPECT_LT(s.axisRms(2), 1.0);
  EXPECT_LT(std::hypot(s.axisRms(3), s.axisRms(4)), 0.05);
}

TEST(PoseDelta, FlatTexturedBoardWithTexture)
{
  Rock board;
  board.relief = 0.0;
  const Stats s = trackWithTexture(board, 9, 100, "flat textured board, texture on");
  EXPECT_LT(s.rmsTranslationMm(), 1.0);
  EXPECT_LT(s.rmsRotationDeg(), 0.05);
  EXPECT_GE(s.validPercent(), 95.0);
}

TEST(PoseDelta, FrameToFrameChainsTheDeltas)
{
  const Rock rock;
  const ProjectorCalibration proj = defaultProjector();
  std::mt19937 rng(13);
  const CameraModel cam = CameraModel::studyDesign();
  PoseDeltaParams cfg;
  cfg.mode = PoseDeltaMode::kFrameToFrame;
  PoseDeltaEstimator est(cfg);
  est.setCamera(cam);
  {
    const auto pts = beamPoints(rock, proj, Eigen::Isometry3d::Identity());
    est.process(frameOf(pts, renderImage(rock, cam, Eigen::Isometry3d::Identity(), pts, 1)));
  }
  // A slow smooth motion: successive frames close, the total up to 10 mm / 1 deg.
  Stats s;
  for (int k = 1; k <= 12; ++k)
  {
    const double a = k / 12.0;
    Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
    truth.linear() = expSO3(Eigen::Vector3d(0.6, -0.8, 0.5) * a * kPi / 180);
    truth.translation() = Eigen::Vector3d(-8e-3, 6e-3, 10e-3) * a;
    const auto pts = beamPoints(rock, proj, truth);
    const PoseDeltaResult r = est.process(frameOf(pts, renderImage(rock, cam, truth, pts, 300 + k)));
    s.add(r.transform, truth, r.valid);
  }
  s.print("rough rock, frame_to_frame, 12 chained frames, texture on");
  EXPECT_LT(s.rmsTranslationMm(), 1.0);
  EXPECT_LT(s.rmsRotationDeg(), 0.05);
  EXPECT_GE(s.validPercent(), 95.0);
}

TEST(PoseDelta, BadInputIsNotValidAndSaysWhy)
{
  const Rock rock;
  const ProjectorCalibration proj = defaultProjector();
  PoseDeltaEstimator est;
  // Nothing locked yet, empty cloud.
  PoseDeltaInput empty;
  PoseDeltaResult r = est.process(empty);
  EXPECT_FALSE(r.valid);
  EXPECT_NE(r.status.find("empty"), std::string::npos) << r.status;
  EXPECT_FALSE(est.hasReference());

  std::vector<Eigen::Vector3d> nan(100, Eigen::Vector3d::Constant(NAN));
  r = est.process(frameOf(nan));
  EXPECT_FALSE(r.valid);
  EXPECT_NE(r.status.find("all NaN"), std::string::npos) << r.status;

  std::vector<Eigen::Vector3d> few = beamPoints(rock, proj, Eigen::Isometry3d::Identity());
  for (size_t i = 5; i < few.size(); ++i)
    few[i] = Eigen::Vector3d::Constant(NAN);
  r = est.process(frameOf(few));
  EXPECT_FALSE(r.valid);
  EXPECT_NE(r.status.find("too few points"), std::string::npos) << r.status;
  EXPECT_FALSE(est.hasReference());

  // Lock, then a cloud of another layout.
  PoseDeltaParams cfg;
  cfg.use_texture = false;
  est.setParams(cfg);
  r = est.process(frameOf(beamPoints(rock, proj, Eigen::Isometry3d::Identity())));
  EXPECT_TRUE(r.valid) << r.status;
  EXPECT_TRUE(est.hasReference());
  PoseDeltaInput other;
  other.rows = 5;
  other.cols = 20;
  other.points = beamPoints(rock, proj, Eigen::Isometry3d::Identity());
  r = est.process(other);
  EXPECT_FALSE(r.valid);
  EXPECT_NE(r.status.find("differs from the reference"), std::string::npos) << r.status;

  // Inconsistent size.
  PoseDeltaInput odd = frameOf(beamPoints(rock, proj, Eigen::Isometry3d::Identity()));
  odd.points.resize(50);
  r = est.process(odd);
  EXPECT_FALSE(r.valid);

  // Points that are not on the reference rock at all (a different surface).
  Rock other_rock;
  other_rock.distance = 1.0;
  other_rock.relief = -0.15;
  r = est.process(frameOf(beamPoints(other_rock, proj, Eigen::Isometry3d::Identity())));
  EXPECT_FALSE(r.valid) << r.status;
  std::cout << "  different rock: " << r.status << "\n";

  // Texture asked for but no camera: geometry still works and the status says so.
  PoseDeltaEstimator tex;
  r = tex.process(frameOf(beamPoints(rock, proj, Eigen::Isometry3d::Identity())));
  EXPECT_NE(r.status.find("no camera_info"), std::string::npos) << r.status;

  EXPECT_THROW(est.setParams(
                   []
                   {
                     PoseDeltaParams c;
                     c.min_points = 2;
                     return c;
                   }()),
               std::invalid_argument);
}
