// Minimum-cost assignment (Kuhn-Munkres / Hungarian method), ROS-free.
//
// Contract: `cost` is an n x n matrix, row-major (cost[r * n + c]), of
// finite values; a pair that must not be chosen gets a large finite cost
// (an infinity would break the potentials). The result is a perfect
// matching of minimum total cost: (*col_of_row)[r] is the column of row r.
// Ties between equal-cost matchings are broken deterministically (the same
// input always gives the same matching). O(n^3) time, O(n) extra memory.
// Throws std::invalid_argument when cost.size() != n * n or n < 0.
// Thread-safe (no shared state).
#pragma once

#include <vector>

namespace structured_light_stabilizer
{

// Returns the total cost of the matching (summed in column order).
double solveAssignment(const std::vector<double>& cost, int n, std::vector<int>* col_of_row);

}  // namespace structured_light_stabilizer
