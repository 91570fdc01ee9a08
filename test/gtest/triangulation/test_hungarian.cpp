// solveAssignment (hungarian.h) against brute force over every permutation
// on small random matrices, with forbidden (large) entries as the
// Triangulator uses them.
#include <algorithm>
#include <numeric>
#include <random>
#include <stdexcept>

#include <gtest/gtest.h>

#include "structured_light_stabilizer/triangulation/hungarian.h"

using structured_light_stabilizer::solveAssignment;

TEST(Hungarian, MatchesBruteForce)
{
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uni(0.0, 3.0);
  std::bernoulli_distribution forbidden(0.3);
  for (int trial = 0; trial < 300; ++trial)
  {
    const int n = 1 + trial % 7;
    std::vector<double> cost(n * n);
    for (double& c : cost)
      c = forbidden(rng) ? 1e6 : uni(rng);
    std::vector<int> perm(n);
    std::iota(perm.begin(), perm.end(), 0);
    double best = 1e300;
    do
    {
      double total = 0.0;
      for (int r = 0; r < n; ++r)
        total += cost[r * n + perm[r]];
      best = std::min(best, total);
    } while (std::next_permutation(perm.begin(), perm.end()));
    std::vector<int> col_of_row;
    const double total = solveAssignment(cost, n, &col_of_row);
    ASSERT_EQ(static_cast<int>(col_of_row.size()), n);
    std::vector<int> sorted = col_of_row;
    std::sort(sorted.begin(), sorted.end());
    for (int c = 0; c < n; ++c)
      ASSERT_EQ(sorted[c], c) << "not a permutation";
    double check = 0.0;
    for (int r = 0; r < n; ++r)
      check += cost[r * n + col_of_row[r]];
    EXPECT_NEAR(total, check, 1e-9 * std::max(1.0, check));
    EXPECT_NEAR(total, best, 1e-9 * std::max(1.0, best));
  }
}

TEST(Hungarian, EmptyAndMalformed)
{
  std::vector<int> col_of_row{7};
  EXPECT_EQ(solveAssignment({}, 0, &col_of_row), 0.0);
  EXPECT_TRUE(col_of_row.empty());
  EXPECT_THROW(solveAssignment({1.0, 2.0, 3.0}, 2, &col_of_row), std::invalid_argument);
  EXPECT_THROW(solveAssignment({}, -1, &col_of_row), std::invalid_argument);
}
