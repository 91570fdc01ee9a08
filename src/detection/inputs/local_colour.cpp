// The colour path's local scores (FastParams::local_colour; planes.h): the
// projector's share of each cell measured against the rock's own colour
// around it, and thresholds from the local noise.
//
// A cell's colour is v = a k + s p + n: the rock (its local colour k times
// its brightness a, which texture makes vary from cell to cell), the dot
// (the projector's colour p as the camera sees it, times its strength s) and
// the noise n. The score is s estimated by q . v with q . k = 0 (the rock's
// brightness texture, of any albedo and colour, scores nothing) and q . p = 1
// (a dot scores its strength in DN of the projector's signal channel), the q
// of least noise: q = W^-1 A^T (A W^-1 A^T)^-1 (0, 1) with A = (k; p) and W
// the channels' noise variances. Nothing is assumed of the rock's colour: k
// is measured per block of kBlock x kBlock cells from the 5 x 5 blocks
// around, the half of them that the projector's colour explains least (a dot
// only adds that colour; the rock's own colour varies both ways; a dot
// touches at most 4 of them, a bloom streak along a column 5).
//
// What the rock's local colour leaves over areas wider than a dot (its colour
// texture, shading of another hue) is taken off with a band-pass: the score's
// background is an opening (min, then max, over 5 x 5 bins of 4 x 4 cells) of
// its bin means, which a dot of sigma up to about 4 cells does not reach.
//
// The noise of the band-passed score, per block: the larger of the sensor's
// (shot plus read noise at the block's level, through q) and the spread the
// scores show: within bins (the median of the block's 16 bins' variances, so
// a dot's bins do not count) and between bins (for the coarse pass), each the
// median over the 3 x 3 blocks around. The sensor's noise is set
// (noise_read_dn, noise_gain_dn) or estimated from the frame: per level, the
// quietest blocks' channel differences give the lower envelope
// sigma^2 = read^2 + gain level.
//
// Cost: two passes over the frame (the first on every second row), and maps
// of blocks and bins (1/256 and 1/16 of the cells).
#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "detection/inputs/pixels.h"
#include "detection/inputs/planes.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

namespace
{

// sqrt(pi) / 2: sigma of Gaussian noise from the mean absolute difference of
// two independent samples (E|x - y| = 2 sigma / sqrt(pi)).
constexpr double kDiffToSigma = 0.8862269254527580;
constexpr int kUnit = 16;  // score units per DN
constexpr int kBin = 4;    // bins of kBin x kBin cells (the coarse pass's)

struct BlockSums
{
  std::array<int64_t, 3> sum{{0, 0, 0}};       // r, g, b
  std::array<int64_t, 3> abs_diff{{0, 0, 0}};  // |v(x + 1) - v(x)| per channel
  int count = 0, diff_count = 0;
};

// One grid row as r, g, b per cell: in place for bgr8, decoded otherwise.
const int* rowOf(const cv::Mat& image, PixelFormat format, int gy, int cols, std::vector<int>* scratch,
                 bool* interleaved_bgr8)
{
  *interleaved_bgr8 = format == PixelFormat::kBgr8;
  if (*interleaved_bgr8)
    return nullptr;
  scratch->resize(3 * static_cast<size_t>(cols));
  pixels::decodeRow(image, format, gy, cols, scratch->data());
  if (format == PixelFormat::kMono16)  // in DN, as the colour formats
    for (int& v : *scratch)
      v = pixels::dn16(v);
  return scratch->data();
}

// Per block: the channel sums and the absolute horizontal differences, on
// every fourth row (the statistics need no more).
std::vector<BlockSums> measureBlocks(const cv::Mat& image, PixelFormat format, int cols, int rows, int block, int bc,
                                     int br)
{
  std::vector<BlockSums> blocks(static_cast<size_t>(bc) * br);
  std::vector<int> scratch;
  for (int gy = 1; gy < rows; gy += 4)
  {
    bool bgr8 = false;
    const int* row = rowOf(image, format, gy, cols, &scratch, &bgr8);
    const uint8_t* px = image.ptr<uint8_t>(gy);
    BlockSums* line = &blocks[static_cast<size_t>(gy / block) * bc];
    for (int x0 = 0, bx = 0; x0 < cols; x0 += block, ++bx)
    {
      const int x1 = std::min(cols, x0 + block);
      int s[3] = {0, 0, 0}, d[3] = {0, 0, 0}, prev[3] = {0, 0, 0};
      for (int gx = x0; gx < x1; ++gx)
      {
        int v[3];
        if (bgr8)
        {
          v[0] = px[3 * gx + 2];
          v[1] = px[3 * gx + 1];
          v[2] = px[3 * gx];
        }
        else
        {
          v[0] = row[3 * gx];
          v[1] = row[3 * gx + 1];
          v[2] = row[3 * gx + 2];
        }
        for (int c = 0; c < 3; ++c)
        {
          s[c] += v[c];
          if (gx > x0)
            d[c] += std::abs(v[c] - prev[c]);
          prev[c] = v[c];
        }
      }
      BlockSums& b = line[bx];
      for (int c = 0; c < 3; ++c)
      {
        b.sum[c] += s[c];
        b.abs_diff[c] += d[c];
      }
      b.count += x1 - x0;
      b.diff_count += std::max(0, x1 - x0 - 1);
    }
  }
  return blocks;
}

// The sensor's noise variance per channel at a level (DN^2).
struct NoiseModel
{
  double read2 = 0.0, gain = 0.0;  // sigma^2 = read2 + gain level
  double variance(double level) const { return read2 + gain * std::max(0.0, level); }
};

// Lower envelope of the blocks' (level, difference variance) per channel,
// pooled: in each of 8 level bins of 32 DN the 10th percentile of the
// variance, then a least-squares line through the bins' points with
// non-negative terms.
NoiseModel estimateNoise(const std::vector<BlockSums>& blocks)
{
  constexpr int kBins = 8;
  std::vector<double> var[kBins];
  double level_sum[kBins] = {0};
  for (const BlockSums& b : blocks)
    for (int c = 0; c < 3; ++c)
      if (b.count > 0 && b.diff_count > 0)
      {
        const double level = static_cast<double>(b.sum[c]) / b.count;
        if (!(level > 1.0 && level < 240.0))  // clipped blocks say nothing of the noise
          continue;
        const double sigma = kDiffToSigma * static_cast<double>(b.abs_diff[c]) / b.diff_count;
        const int k = std::min(kBins - 1, static_cast<int>(level / 32.0));
        var[k].push_back(sigma * sigma);
        level_sum[k] += level;
      }
  NoiseModel m;
  m.read2 = 1.0 / 12.0;  // the 8-bit quantisation's
  double sx = 0, sy = 0, sxx = 0, sxy = 0, n = 0;
  for (int k = 0; k < kBins; ++k)
  {
    std::vector<double>& v = var[k];
    if (v.size() < 8)
      continue;
    const double x = level_sum[k] / v.size();
    std::nth_element(v.begin(), v.begin() + v.size() / 10, v.end());
    const double y = v[v.size() / 10];
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
    n += 1;
  }
  if (n < 1)
    return m;
  const double det = n * sxx - sx * sx;
  const double b = det > 1e-9 ? std::max(0.0, (n * sxy - sx * sy) / det) : 0.0;
  const double a = std::max(0.0, (sy - b * sx) / n);
  m.read2 = std::max(a, m.read2);
  m.gain = b;
  return m;
}

// q with q . k = 0, q . p = 1 and the least noise sum q_c^2 w_c; false when k
// and p are too alike in colour for the rock and the dot to be told apart.
bool localProjection(const std::array<double, 3>& k, const std::array<double, 3>& p, const std::array<double, 3>& w,
                     std::array<double, 3>* q)
{
  double kk = 0, kp = 0, pp = 0;  // A W^-1 A^T with A = (k; p)
  for (int c = 0; c < 3; ++c)
  {
    kk += k[c] * k[c] / w[c];
    kp += k[c] * p[c] / w[c];
    pp += p[c] * p[c] / w[c];
  }
  const double det = kk * pp - kp * kp;
  // The squared sine of the angle between k and p in the noise's metric.
  if (!(det > 0.01 * kk * pp))
    return false;
  const double a = -kp / det, b = kk / det;  // (A W^-1 A^T)^-1 (0, 1)
  for (int c = 0; c < 3; ++c)
    (*q)[c] = (a * k[c] + b * p[c]) / w[c];
  return true;
}

// One row's raw scores (q of each block, 1/256) and its bins' sums of scores
// and of their squares. Stride: 3 for interleaved r, g, b ints (decoded) or
// bgr8 bytes (Bgr8).
template <bool Bgr8, typename T>
void scoreLocalRow(const T* in, int cols, int block, const std::array<int, 3>* q, int16_t* out, int64_t* bin_sum,
              int64_t* bin_sq)
{
  constexpr int kR = Bgr8 ? 2 : 0, kB = Bgr8 ? 0 : 2;
  for (int x0 = 0, bx = 0; x0 < cols; x0 += block, ++bx)
  {
    const int q0 = q[bx][0], q1 = q[bx][1], q2 = q[bx][2];
    const int x1 = std::min(cols, x0 + block);
    const T* v = in + 3 * x0;
    for (int x = x0; x < x1; ++x, v += 3)
      out[x] = static_cast<int16_t>((q0 * static_cast<int>(v[kR]) + q1 * static_cast<int>(v[1]) +
                                     q2 * static_cast<int>(v[kB]) + 128) >> 8);
  }
  for (int x = 0; x < cols; x += kBin)
  {
    const int e = std::min(cols, x + kBin);
    int sum = 0;
    int64_t sq = 0;
    for (int k = x; k < e; ++k)
    {
      const int sc = out[k];
      sum += sc;
      sq += sc * sc;
    }
    bin_sum[x / kBin] += sum;
    bin_sq[x / kBin] += sq;
  }
}

// The median of the 3 x 3 entries of m (rows x cols, row-major) around (y, x).
double median3x3(const std::vector<double>& m, int rows, int cols, int y, int x)
{
  double v[9];
  int n = 0;
  for (int yy = std::max(0, y - 1); yy <= std::min(rows - 1, y + 1); ++yy)
    for (int xx = std::max(0, x - 1); xx <= std::min(cols - 1, x + 1); ++xx)
      v[n++] = m[static_cast<size_t>(yy) * cols + xx];
  std::nth_element(v, v + n / 2, v + n);
  return v[n / 2];
}

}  // namespace

void FramePlanes::buildLocalColour(const FastParams& p)
{
  const int bc = (grid_cols_ + kBlock - 1) / kBlock, br = (grid_rows_ + kBlock - 1) / kBlock;
  const size_t nb = static_cast<size_t>(bc) * br;
  const std::vector<BlockSums> blocks = measureBlocks(image_, format_, grid_cols_, grid_rows_, kBlock, bc, br);
  NoiseModel noise;
  if (p.noise_read_dn > 0.0 || p.noise_gain_dn > 0.0)
  {
    noise.read2 = std::max(p.noise_read_dn * p.noise_read_dn, 1.0 / 12.0);
    noise.gain = p.noise_gain_dn;
  }
  else
  {
    noise = estimateNoise(blocks);
  }
  // A Bayer cell averages two green samples and holds one red and one blue.
  const double cell_var[3] = {1.0, scale_ == 2 ? 0.5 : 1.0, 1.0};

  // The projector's colour as the camera sees it, signal channel = 1: the
  // camera's response to a narrowband source, whatever the rock reflects of
  // it. The intensity path (mono frames, nir and white projectors): grey,
  // and the rock is told from the dots by the band-pass alone.
  std::array<double, 3> pc{{1.0, 1.0, 1.0}};
  if (model_.colour)
  {
    pc[model_.signal] = 1.0;
    pc[model_.reference] = model_.led_reference;
    pc[model_.third] = model_.led_third;
  }

  // Each block's mean colour and its excess along the projector's colour over
  // the frame's typical rock (what ranks the blocks around a block).
  std::vector<std::array<double, 3>> mean(nb);
  std::vector<double> chroma[3];
  for (size_t i = 0; i < nb; ++i)
  {
    const double n = std::max(1, blocks[i].count);
    double total = 0;
    for (int c = 0; c < 3; ++c)
    {
      mean[i][c] = static_cast<double>(blocks[i].sum[c]) / n;
      total += mean[i][c];
    }
    if (total > 3.0)
      for (int c = 0; c < 3; ++c)
        chroma[c].push_back(mean[i][c] / total);
  }
  std::array<double, 3> typical{{1.0 / 3, 1.0 / 3, 1.0 / 3}};
  for (int c = 0; c < 3; ++c)
    if (!chroma[c].empty())
      typical[c] = detail::medianInPlace(chroma[c].begin(), chroma[c].end());
  // The excess is along the projector's colour away from the typical rock's
  // (relative to the block's brightness); where the two are alike (a grey
  // projector, dark rock) it is the brightness along the projector's colour:
  // the dots only add to either.
  std::array<double, 3> q_typical{{0, 0, 0}};
  const bool typical_ok = localProjection(typical, pc, {{1.0, 1.0, 1.0}}, &q_typical);
  const double pp = pc[0] * pc[0] + pc[1] * pc[1] + pc[2] * pc[2];
  std::vector<double> excess(nb, 0.0);
  for (size_t i = 0; i < nb; ++i)
  {
    const double total = mean[i][0] + mean[i][1] + mean[i][2];
    if (typical_ok && total > 3.0)
      excess[i] = (q_typical[0] * mean[i][0] + q_typical[1] * mean[i][1] + q_typical[2] * mean[i][2]) / total;
    else if (!typical_ok)
      excess[i] = (pc[0] * mean[i][0] + pc[1] * mean[i][1] + pc[2] * mean[i][2]) / pp;
  }

  // Per block: the rock's local colour, the projection q (1/256) and the
  // sensor's noise of q . v (DN).
  std::vector<std::array<int, 3>> q_fixed(nb);
  std::vector<double> model_sigma(nb);
  constexpr int kAround = 2;  // 5 x 5 blocks: long bloom streaks cover fewer of them than of 3 x 3
  std::pair<double, size_t> around[25];
  for (int by = 0; by < br; ++by)
    for (int bx = 0; bx < bc; ++bx)
    {
      const size_t i = static_cast<size_t>(by) * bc + bx;
      int n = 0;
      for (int y = std::max(0, by - kAround); y <= std::min(br - 1, by + kAround); ++y)
        for (int x = std::max(0, bx - kAround); x <= std::min(bc - 1, bx + kAround); ++x)
        {
          const size_t j = static_cast<size_t>(y) * bc + x;
          around[n++] = {excess[j], j};
        }
      const int half = (n + 1) / 2;
      std::nth_element(around, around + (half - 1), around + n);
      std::array<double, 3> k{{0, 0, 0}};
      for (int j = 0; j < half; ++j)
        for (int c = 0; c < 3; ++c)
          k[c] += mean[around[j].second][c];
      std::array<double, 3> w;
      double k_level = 0, w_level = 0;
      for (int c = 0; c < 3; ++c)
      {
        w[c] = cell_var[c] * noise.variance(mean[i][c]);
        k_level += k[c] / half;
        w_level += w[c];
      }
      std::array<double, 3> q;
      // Rock too dark to show its colour above the noise (by night): nothing
      // to cancel, the brightness along the projector's colour.
      const bool dark = k_level * k_level < 9.0 * w_level;
      // A broadband projector's light (white; an NIR one on a mono camera) is
      // reflected in the rock's own colour: only its brightness tells it.
      if (!model_.colour || dark || !localProjection(k, pc, w, &q))
      {
        // The rock has the projector's colour: its brightness alone (the
        // band-pass below takes off its level; its texture counts as noise).
        double pw = 0;
        for (int c = 0; c < 3; ++c)
          pw += pc[c] * pc[c] / w[c];
        for (int c = 0; c < 3; ++c)
          q[c] = pc[c] / w[c] / pw;
      }
      double var = 0;
      for (int c = 0; c < 3; ++c)
      {
        q[c] = std::min(7.0, std::max(-7.0, q[c]));
        q_fixed[i][c] = static_cast<int>(std::lround(256.0 * kUnit * q[c]));
        var += q[c] * q[c] * w[c];
      }
      model_sigma[i] = kUnit * std::sqrt(var);
    }
  // The raw scores (1/kUnit DN), and per bin the sum of scores and of their
  // squares.
  local_scores_.create(grid_rows_, grid_cols_, CV_16S);
  const int bins_x = (grid_cols_ + kBin - 1) / kBin, bins_y = (grid_rows_ + kBin - 1) / kBin;
  std::vector<int64_t> bin_sum(static_cast<size_t>(bins_x) * bins_y, 0), bin_sq(bin_sum.size(), 0);
  std::vector<int> bin_count(bin_sum.size(), 0);
  std::vector<int> scratch;
  std::vector<cv::Point> clipped;
  for (int gy = 0; gy < grid_rows_; ++gy)
  {
    bool bgr8 = false;
    const int* row = rowOf(image_, format_, gy, grid_cols_, &scratch, &bgr8);
    const uint8_t* px = image_.ptr<uint8_t>(gy);
    int16_t* out = local_scores_.ptr<int16_t>(gy);
    const size_t line = static_cast<size_t>(gy / kBlock) * bc;
    const size_t bin_line = static_cast<size_t>(gy / kBin) * bins_x;
    const std::array<int, 3>* q = &q_fixed[line];
    if (bgr8)
      scoreLocalRow<true>(px, grid_cols_, kBlock, q, out, &bin_sum[bin_line], &bin_sq[bin_line]);
    else
      scoreLocalRow<false>(row, grid_cols_, kBlock, q, out, &bin_sum[bin_line], &bin_sq[bin_line]);
    for (int x = 0; x < grid_cols_; x += kBin)
      bin_count[bin_line + x / kBin] += std::min(kBin, grid_cols_ - x);
    // Cells whose signal channel is clipped (below).
    const int signal = model_.colour ? model_.signal : 1;
    const int channel = bgr8 ? 2 - signal : signal;
    const int saturation = p.saturation_level;
    if (bgr8)
    {
      for (int x = 0; x < grid_cols_; ++x)
        if (px[3 * x + channel] >= saturation)
          clipped.emplace_back(x, gy);
    }
    else
    {
      for (int x = 0; x < grid_cols_; ++x)
        if (row[3 * x + channel] >= saturation)
          clipped.emplace_back(x, gy);
    }
  }
  // The background: an opening of the bin means.
  cv::Mat bin_mean(bins_y, bins_x, CV_32F);
  std::vector<float> bin_var(bin_sum.size());
  for (int y = 0; y < bins_y; ++y)
  {
    float* m = bin_mean.ptr<float>(y);
    for (int x = 0; x < bins_x; ++x)
    {
      const size_t k = static_cast<size_t>(y) * bins_x + x;
      const double n = std::max(1, bin_count[k]);
      const double mk = static_cast<double>(bin_sum[k]) / n;
      m[x] = static_cast<float>(mk);
      bin_var[k] = static_cast<float>(std::max(0.0, static_cast<double>(bin_sq[k]) / n - mk * mk));
    }
  }
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5));
  cv::Mat background;
  cv::morphologyEx(bin_mean, background, cv::MORPH_OPEN, kernel, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
  local_background_.create(bins_y, bins_x, CV_16S);
  background.convertTo(local_background_, CV_16S);
  // Per block: the spread of the scores within bins (median of its bins'
  // variances) and of the bins about the background (1.4826 x the median
  // absolute residual).
  const int per_block = kBlock / kBin;
  std::vector<double> within(nb, 0.0), between(nb, 0.0);
  float v[kBlock / kBin * kBlock / kBin], a[kBlock / kBin * kBlock / kBin];
  for (int by = 0; by < br; ++by)
    for (int bx = 0; bx < bc; ++bx)
    {
      int n = 0;
      for (int y = by * per_block; y < std::min(bins_y, (by + 1) * per_block); ++y)
      {
        const float* m = bin_mean.ptr<float>(y);
        const float* bg = background.ptr<float>(y);
        for (int x = bx * per_block; x < std::min(bins_x, (bx + 1) * per_block); ++x, ++n)
        {
          v[n] = bin_var[static_cast<size_t>(y) * bins_x + x];
          a[n] = std::abs(m[x] - bg[x]);
        }
      }
      if (n == 0)
        continue;
      const size_t i = static_cast<size_t>(by) * bc + bx;
      std::nth_element(v, v + n / 2, v + n);
      std::nth_element(a, a + n / 2, a + n);
      within[i] = std::sqrt(v[n / 2]);
      between[i] = 1.4826 * a[n / 2];
    }
  // Thresholds: per block for the peaks (band-passed scores), per bin for the
  // cells (raw scores: the band-passed threshold plus the bin's background),
  // per bin for the coarse pass.
  block_peak_.create(br, bc, CV_32S);
  block_sigma_.create(br, bc, CV_32F);
  block_threshold_.create(br, bc, CV_32S);
  std::vector<double> bin_sigma(nb);
  for (int by = 0; by < br; ++by)
    for (int bx = 0; bx < bc; ++bx)
    {
      const size_t i = static_cast<size_t>(by) * bc + bx;
      // The rock's texture at the bins' scale shows in the bins' spread; a
      // dot must stand out of it as out of the noise.
      const double spread = median3x3(between, br, bc, by, bx);
      const double sigma = std::max({model_sigma[i], median3x3(within, br, bc, by, bx), spread, 0.1 * kUnit});
      bin_sigma[i] = std::max(model_sigma[i] / kBin, spread);
      block_sigma_.at<float>(by, bx) = static_cast<float>(sigma);
      block_threshold_.at<int>(by, bx) = std::max(1, static_cast<int>(std::ceil(p.candidate_snr * sigma)));
      block_peak_.at<int>(by, bx) = std::max(1, static_cast<int>(std::ceil(p.peak_snr * sigma)));
    }
  bin_threshold_.create(bins_y, bins_x, CV_32S);
  coarse_threshold_.create(grid_rows_ / kBin, grid_cols_ / kBin, CV_8U);
  for (int y = 0; y < bins_y; ++y)
  {
    const int by = y / per_block;
    const int* cell_thr = block_threshold_.ptr<int>(by);
    const int16_t* bg = local_background_.ptr<int16_t>(y);
    int* thr = bin_threshold_.ptr<int>(y);
    uint8_t* coarse = y < coarse_threshold_.rows ? coarse_threshold_.ptr<uint8_t>(y) : nullptr;
    for (int x = 0; x < bins_x; ++x)
    {
      const int bx = x / per_block;
      thr[x] = cell_thr[bx] + bg[x];
      if (coarse && x < coarse_threshold_.cols)
        coarse[x] = static_cast<uint8_t>(
            std::min(255.0, std::max(1.0, std::ceil(p.peak_snr * bin_sigma[static_cast<size_t>(by) * bc + bx]))));
    }
  }
  // A clipped cell's colour says nothing (a clipped core is white whatever the
  // projector's colour): it is a candidate cell, so that a clipped dot is one
  // blob with its flanks, but no peak (those come from unclipped cells).
  for (const cv::Point& c : clipped)
  {
    int16_t& v = local_scores_.at<int16_t>(c.y, c.x);
    v = static_cast<int16_t>(std::min(32767, std::max<int>(v, bin_threshold_.at<int>(c.y / kBin, c.x / kBin))));
  }
}

double FramePlanes::significance(int gx, int gy, double score) const
{
  if (localPath() || (!model_.colour && !matchedPath()))
  {
    const int by = std::min(std::max(gy, 0), grid_rows_ - 1) / kBlock;
    const int bx = std::min(std::max(gx, 0), grid_cols_ - 1) / kBlock;
    return score / std::max(1e-3, static_cast<double>(block_sigma_.at<float>(by, bx)));
  }
  if (matchedPath())
    return score / std::max(1e-3, static_cast<double>(kMatchedUnit) * matched_noise_.sigma);
  return score / std::max(1, thresholdOf(gx, gy));
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
