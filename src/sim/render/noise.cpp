#include "sim/render/noise.h"

#include <cmath>

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

// Inverse of the standard normal CDF (Acklam's rational approximation,
// relative error 1.2e-9), used once to build the noise table.
double inverseNormalCdf(double p)
{
  static const double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,  -2.759285104469687e+02,
                             1.383577518672690e+02,  -3.066479806614716e+01, 2.506628277459239e+00};
  static const double b[] = {-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
                             6.680131188771972e+01, -1.328068155288572e+01};
  static const double c[] = {-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
                             -2.549732539343734e+00, 4.374664141464968e+00,  2.938163982698783e+00};
  static const double d[] = {7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
                             3.754408661907416e+00};
  const double plow = 0.02425;
  if (p < plow)
  {
    const double q = std::sqrt(-2.0 * std::log(p));
    return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  if (p > 1.0 - plow)
  {
    const double q = std::sqrt(-2.0 * std::log(1.0 - p));
    return -(((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
  }
  const double q = p - 0.5;
  const double r = q * q;
  return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
         (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
}

}  // namespace

double valueNoise(double x, double y, uint32_t seed)
{
  const double fx = std::floor(x), fy = std::floor(y);
  const int32_t ix = static_cast<int32_t>(fx), iy = static_cast<int32_t>(fy);
  const double tx = x - fx, ty = y - fy;
  const double sx = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0);
  const double sy = ty * ty * ty * (ty * (ty * 6.0 - 15.0) + 10.0);
  auto v = [&](int32_t a, int32_t b) { return hash32(a, b, seed) * (2.0 / 4294967295.0) - 1.0; };
  const double a = v(ix, iy) + sx * (v(ix + 1, iy) - v(ix, iy));
  const double b = v(ix, iy + 1) + sx * (v(ix + 1, iy + 1) - v(ix, iy + 1));
  return a + sy * (b - a);
}

double fractalNoise(double x, double y, uint32_t seed, const NoiseOctaves& octaves)
{
  double sum = 0.0, wsum = 0.0;
  for (size_t k = 0; k < octaves.size(); ++k)
  {
    const double a = 0.61 + 1.37 * k;
    const double c = std::cos(a), s = std::sin(a);
    const double u = (c * x - s * y) / octaves[k].first;
    const double v = (s * x + c * y) / octaves[k].first;
    sum += octaves[k].second * valueNoise(u, v, seed + 7919u * static_cast<uint32_t>(k + 1));
    wsum += octaves[k].second;
  }
  return wsum > 0.0 ? sum / wsum : 0.0;
}

const std::vector<float>& normalTable()
{
  static const std::vector<float> table = []
  {
    std::vector<float> t(kNormalTableSize);
    for (int i = 0; i < kNormalTableSize; ++i)
      t[i] = static_cast<float>(inverseNormalCdf((i + 0.5) / kNormalTableSize));
    return t;
  }();
  return table;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
