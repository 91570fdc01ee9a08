#include "cli/evaluate_pose_delta_cli.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <sstream>

#include "support/pose_delta_chain.h"
#include "support/scene_ablations.h"

namespace structured_light_stabilizer
{

namespace
{

using sls_test::ChainScene;
using sls_test::ChainTally;

void print(std::ostream& out, const std::string& what, const ChainTally& s)
{
  const double n = std::max(s.frames, 1);
  out << std::fixed << std::setprecision(3) << what << ": valid " << std::setprecision(1) << 100.0 * s.validFraction()
      << " %, over valid frames t " << std::setprecision(3) << s.rmsTmm() << " mm, r " << std::setprecision(4)
      << s.rmsRdeg() << " deg (worst " << std::setprecision(3) << s.worst_t_mm << " mm, " << std::setprecision(4)
      << s.worst_r_deg << " deg); all frames t " << std::setprecision(3) << std::sqrt(s.t2 / n) << " mm, r "
      << std::setprecision(4) << std::sqrt(s.r2 / n) << " deg; wrong beams " << s.wrong_beams << "/" << s.points
      << "; err/sigma tx ty tz (mm) rx ry rz (deg):" << std::setprecision(3);
  for (int a = 0; a < 6; ++a)
    out << " " << std::sqrt(s.axis2[a] / n) << "/" << std::sqrt(s.sigma2[a] / n);
  out << "; per frame: " << std::setprecision(0) << s.features / n << " features, sigma " << std::setprecision(3)
      << s.sigma_texture_px / n << " px, geometry " << s.sigma_geometry_mm / n << " mm; centroid "
      << std::setprecision(4) << s.truths.rms(s.truths.hit2) << " px (along the epipolar line "
      << s.truths.rms(s.truths.along2) << ", against the light " << s.truths.rms(s.truths.light2) << ", light from hit "
      << s.truths.rms(s.truths.light_hit2) << "), depth " << s.depthPercent() << " % of z\n";
}

std::vector<std::string> split(const std::string& list)
{
  std::vector<std::string> items;
  std::stringstream ss(list);
  std::string item;
  while (std::getline(ss, item, ','))
    if (!item.empty())
      items.push_back(item);
  return items;
}

// What the command line asks for.
struct Request
{
  std::string scenes = "weak_texture,missing_dots,worst_snr,flat_textured,rough,textureless";
  int first = 1, seeds = 4, frames = 30;
  double dt = 0.1;
  sls_test::StageSettings settings;
  sls_test::SceneAblations ablations;
  ChainScene::TrueSurface true_surface = ChainScene::TrueSurface::kNone;
  bool projector_off_lock = false;
};

// "" when the arguments read, else why not.
std::string parse(const std::vector<std::string>& args, Request* q)
{
  size_t positional = 0;
  for (size_t i = 0; i < args.size(); ++i)
  {
    const std::string& a = args[i];
    if (a.rfind("--", 0) == 0)
    {
      if (i + 1 >= args.size())
        return a + " needs a value";
      const std::string& v = args[++i];
      const std::string why = q->ablations.parse(a, v);
      if (why.empty())
        continue;
      if (why != "?")
        return why;
      if (a == "--param")
      {
        const std::string bad = q->settings.set(v);
        if (!bad.empty())
          return "--param " + v + ": " + bad;
      }
      else if (a == "--true-surface" && (v == "box" || v == "image" || v == "0"))
        q->true_surface = v == "box"     ? ChainScene::TrueSurface::kDotBox
                          : v == "image" ? ChainScene::TrueSurface::kImage
                                         : ChainScene::TrueSurface::kNone;
      else if (a == "--projector-off-lock" && (v == "0" || v == "1"))
        q->projector_off_lock = v == "1";
      else
        return "unknown option or bad value: " + a + " " + v;
    }
    else if (a.rfind("dt=", 0) == 0)
    {
      // "dt=1/30" as well: the strobed test's frame time exactly (the
      // renders' noise follows the time, so 0.0333 gives other frames).
      const size_t slash = a.find('/');
      q->dt = slash == std::string::npos ? std::atof(a.c_str() + 3)
                                         : std::atof(a.substr(3, slash - 3).c_str()) / std::atof(a.c_str() + slash + 1);
    }
    else if (a.find('=') != std::string::npos)
    {
      const std::string bad = q->settings.set(a);
      if (!bad.empty())
        return a + ": " + bad;
    }
    else if (positional == 0)
      (q->scenes = a, ++positional);
    else if (positional <= 3)
    {
      const int v = std::max(1, std::atoi(a.c_str()));
      (positional == 1 ? q->first : positional == 2 ? q->seeds : q->frames) = v;
      ++positional;
    }
    else
      return "unexpected argument: " + a;
  }
  if (!(q->dt > 0.0))
    return "dt must be positive";
  return q->settings.validate();
}

}  // namespace

int evaluatePoseDeltaMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err)
{
  Request q;
  const std::string bad = parse(args, &q);
  if (!bad.empty())
  {
    err << "evaluate_pose_delta: " << bad << "\n";
    return 2;
  }
  if (!q.ablations.describe().empty())
    out << "scene changes:" << q.ablations.describe() << "\n";
  for (const std::string& name : split(q.scenes))
  {
    ChainTally all;
    for (int s = q.first; s < q.first + q.seeds; ++s)
    {
      ChainScene scene = sls_test::chainScene(name, static_cast<uint32_t>(s));
      q.ablations.apply(&scene.sim);
      scene.sim.dot_centroid_truth = true;  // (the image is the same)
      scene.true_surface = q.true_surface;
      scene.projector_off_lock = q.projector_off_lock;
      sls_test::StageSettings settings = q.settings;
      settings.detector.projector_rows = scene.sim.projector.rows;
      settings.detector.projector_cols = scene.sim.projector.cols;
      std::string log;
      // Lock at a seed-dependent instant (not at rest), as test_pose_delta_chain does.
      const ChainTally one =
          sls_test::runChain(scene, settings, sls_test::chainLockTime(static_cast<uint32_t>(s)), q.frames, q.dt, &log);
      print(out, "  " + name + " seed " + std::to_string(s), one);
      out << log;
      all.add(one);
    }
    print(out, name + " all seeds", all);
  }
  return 0;
}

}  // namespace structured_light_stabilizer
