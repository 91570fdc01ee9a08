// Small numeric helpers shared by the core's .cpp files (not a public API:
// names may change without notice).
#pragma once

#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <vector>

namespace structured_light_stabilizer
{
namespace detail
{

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kPi = 3.14159265358979323846;

template <typename T>
constexpr T square(T v)
{
  return v * v;
}

// Upper median of [first, last): the element that would stand at index n / 2
// after sorting (no averaging of the two middle values, so the result is
// always one of the inputs). Reorders the range; value-initialised T when it
// is empty.
template <typename RandomIt>
typename std::iterator_traits<RandomIt>::value_type medianInPlace(RandomIt first, RandomIt last)
{
  using T = typename std::iterator_traits<RandomIt>::value_type;
  if (first == last)
    return T();
  const RandomIt mid = first + (last - first) / 2;
  std::nth_element(first, mid, last);
  return *mid;
}

// Upper median of a copy of v (see medianInPlace); 0 when empty.
template <typename T>
T median(std::vector<T> v)
{
  return medianInPlace(v.begin(), v.end());
}

}  // namespace detail
}  // namespace structured_light_stabilizer
