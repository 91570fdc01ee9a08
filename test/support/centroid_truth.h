// The centroids of detected spots against the simulator's truths, shared by
// the evaluation tools (support/daylight_run.h, support/pose_delta_chain.h):
// the beam's hit point (SimFrame::pixels: what depth needs; and the part of
// the error along the beam's epipolar line, the only part that moves the
// depth) and the dot's own light (SimFrame::light_centroids and
// footprint_centroids, with SimulatorParams::dot_centroid_truth: what a
// detector can reach), with how far the light itself lies from the hit
// point (what the rendering puts between the two).
#pragma once

#include <cmath>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/common/spot.h"
#include "structured_light_stabilizer/sim/render/simulator.h"

namespace sls_test
{

using structured_light_stabilizer::SimFrame;
using structured_light_stabilizer::Simulator;
using structured_light_stabilizer::Spots;

// Squared centroid errors of the matched spots against the other truths.
struct TruthErrors
{
  double hit2 = 0.0;        // against the hit point (px^2)
  double along2 = 0.0;      // its part along the epipolar line
  double light2 = 0.0;      // against the light's own centroid
  double footprint2 = 0.0;  // against the footprint's centroid
  double light_hit2 = 0.0;  // the light's centroid from the hit point (the rendering's own shift)
  int n = 0;

  void add(const TruthErrors& o)
  {
    hit2 += o.hit2;
    along2 += o.along2;
    light2 += o.light2;
    footprint2 += o.footprint2;
    light_hit2 += o.light_hit2;
    n += o.n;
  }
  double rms(double sum2) const { return n ? std::sqrt(sum2 / n) : NAN; }
};

// The centroid errors of the spots against the frame's other truths: each
// visible beam's nearest spot within 3 px of its hit point (the pairing of
// score()), its error along the beam's epipolar line (the image direction
// in which the hit point moves with depth), against the light's and the
// footprint's centroids (needs SimulatorParams::dot_centroid_truth).
inline TruthErrors truthErrors(const Spots& spots, const SimFrame& f, const Simulator& sim)
{
  TruthErrors e;
  if (f.light_centroids.size() != f.pixels.size())
    return e;
  std::vector<char> used(spots.size(), 0);
  for (size_t b = 0; b < f.pixels.size(); ++b)
  {
    if (!f.visible[b] || !std::isfinite(f.light_centroids[b].x))
      continue;
    int best = -1;
    double best_d = 3.0;
    for (size_t s = 0; s < spots.size(); ++s)
    {
      const double d = std::hypot(spots[s].x - f.pixels[b].x, spots[s].y - f.pixels[b].y);
      if (!used[s] && d < best_d)
        (best = static_cast<int>(s), best_d = d);
    }
    if (best < 0)
      continue;
    used[best] = 1;
    const cv::Point2d p(spots[best].x, spots[best].y);
    const cv::Point2d along = sim.camera().project(f.points[b] + 1e-3 * sim.projector().beams[b].direction) - f.pixels[b];
    const double len = std::hypot(along.x, along.y);
    if (len > 0.0)
    {
      const double a = ((p - f.pixels[b]).x * along.x + (p - f.pixels[b]).y * along.y) / len;
      e.along2 += a * a;
    }
    const cv::Point2d dl = p - f.light_centroids[b], df = p - f.footprint_centroids[b],
                      lh = f.light_centroids[b] - f.pixels[b];
    const cv::Point2d dh = p - f.pixels[b];
    e.hit2 += dh.dot(dh);
    e.light2 += dl.dot(dl);
    e.footprint2 += df.dot(df);
    e.light_hit2 += lh.dot(lh);
    ++e.n;
  }
  return e;
}

}  // namespace sls_test
