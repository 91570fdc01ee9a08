#include "structured_light_stabilizer/sim/design/beam_design.h"

#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "structured_light_stabilizer/sim/design/rig_design.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

namespace structured_light_stabilizer
{

namespace
{

constexpr double kDeg = 3.14159265358979323846 / 180.0;

// The scene of a floor measurement: nothing but the dots' geometry.
SimulatorParams floorScene(const BeamDesignOptions& o, double beam_sigma, double focus, double distance, uint32_t seed)
{
  SimulatorParams p;
  p.rock.seed = seed;
  p.rock.distance_m = distance;
  p.rock.relief_m = o.relief_m;
  p.rock.albedo_min = p.rock.albedo_max = 0.25;
  p.lighting.sun_level = 0.0;  // the rock's own radiance plays no part in the dot's light
  p.sensor.read_noise_dn = 0.0;
  p.sensor.shot_noise = false;
  p.sensor.focus_distance_m = focus;
  p.projector.beam_sigma_rad = beam_sigma;
  p.motion.jitter_translation_m = 0.010;
  p.motion.jitter_rotation_rad = 1.0 * kDeg;
  p.dot_centroid_truth = true;
  return p;
}

BeamDesign::At measure(const BeamDesignOptions& o, double beam_sigma, double focus, double distance)
{
  BeamDesign::At at;
  at.distance_m = distance;
  at.footprint_sigma_mm = beam_sigma * distance * 1e3;
  double sum2 = 0.0, along2 = 0.0, depth2 = 0.0, sigma = 0.0;
  for (uint32_t seed = 1; seed <= static_cast<uint32_t>(o.seeds); ++seed)
  {
    const Simulator sim(floorScene(o, beam_sigma, focus, distance, seed));
    for (int k = 0; k < o.frames; ++k)
    {
      const SimFrame f = sim.render(0.9 * k + 0.1 * seed);
      for (size_t b = 0; b < f.pixels.size(); ++b)
      {
        if (!f.visible[b] || !std::isfinite(f.light_centroids[b].x))
          continue;
        const cv::Point2d d = f.light_centroids[b] - f.pixels[b];
        // The epipolar direction: where the hit point moves as the depth along the beam grows.
        const Eigen::Vector3d dir = sim.projector().beams[b].direction.normalized();
        const cv::Point2d step = sim.camera().project(f.points[b] + 1e-3 * dir) - f.pixels[b];
        const double px_per_mm = std::hypot(step.x, step.y);
        if (!(px_per_mm > 0.0))
          continue;
        const double along = (d.x * step.x + d.y * step.y) / px_per_mm;
        const double depth_m = along / px_per_mm * 1e-3 * dir.z();
        sum2 += d.dot(d);
        along2 += along * along;
        depth2 += (depth_m / f.points[b].z()) * (depth_m / f.points[b].z());
        sigma += f.blur_sigma_px[b];
        ++at.dots;
      }
    }
  }
  if (at.dots > 0)
  {
    at.floor_px = std::sqrt(sum2 / at.dots);
    at.floor_along_px = std::sqrt(along2 / at.dots);
    at.depth_percent = 100.0 * std::sqrt(depth2 / at.dots);
    at.dot_sigma_px = sigma / at.dots;
  }
  return at;
}

}  // namespace

std::vector<BeamDesign> designBeams(const DesignInputs& inputs)
{
  const BeamDesignOptions& o = inputs.beams;
  if (o.frames < 1 || o.seeds < 1 || !(o.relief_m >= 0.0))
    throw std::invalid_argument("beams: need frames >= 1, seeds >= 1 and relief_m >= 0");
  for (double s : o.beam_sigma_rad)
    if (!(s > 0.0))
      throw std::invalid_argument("beams: beam_sigma_mrad must be positive");
  for (double f : o.focus_distance_m)
    if (!(f > 0.05))
      throw std::invalid_argument("beams: focus_distance_m must be beyond 0.05 m");
  std::vector<BeamDesign> designs;
  for (double sigma : o.beam_sigma_rad)
    for (double focus : o.focus_distance_m)
    {
      BeamDesign d;
      d.beam_sigma_rad = sigma;
      d.focus_distance_m = focus;
      d.dot_ok = true;
      for (double distance : {inputs.conditions.distance_min_m, inputs.conditions.distance_max_m})
      {
        d.at.push_back(measure(o, sigma, focus, distance));
        d.dot_ok = d.dot_ok && d.at.back().dot_sigma_px >= inputs.target.min_dot_sigma_px;
      }
      designs.push_back(d);
    }
  return designs;
}

std::string formatBeamDesigns(const std::vector<BeamDesign>& designs, const DesignInputs& inputs)
{
  std::ostringstream os;
  char buf[300];
  std::snprintf(buf, sizeof(buf),
                "Beam and focus: the relief floor (the dot's own light from the beam's hit point on %.2f m of relief, "
                "uniform albedo, no noise; simulator, rock seeds 1-%d, %d frames each).\n",
                inputs.beams.relief_m, inputs.beams.seeds, inputs.beams.frames);
  os << buf;
  os << " mrad focus_m | per distance: m  footprint_mm dot_px floor_px along_px depth_%z | dot >= "
     << inputs.target.min_dot_sigma_px << " px\n";
  for (const BeamDesign& d : designs)
  {
    std::snprintf(buf, sizeof(buf), "%5.2f %7.2f |", d.beam_sigma_rad * 1e3, d.focus_distance_m);
    os << buf;
    for (const BeamDesign::At& a : d.at)
    {
      std::snprintf(buf, sizeof(buf), " %4.1f %6.2f %6.2f %7.4f %7.4f %7.4f |", a.distance_m, a.footprint_sigma_mm,
                    a.dot_sigma_px, a.floor_px, a.floor_along_px, a.depth_percent);
      os << buf;
    }
    os << (d.dot_ok ? " yes" : " no") << "\n";
  }
  return os.str();
}

}  // namespace structured_light_stabilizer
