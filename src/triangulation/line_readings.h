// Ordered readings of one grid line for the joint line reading
// (line_reader.cpp; internal to the Triangulator). A reading gives each
// open beam of the line (in order along it) one of the line's open spots
// (in order along the image line) or none, never crossing: on a surface
// without overhangs the dots keep the beams' order along the line.
#pragma once

#include <vector>

#include <Eigen/Core>

namespace structured_light_stabilizer
{
namespace detail
{

// A candidate pair of a line.
struct LinePair
{
  int k, l;     // local beam (along the line) and local spot (along the image line)
  double data;  // epipolar cost + smoothness to accepted grid neighbours
  Eigen::Vector3d point;
};

// One grid line (a row, or a column) and its readings.
struct GridLine
{
  int orient = 0;                              // 0: a grid row, 1: a grid column
  int line = 0;                                // its row (column) index
  std::vector<int> beams, spots;               // open ones, in order along the line
  std::vector<LinePair> pairs;                 // in (k, l) order
  std::vector<int> pair_of;                    // k * spots + l -> pair, -1 = not a candidate
  std::vector<double> S;                       // smoothness of consecutive matches, pairs x pairs
  std::vector<std::vector<int>> reading;       // per hypothesis: local spot per local beam, -1 = none
  std::vector<double> unary;                   // its cost within the line
  std::vector<std::vector<int>> reading_pair;  // the same as pair indices
  std::vector<int> k_of_pos;                   // local beam at each position along the line, -1 = none
  std::vector<double> last_extra;              // the neighbours' costs of the last generation
  std::vector<double> marginal;                // min-marginal over the chain
  int map = 0;                                 // hypothesis of the chain's optimum

  int m() const { return static_cast<int>(beams.size()); }
  int q() const { return static_cast<int>(spots.size()); }
  int np() const { return static_cast<int>(pairs.size()); }
  // Pair of local beam k in hypothesis h (-1 = none).
  int pairIn(int h, int k) const { return reading[h][k] >= 0 ? pair_of[k * q() + reading[h][k]] : -1; }

  // Cost of a reading within its line: data, a beam without a spot or a
  // spot without a beam 1 each, smoothness between neighbouring matches.
  double readingCost(const std::vector<int>& rd) const;
  // Adds the readings not held yet; returns how many.
  int addReadings(const std::vector<std::vector<int>>& found);
};

// Adds to a line the readings that are best under the cost data + extra
// (per pair): the best one, the best through every pair within a window of
// it, and the best without each pair of the best one. Returns how many were
// new.
int addBestReadings(GridLine* line, const std::vector<double>& extra);

}  // namespace detail
}  // namespace structured_light_stabilizer
