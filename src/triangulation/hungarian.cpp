#include "structured_light_stabilizer/triangulation/hungarian.h"

#include <algorithm>
#include <stdexcept>

#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

double solveAssignment(const std::vector<double>& cost, int n, std::vector<int>* col_of_row)
{
  if (n < 0 || cost.size() != static_cast<size_t>(n) * static_cast<size_t>(n))
    throw std::invalid_argument("solveAssignment: the cost matrix must hold n * n entries");
  // Shortest augmenting paths with row potentials u and column potentials v
  // (1-based; column 0 is the virtual start of each path). p[j] is the row
  // matched to column j, way[j] the previous column on the current path.
  std::vector<double> u(n + 1, 0.0), v(n + 1, 0.0), minv(n + 1);
  std::vector<int> p(n + 1, 0), way(n + 1, 0);
  std::vector<char> used(n + 1);
  for (int i = 1; i <= n; ++i)
  {
    p[0] = i;
    int j0 = 0;
    std::fill(minv.begin(), minv.end(), detail::kInf);
    std::fill(used.begin(), used.end(), 0);
    do
    {
      used[j0] = 1;
      const int i0 = p[j0];
      double delta = detail::kInf;
      int j1 = 0;
      for (int j = 1; j <= n; ++j)
      {
        if (used[j])
          continue;
        const double cur = cost[(i0 - 1) * n + (j - 1)] - u[i0] - v[j];
        if (cur < minv[j])
        {
          minv[j] = cur;
          way[j] = j0;
        }
        if (minv[j] < delta)
        {
          delta = minv[j];
          j1 = j;
        }
      }
      for (int j = 0; j <= n; ++j)
      {
        if (used[j])
        {
          u[p[j]] += delta;
          v[j] -= delta;
        }
        else
        {
          minv[j] -= delta;
        }
      }
      j0 = j1;
    } while (p[j0] != 0);
    // Augment along the path back to the virtual column.
    do
    {
      const int j1 = way[j0];
      p[j0] = p[j1];
      j0 = j1;
    } while (j0);
  }
  col_of_row->assign(n, -1);
  double total = 0.0;
  for (int j = 1; j <= n; ++j)
  {
    (*col_of_row)[p[j] - 1] = j - 1;
    total += cost[(p[j] - 1) * n + (j - 1)];
  }
  return total;
}

}  // namespace structured_light_stabilizer
