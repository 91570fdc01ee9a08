// Every malformed file of test/data/bad/ is fed to the loader its name
// prefix selects, which must refuse it with a message naming the file and
// what is wrong (the key, the line or the beam): the fixture's first line
// "# expect: <text>" says which text the message must contain.
//   projector_*.yaml   -> loadProjectorCalibration (projector_calibration.h)
//   scene_*.yaml       -> loadSceneInputs (scene_analysis.h)
//   camera_info_*.yaml -> camera_info_manager's parser, through the
//                         CameraDriver: rostest bad_camera_info_files.test
// A fixture with no known prefix fails the test, so none goes unchecked.
#include <dirent.h>

#include <algorithm>
#include <fstream>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/sim/design/scene_analysis.h"

namespace
{
using namespace structured_light_stabilizer;

const std::string kBadDir = std::string(SLS_TEST_DATA_DIR) + "/bad";

std::vector<std::string> badFiles()
{
  std::vector<std::string> names;
  if (DIR* dir = opendir(kBadDir.c_str()))
  {
    while (const dirent* e = readdir(dir))
    {
      const std::string name = e->d_name;
      if (name.size() > 5 && name.compare(name.size() - 5, 5, ".yaml") == 0)
        names.push_back(name);
    }
    closedir(dir);
  }
  std::sort(names.begin(), names.end());
  return names;
}

bool startsWith(const std::string& s, const std::string& prefix)
{
  return s.compare(0, prefix.size(), prefix) == 0;
}

// The text after "# expect: " on the first line of the fixture.
std::string expectation(const std::string& name)
{
  std::ifstream in(kBadDir + "/" + name);
  std::string line;
  std::getline(in, line);
  const std::string tag = "# expect: ";
  return startsWith(line, tag) ? line.substr(tag.size()) : std::string();
}

TEST(BadFiles, EveryFixtureHasALoaderAndAnExpectation)
{
  const std::vector<std::string> names = badFiles();
  ASSERT_GE(names.size(), 20u) << "fixtures missing from " << kBadDir;
  for (const std::string& name : names)
  {
    EXPECT_TRUE(startsWith(name, "projector_") || startsWith(name, "scene_") || startsWith(name, "camera_info_"))
        << name << ": no loader for this prefix";
    EXPECT_FALSE(expectation(name).empty()) << name << ": first line must be '# expect: <text of the refusal>'";
  }
}

TEST(BadFiles, ProjectorCalibrationRefusesEachWithReason)
{
  int n = 0;
  for (const std::string& name : badFiles())
  {
    if (!startsWith(name, "projector_"))
      continue;
    ProjectorCalibration cal;
    cal.rows = 7;  // a previous, good state must not be half-overwritten
    std::string err;
    EXPECT_FALSE(loadProjectorCalibration(kBadDir + "/" + name, &cal, &err)) << name << " was accepted";
    EXPECT_NE(err.find(name), std::string::npos) << name << ": the message does not name the file: " << err;
    EXPECT_NE(err.find(expectation(name)), std::string::npos)
        << name << ": the message does not mention '" << expectation(name) << "': " << err;
    std::cout << "[ MEASURE ] " << name << " -> " << err << "\n";
    ++n;
  }
  EXPECT_GE(n, 10);
}

TEST(BadFiles, SceneInputsRefusesEachWithReason)
{
  int n = 0;
  for (const std::string& name : badFiles())
  {
    if (!startsWith(name, "scene_"))
      continue;
    std::string err;
    try
    {
      (void)loadSceneInputs(kBadDir + "/" + name);
      ADD_FAILURE() << name << " was accepted";
    }
    catch (const std::invalid_argument& e)
    {
      err = e.what();
    }
    // Any other exception type escapes and fails the test: the loader's
    // contract is std::invalid_argument.
    EXPECT_NE(err.find(name), std::string::npos) << name << ": the message does not name the file: " << err;
    EXPECT_NE(err.find(expectation(name)), std::string::npos)
        << name << ": the message does not mention '" << expectation(name) << "': " << err;
    std::cout << "[ MEASURE ] " << name << " -> " << err << "\n";
    ++n;
  }
  EXPECT_GE(n, 10);
}

TEST(BadFiles, GoodFilesStillLoad)
{
  // The refusals above are not a loader that refuses everything.
  const std::string data = SLS_TEST_DATA_DIR;
  ProjectorCalibration cal;
  std::string err;
  EXPECT_TRUE(loadProjectorCalibration(data + "/projector_10x10.yaml", &cal, &err)) << err;
  EXPECT_EQ(cal.beamCount(), 100);
  EXPECT_NO_THROW((void)loadSceneInputs(data + "/../../config/scene_analysis.yaml"));
}

}  // namespace
