// Ordered readings of one grid line by dynamic programming (see
// line_readings.h).
#include "triangulation/line_readings.h"

#include <algorithm>
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace detail
{

namespace
{

// Readings up to this much above a line's best are kept as hypotheses: a
// reading shifted by one column costs the best + 0 or + 2 (a missing end
// dot, a spurious one); the neighbouring lines have to decide.
constexpr double kWindow = 2.5;

// The readings of one line that are best under the cost data + extra (per
// pair): an order-preserving matching with smoothness between consecutive
// matches, by dynamic programming over the pairs (F: best reading ending
// with a pair, B: best reading starting with it).
class ReadingSearch
{
public:
  ReadingSearch(const GridLine& line, const std::vector<double>& extra) : line_(line), extra_(extra)
  {
    // First pair of each beam: predecessors of a pair are the pairs of
    // earlier beams only.
    block_.resize(line_.np());
    for (int p2 = 0; p2 < line_.np(); ++p2)
      block_[p2] = p2 > 0 && line_.pairs[p2 - 1].k == line_.pairs[p2].k ? block_[p2 - 1] : p2;
    backward();
  }

  // The best reading, the best through every pair within kWindow of it,
  // and the best without each pair of the best one.
  std::vector<std::vector<int>> readings() const;

private:
  double cost(int p2) const { return line_.pairs[p2].data + extra_[p2]; }
  void forward(int forbid, std::vector<double>* F, std::vector<int>* pred) const;
  int bestEnd(const std::vector<double>& F, double* total) const;
  void backward();
  std::vector<int> trace(const std::vector<int>& pred, int p2, bool forward_too) const;

  const GridLine& line_;
  const std::vector<double>& extra_;
  std::vector<int> block_;
  std::vector<double> B_;
  std::vector<int> succ_;
};

// F and pred must hold a run without `forbid` up to `forbid` (the values
// before the forbidden pair do not depend on it); -1 = forbid nothing.
void ReadingSearch::forward(int forbid, std::vector<double>* F, std::vector<int>* pred) const
{
  const int np = line_.np();
  for (int p2 = std::max(0, forbid); p2 < np; ++p2)
  {
    if (p2 == forbid)
    {
      (*F)[p2] = kInf;
      (*pred)[p2] = -1;
      continue;
    }
    const LinePair& pb = line_.pairs[p2];
    double best_in = pb.k + pb.l;
    int from = -1;
    for (int p1 = 0; p1 < block_[p2]; ++p1)
    {
      const LinePair& pa = line_.pairs[p1];
      if (p1 == forbid || pa.l >= pb.l)
        continue;
      const double v = (*F)[p1] + (pb.k - pa.k - 1) + (pb.l - pa.l - 1) + line_.S[p1 * np + p2];
      if (v < best_in)
      {
        best_in = v;
        from = p1;
      }
    }
    (*F)[p2] = cost(p2) + best_in;
    (*pred)[p2] = from;
  }
}

int ReadingSearch::bestEnd(const std::vector<double>& F, double* total) const
{
  const int m = line_.m(), q = line_.q();
  *total = m + q;
  int end = -1;
  for (int p2 = 0; p2 < line_.np(); ++p2)
  {
    const double v = F[p2] + (m - 1 - line_.pairs[p2].k) + (q - 1 - line_.pairs[p2].l);
    if (v < *total)
    {
      *total = v;
      end = p2;
    }
  }
  return end;
}

void ReadingSearch::backward()
{
  const int m = line_.m(), q = line_.q(), np = line_.np();
  B_.assign(np, kInf);
  succ_.assign(np, -1);
  for (int p2 = np - 1; p2 >= 0; --p2)
  {
    const LinePair& pa = line_.pairs[p2];
    double best_out = (m - 1 - pa.k) + (q - 1 - pa.l);
    for (int p3 = p2 + 1; p3 < np; ++p3)
    {
      const LinePair& pb = line_.pairs[p3];
      if (!(pb.k > pa.k && pb.l > pa.l))
        continue;
      const double v = B_[p3] + (pb.k - pa.k - 1) + (pb.l - pa.l - 1) + line_.S[p2 * np + p3];
      if (v < best_out)
      {
        best_out = v;
        succ_[p2] = p3;
      }
    }
    B_[p2] = cost(p2) + best_out;
  }
}

// The reading ending with pair p2 along `pred` (and, forward_too, going on
// from it along the best continuation); p2 = -1: no match at all.
std::vector<int> ReadingSearch::trace(const std::vector<int>& pred, int p2, bool forward_too) const
{
  std::vector<int> rd(line_.m(), -1);
  for (int p1 = p2; p1 >= 0; p1 = pred[p1])
    rd[line_.pairs[p1].k] = line_.pairs[p1].l;
  if (forward_too && p2 >= 0)
    for (int p3 = succ_[p2]; p3 >= 0; p3 = succ_[p3])
      rd[line_.pairs[p3].k] = line_.pairs[p3].l;
  return rd;
}

std::vector<std::vector<int>> ReadingSearch::readings() const
{
  const int np = line_.np();
  std::vector<std::vector<int>> found;
  std::vector<double> F(np, kInf);
  std::vector<int> pred(np, -1);
  forward(-1, &F, &pred);
  double best = 0.0;
  const int end = bestEnd(F, &best);
  found.push_back(trace(pred, end, false));
  for (int p2 = 0; p2 < np; ++p2)
    if (F[p2] + B_[p2] - cost(p2) <= best + kWindow)
      found.push_back(trace(pred, p2, true));
  std::vector<int> best_pairs;
  for (int p2 = end; p2 >= 0; p2 = pred[p2])
    best_pairs.push_back(p2);
  for (int p2 : best_pairs)
  {
    std::vector<double> Fx = F;
    std::vector<int> predx = pred;
    forward(p2, &Fx, &predx);
    double total = 0.0;
    found.push_back(trace(predx, bestEnd(Fx, &total), false));
  }
  return found;
}

}  // namespace

double GridLine::readingCost(const std::vector<int>& rd) const
{
  double u = 0.0;
  int matched = 0, prev = -1;
  for (int k = 0; k < m(); ++k)
  {
    if (rd[k] < 0)
      continue;
    const int p2 = pair_of[k * q() + rd[k]];
    u += pairs[p2].data;
    if (prev >= 0)
      u += S[prev * np() + p2];
    prev = p2;
    ++matched;
  }
  return u + (m() - matched) + (q() - matched);
}

int GridLine::addReadings(const std::vector<std::vector<int>>& found)
{
  int added = 0;
  for (const std::vector<int>& rd : found)
  {
    if (std::find(reading.begin(), reading.end(), rd) != reading.end())
      continue;
    reading.push_back(rd);
    unary.push_back(readingCost(rd));
    std::vector<int> rp(m(), -1);
    for (int k = 0; k < m(); ++k)
      if (rd[k] >= 0)
        rp[k] = pair_of[k * q() + rd[k]];
    reading_pair.push_back(rp);
    ++added;
  }
  return added;
}

int addBestReadings(GridLine* line, const std::vector<double>& extra)
{
  return line->addReadings(ReadingSearch(*line, extra).readings());
}

}  // namespace detail
}  // namespace structured_light_stabilizer
