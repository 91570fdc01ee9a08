// Changes to a simulated scene that the evaluation tools take as flags
// (tools/evaluate_daylight, tools/evaluate_pose_delta), so that each cause
// of an error can be switched off by itself:
//   --vignetting 0|1   natural vignetting (cos^4) off or on
//   --grid RxC         the projector's grid: R rows x C columns over the same
//                      pattern (the outer beams stay where they were)
//   --pitch-mrad P     the angle between neighbouring beams (after --grid: a
//                      wider or narrower pattern)
//   --noise-free 0|1   no shot nor read noise (quantisation stays)
//   --relief M         the rock's peak-to-peak relief (m; 0: a flat rock)
//   --colour-texture A the rock's green albedo varies against its red by
//                      about +-A over 1-3 cm (RockParams::fine_texture_green;
//                      on a rock without fine texture: period 2 cm, colour
//                      only)
#pragma once

#include <cstdio>
#include <cstdlib>
#include <string>

#include "structured_light_stabilizer/sim/render/simulator_params.h"

namespace sls_test
{

struct SceneAblations
{
  int vignetting = -1;  // -1: the scene's; 0 off; 1 on
  int grid_rows = 0;    // 0: the scene's grid
  int grid_cols = 0;
  double pitch_rad = 0;        // 0: the scene's (or --grid's)
  int noise_free = -1;         // -1: the scene's; 1: no shot nor read noise
  double relief_m = -1;        // < 0: the scene's
  double colour_texture = -1;  // < 0: the scene's

  // Reads `flag value` when it is one of the flags above: "" when read, "?"
  // when the flag is none of them, else why the value is bad.
  std::string parse(const std::string& flag, const std::string& value)
  {
    char* end = nullptr;
    if (flag == "--vignetting" || flag == "--noise-free")
    {
      if (value != "0" && value != "1")
        return flag + " takes 0 or 1, not '" + value + "'";
      (flag == "--vignetting" ? vignetting : noise_free) = value == "1";
      return "";
    }
    if (flag == "--relief")
    {
      relief_m = std::strtod(value.c_str(), &end);
      return *end == '\0' && relief_m >= 0.0 ? "" : "--relief takes metres >= 0, not '" + value + "'";
    }
    if (flag == "--colour-texture")
    {
      colour_texture = std::strtod(value.c_str(), &end);
      return *end == '\0' && colour_texture >= 0.0 && colour_texture <= 0.9
                 ? ""
                 : "--colour-texture takes 0-0.9, not '" + value + "'";
    }
    if (flag == "--pitch-mrad")
    {
      pitch_rad = 1e-3 * std::strtod(value.c_str(), &end);
      return *end == '\0' && pitch_rad > 0.0 && pitch_rad < 0.2 ? "" : "--pitch-mrad takes 0-200, not '" + value + "'";
    }
    if (flag == "--grid")
    {
      int r = 0, c = 0;
      char x = 0, extra = 0;
      if (std::sscanf(value.c_str(), "%d%c%d%c", &r, &x, &c, &extra) != 3 || x != 'x' || r < 2 || c < 2 || r > 64 ||
          c > 64)
        return "--grid takes ROWSxCOLS (2-64 each), not '" + value + "'";
      grid_rows = r;
      grid_cols = c;
      return "";
    }
    return "?";
  }

  void apply(structured_light_stabilizer::SimulatorParams* p) const
  {
    if (vignetting >= 0)
      p->sensor.natural_vignetting = vignetting == 1;
    if (grid_rows > 0)
    {
      // The pitch scaled so that the outer beams stay in place.
      p->projector.pitch_y_rad *= (p->projector.rows - 1.0) / (grid_rows - 1.0);
      p->projector.pitch_x_rad *= (p->projector.cols - 1.0) / (grid_cols - 1.0);
      p->projector.rows = grid_rows;
      p->projector.cols = grid_cols;
    }
    if (pitch_rad > 0.0)
      p->projector.pitch_x_rad = p->projector.pitch_y_rad = pitch_rad;
    if (noise_free == 1)
    {
      p->sensor.read_noise_dn = 0.0;
      p->sensor.shot_noise = false;
    }
    if (relief_m >= 0.0)
      p->rock.relief_m = relief_m;
    if (colour_texture >= 0.0)
    {
      if (p->rock.fine_texture_period_m == 0.0)
      {
        p->rock.fine_texture_period_m = 0.02;
        p->rock.fine_texture_amplitude = 0.0;  // the colour alone
      }
      p->rock.fine_texture_green = colour_texture;
    }
  }

  // What was changed, for the tools' headers ("" when nothing).
  std::string describe() const
  {
    std::string d;
    if (vignetting >= 0)
      d += std::string(" vignetting ") + (vignetting ? "on" : "off") + ";";
    if (grid_rows > 0)
      d += " grid " + std::to_string(grid_rows) + "x" + std::to_string(grid_cols) + ";";
    if (pitch_rad > 0.0)
      d += " pitch " + std::to_string(pitch_rad * 1e3) + " mrad;";
    if (noise_free == 1)
      d += " noise-free;";
    if (relief_m >= 0.0)
      d += " relief " + std::to_string(relief_m) + " m;";
    if (colour_texture >= 0.0)
      d += " colour texture " + std::to_string(colour_texture) + ";";
    return d;
  }
};

}  // namespace sls_test
