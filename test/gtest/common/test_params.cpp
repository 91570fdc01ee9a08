// The parameter definitions (common/params.h): every settings struct built
// from a .def compares, clamps, sets by name and copies to and from a
// dynamic_reconfigure-like Config field by field, with nothing left out.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/common/params.h"
#include "structured_light_stabilizer/control/stabilization_controller.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/detection/spot_search_planner.h"
#include "structured_light_stabilizer/pose/pose_delta_params.h"
#include "structured_light_stabilizer/triangulation/beam_tracker.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace sls = structured_light_stabilizer;
using sls::params::Changes;

namespace
{

struct Field
{
  std::string name;
  std::string kind;  // param, enum, fixed
  std::string type;
};

// The fields of a .def, in order, read by the same macros as the structs.
template <int Which>
std::vector<Field> fieldsOf();

#define SLS_PARAM(type, name, def, lo, hi, doc) f.push_back({#name, "param", #type});
#define SLS_ENUM(type, name, def, choices, doc) f.push_back({#name, "enum", #type});
#define SLS_INT_ENUM(type, name, def, choices, doc) f.push_back({#name, "enum", #type});
#define SLS_FIXED(type, name, def, doc) f.push_back({#name, "fixed", #type});
#define SLS_SECTION(name, type)
#define SLS_GROUP(type, name, file, group)
template <>
std::vector<Field> fieldsOf<0>()
{
  std::vector<Field> f;
#include "structured_light_stabilizer/triangulation/triangulator_params.def"
  return f;
}
template <>
std::vector<Field> fieldsOf<1>()
{
  std::vector<Field> f;
#include "structured_light_stabilizer/pose/pose_delta_params.def"
  return f;
}
template <>
std::vector<Field> fieldsOf<2>()
{
  std::vector<Field> f;
#include "structured_light_stabilizer/control/stabilization_controller_params.def"
  return f;
}
template <>
std::vector<Field> fieldsOf<3>()
{
  std::vector<Field> f;
#include "structured_light_stabilizer/detection/fast_params.def"
#include "structured_light_stabilizer/detection/colour_test_params.def"
#include "structured_light_stabilizer/detection/baseline_params.def"
#include "structured_light_stabilizer/detection/spot_detector_params.def"
  return f;
}
#undef SLS_PARAM
#undef SLS_ENUM
#undef SLS_INT_ENUM
#undef SLS_FIXED
#undef SLS_SECTION
#undef SLS_GROUP

// Every field set by name to another value makes the struct unequal to the
// default, and only then (equality and set() cover every field).
template <typename Params, int Which>
void everyFieldCounts()
{
  const std::vector<Field> fields = fieldsOf<Which>();
  ASSERT_FALSE(fields.empty());
  for (const Field& f : fields)
  {
    Params p;
    std::vector<std::string> tries;
    if (f.type == "bool")
      tries = {"true", "false"};
    else if (f.kind == "enum")
      tries = {"baseline", "fast", "red", "value", "sort", "frame_to_frame", "green", "epipolar", "saturation",
               "reference"};
    else
      tries = {"3", "7"};
    bool changed = false;
    for (const std::string& v : tries)
    {
      Params q;
      if (q.set(f.name, v) && !(q == p))
      {
        changed = true;
        EXPECT_TRUE(q != p);
        break;
      }
    }
    EXPECT_TRUE(changed) << f.name << ": set() by name did not change the struct, or == ignores the field";
  }
  Params p;
  EXPECT_FALSE(p.set("no_such_parameter", "1"));
}

// A stand-in for a dynamic_reconfigure Config: the live fields by name.
struct FakeTriangulatorConfig
{
  double min_depth = 0, max_depth = 0, max_epipolar_distance_px = 0, max_ray_gap = 0, ambiguity_margin = 0,
         prediction_tolerance_px = 0, tracking_radius_px = 0;
  std::string assignment;
};

}  // namespace

TEST(Params, ChoicesByNameAndIndex)
{
  const char* choices = "a:first|bb:second|c";
  EXPECT_EQ(sls::params::choiceName(choices, 0), "a");
  EXPECT_EQ(sls::params::choiceName(choices, 1), "bb");
  EXPECT_EQ(sls::params::choiceName(choices, 2), "c");
  EXPECT_EQ(sls::params::choiceName(choices, 3), "");
  EXPECT_EQ(sls::params::choiceIndex(choices, "c"), 2);
  EXPECT_EQ(sls::params::choiceIndex(choices, "first"), -1);
  sls::BeamAssignment a = sls::BeamAssignment::kEpipolar;
  EXPECT_FALSE(sls::params::enumFromName("epipolar|sort", "nonsense", &a));
  EXPECT_EQ(a, sls::BeamAssignment::kEpipolar);
}

TEST(Params, ClampSaysWhatItChanged)
{
  Changes changes;
  double x = 7.0;
  sls::params::clampTo(&x, 0.0, 5.0, "x", &changes);
  EXPECT_EQ(x, 5.0);
  double nan = std::nan("");
  sls::params::clampTo(&nan, 1.0, 5.0, "nan", &changes);
  EXPECT_EQ(nan, 1.0);
  int n = 3;
  sls::params::clampTo(&n, 0, 5, "n", &changes);
  ASSERT_EQ(changes.size(), 2u);
  EXPECT_NE(changes[0].find("x 7 out of [0, 5], clamped to 5"), std::string::npos) << changes[0];

  sls::TriangulatorParams p;
  p.max_ray_gap = 1.0;  // range [1e-5, 0.1] in the .def
  p.min_depth = -1.0;
  changes.clear();
  p.clampToRanges(&changes);
  EXPECT_EQ(p.max_ray_gap, 0.1);
  EXPECT_EQ(p.min_depth, 0.05);
  EXPECT_EQ(changes.size(), 2u);
}

TEST(Params, EveryFieldIsComparedAndSettable)
{
  everyFieldCounts<sls::TriangulatorParams, 0>();
  everyFieldCounts<sls::PoseDeltaParams, 1>();
  everyFieldCounts<sls::StabilizationControllerParams, 2>();
  everyFieldCounts<sls::SpotDetectorParams, 3>();
}

TEST(Params, SetReadsTextAsTheFieldsType)
{
  sls::PoseDeltaParams p;
  EXPECT_TRUE(p.set("texture_refinement_window_px", "31"));
  EXPECT_EQ(p.texture_refinement_window_px, 31);
  EXPECT_FALSE(p.set("texture_refinement_window_px", "3.5"));
  EXPECT_FALSE(p.set("use_texture", "yes"));
  EXPECT_TRUE(p.set("use_texture", "0"));
  EXPECT_FALSE(p.use_texture);
  EXPECT_TRUE(p.set("mode", "frame_to_frame"));
  EXPECT_EQ(p.mode, sls::PoseDeltaMode::kFrameToFrame);
  EXPECT_FALSE(p.set("mode", "sideways"));
  sls::SpotDetectorParams d;
  EXPECT_TRUE(d.set("led_red_ratio", "0.5"));  // in a nested group
  EXPECT_EQ(d.fast.colour_test.led_red_ratio, 0.5);
}

TEST(Params, ConfigRoundTrip)
{
  sls::TriangulatorParams p;
  p.max_depth = 2.0;
  p.assignment = sls::BeamAssignment::kSort;
  FakeTriangulatorConfig c;
  p.toConfig(&c);
  EXPECT_EQ(c.max_depth, 2.0);
  EXPECT_EQ(c.assignment, "sort");
  sls::TriangulatorParams q;
  EXPECT_TRUE(q.fromConfig(c));
  EXPECT_TRUE(q == p);
  c.assignment = "nonsense";
  EXPECT_FALSE(q.fromConfig(c));
  EXPECT_EQ(q.assignment, sls::BeamAssignment::kSort);  // left as it was
}

TEST(Params, DefaultsAreWithinTheirRanges)
{
  Changes changes;
  sls::TriangulatorParams().clampToRanges(&changes);
  sls::BeamTrackerParams().clampToRanges(&changes);
  sls::PoseDeltaParams().clampToRanges(&changes);
  sls::StabilizationControllerParams().clampToRanges(&changes);
  sls::SpotDetectorParams().clampToRanges(&changes);
  sls::SpotSearchParams().clampToRanges(&changes);
  EXPECT_TRUE(changes.empty()) << changes.front();
}
