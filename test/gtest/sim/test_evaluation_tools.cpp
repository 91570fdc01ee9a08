// The evaluation tools run in-process on small cases, so that none of them
// rots: evaluate_pose_delta (with its experiments' flags), evaluate_daylight
// (with --param and the scene flags), design_rig (with the beam x focus
// table), evaluate_photos (on a rendered photo and its label file). Each run's exit status, its figures against loose
// bounds (the tools' full figures are the docs', each with its command), and a bad usage refused with status 2 naming
// the problem. Seeds 11-12: held out.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "cli/design_rig_cli.h"
#include "cli/evaluate_daylight_cli.h"
#include "cli/evaluate_photos_cli.h"
#include "cli/evaluate_pose_delta_cli.h"

using namespace structured_light_stabilizer;

namespace
{

struct ToolRun
{
  int status = -1;
  std::string out, err;
};

template <typename Main>
ToolRun run(Main main, const std::vector<std::string>& args)
{
  std::ostringstream out, err;
  ToolRun r;
  r.status = main(args, out, err);
  r.out = out.str();
  r.err = err.str();
  return r;
}

// The number after `label` on the first line that has `line_start` (NaN when absent).
double figure(const std::string& text, const std::string& line_start, const std::string& label)
{
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);)
  {
    if (line.find(line_start) == std::string::npos)
      continue;
    const size_t at = line.find(label);
    if (at != std::string::npos)
      return std::atof(line.c_str() + at + label.size());
  }
  return std::nan("");
}

// evaluate_daylight with the recommended rig at 1.5 m, held-out seed 11, 4
// dot frames, plus `extra`: its pooled centroid against the hit point (px),
// and its output in *out when given.
double daylightCentroid(const std::vector<std::string>& extra, std::string* out = nullptr)
{
  std::vector<std::string> args{"--rig",      std::string(SLS_TEST_DATA_DIR) + "/../../config/rig_daylight.yaml",
                                "--distance", "1.5",
                                "--seeds",    "11",
                                "--frames",   "4"};
  args.insert(args.end(), extra.begin(), extra.end());
  const ToolRun r = run(evaluateDaylightMain, args);
  EXPECT_EQ(r.status, 0) << r.err;
  if (out)
    *out = r.out;
  return figure(r.out, "all:", "centroid ");
}

}  // namespace

// The rough rock through the chain with a true reference surface over the
// dots and a denser 12 x 12 grid; every frame valid, well within 1 mm.
TEST(EvaluationTools, EvaluatePoseDeltaWithItsExperiments)
{
  const ToolRun r = run(evaluatePoseDeltaMain, {"rough", "11", "1", "3", "--true-surface", "box", "--grid", "12x12",
                                                "--param", "pose.texture_max_features=150"});
  std::cout << r.out;
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("grid 12x12"), std::string::npos);
  const double valid = figure(r.out, "rough all seeds", "valid ");
  const double t = figure(r.out, "rough all seeds", "over valid frames t ");
  std::cout << "[ MEASURE ] evaluate_pose_delta rough 11 1 3 (true surface, 12x12): valid " << valid << " %, " << t
            << " mm\n";
  EXPECT_EQ(valid, 100.0);
  EXPECT_LT(t, 1.0);

  // No stage has it; a stage that is none: refused with the reason.
  const ToolRun bad = run(evaluatePoseDeltaMain, {"rough", "--param", "enabled=0"});
  EXPECT_EQ(bad.status, 2);
  EXPECT_NE(bad.err.find("no stage has a setting 'enabled'"), std::string::npos) << bad.err;
  const ToolRun no_stage = run(evaluatePoseDeltaMain, {"rough", "--param", "camera.min_points=6"});
  EXPECT_EQ(no_stage.status, 2);
  EXPECT_NE(no_stage.err.find("is no stage"), std::string::npos) << no_stage.err;
  // A setting of another stage than the one named.
  const ToolRun wrong_stage = run(evaluatePoseDeltaMain, {"rough", "--param", "pose.normalise_albedo=0"});
  EXPECT_EQ(wrong_stage.status, 2);
  EXPECT_NE(wrong_stage.err.find("no pose has a setting 'normalise_albedo'"), std::string::npos) << wrong_stage.err;
  EXPECT_EQ(run(evaluatePoseDeltaMain, {"--grid", "1x9"}).status, 2);
  EXPECT_EQ(run(evaluatePoseDeltaMain, {"--true-surface", "everywhere"}).status, 2);
}

// One colour frame at 1.5 m with the detector's albedo normalisation off and
// vignetting off: every dot found; the centroid against the hit point and
// against the light's own centroid both printed.
TEST(EvaluationTools, EvaluateDaylightWithParamsAndSceneFlags)
{
  const ToolRun r = run(evaluateDaylightMain, {"--strobe", "0", "--ratio", "8", "--distance", "1.5", "--seeds", "11",
                                               "--frames", "3", "--param", "normalise_albedo=0", "--vignetting", "0"});
  std::cout << r.out;
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("vignetting off"), std::string::npos);
  const double recall = figure(r.out, "all:", "recall ");
  const double hit = figure(r.out, "all:", "centroid ");
  const double light = figure(r.out, "all:", "against the light ");
  const double depth = figure(r.out, "all:", "mm (");
  std::cout << "[ MEASURE ] evaluate_daylight one frame 1.5 m seed 11: recall " << recall << ", centroid " << hit
            << " px against the hit point, " << light << " px against the light, depth " << depth << " % of z\n";
  EXPECT_GE(recall, 0.99);
  EXPECT_LT(hit, 0.5);
  EXPECT_LT(light, 0.5);
  EXPECT_LT(depth, 0.2);

  const ToolRun bad = run(evaluateDaylightMain, {"--param", "no_such_setting=1"});
  EXPECT_EQ(bad.status, 2);
  EXPECT_NE(bad.err.find("no_such_setting"), std::string::npos) << bad.err;
  EXPECT_EQ(run(evaluateDaylightMain, {"--frames"}).status, 2);
}

// The experiment that isolates the smooth rock's centroid error
// (docs/daylight.md, "What holds the centroid above its bound"): the
// recommended rig at 1.5 m on a uniform rock, held-out seed 11, 4 dot
// frames. The albedo normalisation (dividing by the ambient) costs about
// 0.028 px in quadrature over the same frames without it (0.032 against
// 0.015 px measured), and nothing on a flat rock (0.010 px): it is the
// sun's shading of the relief that the ambient carries. Bounds: without it
// within the 0.03 px goal; with it at least 1.5 x that; flat within 0.02.
TEST(EvaluationTools, EvaluateDaylightIsolatesTheNormalisationOnASmoothRock)
{
  const double on = daylightCentroid({"--albedo", "0.2"});
  const double off = daylightCentroid({"--albedo", "0.2", "--param", "normalise_albedo=0"});
  const double flat = daylightCentroid({"--albedo", "0.2", "--relief", "0"});
  std::cout << "[ MEASURE ] evaluate_daylight smooth rock 1.5 m seed 11: centroid against the hit point " << on
            << " px normalised, " << off << " px without, " << flat << " px normalised on a flat rock\n";
  EXPECT_LE(off, 0.03);
  EXPECT_GE(on, 1.5 * off);
  EXPECT_LE(flat, 0.02);
}

// Colour texture (--colour-texture 0.15: the rock's green albedo against its
// red within about +-15 % over 1-3 cm), the recommended rig at 1.5 m,
// held-out seed 11, 4 dot frames. Strobed, the albedo comes from the
// projector-off frame's own green: the issue's 0.05 px holds (0.037 px
// measured, as without it). In one frame (ratio 8) the red channel stands in
// for the green albedo under the dot, and the green's own variation moves
// the centroid by sigma^2 times its log-gradient: 0.117 against 0.032 px.
TEST(EvaluationTools, EvaluateDaylightIsolatesColourTexture)
{
  std::string out;
  const double strobed = daylightCentroid({"--colour-texture", "0.15"}, &out);
  EXPECT_NE(out.find("colour texture 0.15"), std::string::npos) << out;
  const double one_frame = daylightCentroid({"--strobe", "0", "--ratio", "8"});
  const double one_frame_colour = daylightCentroid({"--strobe", "0", "--ratio", "8", "--colour-texture", "0.15"});
  std::cout << "[ MEASURE ] evaluate_daylight colour texture 0.15, 1.5 m seed 11: strobed " << strobed
            << " px; one frame " << one_frame_colour << " px (" << one_frame << " px without it)\n";
  EXPECT_LE(strobed, 0.05);
  EXPECT_LE(one_frame, 0.05);
  EXPECT_GE(one_frame_colour, 2.0 * one_frame);
  EXPECT_EQ(run(evaluateDaylightMain, {"--colour-texture", "2"}).status, 2);
}

// A one-rig design with two beams at the study's focus: the table, and the
// narrower beam's relief floor below the wider one's at the far distance.
TEST(EvaluationTools, DesignRigWithTheBeamTable)
{
  const std::string path =
      std::filesystem::temp_directory_path() / ("sls_design_" + std::to_string(getpid()) + ".yaml");
  {
    std::ofstream f(path);
    f << "options: {beam_sigma_mrad: [1.5], pulsed: [true], exposure_ms: [2], filter_fwhm_nm: [0], strobe: [true]}\n"
         "beams: {beam_sigma_mrad: [0.5, 2.0], focus_distance_m: [1.0], seeds: 1, frames: 1}\n";
  }
  const ToolRun r = run(designRigMain, {path});
  std::remove(path.c_str());
  std::cout << r.out;
  ASSERT_EQ(r.status, 0) << r.err;
  // The rows of the beam table: " 0.50    1.00 | 1.0 ... | 2.0 fp dot floor along depth |".
  std::smatch m;
  std::vector<double> far_floor;
  const std::regex row(R"(\s*([0-9.]+)\s+1\.00 \|[^|]*\|\s*2\.0\s+[0-9.]+\s+[0-9.]+\s+([0-9.]+))");
  std::istringstream lines(r.out);
  for (std::string line; std::getline(lines, line);)
    if (std::regex_search(line, m, row))
      far_floor.push_back(std::stod(m[2]));
  ASSERT_EQ(far_floor.size(), 2u) << r.out;
  std::cout << "[ MEASURE ] relief floor at 2 m: 0.5 mrad " << far_floor[0] << " px, 2.0 mrad " << far_floor[1]
            << " px\n";
  EXPECT_LT(far_floor[0], far_floor[1]);

  EXPECT_EQ(run(designRigMain, {"--beams", "2"}).status, 2);
}

// A mono8 "photo" of 12 Gaussian dots (sigma 1.5 px, 90 DN over 20 DN, read
// noise 1.5 DN) with its label file, projector_dots and an ignored
// rectangle over a 13th dot: every labelled dot found, nothing else counted.
TEST(EvaluationTools, EvaluatePhotosOnARenderedPhotoAndItsLabels)
{
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / ("sls_photos_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir / "labels");
  cv::Mat1f light(160, 200, 20.0f);
  std::ostringstream dots;
  std::vector<cv::Point2d> centres;
  for (int j = 0; j < 3; ++j)
    for (int i = 0; i < 4; ++i)
      centres.emplace_back(30.3 + 45.0 * i + 0.1 * j, 30.6 + 45.0 * j - 0.2 * i);
  centres.emplace_back(185.0, 145.0);  // under the ignored rectangle
  for (const cv::Point2d& c : centres)
    for (int y = 0; y < light.rows; ++y)
      for (int x = 0; x < light.cols; ++x)
        light(y, x) += 90.0f * static_cast<float>(std::exp(-((x - c.x) * (x - c.x) + (y - c.y) * (y - c.y)) / 4.5));
  cv::Mat1f noise(light.size());
  cv::RNG rng(11);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.5);
  cv::Mat image;
  cv::Mat1f(light + noise).convertTo(image, CV_8U);
  ASSERT_TRUE(cv::imwrite((dir / "dots.png").string(), image));
  {
    std::ofstream f(dir / "labels" / "rendered.yaml");
    f << "image: dots.png\nencoding: mono8\nprojector_color: nir\nhalf: heldout\nprojector_dots: 12\n"
         "ignore:\n- [175, 135, 25, 25]\ndots:\n";
    for (size_t k = 0; k + 1 < centres.size(); ++k)
      f << "  - [" << centres[k].x << ", " << centres[k].y << "]\n";
  }
  const std::vector<std::string> base{"--photos", dir.string(), "--labels", (dir / "labels").string()};
  const ToolRun r = run(evaluatePhotosMain, base);
  std::cout << r.out;
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(figure(r.out, "pooled:", "recall "), 1.0) << r.out;
  EXPECT_EQ(figure(r.out, "pooled:", "precision "), 1.0) << r.out;
  EXPECT_EQ(figure(r.out, "pooled:", "images, "), 12.0) << r.out;  // labels counted outside the ignored part
  std::vector<std::string> tuning = base;
  tuning.insert(tuning.end(), {"--half", "tuning"});
  EXPECT_NE(run(evaluatePhotosMain, tuning).out.find("pooled: 0 images"), std::string::npos);

  std::vector<std::string> bad = base;
  bad.insert(bad.end(), {"--half", "most"});
  EXPECT_EQ(run(evaluatePhotosMain, bad).status, 2);
  EXPECT_EQ(run(evaluatePhotosMain, {"--photos", dir.string(), "--labels", (dir / "none").string()}).status, 2);
  std::filesystem::remove_all(dir);
}
