// Scoring detected spots against true dot positions, shared by the detector
// gtests: nearest-neighbour matching within max_dist px, closest pairs first,
// each spot and each truth used once.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/common/spot.h"

namespace structured_light_stabilizer
{
namespace test
{

struct Score
{
  double sum_sq = 0;
  int matched = 0, truth = 0, false_spots = 0, frames = 0;
  double rms() const { return matched ? std::sqrt(sum_sq / matched) : NAN; }
  double recall() const { return truth ? double(matched) / truth : NAN; }
  double falsePerFrame() const { return frames ? double(false_spots) / frames : NAN; }
  void add(const Score& o)
  {
    sum_sq += o.sum_sq;
    matched += o.matched;
    truth += o.truth;
    false_spots += o.false_spots;
    frames += o.frames;
  }
};

inline Score score(const Spots& spots, const std::vector<cv::Point2d>& truth, double max_dist = 3.0)
{
  struct Pair
  {
    double d;
    size_t s, t;
  };
  std::vector<Pair> pairs;
  for (size_t s = 0; s < spots.size(); ++s)
    for (size_t t = 0; t < truth.size(); ++t)
    {
      const double d = std::hypot(spots[s].x - truth[t].x, spots[s].y - truth[t].y);
      if (d < max_dist)
        pairs.push_back({d, s, t});
    }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) { return a.d < b.d; });
  std::vector<char> used_s(spots.size(), 0), used_t(truth.size(), 0);
  Score sc;
  for (const Pair& p : pairs)
  {
    if (used_s[p.s] || used_t[p.t])
      continue;
    used_s[p.s] = used_t[p.t] = 1;
    sc.sum_sq += p.d * p.d;
    ++sc.matched;
  }
  sc.truth = static_cast<int>(truth.size());
  for (char u : used_s)
    sc.false_spots += u ? 0 : 1;
  sc.frames = 1;
  return sc;
}

}  // namespace test
}  // namespace structured_light_stabilizer
