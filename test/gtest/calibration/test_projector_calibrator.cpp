// Projector calibration from flat boards: fit quality against the exact rig,
// depth accuracy with the fitted calibration, the self-check that flags a
// misidentified beam, the study's one-distance procedure and the file forms.
#include <cmath>
#include <cstdio>
#include <iostream>

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

BoardView boardView(const CameraModel& cam, const ProjectorCalibration& proj, double distance, double noise_px,
                    uint32_t seed)
{
  Scene board;
  board.distance = distance;
  FrameOptions fo;
  fo.noise_px = noise_px;
  fo.seed = seed;
  const Frame f = sls_test::makeFrame(cam, proj, board, fo);
  BoardView v;
  v.distance_m = distance;
  v.spots = f.spots;
  return v;
}

// Depth RMS (fraction of the distance) on rocks at `z` triangulated with `cal`.
double depthRms(const CameraModel& cam, const ProjectorCalibration& truth, const ProjectorCalibration& cal, double z,
                double noise_px, double* rms_mm)
{
  Triangulator tri(cam, cal);
  double sum2 = 0.0, sum2_rel = 0.0;
  int n = 0;
  for (int trial = 0; trial < 5; ++trial)
  {
    Scene scene;
    scene.distance = z;
    scene.relief = 0.15;
    scene.phase = 1.3 * trial;
    FrameOptions fo;
    fo.noise_px = noise_px;
    fo.seed = 500 + trial;
    const Frame f = sls_test::makeFrame(cam, truth, scene, fo);
    const TriangulationResult r = tri.process(f.spots);
    for (int i = 0; i < truth.beamCount(); ++i)
    {
      if (std::isnan(f.truth[i].z()) || std::isnan(r.points[i].z()))
        continue;
      const double e = r.points[i].z() - f.truth[i].z();
      sum2 += e * e;
      sum2_rel += e * e / (f.truth[i].z() * f.truth[i].z());
      ++n;
    }
  }
  EXPECT_GT(n, 400);
  *rms_mm = std::sqrt(sum2 / std::max(1, n)) * 1e3;
  return std::sqrt(sum2_rel / std::max(1, n));
}

}  // namespace

TEST(ProjectorCalibrator, TwoBoardsGiveAccurateDepth)
{
  for (bool distorted : {false, true})
  {
    CameraModel cam = CameraModel::studyDesign();
    if (distorted)
    {
      cam.distortion = DistortionModel::kPlumbBob;
      cam.D = {-0.12, 0.05, 0.0005, -0.0003, 0.0};
    }
    const ProjectorCalibration truth = sls_test::simLikeProjector(0.087);
    const std::vector<BoardView> views{boardView(cam, truth, 1.0, 0.05, 1), boardView(cam, truth, 2.0, 0.05, 2)};
    BoardCalibrationParams opt;
    const BoardCalibrationResult res = calibrateFromBoards(cam, views, opt);
    ASSERT_TRUE(res.ok) << res.error;
    std::cout << "[ MEASURE ] " << res.report() << "\n";
    double worst_angle = 0.0;
    for (int i = 0; i < truth.beamCount(); ++i)
      worst_angle = std::max(
          worst_angle, std::acos(std::min(1.0, res.calibration.beams[i].direction.dot(truth.beams[i].direction))));
    std::cout << "[ MEASURE ] " << (distorted ? "plumb_bob" : "no distortion")
              << ": boards at 1.0 + 2.0 m, 0.05 px noise: worst beam direction error " << worst_angle * 1e6
              << " urad, common centre error " << (res.common_centre - truth.beams[0].origin).norm() * 1e3 << " mm\n";
    EXPECT_EQ(res.poor_beams, 0);
    for (double z : {1.0, 1.5, 2.0})
    {
      double mm = 0.0;
      const double rel = depthRms(cam, truth, res.calibration, z, 0.04, &mm);
      std::cout << "[ MEASURE ]   depth RMS with the fitted calibration at " << z << " m: " << mm
                << " mm = " << rel * 100 << " %\n";
      EXPECT_LT(rel, 0.002);
    }
  }
}

TEST(ProjectorCalibrator, SelfCheckFlagsAMisidentifiedBeam)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration truth = sls_test::simLikeProjector(0.087);
  std::vector<BoardView> views{boardView(cam, truth, 1.0, 0.05, 3), boardView(cam, truth, 1.5, 0.05, 4),
                               boardView(cam, truth, 2.0, 0.05, 5)};
  BoardCalibrationParams opt;
  BoardCalibrationResult ok = calibrateFromBoards(cam, views, opt);
  ASSERT_TRUE(ok.ok) << ok.error;
  double worst = 0.0;
  for (const BeamFit& f : ok.beams)
    worst = std::max(worst, f.residual_px);
  std::cout << "[ MEASURE ] three boards, 0.05 px noise: worst per-beam residual " << worst << " px, poor beams "
            << ok.poor_beams << "\n";
  EXPECT_EQ(ok.poor_beams, 0);
  // Swap the ids of beams 44 and 45 in the middle view.
  for (Spot& s : views[1].spots)
    s.beam = s.beam == 44 ? 45 : (s.beam == 45 ? 44 : s.beam);
  const BoardCalibrationResult bad = calibrateFromBoards(cam, views, opt);
  ASSERT_TRUE(bad.ok) << bad.error;
  std::cout << "[ MEASURE ] with beams 44/45 swapped in one view: " << bad.report() << "\n";
  EXPECT_TRUE(bad.beams[44].poor);
  EXPECT_TRUE(bad.beams[45].poor);
  EXPECT_EQ(bad.poor_beams, 2);
  // Two views only: the residual is zero, the common-centre check still sees it.
  const std::vector<BoardView> two{views[0], views[1]};
  const BoardCalibrationResult bad2 = calibrateFromBoards(cam, two, opt);
  ASSERT_TRUE(bad2.ok);
  EXPECT_TRUE(bad2.beams[44].poor);
  EXPECT_TRUE(bad2.beams[45].poor);
}

TEST(ProjectorCalibrator, UnlabelledViewsAreSortedAndRefusalsNameTheProblem)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration truth = sls_test::simLikeProjector(0.087);
  std::vector<BoardView> views{boardView(cam, truth, 1.0, 0.0, 6), boardView(cam, truth, 2.0, 0.0, 7)};
  for (BoardView& v : views)
    for (Spot& s : v.spots)
      s.beam = -1;
  const BoardCalibrationResult res = calibrateFromBoards(cam, views, BoardCalibrationParams());
  ASSERT_TRUE(res.ok) << res.error;
  for (int i = 0; i < truth.beamCount(); ++i)
    EXPECT_LT((res.calibration.beams[i].direction - truth.beams[i].direction).norm(), 1e-9);
  // Refusals.
  EXPECT_FALSE(calibrateFromBoards(cam, {views[0]}, BoardCalibrationParams()).ok);
  std::vector<BoardView> missing = views;
  missing[1].spots.pop_back();
  const BoardCalibrationResult r2 = calibrateFromBoards(cam, missing, BoardCalibrationParams());
  EXPECT_FALSE(r2.ok);
  EXPECT_NE(r2.error.find("view 1"), std::string::npos) << r2.error;
  std::vector<BoardView> same{views[0], views[0]};
  const BoardCalibrationResult r3 = calibrateFromBoards(cam, same, BoardCalibrationParams());
  EXPECT_FALSE(r3.ok);
  EXPECT_NE(r3.error.find("beam 0"), std::string::npos) << r3.error;
}

TEST(ProjectorCalibrator, FilesRoundTrip)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration truth = sls_test::simLikeProjector(0.087);
  const BoardView v = boardView(cam, truth, 1.25, 0.0, 8);
  const std::string view_path = ::testing::TempDir() + "sls_board_view.yaml";
  std::string err;
  ASSERT_TRUE(saveBoardView(view_path, v, &err)) << err;
  BoardView back;
  ASSERT_TRUE(loadBoardView(view_path, &back, &err)) << err;
  EXPECT_EQ(back.distance_m, 1.25);
  ASSERT_EQ(back.spots.size(), v.spots.size());
  EXPECT_NEAR(back.spots[3].x, v.spots[3].x, 1e-9);
  EXPECT_EQ(back.spots[3].beam, v.spots[3].beam);
  const std::string cal_path = ::testing::TempDir() + "sls_projector.yaml";
  ASSERT_TRUE(saveProjectorCalibration(cal_path, truth, &err)) << err;
  ProjectorCalibration loaded;
  ASSERT_TRUE(loadProjectorCalibration(cal_path, &loaded, &err)) << err;
  EXPECT_LT((loaded.beams[17].direction - truth.beams[17].direction).norm(), 1e-10);
  CameraModel cam2;
  ASSERT_TRUE(loadCameraModelYaml(std::string(SLS_TEST_DATA_DIR) + "/camera_study.yaml", &cam2, &err)) << err;
  EXPECT_NEAR(cam2.fx, cam.fx, 1e-3);
  std::remove(view_path.c_str());
  std::remove(cal_path.c_str());
}

// The three file forms load to rays; malformed files are refused with a
// message that names the line or the beam at fault.
TEST(ProjectorCalibrationFiles, FormsAndRefusals)
{
  const std::string dir = SLS_TEST_DATA_DIR;
  ProjectorCalibration grid, rays, study;
  std::string err;
  ASSERT_TRUE(loadProjectorCalibration(dir + "/projector_grid.yaml", &grid, &err)) << err;
  ASSERT_TRUE(loadProjectorCalibration(dir + "/projector_10x10.yaml", &rays, &err)) << err;
  const ProjectorCalibration expected = sls_test::simLikeProjector(0.087);
  ASSERT_EQ(grid.beamCount(), 100);
  for (int i = 0; i < 100; ++i)
    EXPECT_LT((grid.beams[i].direction - expected.beams[i].direction).norm(), 1e-12) << i;
  ASSERT_TRUE(loadProjectorCalibration(dir + "/projector_study_1x10.yaml", &study, &err)) << err;
  ASSERT_EQ(study.beamCount(), 10);
  EXPECT_NEAR(study.beams[4].origin.x(), -0.30, 1e-12);
  EXPECT_NEAR(study.beams[4].direction.x() / study.beams[4].direction.z(), 0.1944, 1e-12);
  const struct
  {
    const char* file;
    const char* must_mention;
  } bad[] = {{"wrong_count.yaml", "3 entries"},
             {"zero_direction.yaml", "beam 2"},
             {"not_a_number.yaml", "beam 1 origin"},
             {"backwards_beam.yaml", "beam 0"},
             {"bad_rows.yaml", "'rows'"},
             {"study_missing_key.yaml", "beam 1"},
             {"not_yaml.yaml", "not valid YAML"},
             {"does_not_exist.yaml", "cannot open"}};
  for (const auto& b : bad)
  {
    ProjectorCalibration cal;
    err.clear();
    EXPECT_FALSE(loadProjectorCalibration(dir + "/bad/projector_" + b.file, &cal, &err)) << b.file;
    EXPECT_NE(err.find(b.must_mention), std::string::npos) << b.file << ": " << err;
    std::cout << "[ MEASURE ] " << b.file << " -> " << err << "\n";
  }
}
