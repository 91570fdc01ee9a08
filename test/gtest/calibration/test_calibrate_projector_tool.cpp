// The calibrate_projector tool run in-process on folders of
// simulated chessboard views: a good folder is calibrated (rays against the
// simulator's projector, the YAML and the PNG written, a view without a
// board reported), and every refusal exits with its own status and a
// message naming the problem. Noise seeds 71-79 (held out).
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "cli/calibrate_projector_cli.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

namespace fs = std::filesystem;
using namespace structured_light_stabilizer;

namespace
{

const std::string kCamera = std::string(SLS_TEST_DATA_DIR) + "/camera_study.yaml";

// A board view of the simulator; offset_y moves the board down (m) so that
// the pattern's top rows fall beyond it.
cv::Mat boardImage(double distance, double tilt_x, double tilt_y, double offset_y, uint32_t seed)
{
  SimulatorParams c = studySimulatorParams();  // the board views of the tests below
  c.target.kind = TargetKind::kChessboard;
  c.target.chessboard.distance_m = distance;
  c.target.chessboard.tilt_x_rad = tilt_x;
  c.target.chessboard.tilt_y_rad = tilt_y;
  c.target.chessboard.offset_m = Eigen::Vector2d(0.0, offset_y);
  c.noise_seed = seed;
  return Simulator(c).render(0.0).image;
}

cv::Mat rockImage(uint32_t seed)
{
  SimulatorParams c = studySimulatorParams();
  c.noise_seed = seed;
  return Simulator(c).render(0.0).image;
}

struct ToolRun
{
  int status = -1;
  std::string out, err;
};

ToolRun run(const std::vector<std::string>& args)
{
  std::ostringstream out, err;
  ToolRun r;
  r.status = calibrateProjectorMain(args, out, err);
  r.out = out.str();
  r.err = err.str();
  return r;
}

std::vector<std::string> args(const fs::path& dir, const fs::path& output, const std::string& camera = kCamera)
{
  return {"--images", dir.string(), "--camera-info", camera,     "--board",
          "10x8",     "--square",   "0.08",          "--output", output.string()};
}

class CalibrateProjectorTool : public ::testing::Test
{
protected:
  static void SetUpTestSuite()
  {
    root_ = fs::temp_directory_path() / ("sls_calibrate_projector_" + std::to_string(::getpid()));
    fs::create_directories(root_);
    // Four good views, a rock (no board), two views with the pattern's top
    // rows beyond the board.
    good_ = {boardImage(1.25, 0.30, 0.15, 0.0, 71), boardImage(1.35, -0.25, -0.30, 0.0, 72),
             boardImage(1.50, 0.10, 0.34, 0.0, 73), boardImage(1.60, -0.30, -0.10, 0.0, 74)};
    rock_ = rockImage(75);
    half_ = {boardImage(1.40, 0.2, 0.1, 0.3, 76), boardImage(1.50, -0.2, -0.2, 0.3, 77)};
  }
  static void TearDownTestSuite()
  {
    if (!getenv("SLS_KEEP_TMP"))
      fs::remove_all(root_);
  }

  fs::path folder(const std::string& name, const std::vector<cv::Mat>& images)
  {
    const fs::path dir = root_ / name;
    fs::create_directories(dir);
    for (size_t k = 0; k < images.size(); ++k)
      cv::imwrite((dir / ("view_" + std::to_string(k) + ".png")).string(), images[k]);
    return dir;
  }

  static fs::path root_;
  static std::vector<cv::Mat> good_, half_;
  static cv::Mat rock_;
};

fs::path CalibrateProjectorTool::root_;
std::vector<cv::Mat> CalibrateProjectorTool::good_, CalibrateProjectorTool::half_;
cv::Mat CalibrateProjectorTool::rock_;

}  // namespace

TEST_F(CalibrateProjectorTool, CalibratesAFolderAndReportsAViewWithoutBoard)
{
  std::vector<cv::Mat> images = good_;
  images.push_back(rock_);
  const fs::path dir = folder("good", images), yaml = root_ / "projector.yaml";
  const ToolRun r = run(args(dir, yaml));
  std::cout << r.out << r.err;
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("view_4.png: no chessboard"), std::string::npos);
  EXPECT_TRUE(fs::exists(root_ / "projector.png"));
  EXPECT_NE(r.out.find("model: central"), std::string::npos);  // the simulator's projector has one centre
  ProjectorCalibration fitted;
  std::string err;
  ASSERT_TRUE(loadProjectorCalibration(yaml.string(), &fitted, &err)) << err;
  const ProjectorCalibration truth = Simulator(SimulatorParams()).projector();
  double sum2 = 0.0;
  for (int b = 0; b < truth.beamCount(); ++b)
  {
    const auto at = [](const BeamRay& ray) { return ray.pointAt((1.5 - ray.origin.z()) / ray.direction.z()); };
    sum2 += (at(fitted.beams[b]) - at(truth.beams[b])).squaredNorm();
  }
  const double rms = std::sqrt(sum2 / truth.beamCount());
  std::cout << "[ MEASURE ] calibrate_projector on 4 simulated views: rays " << rms * 1e3 << " mm RMS at 1.5 m\n";
  EXPECT_LT(rms, 0.5e-3);
}

TEST_F(CalibrateProjectorTool, RefusalsExitWithTheirStatusAndNameTheProblem)
{
  const fs::path out = root_ / "refused.yaml";
  // Bad usage.
  EXPECT_EQ(run({"--images", root_.string()}).status, 1);
  ToolRun r = run({"--images", root_.string(), "--camera-info", kCamera, "--board", "10by8", "--square", "0.08",
                   "--output", out.string()});
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("--board"), std::string::npos) << r.err;
  // The camera_info.
  r = run(args(folder("cam", {good_[0]}), out, std::string(SLS_TEST_DATA_DIR) + "/bad/camera_info_zero_focal.yaml"));
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("camera_info"), std::string::npos) << r.err;
  // An unreadable image.
  const fs::path broken = folder("broken", {good_[0], good_[1]});
  std::ofstream(broken / "view_9.png") << "not a png";
  r = run(args(broken, out));
  EXPECT_EQ(r.status, 3);
  EXPECT_NE(r.err.find("view_9.png"), std::string::npos) << r.err;
  // One view with the board.
  r = run(args(folder("one", {good_[0], rock_}), out));
  EXPECT_EQ(r.status, 4);
  EXPECT_NE(r.err.find("two views"), std::string::npos) << r.err;
  // No view shows the whole pattern.
  r = run(args(folder("halves", half_), out));
  EXPECT_EQ(r.status, 6) << r.out << r.err;
  EXPECT_NE(r.err.find("whole"), std::string::npos) << r.err;
  // Half of the beams only in one view.
  r = run(args(folder("beams", {good_[0], half_[0], half_[1]}), out));
  EXPECT_EQ(r.status, 5) << r.out << r.err;
  EXPECT_NE(r.err.find("beam"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));
}
