// Deterministic noise for the simulator: integer hashes, a counter-based
// generator and smooth value noise, independent of the standard library's
// distributions (whose output differs between implementations), so that the
// same seed gives the same frame on every platform.
#pragma once

#include <cstdint>
#include <cstring>
#include <utility>
#include <vector>

namespace structured_light_stabilizer
{
namespace sim
{

inline uint32_t hash32(int32_t x, int32_t y, uint32_t seed)
{
  uint32_t h = seed * 0x9E3779B1u;
  h ^= static_cast<uint32_t>(x) * 0x85EBCA77u;
  h = (h << 13) | (h >> 19);
  h ^= static_cast<uint32_t>(y) * 0xC2B2AE3Du;
  h ^= h >> 15;
  h *= 0x2C1B3C6Du;
  h ^= h >> 12;
  h *= 0x297A2D39u;
  h ^= h >> 15;
  return h;
}

// Advances *state and returns the next 64 random bits (SplitMix64).
inline uint64_t splitmix64(uint64_t* state)
{
  uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

inline uint64_t doubleBits(double v)
{
  uint64_t u;
  std::memcpy(&u, &v, sizeof(u));
  return u;
}

// Smooth value noise in [-1, 1] with a unit lattice.
double valueNoise(double x, double y, uint32_t seed);

// Octaves of fractalNoise: (feature size in m, weight).
using NoiseOctaves = std::vector<std::pair<double, double>>;

// Sum of value-noise octaves of the given feature sizes (m) and weights; each
// octave is rotated so that the lattice does not show as a grid.
double fractalNoise(double x, double y, uint32_t seed, const NoiseOctaves& octaves);

// Standard normal deviates as kNormalTableSize equiprobable quantiles indexed
// by 12 random bits: one 64-bit draw gives five, from a table that stays in
// L1. The tails end at +-3.67 sigma and the variance is 0.9997 (both far below
// what an 8-bit frame shows). Built on first use (thread-safe).
constexpr int kNormalTableSize = 4096;
const std::vector<float>& normalTable();

}  // namespace sim
}  // namespace structured_light_stabilizer
