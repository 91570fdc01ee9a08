// TextureTracker's windows: the template of each feature on its pyramid
// level, its information against the image noise, and the sub-pixel
// refinement with a photometric model (texture_tracker.h).
#include <array>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "structured_light_stabilizer/pose/texture_tracker.h"

namespace structured_light_stabilizer
{

namespace
{
// The refinement sums run over rows padded to a multiple of this many lanes,
// with independent per-lane accumulators, so that the compiler vectorises
// them without reassociating float sums (the padding has zero weight).
constexpr int kLanes = 8;
int paddedWidth(int width)
{
  return (width + kLanes - 1) / kLanes * kLanes;
}
// A fitted gain outside this range means the window does not hold the
// template's texture: regression dilution pulls the gain of a window that is
// mostly noise towards 0 (its content does not recur), and an occlusion or
// clipping changes it wildly. Real gain changes (vignetting, exposure) stay
// within tens of per cent.
constexpr double kMinGain = 0.5;
constexpr double kMaxGain = 2.0;
// Parameters of the photometric model: shift x, y, gain, offset, gain slope x, y.
constexpr int kParams = 6;
// A warp moving the window's corner by less than this (level pixels) is not applied.
constexpr double kNegligibleWarpPx = 0.05;
// Widest window warpTemplate() handles (texture_refinement_window_px is at most 61).
constexpr int kMaxWindow = 128;

// Inverse of a symmetric positive definite 6x6 matrix (Cholesky); false
// when it is not positive definite. (Eigen's fixed-size LLT: inline, unlike
// cv::Matx::inv.)
bool invertSpd(const cv::Matx66d& A, cv::Matx66d* inverse)
{
  using M6 = Eigen::Matrix<double, 6, 6, Eigen::RowMajor>;
  const Eigen::LLT<M6> llt(Eigen::Map<const M6>(A.val));
  if (llt.info() != Eigen::Success)
    return false;
  Eigen::Map<M6>(inverse->val) = llt.solve(M6::Identity());
  return true;
}

// Where a full-image point lies on a pyramid level: cv::pyrDown centres
// pixel x of a level on pixel 2x of the level below.
double toLevel(double full, int level)
{
  return full / static_cast<double>(1 << level);
}
}  // namespace

TextureTracker::LevelNoise TextureTracker::levelNoise(int level)
{
  // The 1D weights of one level-L pixel over full-resolution pixels: the
  // 5-tap binomial kernel of cv::pyrDown applied L times with decimation.
  static const double k[5] = {1.0 / 16, 4.0 / 16, 6.0 / 16, 4.0 / 16, 1.0 / 16};
  std::vector<double> h{1.0};
  int half = 0;
  for (int l = 0; l < level; ++l)
  {
    const int step = 1 << l, nh = half + 2 * step;
    std::vector<double> g(static_cast<size_t>(2 * nh + 1), 0.0);
    for (int j = -2; j <= 2; ++j)
      for (int x = -half; x <= half; ++x)
        g[static_cast<size_t>(x + j * step + nh)] += k[j + 2] * h[static_cast<size_t>(x + half)];
    h.swap(g);
    half = nh;
  }
  auto at = [&](int x) { return x >= -half && x <= half ? h[static_cast<size_t>(x + half)] : 0.0; };
  double s2 = 0.0, d2 = 0.0;
  const int D = 1 << level;
  for (int x = -half - D; x <= half + D; ++x)
  {
    s2 += at(x) * at(x);
    d2 += 0.25 * (at(x - D) - at(x + D)) * (at(x - D) - at(x + D));
  }
  LevelNoise n;
  n.value_factor = s2;  // (sum h^2)^2 is the 2D variance factor: its square root is s2
  n.gradient_factor = d2 * s2;
  return n;
}

int TextureTracker::windowHalf(int level) const
{
  if (!config_.photometric_refinement)
    return config_.window_px / 2 + 1;
  return (refinementHalf() + 2) << level;
}

// Zeroes the weight of the window samples within the dot clearance of a dot
// (on the window's level; cv::pyrDown spreads a dot by about one more
// level pixel). `centre` and `dots` in full-image pixels. False when no dot
// touches the window.
bool TextureTracker::maskDots(const std::vector<cv::Point2f>& dots, const cv::Point2f& centre, int level,
                              std::vector<float>* mask) const
{
  const int h = refinementHalf(), stride = paddedWidth(2 * h + 1);
  const float scale = 1.0f / static_cast<float>(1 << level);
  const float reach = static_cast<float>(config_.dot_clearance_px) * scale + (level > 0 ? 1.0f : 0.0f);
  bool any = false;
  for (const cv::Point2f& d : dots)
  {
    const float cx = (d.x - centre.x) * scale, cy = (d.y - centre.y) * scale;
    if (std::abs(cx) > h + reach || std::abs(cy) > h + reach)
      continue;
    any = true;
    const int ylo = std::max(-h, static_cast<int>(std::floor(cy - reach))),
              yhi = std::min(h, static_cast<int>(std::ceil(cy + reach)));
    const int xlo = std::max(-h, static_cast<int>(std::floor(cx - reach))),
              xhi = std::min(h, static_cast<int>(std::ceil(cx + reach)));
    for (int dy = ylo; dy <= yhi; ++dy)
      for (int dx = xlo; dx <= xhi; ++dx)
        if ((dx - cx) * (dx - cx) + (dy - cy) * (dy - cy) < reach * reach)
          (*mask)[static_cast<size_t>(dy + h) * stride + (dx + h)] = 0.0f;
  }
  return any;
}

namespace
{
// The upper triangle of the sum of j j^T over the window samples k where
// use(k) holds (the matrix is symmetric), j the model's Jacobian at k; each
// entry summed in the same order as a full outer product would. *count gets
// the number of those samples.
template <typename Use>
cv::Matx66d outerSum(const std::vector<float>& value, const std::vector<float>& gx, const std::vector<float>& gy, int h,
                     int stride, Use use, double* count)
{
  const int width = 2 * h + 1;
  const double inv_h = 1.0 / std::max(h, 1);
  double sum[kParams][kParams] = {};
  *count = 0.0;
  for (int dy = 0; dy < width; ++dy)
    for (int dx = 0; dx < width; ++dx)
    {
      const size_t k = static_cast<size_t>(dy) * stride + dx;
      if (!use(k))
        continue;
      *count += 1.0;
      const double v = value[k];
      const double j[kParams] = {gx[k], gy[k], -v, -1.0, -v * (dx - h) * inv_h, -v * (dy - h) * inv_h};
      for (int a = 0; a < kParams; ++a)
        for (int b = a; b < kParams; ++b)
          sum[a][b] += j[a] * j[b];
    }
  cv::Matx66d normal;
  for (int a = 0; a < kParams; ++a)
    for (int b = a; b < kParams; ++b)
      normal(a, b) = normal(b, a) = sum[a][b];
  return normal;
}
}  // namespace

cv::Matx66d TextureTracker::normalOf(const Template& t, const std::vector<float>& mask, double* samples) const
{
  const int h = refinementHalf();
  return outerSum(
      t.value, t.gx, t.gy, h, paddedWidth(2 * h + 1), [&](size_t k) { return mask[k] > 0.0f; }, samples);
}

// `mask` is the template's own with some samples zeroed (this frame's dots):
// its normal matrix is the template's less what those samples added.
cv::Matx66d TextureTracker::maskedNormal(const Template& t, const std::vector<float>& mask, double* samples) const
{
  const int h = refinementHalf();
  double removed = 0.0;
  const cv::Matx66d less = outerSum(
      t.value, t.gx, t.gy, h, paddedWidth(2 * h + 1), [&](size_t k) { return t.mask[k] > 0.0f && !(mask[k] > 0.0f); },
      &removed);
  *samples = t.samples - removed;
  return t.normal - less;
}

bool TextureTracker::buildTemplate(const cv::Point2f& position, int level, const std::vector<cv::Point2f>& dots,
                                   Template* t) const
{
  const cv::Mat& image = reference_levels_[static_cast<size_t>(level)];
  const int h = refinementHalf(), width = 2 * h + 1, stride = paddedWidth(width);
  // Features sit on whole pixels of their level, so the template is read
  // without interpolation.
  const int x0 = cvRound(toLevel(position.x - roi_.x, level)), y0 = cvRound(toLevel(position.y - roi_.y, level));
  if (x0 - h - 1 < 0 || y0 - h - 1 < 0 || x0 + h + 1 >= image.cols || y0 + h + 1 >= image.rows)
    return false;
  const size_t n = static_cast<size_t>(width) * stride;
  t->value.assign(n, 0.0f);
  t->gx.assign(n, 0.0f);
  t->gy.assign(n, 0.0f);
  t->mask.assign(n, 0.0f);
  for (int dy = -h; dy <= h; ++dy)
  {
    const float* row = image.ptr<float>(y0 + dy);
    const float* up = image.ptr<float>(y0 + dy - 1);
    const float* down = image.ptr<float>(y0 + dy + 1);
    for (int dx = -h; dx <= h; ++dx)
    {
      const size_t k = static_cast<size_t>(dy + h) * stride + (dx + h);
      const int x = x0 + dx;
      t->value[k] = row[x];
      t->gx[k] = 0.5f * (row[x + 1] - row[x - 1]);
      t->gy[k] = 0.5f * (down[x] - up[x]);
      t->mask[k] = 1.0f;
    }
  }
  // The reference's own dots are not rock texture either.
  maskDots(dots, position, level, &t->mask);
  t->normal = normalOf(*t, t->mask, &t->samples);
  const cv::Matx66d& normal = t->normal;
  const bool invertible = invertSpd(normal, &t->inverse_normal);
  t->noise_sigma0 = noiseAt(cv::Point2f(position.x - roi_.x, position.y - roi_.y));
  t->gradient_noise_var = t->noise_sigma0 * t->noise_sigma0 * levelNoise(level).gradient_factor;
  t->ok = invertible && signalInverse(normal, t->samples, t->gradient_noise_var, &t->inverse_signal);
  t->shift_covariance = shiftCovariance(t->inverse_signal, level);
  return t->ok;
}

TextureTracker::Information TextureTracker::information(const Template& t, int level) const
{
  Information info;
  double gxx = 0.0, gxy = 0.0, gyy = 0.0;
  for (size_t k = 0; k < t.mask.size(); ++k)
    if (t.mask[k] > 0.0f)
    {
      gxx += t.gx[k] * t.gx[k];
      gxy += t.gx[k] * t.gy[k];
      gyy += t.gy[k] * t.gy[k];
    }
  info.noise_energy = t.samples * t.gradient_noise_var;
  // Smallest eigenvalue of the gradient energy, less what the noise adds.
  const double tr = gxx + gyy, det = gxx * gyy - gxy * gxy;
  info.signal_min = 0.5 * tr - std::sqrt(std::max(0.0, 0.25 * tr * tr - det)) - info.noise_energy;
  info.sigma_px = HUGE_VAL;
  if (!(info.signal_min > 0.0) || !t.ok)
    return info;
  // Both images carry the noise: twice its variance per residual sample.
  const double sigma_level = t.noise_sigma0 * levelNoise(level).value_factor;
  const cv::Matx22d cov = t.shift_covariance * (2.0 * sigma_level * sigma_level);
  const double a = cov(0, 0), b = cov(0, 1), c = cov(1, 1);
  info.sigma_px = std::sqrt(0.5 * (a + c) + std::sqrt(0.25 * (a - c) * (a - c) + b * b));
  return info;
}

bool TextureTracker::signalInverse(const cv::Matx66d& normal, double samples, double gradient_noise_var,
                                   cv::Matx66d* inverse)
{
  // The template's gradients carry its noise: take it out of the shift's
  // information (what is left is the texture's).
  cv::Matx66d signal = normal;
  signal(0, 0) -= samples * gradient_noise_var;
  signal(1, 1) -= samples * gradient_noise_var;
  return invertSpd(signal, inverse) && (*inverse)(0, 0) > 0.0 && (*inverse)(1, 1) > 0.0;
}

cv::Matx22d TextureTracker::shiftCovariance(const cv::Matx66d& inverse_signal, int level)
{
  const double scale = static_cast<double>(1 << level) * static_cast<double>(1 << level);
  return cv::Matx22d(inverse_signal(0, 0), inverse_signal(0, 1), inverse_signal(1, 0), inverse_signal(1, 1)) * scale;
}

namespace
{
// The largest move (level pixels) of the window's corners through the linear map d.
double cornerMove(const cv::Matx22d& d, int h)
{
  return (std::abs(d(0, 0)) + std::abs(d(0, 1)) + std::abs(d(1, 0)) + std::abs(d(1, 1))) * h;
}
}  // namespace

const std::vector<float>* TextureTracker::warped(size_t i, const cv::Matx22d& warp) const
{
  const int h = refinementHalf();
  const cv::Matx22d inverse = warp.inv();
  // Below this at the window's corner (level pixels) the warp changes nothing that matters.
  if (!(cornerMove(inverse - cv::Matx22d::eye(), h) > kNegligibleWarpPx))
    return nullptr;  // also when the warp is not finite
  // Nor does a change of the warp by as little since it was last applied:
  // the window keeps its warped template from frame to frame while the
  // rig's roll, scale and tilt barely change.
  if (warp_cache_.size() != templates_.size())
    warp_cache_.assign(templates_.size(), WarpCache());
  WarpCache& cache = warp_cache_[i];
  if (cache.valid && cornerMove(inverse - cache.inverse, h) <= kNegligibleWarpPx)
    return &cache.values;
  cache.inverse = inverse;
  cache.valid = warpTemplate(templates_[i], features_[i], levels_[i], inverse, &cache.values);
  return cache.valid ? &cache.values : nullptr;
}

bool TextureTracker::warpTemplate(const Template& t, const cv::Point2f& position, int level, const cv::Matx22d& inverse,
                                  std::vector<float>* values) const
{
  const int h = refinementHalf(), width = 2 * h + 1, stride = paddedWidth(width);
  if (width > kMaxWindow)
    return false;
  const cv::Mat& image = reference_levels_[static_cast<size_t>(level)];
  const double cx = toLevel(position.x - roi_.x, level), cy = toLevel(position.y - roi_.y, level);
  // The window's corners through the warp must stay inside the level.
  const double reach =
      (std::abs(inverse(0, 0)) + std::abs(inverse(0, 1)) + std::abs(inverse(1, 0)) + std::abs(inverse(1, 1))) * h;
  if (cx - reach < 0.0 || cy - reach < 0.0 || cx + reach + 1.0 >= image.cols || cy + reach + 1.0 >= image.rows)
    return false;
  values->assign(t.value.size(), 0.0f);
  const float i00 = static_cast<float>(inverse(0, 0)), i10 = static_cast<float>(inverse(1, 0));
  const int row_step = static_cast<int>(image.step1());
  const float* base = image.ptr<float>(0);
  // Per row: the sample positions first (each from the row's start, no
  // running sum, so that the loops vectorise), then their cells and
  // weights, then the bilinear reads.
  std::array<float, kMaxWindow> fx, fy;
  std::array<int, kMaxWindow> at;
  for (int dy = -h; dy <= h; ++dy)
  {
    // The reference sample that lands at (dx, dy) of the current window.
    const float x = static_cast<float>(cx + inverse(0, 1) * dy - inverse(0, 0) * h);
    const float y = static_cast<float>(cy + inverse(1, 1) * dy - inverse(1, 0) * h);
    for (int k = 0; k < width; ++k)
    {
      fx[k] = x + i00 * static_cast<float>(k);
      fy[k] = y + i10 * static_cast<float>(k);
    }
    for (int k = 0; k < width; ++k)
    {
      const int x0 = static_cast<int>(fx[k]), y0 = static_cast<int>(fy[k]);  // non-negative: truncation is floor
      fx[k] -= static_cast<float>(x0);
      fy[k] -= static_cast<float>(y0);
      at[k] = y0 * row_step + x0;
    }
    float* out = &(*values)[static_cast<size_t>(dy + h) * stride];
    for (int k = 0; k < width; ++k)
    {
      const float* r0 = base + at[k];
      const float* r1 = r0 + row_step;
      const float wx = fx[k], wy = fy[k];
      out[k] = (1 - wy) * ((1 - wx) * r0[0] + wx * r0[1]) + wy * ((1 - wx) * r1[0] + wx * r1[1]);
    }
  }
  return true;
}

namespace
{
// The model's normal-equation right-hand side b = J^T r and the residual sum
// rr = r^T r of a window of template values T (gradients GX, GY, weights M,
// rows of `stride`) against `image` sampled at (x0, y0) + (fx, fy) + offset.
// Residual r = I(q + xi) - T(xi); the model I = (a + ax xi_x + ay xi_y) T + b
// is linear in its photometric parameters, so each pass solves for them
// afresh (from a = 1, the others 0) together with the shift increment.
struct WindowSums
{
  cv::Vec<double, 6> b;
  double rr = 0.0;
};

WindowSums windowSums(const cv::Mat& image, int x0, int y0, float fx, float fy, int h, int stride, const float* T,
                      const float* GX, const float* GY, const float* M)
{
  // Integer window offsets: the bilinear weights are the same for every sample.
  const float w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
  const float inv_h = 1.0f / static_cast<float>(std::max(h, 1));
  const int width = 2 * h + 1;
  float a0[kLanes] = {}, a1[kLanes] = {}, a2[kLanes] = {}, a3[kLanes] = {}, a4[kLanes] = {}, a5[kLanes] = {},
        a6[kLanes] = {};
  for (int dy = 0; dy < width; ++dy)
  {
    const float* r0 = image.ptr<float>(y0 - h + dy) + (x0 - h);
    const float* r1 = image.ptr<float>(y0 - h + dy + 1) + (x0 - h);
    const size_t o = static_cast<size_t>(dy) * stride;
    const float ey = static_cast<float>(dy - h) * inv_h;
    for (int c = 0; c < stride; c += kLanes)
      for (int l = 0; l < kLanes; ++l)
      {
        const int x = c + l;
        const float v = w00 * r0[x] + w01 * r0[x + 1] + w10 * r1[x] + w11 * r1[x + 1];
        const float r = M[o + x] * (v - T[o + x]);
        const float tr = T[o + x] * r;
        a0[l] += GX[o + x] * r;
        a1[l] += GY[o + x] * r;
        a2[l] += tr;
        a3[l] += r;
        a4[l] += tr * (static_cast<float>(x - h) * inv_h);
        a5[l] += tr * ey;
        a6[l] += r * r;
      }
  }
  WindowSums s;
  for (int l = 0; l < kLanes; ++l)
  {
    s.b[0] += a0[l];
    s.b[1] += a1[l];
    s.b[2] -= a2[l];
    s.b[3] -= a3[l];
    s.b[4] -= a4[l];
    s.b[5] -= a5[l];
    s.rr += a6[l];
  }
  return s;
}
}  // namespace

bool TextureTracker::refine(const Template& t, const std::vector<float>& values, const cv::Mat& image,
                            const std::vector<float>& mask, const cv::Matx66d& inverse_normal,
                            const cv::Matx66d& inverse_signal, cv::Point2d* q, double* residual_ss) const
{
  const int h = refinementHalf(), stride = paddedWidth(2 * h + 1);
  const cv::Point2d start = *q;
  double qx = q->x, qy = q->y;
  for (int it = 0; it < config_.refinement_iterations; ++it)
  {
    const int x0 = static_cast<int>(std::floor(qx)), y0 = static_cast<int>(std::floor(qy));
    if (x0 - h < 0 || y0 - h < 0 || x0 - h + stride + 1 >= image.cols || y0 + h + 1 >= image.rows)
      return false;
    const WindowSums s = windowSums(image, x0, y0, static_cast<float>(qx - x0), static_cast<float>(qy - y0), h, stride,
                                    values.data(), t.gx.data(), t.gy.data(), mask.data());
    // Least squares with the template as it is (its noise included): the
    // residual it leaves, rr - b^T N^-1 b, and the gain, which regression
    // dilution pulls towards 0 when the window is not the template's texture.
    const cv::Vec<double, kParams> fit = -(inverse_normal * s.b);
    *residual_ss = std::max(0.0, s.rr + s.b.dot(fit));
    if (!(1.0 + fit[2] >= kMinGain && 1.0 + fit[2] <= kMaxGain))
      return false;
    // The step with the template noise's share taken out of the normal
    // matrix: a full Newton step (the noisy one falls short by the noise's
    // share of the gradient energy, and stopping early would leave every
    // window a little towards its prediction, a common error). The step is
    // taken along the template's gradient; the image's is the gain times that.
    const cv::Vec<double, kParams> step = -(inverse_signal * s.b);
    const double gain = std::max(1.0 + step[2], kMinGain);
    const double sx = step[0] / gain, sy = step[1] / gain;
    qx += sx;
    qy += sy;
    if (std::hypot(qx - start.x, qy - start.y) > config_.max_refinement_px)
      return false;
    if (sx * sx + sy * sy < 1e-4)  // 0.01 px: well below the noise of one feature
      break;
  }
  *q = cv::Point2d(qx, qy);
  return true;
}

int TextureTracker::refineAll(const std::vector<cv::Point2f>& predicted, const std::vector<cv::Point2f>& dots,
                              std::vector<cv::Point2f>* tracked, std::vector<uint8_t>* ok,
                              std::vector<cv::Matx22d>* covariance, const std::vector<cv::Matx22d>* warps) const
{
  const size_t n = features_.size();
  tracked->assign(n, cv::Point2f(NAN, NAN));
  ok->assign(n, 0);
  if (covariance)
    covariance->assign(n, cv::Matx22d::zeros());
  if (!frame_ok_ || predicted.size() != n || templates_.size() != n)
    return 0;
  const cv::Point2f offset(static_cast<float>(roi_.x), static_cast<float>(roi_.y));
  std::vector<float> local_mask;
  int good = 0;
  for (size_t i = 0; i < n; ++i)
  {
    const Template& t = templates_[i];
    const int level = levels_[i];
    cv::Point2f p = predicted[i] - offset, full;
    if (!t.ok || !std::isfinite(p.x) || !std::isfinite(p.y) || !accept(p, level, dots, &full))
      continue;  // a feature centred on a dot has lost its own texture
    // Through the predicted warp (the dots' mask moves by a fraction of a
    // pixel: kept as it is); this frame's dots in the window get no weight either.
    const std::vector<float>* values = warps && warps->size() == n ? warped(i, (*warps)[i]) : nullptr;
    local_mask = t.mask;
    const bool masked = maskDots(dots, predicted[i], level, &local_mask);
    cv::Matx66d inverse_normal = t.inverse_normal, inverse_signal = t.inverse_signal;
    cv::Matx22d unit_covariance = t.shift_covariance;
    double samples = t.samples;
    if (masked)
    {
      const cv::Matx66d normal = maskedNormal(t, local_mask, &samples);
      if (!invertSpd(normal, &inverse_normal) || !signalInverse(normal, samples, t.gradient_noise_var, &inverse_signal))
        continue;
      unit_covariance = shiftCovariance(inverse_signal, level);
    }
    cv::Point2d q(toLevel(p.x, level), toLevel(p.y, level));
    double residual_ss = 0.0;
    if (!refine(t, values ? *values : t.value, frame_levels_[static_cast<size_t>(level)], masked ? local_mask : t.mask,
                inverse_normal, inverse_signal, &q, &residual_ss))
      continue;
    const double residual_var = residual_ss / std::max(1.0, samples - kParams);
    const cv::Matx22d cov = unit_covariance * residual_var;
    const double scale = static_cast<double>(1 << level);
    p = cv::Point2f(static_cast<float>(scale * q.x), static_cast<float>(scale * q.y));
    if (!accept(p, level, dots, &full))
      continue;
    (*tracked)[i] = full;
    (*ok)[i] = 1;
    if (covariance)
      (*covariance)[i] = cov;
    ++good;
  }
  return good;
}

}  // namespace structured_light_stabilizer
