// Small numeric helpers shared by the core's .cpp files (not a public API:
// names may change without notice).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <iterator>
#include <limits>
#include <type_traits>
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

// The same element as medianInPlace for a large vector, by bracketing it
// first (Floyd and Rivest's selection): the values of an evenly spaced
// sample of 4096 at ranks k_s -/+ 128 around the median's rank k_s in the
// sample bound the median with high probability (a rank in a sample of 4096
// is off by 32 values RMS); one pass counts the values below the lower bound
// and copies those between the bounds (about 6 % of them) to scratch, and
// nth_element runs on those alone. A median that falls outside the bounds
// (or values that do not compare, as NaN) falls back to nth_element on all
// of v. Linear, branch-free passes instead of nth_element's partitions,
// whose branches mispredict on noise. v is not reordered unless it falls
// back; scratch is kept by the caller to spare an allocation. Fewer than
// 16384 values: medianInPlace on v.
template <typename T>
T medianOfMany(std::vector<T>* v, std::vector<T>* scratch)
{
  constexpr size_t kSample = 4096, kMargin = 128;
  const size_t n = v->size();
  if (n < 4 * kSample)
    return medianInPlace(v->begin(), v->end());
  const size_t k = n / 2;
  const T* x = v->data();
  scratch->resize(n);
  T* s = scratch->data();
  for (size_t i = 0; i < kSample; ++i)
    s[i] = x[i * n / kSample];
  const size_t ks = kSample / 2;
  std::nth_element(s, s + ks - kMargin, s + kSample);
  const T lo = s[ks - kMargin];
  std::nth_element(s + ks - kMargin + 1, s + ks + kMargin, s + kSample);
  const T hi = s[ks + kMargin];
  size_t below = 0, m = 0, outside = 0;
  for (size_t i = 0; i < n; ++i)
  {
    const T value = x[i];
    const bool low = value<lo, high = value> hi;
    below += low;
    outside += !low && !high && !(value >= lo && value <= hi);  // NaN
    s[m] = value;
    m += !low && !high;
  }
  if (outside || k < below || k >= below + m)
    return medianInPlace(v->begin(), v->end());
  std::nth_element(s, s + (k - below), s + m);
  return s[k - below];
}

// Upper median of a copy of v (see medianInPlace); 0 when empty.
template <typename T>
T median(std::vector<T> v)
{
  return medianInPlace(v.begin(), v.end());
}

}  // namespace detail
}  // namespace structured_light_stabilizer
