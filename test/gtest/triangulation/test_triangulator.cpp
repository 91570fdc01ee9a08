// Triangulator: ray-ray triangulation against the study's formulas 2.27-2.30,
// the study's two experiments (§3.3 one dot, §3.4 line of ten dots) on exact
// synthetic centroids, depth accuracy on synthetic rocks, and beam
// identification under missing / spurious / merged / permuted dots.
#include <cmath>
#include <iomanip>
#include <iostream>
#include <random>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/calibration/projector_calibrator.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"
#include "support/triangulator_scene.h"

using namespace structured_light_stabilizer;
using sls_test::Frame;
using sls_test::FrameOptions;
using sls_test::Scene;

namespace
{

CameraModel webcam(double f)
{
  CameraModel m;
  m.width = 640;
  m.height = 480;
  m.fx = m.fy = f;
  m.cx = 319.5;
  m.cy = 239.5;
  return m;
}

struct IdStats
{
  int visible = 0;  // spots of a real beam presented to the triangulator
  int correct = 0;
  int wrong = 0;   // a beam given another beam's dot, a clutter spot or a merged blob
  int missed = 0;  // a real spot left unassigned
};

void countIdentification(const Frame& f, const TriangulationResult& r, IdStats* s)
{
  for (size_t j = 0; j < f.spots.size(); ++j)
  {
    const int truth = f.spots[j].beam;
    const int got = r.beam_of_spot[j];
    if (truth >= 0)
      ++s->visible;
    if (got < 0)
    {
      if (truth >= 0)
        ++s->missed;
    }
    else if (got == truth)
      ++s->correct;
    else
      ++s->wrong;
  }
}

}  // namespace

// In the study's geometry (camera at the origin, the beam leaving the light
// source at x = -d in the plane y = 0 at angle alpha to the optical axis), the
// closest point of the two rays is their intersection and its depth is
// formula 2.27 with p_pixels = cx - u (see the note on signs in the README).
TEST(Triangulator, ReducesToStudyFormula227)
{
  const CameraModel cam = webcam(826.0);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ud(0.05, 0.6), ua(0.02, 0.4), uz(0.5, 5.0), uy(-0.2, 0.2);
  double worst = 0.0;
  for (int k = 0; k < 200; ++k)
  {
    const double d = ud(rng), tan_a = ua(rng), z_true = uz(rng);
    BeamRay beam;
    beam.origin = Eigen::Vector3d(-d, 0.0, 0.0);
    beam.direction = Eigen::Vector3d(tan_a, 0.0, 1.0).normalized();
    const Eigen::Vector3d hit = beam.pointAt((z_true) / beam.direction.z());
    const cv::Point2d px = cam.project(hit);
    const double p_pixels = cam.cx - px.x;
    const double z_227 = d / (p_pixels / cam.fx + tan_a);
    Eigen::Vector3d p;
    double gap = 1.0;
    ASSERT_TRUE(triangulateBeam(cam.ray(px), beam, &p, &gap));
    worst = std::max(worst, std::abs(p.z() - z_227) / z_227);
    EXPECT_LT(gap, 1e-9);
    // 2.29: x = z tan(alpha) - d.
    EXPECT_NEAR(p.x(), p.z() * tan_a - d, 1e-9);
  }
  // The general study form (2.28-2.30) with d_y and beta, loaded from YAML.
  ProjectorCalibration cal;
  std::string err;
  ASSERT_TRUE(parseProjectorCalibration(
      "rows: 1\ncols: 1\nbeams:\n  - {tan_alpha: 0.2, tan_beta: -0.05, d_x: 0.3, d_y: 0.1}\n", &cal, &err))
      << err;
  for (double z : {0.9, 1.4, 2.2})
  {
    const Eigen::Vector3d hit = cal.beams[0].pointAt((z - cal.beams[0].origin.z()) / cal.beams[0].direction.z());
    const cv::Point2d px = cam.project(hit);
    const double z_228 = 0.3 / ((cam.cx - px.x) / cam.fx + 0.2);
    Eigen::Vector3d p;
    double gap = 1.0;
    ASSERT_TRUE(triangulateBeam(cam.ray(px), cal.beams[0], &p, &gap));
    EXPECT_NEAR(p.z(), z_228, 1e-9 * z);
    EXPECT_NEAR(p.x(), p.z() * 0.2 - 0.3, 1e-9);    // 2.29
    EXPECT_NEAR(p.y(), p.z() * -0.05 - 0.1, 1e-9);  // 2.30
  }
  std::cout << "[ MEASURE ] worst relative difference to formula 2.27 over 200 random geometries: " << worst << "\n";
  EXPECT_LT(worst, 1e-12);
}

// §3.3: d = 30 cm, calibrated with the board at 137 cm (the dot on the image
// centre), board moved to 137 / 124 / 111.5 / 98.5 cm. Exact centroids give
// the exact distances; the study's Table 3.2 is compared with them.
TEST(Triangulator, StudyOneDotExperiment)
{
  const double d = 0.30, D = 1.37;
  const CameraModel cam = webcam(826.0);  // f_x of the study's Table 3.1
  const double alpha_deg = std::atan(d / D) * 180.0 / M_PI;
  std::cout << "[ MEASURE ] alpha from d = 30 cm, D = 137 cm: " << alpha_deg
            << " deg (the study states 12.75 deg; tan(12.75 deg) * 137 cm = " << std::tan(12.75 * M_PI / 180) * 137
            << " cm, not 30 cm)\n";
  // The study's one-distance calibration with the light source at x = -d.
  BoardView calib;
  calib.distance_m = D;
  Spot s;
  s.x = cam.cx;  // the dot on the image centre at the calibration distance
  s.y = cam.cy;
  s.beam = 0;
  calib.spots.push_back(s);
  BoardCalibrationParams opt;
  opt.rows = opt.cols = 1;
  const BoardCalibrationResult cr = calibrateFromOneBoard(cam, calib, Eigen::Vector3d(-d, 0, 0), opt);
  ASSERT_TRUE(cr.ok) << cr.error;
  EXPECT_NEAR(cr.calibration.beams[0].direction.x() / cr.calibration.beams[0].direction.z(), d / D, 1e-12);

  // The true rig: same beam. Table 3.2 (cm): truth, without distortion, with distortion.
  const double table[4][3] = {
      {137, 136.2463, 136.2557}, {124, 125.2243, 125.2153}, {111.5, 113.2045, 113.1927}, {98.5, 100.7686, 106.4445}};
  TriangulatorParams tc;
  tc.min_depth = 0.5;
  tc.max_depth = 3.0;
  Triangulator tri(cam, cr.calibration, tc);
  std::cout << "[ MEASURE ]  board cm | exact centroids cm | study (no dist.) cm, error, implied centroid offset px"
               " | study (with dist.) cm, error\n";
  for (const auto& row : table)
  {
    const double z = row[0] / 100.0;
    const BeamRay& b = cr.calibration.beams[0];
    const cv::Point2d px = cam.project(b.pointAt((z - b.origin.z()) / b.direction.z()));
    Spots spots(1);
    spots[0].x = px.x;
    spots[0].y = px.y;
    const TriangulationResult r = tri.process(spots);
    ASSERT_EQ(r.valid_points, 1);
    const double z_cm = r.points[0].z() * 100.0;
    EXPECT_NEAR(z_cm, row[0], 1e-8);
    // Centroid offset (px) that would turn the exact depth into the study's.
    const double p_exact = cam.fx * (d / z - d / D);
    const double p_study = cam.fx * (d / (row[1] / 100.0) - d / D);
    std::cout << "[ MEASURE ] " << std::setw(8) << row[0] << " | " << std::setw(12) << z_cm << " | " << row[1] << ", "
              << std::showpos << (row[1] - row[0]) / row[0] * 100 << " %, " << (p_study - p_exact) << " px"
              << std::noshowpos << " | " << row[2] << ", " << std::showpos << (row[2] - row[0]) / row[0] * 100 << " %"
              << std::noshowpos << "\n";
  }
  // Depth change per pixel of centroid error at 98.5 cm: dz/dp = z^2 / (f d).
  std::cout << "[ MEASURE ] 1 px of centroid error at 98.5 cm = " << 0.985 * 0.985 / (cam.fx * d) * 1000
            << " mm of depth\n";
}

// §3.4: a line of ten dots from a projector above the camera (d = 1 m
// across, 0.3 m higher), calibrated with the study's one-distance formula at
// D = 5.21 m (tan(alpha_i) = d/D - P_i Psize/f0, f0/Psize = 1/0.0013), then an
// object in front of dots 1 and 2 at 0.5 / 0.9 / 1.5 m from the board. The
// epipolar assignment keeps every dot right, including the permutation the
// study saw beyond 1 m that its sort cannot undo.
TEST(Triangulator, StudyLineOfTenDots)
{
  const CameraModel cam = webcam(1.0 / 0.0013);
  const double D = 5.21;
  const Eigen::Vector3d origin(-1.0, -0.3, 0.0);
  ProjectorCalibration truth;
  truth.rows = 1;
  truth.cols = 10;
  for (int k = 0; k < 10; ++k)
  {
    BeamRay b;
    b.origin = origin;
    b.direction = (Eigen::Vector3d(-1.2 + k * 2.4 / 9.0, 0.0, D) - origin).normalized();
    truth.beams.push_back(b);
  }
  // Calibration view: the bare board at D.
  Scene board;
  board.distance = D;
  const Frame calib_frame = sls_test::makeFrame(cam, truth, board, FrameOptions());
  BoardView view;
  view.distance_m = D;
  view.spots = calib_frame.spots;
  for (Spot& s : view.spots)
    s.beam = -1;  // identified by the study's sort, as the study does
  BoardCalibrationParams opt;
  opt.rows = 1;
  opt.cols = 10;
  const BoardCalibrationResult cr = calibrateFromOneBoard(cam, view, origin, opt);
  ASSERT_TRUE(cr.ok) << cr.error;
  for (int k = 0; k < 10; ++k)
  {
    // The study's formula, written with this rig's x offset (its d) and p = cx - u.
    const cv::Point2d px = cam.project(truth.beams[k].pointAt(D / truth.beams[k].direction.z()));
    const double tan_alpha_study = 1.0 / D - (cam.cx - px.x) / cam.fx;
    const Eigen::Vector3d& u = cr.calibration.beams[k].direction;
    EXPECT_NEAR(u.x() / u.z(), tan_alpha_study, 1e-12) << "beam " << k;
  }

  TriangulatorParams tc;
  tc.min_depth = 3.0;
  tc.max_depth = 6.0;
  for (double gap_m : {0.5, 0.9, 1.5})
  {
    Scene scene = board;
    scene.occluder = true;
    scene.occluder_z = D - gap_m;
    // In front of dots 1 and 2 (0-based) as seen along their beams.
    scene.occ_x0 = -0.95 * (D - gap_m) / D - 0.02;
    scene.occ_x1 = -0.55 * (D - gap_m) / D;
    scene.occ_y0 = -0.5;
    scene.occ_y1 = 0.5;
    const Frame f = sls_test::makeFrame(cam, truth, scene, FrameOptions());
    IdStats epi, srt;
    double worst_mm = 0.0;
    int on_object = 0;
    for (BeamAssignment method : {BeamAssignment::kEpipolar, BeamAssignment::kSort})
    {
      tc.assignment = method;
      Triangulator tri(cam, cr.calibration, tc);
      const TriangulationResult r = tri.process(f.spots);
      countIdentification(f, r, method == BeamAssignment::kEpipolar ? &epi : &srt);
      if (method != BeamAssignment::kEpipolar)
        continue;
      for (int k = 0; k < 10; ++k)
      {
        if (std::isnan(f.truth[k].z()))
          continue;
        on_object += std::abs(f.truth[k].z() - scene.occluder_z) < 1e-9;
        ASSERT_FALSE(std::isnan(r.points[k].z())) << "beam " << k;
        worst_mm = std::max(worst_mm, (r.points[k] - f.truth[k]).norm() * 1e3);
      }
    }
    std::cout << "[ MEASURE ] object " << gap_m << " m before the board (" << on_object << " dots on it): epipolar "
              << epi.correct << "/" << epi.visible << " right, " << epi.wrong << " wrong, worst 3D error " << worst_mm
              << " mm; study sort " << srt.correct << "/" << srt.visible << " right, " << srt.wrong << " wrong\n";
    EXPECT_EQ(epi.wrong, 0);
    EXPECT_EQ(epi.correct, epi.visible);
    EXPECT_LT(worst_mm, 1e-6);
    if (gap_m > 1.0)
    {
      EXPECT_LT(srt.correct, srt.visible) << "the study's sort should fail on this permutation";
    }
  }
  // Figure 3.7 / §3.4.4: depth change of one pixel at 4.71 m (object 0.5 m before the board).
  std::cout << "[ MEASURE ] 1 px at 4.71 m with d = 1 m, f = 769 px: " << 4.71 * 4.71 / (cam.fx * 1.0) * 1e3
            << " mm (the study: 29 mm, 'almost 6 %' of 0.5 m)\n";
}

TEST(Triangulator, SingleDot)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration proj = sls_test::simLikeProjector(0.0, 1, 1);
  Triangulator tri(cam, proj);
  for (double z : {0.9, 1.5, 2.4})
  {
    Scene scene;
    scene.distance = z;
    FrameOptions fo;
    fo.clutter = 3;
    fo.seed = static_cast<uint32_t>(z * 10);
    const Frame f = sls_test::makeFrame(cam, proj, scene, fo);
    const TriangulationResult r = tri.process(f.spots);
    IdStats s;
    countIdentification(f, r, &s);
    EXPECT_EQ(s.wrong, 0);
    EXPECT_EQ(s.correct, 1);
    EXPECT_NEAR(r.points[0].z(), z, 1e-9);
  }
}

// Depth accuracy at 1.0 / 1.5 / 2.0 m with the exact calibration and
// 0.04 px centroid noise, on a rock with 15 cm relief: <= 0.1 % RMS.
TEST(Triangulator, DepthAccuracyOnRock)
{
  for (DistortionModel dm : {DistortionModel::kNone, DistortionModel::kPlumbBob})
  {
    CameraModel cam = CameraModel::studyDesign();
    if (dm == DistortionModel::kPlumbBob)
    {
      cam.distortion = dm;
      cam.D = {-0.12, 0.05, 0.0005, -0.0003, 0.0};
    }
    const ProjectorCalibration proj = sls_test::simLikeProjector(0.087);
    Triangulator tri(cam, proj);
    for (double z : {1.0, 1.5, 2.0})
    {
      double sum2 = 0.0, sum2_rel = 0.0, gap_sum = 0.0;
      int n = 0;
      for (int trial = 0; trial < 10; ++trial)
      {
        Scene scene;
        scene.distance = z;
        scene.relief = 0.15;
        scene.phase = trial;
        FrameOptions fo;
        fo.noise_px = 0.04;
        fo.seed = 100 + trial;
        const Frame f = sls_test::makeFrame(cam, proj, scene, fo);
        const TriangulationResult r = tri.process(f.spots);
        for (int i = 0; i < proj.beamCount(); ++i)
        {
          if (std::isnan(f.truth[i].z()))
            continue;
          ASSERT_FALSE(std::isnan(r.points[i].z())) << "beam " << i << " lost at " << z << " m";
          const double e = r.points[i].z() - f.truth[i].z();
          sum2 += e * e;
          sum2_rel += e * e / (f.truth[i].z() * f.truth[i].z());
          gap_sum += r.ray_gap[i];
          ++n;
        }
      }
      const double rms_mm = std::sqrt(sum2 / n) * 1e3, rms_pct = std::sqrt(sum2_rel / n) * 100.0;
      std::cout << "[ MEASURE ] " << (dm == DistortionModel::kNone ? "no distortion" : "plumb_bob    ") << " rock at "
                << z << " m, 0.04 px noise: depth RMS " << rms_mm << " mm = " << rms_pct << " %, mean ray gap "
                << gap_sum / n * 1e3 << " mm (" << n << " points)\n";
      EXPECT_LT(rms_pct, 0.1);
    }
  }
}

// Identification with 10 % of the dots missing and clutter, on rocks at
// 1-2 m, for the rotated grid (the simulator's 5 deg roll) and an
// axis-aligned grid, whose segments along a row are collinear: every
// identifiable dot right, none wrong. Identifiable = a detected dot (not
// dropped, merged or occluded) with no other spot within the gate of its
// beam's segment and within half a beam pitch of it (sls_test::ambiguousDots:
// two candidates at nearly one depth, which no geometry can separate).
TEST(Triangulator, IdentificationMissingAndClutter)
{
  const CameraModel cam = CameraModel::studyDesign();
  for (double roll : {0.087, 0.0})
  {
    const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
    TriangulatorParams tc;
    Triangulator tri(cam, proj, tc);
    tc.assignment = BeamAssignment::kSort;
    Triangulator sorter(cam, proj, tc);
    IdStats epi, srt;
    int frames_complete = 0, identifiable = 0, identifiable_right = 0, ambiguous = 0, ambiguous_right = 0;
    const int frames = 60;
    for (int trial = 0; trial < frames; ++trial)
    {
      Scene scene;
      scene.distance = 1.0 + (trial % 11) * 0.1;
      scene.relief = 0.15;
      scene.phase = 0.37 * trial;
      FrameOptions fo;
      fo.noise_px = 0.04;
      fo.drop_fraction = 0.1;
      fo.clutter = 20;
      fo.seed = 1000 + trial;
      const Frame f = sls_test::makeFrame(cam, proj, scene, fo);
      IdStats one;
      const TriangulationResult r = tri.process(f.spots);
      countIdentification(f, r, &one);
      const std::vector<char> amb = sls_test::ambiguousDots(tri, f.spots);
      for (size_t j = 0; j < f.spots.size(); ++j)
      {
        if (f.spots[j].beam < 0)
          continue;
        const bool right = r.beam_of_spot[j] == f.spots[j].beam;
        (amb[j] ? ambiguous : identifiable) += 1;
        (amb[j] ? ambiguous_right : identifiable_right) += right;
      }
      frames_complete += one.correct == one.visible;
      epi.visible += one.visible;
      epi.correct += one.correct;
      epi.wrong += one.wrong;
      epi.missed += one.missed;
      countIdentification(f, sorter.process(f.spots), &srt);
    }
    std::cout << "[ MEASURE ] roll " << roll * 180 / M_PI << " deg, 10 % missing, 20 clutter spots, " << frames
              << " frames: epipolar " << epi.correct << "/" << epi.visible << " right, " << epi.wrong << " wrong, "
              << epi.missed << " left unassigned, " << frames_complete << " frames complete; identifiable "
              << identifiable_right << "/" << identifiable
              << " right, ambiguous (a spot within the gate and half a pitch) " << ambiguous_right << "/" << ambiguous
              << " right; study sort " << srt.correct << " right, " << srt.wrong << " wrong\n";
    EXPECT_EQ(epi.wrong, 0);
    // Axis-aligned: rows parallel to the baseline are read jointly
    // (resolveLines). Rotated: order-free assignment + consistency check,
    // with a wider tolerance for predictions extrapolated at the pattern's
    // border (an edge dot at 1 m is 5.1 px off its one-sided prediction).
    EXPECT_EQ(identifiable_right, identifiable);
  }
}

// Merged dots (two neighbours of a row fused in one blob at their midpoint)
// are never given to a beam; the other beams are unaffected.
TEST(Triangulator, MergedDotsAreRejected)
{
  const CameraModel cam = CameraModel::studyDesign();
  for (double roll : {0.087, 0.0})
  {
    const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
    Triangulator tri(cam, proj);
    IdStats s;
    int merged_assigned = 0;
    for (int trial = 0; trial < 10; ++trial)
    {
      Scene scene;
      scene.distance = 1.2 + 0.07 * trial;
      scene.relief = 0.1;
      scene.phase = trial;
      FrameOptions fo;
      fo.noise_px = 0.04;
      fo.merge_pairs = 4;
      fo.seed = 77 + trial;
      const Frame f = sls_test::makeFrame(cam, proj, scene, fo);
      const TriangulationResult r = tri.process(f.spots);
      countIdentification(f, r, &s);
      for (size_t j = 0; j < f.spots.size(); ++j)
        merged_assigned += f.spots[j].beam == -2 && r.beam_of_spot[j] >= 0;
    }
    std::cout << "[ MEASURE ] roll " << roll * 180 / M_PI << " deg, 4 merged pairs per frame: " << s.correct << "/"
              << s.visible << " single dots right, " << s.wrong << " wrong, merged blobs assigned: " << merged_assigned
              << "\n";
    EXPECT_EQ(s.wrong, 0);
    EXPECT_EQ(merged_assigned, 0);
    EXPECT_GE(s.correct, (roll != 0.0 ? 1.0 : 0.9) * s.visible);
  }
}

// An object 0.6 m in front of a rock at 1.9 m: the dots on it jump along
// their segments past their neighbours (permutations). The rotated grid keeps
// every dot right; the axis-aligned grid may leave some unproven, never wrong.
TEST(Triangulator, PermutationsFromAnObject)
{
  const CameraModel cam = CameraModel::studyDesign();
  for (double roll : {0.087, 0.0})
  {
    const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
    Triangulator tri(cam, proj);
    Scene scene;
    scene.distance = 1.9;
    scene.relief = 0.05;
    scene.occluder = true;
    scene.occluder_z = 1.3;
    scene.occ_x0 = -0.12;
    scene.occ_x1 = 0.05;
    scene.occ_y0 = -0.1;
    scene.occ_y1 = 0.08;
    FrameOptions fo;
    fo.noise_px = 0.04;
    fo.clutter = 10;
    const Frame f = sls_test::makeFrame(cam, proj, scene, fo);
    IdStats s;
    const TriangulationResult r = tri.process(f.spots);
    countIdentification(f, r, &s);
    int on_object = 0;
    for (const auto& p : f.truth)
      on_object += std::abs(p.z() - scene.occluder_z) < 1e-9;
    std::cout << "[ MEASURE ] roll " << roll * 180 / M_PI << " deg, object 0.6 m before the rock (" << on_object
              << " dots on it): " << s.correct << "/" << s.visible << " right, " << s.wrong << " wrong, " << s.missed
              << " unassigned\n";
    EXPECT_GT(on_object, 4);
    EXPECT_EQ(s.wrong, 0);
    if (roll != 0.0)
    {
      EXPECT_EQ(s.correct, s.visible);
    }
  }
}

TEST(Triangulator, NanCentroidsAndGates)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration proj = sls_test::simLikeProjector(0.087);
  Triangulator tri(cam, proj);
  Scene scene;
  const Frame f = sls_test::makeFrame(cam, proj, scene, FrameOptions());
  Spots spots = f.spots;
  spots[0].x = std::numeric_limits<double>::quiet_NaN();
  spots[1].y = std::numeric_limits<double>::infinity();
  const TriangulationResult r = tri.process(spots);
  EXPECT_EQ(r.dropped_nan, 2);
  EXPECT_EQ(r.beam_of_spot[0], -1);
  EXPECT_EQ(r.valid_points, static_cast<int>(spots.size()) - 2);
  // A rock outside the depth range gives no points at all.
  Scene far_scene;
  far_scene.distance = 3.5;
  const Frame ff = sls_test::makeFrame(cam, proj, far_scene, FrameOptions());
  EXPECT_EQ(tri.process(ff.spots).valid_points, 0);
  // Invalid configs are refused with a reason.
  TriangulatorParams bad;
  bad.min_depth = 3.0;
  bad.max_depth = 1.0;
  EXPECT_FALSE(bad.validate().empty());
  EXPECT_THROW(Triangulator(cam, proj, bad), std::invalid_argument);
  CameraModel zero = cam;
  zero.fx = 0.0;
  EXPECT_THROW(Triangulator(zero, proj), std::invalid_argument);
}

// Tracking prior, constructed cases. (1) A spurious spot on the segment of
// a beam whose dot was seen last frame and is missing now, 12 px along the
// segment from it (a depth of its own, within the surface tolerance of the
// neighbours): refused with the prior, whatever the single frame decides.
// (2) A prior from another scene (the rock 0.4 m farther; on the aligned
// grid the pattern then looks unmoved, every dot near its row neighbour's
// old position): not used, no wrong beam, nothing the single frame does
// not also find.
TEST(Triangulator, TrackingPrior)
{
  const CameraModel cam = CameraModel::studyDesign();
  for (double roll : {0.087, 0.0})
  {
    const ProjectorCalibration proj = sls_test::simLikeProjector(roll);
    const Triangulator tri(cam, proj);
    Scene scene;
    scene.distance = 1.4;
    scene.relief = 0.1;
    FrameOptions fo;
    fo.noise_px = 0.04;
    const Frame f = sls_test::makeFrame(cam, proj, scene, fo);
    const TriangulationResult previous = tri.process(f.spots);
    int refused = 0, taken_alone = 0, cases = 0;
    for (int beam : {23, 45, 56, 74})
    {
      Frame g = f;
      int j = -1;
      for (size_t k = 0; k < g.spots.size(); ++k)
        if (g.spots[k].beam == beam)
          j = static_cast<int>(k);
      ASSERT_GE(j, 0);
      // Move the dot 12 px along its segment (undistorted) and call it spurious.
      const EpipolarSegment& sg = tri.segments()[beam];
      const Eigen::Vector2d along = (sg.far_px - sg.near_px).normalized();
      const Eigen::Vector2d u = tri.undistortPixel(g.spots[j].x, g.spots[j].y) + 12.0 * along;
      const Eigen::Vector2d d =
          cam.distortNormalized(Eigen::Vector2d((u.x() - cam.cx) / cam.fx, (u.y() - cam.cy) / cam.fy));
      g.spots[j].x = cam.fx * d.x() + cam.cx;
      g.spots[j].y = cam.fy * d.y() + cam.cy;
      g.spots[j].beam = -1;
      const TriangulationResult alone = tri.process(g.spots);
      const TriangulationResult tracked = tri.process(g.spots, &previous);
      ++cases;
      taken_alone += alone.beam_of_spot[j] >= 0;
      refused += tracked.beam_of_spot[j] < 0;
      EXPECT_GE(tracked.tracked, 90);
      IdStats s;
      countIdentification(g, tracked, &s);
      EXPECT_EQ(s.wrong, 0);
      EXPECT_EQ(s.correct, s.visible);
    }
    std::cout << "[ MEASURE ] roll " << roll * 180 / M_PI << " deg: a spurious spot 12 px along the segment of a dot "
              << "seen last frame: taken by the single frame " << taken_alone << "/" << cases
              << ", refused with the prior " << refused << "/" << cases << "\n";
    EXPECT_EQ(refused, cases);

    Scene other = scene;
    other.distance = 1.8;
    const Frame h = sls_test::makeFrame(cam, proj, other, fo);
    const TriangulationResult with_stale = tri.process(h.spots, &previous);
    const TriangulationResult alone = tri.process(h.spots);
    IdStats stale, fresh;
    countIdentification(h, with_stale, &stale);
    countIdentification(h, alone, &fresh);
    std::cout << "[ MEASURE ] roll " << roll * 180 / M_PI << " deg, prior from the rock 0.4 m nearer: " << stale.correct
              << "/" << stale.visible << " right, " << stale.wrong << " wrong (without it " << fresh.correct << ", "
              << fresh.wrong << " wrong)\n";
    EXPECT_EQ(with_stale.tracked, -1);
    EXPECT_EQ(stale.wrong, 0);
    for (size_t j = 0; j < h.spots.size(); ++j)
    {
      if (with_stale.beam_of_spot[j] >= 0)
      {
        EXPECT_EQ(with_stale.beam_of_spot[j], alone.beam_of_spot[j]);
      }
    }
  }
}
