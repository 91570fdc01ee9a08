// config/projector_sim.yaml is the pipeline's default calibration; it must be
// the simulator's exact default projector, or every default-launch depth is off.
#include <gtest/gtest.h>

#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

using namespace structured_light_stabilizer;

TEST(SimCalibrationFile, MatchesTheSimulatorsDefaultProjector)
{
  ProjectorCalibration file;
  std::string error;
  ASSERT_TRUE(
      loadProjectorCalibration(std::string(SLS_TEST_DATA_DIR) + "/../../config/projector_sim.yaml", &file, &error))
      << error;
  const Simulator sim{SimulatorParams()};
  const ProjectorCalibration& exact = sim.projector();
  ASSERT_EQ(file.rows, exact.rows);
  ASSERT_EQ(file.cols, exact.cols);
  double worst_origin = 0.0, worst_direction = 0.0;
  for (size_t i = 0; i < exact.beams.size(); ++i)
  {
    worst_origin = std::max(worst_origin, (file.beams[i].origin - exact.beams[i].origin).norm());
    worst_direction = std::max(worst_direction, (file.beams[i].direction - exact.beams[i].direction).norm());
  }
  // 12 significant digits in the file: 1e-10 rad is 1.5e-10 m at 1.5 m.
  EXPECT_LT(worst_origin, 1e-10);
  EXPECT_LT(worst_direction, 1e-10);
}
