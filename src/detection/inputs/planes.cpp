// The inputs layer of the fast method: colour models, the score grid of the
// threshold pass and the intensity path's background maps (see
// spot_detector_planes.h). The windows of the refinement are in
// spot_detector_windows.cpp; the SIMD row passes in spot_detector_rows.cpp.
#include "detection/inputs/planes.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "detection/inputs/pixels.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

// The colour table. Green: the parameters (red_weight, led ratios). Red
// (635-660 nm) and blue (450 nm): a typical colour sensor's response there
// (about 10 % in green and 4 % in blue for red light; 12-20 % in green and 3 %
// in red for blue light) and the reddish rock's ratios (r/g <= 2.2, r/b <=
// 3; b/r <= 0.5, b/g <= 0.85).
ColourModel colourModel(ProjectorColor color, bool colour_frame, const FastParams& p)
{
  ColourModel m;
  if (!colour_frame || color == ProjectorColor::kNir || color == ProjectorColor::kWhite)
  {
    m.colour = false;
    return m;
  }
  switch (color)
  {
    case ProjectorColor::kRed:
      m = {true, kRed, kGreen, kBlue, 2.2, 3.0, 0.10, 0.04};
      break;
    case ProjectorColor::kBlue:
      m = {true, kBlue, kRed, kGreen, 0.5, 0.85, 0.03, 0.15};
      break;
    default:
      m = {true, kGreen, kRed, kBlue, p.red_weight, 1.0, p.colour_test.led_red_ratio, p.colour_test.led_blue_ratio};
      break;
  }
  return m;
}

// ---------------------------------------------------------------------------
// Binding a frame.

void FramePlanes::bind(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format, ProjectorColor color,
                       const FastParams& p, const MatchedNoise* fixed, const cv::Mat& ambient_fine)
{
  image_ = image;
  ambient_ = ambient;
  ambient_fine_ = ambient.empty() ? cv::Mat() : ambient_fine;
  format_ = format;
  model_ = colourModel(color, hasColour(format), p);
  scale_ = isBayer(format) ? 2 : 1;
  grid_cols_ = image.cols / scale_;
  grid_rows_ = image.rows / scale_;
  unit_ = model_.colour ? 1 : 16;
  k_ref_ = static_cast<int>(std::lround(model_.reference_weight * 256.0));
  k_third_ = static_cast<int>(std::lround(model_.third_weight * 256.0));
  threshold_ = scale_ == 2 ? std::max(1, (3 * p.detect_threshold + 3) / 4) : p.detect_threshold;
  saturation_ = format == PixelFormat::kMono16 ? p.saturation_level * 257 : p.saturation_level;
  row_scores_.resize(static_cast<size_t>(std::max(grid_cols_, 1)));
  matched_.release();
  matched_noise_ = MatchedNoise();
  local_ = false;
  if (ambient_.empty() && p.local_colour && grid_cols_ > 0 && grid_rows_ > 0)
  {
    local_ = true;
    local_row_ = -1;
    unit_ = 16;
    buildLocalColour(p);
  }
  else if (!model_.colour)
    buildIntensityMaps(p);
  else if (!ambient_.empty() && p.matched_sigma_px > 0.0 && grid_cols_ > 0 && grid_rows_ > 0)
    buildMatchedScores(p, fixed && fixed->valid ? fixed : nullptr);
}

// The difference's colour score smoothed by the dot's matched filter, and
// the thresholds from its noise: the median and 1.4826 x the median absolute
// deviation over every 4th cell of every 4th row (dots cover about 1 % of a
// frame, so both are the noise's), or `fixed` (a region, whose own cells are
// mostly dots).
void FramePlanes::buildMatchedScores(const FastParams& p, const MatchedNoise* fixed)
{
  cv::Mat& raw = matched_raw_;  // kept: no allocation per frame
  raw.create(grid_rows_, grid_cols_, CV_16S);
  for (int gy = 0; gy < grid_rows_; ++gy)
    scoreRow(gy, raw.ptr<int16_t>(gy));
  cv::Mat& smooth = matched_smooth_;
  raw.convertTo(smooth, CV_32F);
  cv::GaussianBlur(smooth, smooth, cv::Size(0, 0), p.matched_sigma_px / scale_);
  if (fixed)
    matched_noise_ = *fixed;
  else
    matched_noise_ = sampledNoise(smooth);
  const float centre = matched_noise_.centre;
  const double sigma = matched_noise_.sigma;
  smooth.convertTo(matched_, CV_16S, kMatchedUnit, -kMatchedUnit * centre);
  threshold_ = std::max(1, static_cast<int>(std::ceil(kMatchedUnit * p.matched_detect_snr * sigma)));
  matched_peak_ = std::max(threshold_, static_cast<int>(std::ceil(kMatchedUnit * p.matched_peak_snr * sigma)));
}

MatchedNoise FramePlanes::sampledNoise(const cv::Mat& smooth)
{
  std::vector<float>& sample = noise_sample_;  // kept: 256 kB a frame otherwise
  sample.clear();
  for (int gy = 0; gy < grid_rows_; gy += 4)
  {
    const float* row = smooth.ptr<float>(gy);
    for (int gx = 0; gx < grid_cols_; gx += 4)
      sample.push_back(row[gx]);
  }
  // The medians of 65536 cells by bracketing (medianOfMany): the same values as nth_element's.
  const float centre = detail::medianOfMany(&sample, &noise_scratch_);
  for (float& v : sample)
    v = std::abs(v - centre);
  MatchedNoise noise;
  noise.centre = centre;
  // At least a tenth of a DN: a noise-free frame must not make every cell a candidate.
  noise.sigma = std::max(0.1, 1.4826 * detail::medianOfMany(&sample, &noise_scratch_));
  noise.valid = true;
  return noise;
}

// ---------------------------------------------------------------------------
// Cells.

FramePlanes::Triple FramePlanes::cellAt(const cv::Mat& m, int gx, int gy) const
{
  Triple t;
  pixels::decodeCell(m, format_, gx, gy, t.c);
  return t;
}

int FramePlanes::colourScore(const Triple& t) const
{
  const int s = t.c[model_.signal], r = t.c[model_.reference], b = t.c[model_.third];
  return s - std::max((k_ref_ * r) >> 8, (k_third_ * b) >> 8);
}

int FramePlanes::intensity(const Triple& t) const
{
  return pixels::intensity16(format_, t.c);
}

int FramePlanes::levelOf(int gx, int gy) const
{
  return block_level_.at<int>(gy / kBlock, gx / kBlock);
}

int FramePlanes::thresholdOf(int gx, int gy) const
{
  return model_.colour && !local_ ? threshold_ : block_threshold_.at<int>(gy / kBlock, gx / kBlock);
}

int FramePlanes::cellScore(int gx, int gy) const
{
  if (matchedPath())
    return matched_.at<int16_t>(gy, gx);
  if (local_)
    return localScore(gx, gy);
  if (ambient_.empty())  // the hot paths: a colour camera's bgr8, a mono camera's mono8
  {
    if (format_ == PixelFormat::kMono8)
      return 16 * image_.ptr<uint8_t>(gy)[gx] - levelOf(gx, gy);
    if (format_ == PixelFormat::kBgr8 && model_.colour)
    {
      const uint8_t* px = image_.ptr<uint8_t>(gy) + 3 * gx;
      return colourScore(Triple{{px[2], px[1], px[0]}});
    }
  }
  Triple t = cellAt(image_, gx, gy);
  if (model_.colour)
  {
    if (!ambient_.empty())
    {
      const Triple a = cellAt(ambient_, gx, gy);
      for (int k = 0; k < 3; ++k)
        t.c[k] = std::max(0, t.c[k] - a.c[k]);
    }
    return colourScore(t);
  }
  int v = intensity(t);
  if (!ambient_.empty())
    v -= intensity(cellAt(ambient_, gx, gy));
  return v - levelOf(gx, gy);
}

int FramePlanes::scoreAt(int gx, int gy) const
{
  if (gx < 0 || gy < 0 || gx >= grid_cols_ || gy >= grid_rows_)
    return -1;
  return cellScore(gx, gy);
}

void FramePlanes::scoreRun(int gy, int gx0, int gx1, int* out) const
{
  if (local_)
  {
    const int16_t* s = local_scores_.ptr<int16_t>(gy);
    const int16_t* bg = local_background_.ptr<int16_t>(gy / 4);
    for (int gx = gx0; gx <= gx1; ++gx)
      *out++ = s[gx] - bg[gx / 4];
    return;
  }
  if (!matchedPath() && ambient_.empty() && format_ == PixelFormat::kBgr8 && model_.colour)
  {
    const uint8_t* px = image_.ptr<uint8_t>(gy) + 3 * gx0;
    for (int gx = gx0; gx <= gx1; ++gx, px += 3)
      *out++ = colourScore(Triple{{px[2], px[1], px[0]}});
    return;
  }
  if (!matchedPath() && ambient_.empty() && format_ == PixelFormat::kMono8)
  {
    const uint8_t* px = image_.ptr<uint8_t>(gy);
    const int* level = block_level_.ptr<int>(gy / kBlock);  // levelOf's row
    for (int gx = gx0; gx <= gx1; ++gx)
      *out++ = 16 * px[gx] - level[gx / kBlock];
    return;
  }
  for (int gx = gx0; gx <= gx1; ++gx)
    *out++ = cellScore(gx, gy);
}

// ---------------------------------------------------------------------------
// Rows of the threshold pass.

// Any format and path: the SIMD score rows where rows::colourScoreRow serves
// the format, else one row decoded into channel arrays (a switch per
// row, simple loops per cell), scored, compared.
void FramePlanes::scoreRow(int gy, int16_t* out) const
{
  if (local_)
  {
    const int16_t* s = local_scores_.ptr<int16_t>(gy);
    const int16_t* bg = local_background_.ptr<int16_t>(gy / 4);
    for (int gx = 0; gx < grid_cols_; ++gx)
      out[gx] = static_cast<int16_t>(std::min(32767, std::max(-32768, s[gx] - bg[gx / 4])));
    return;
  }
  if (model_.colour && rows::colourScoreRow(image_, ambient_, format_, model_, k_ref_, k_third_, gy, out))
    return;  // the SIMD rows of the common formats, the same values
  const int n = grid_cols_;
  std::vector<int>& c = decoded_;  // scratch kept across rows and frames
  std::vector<int>& a = decoded_ambient_;
  if (!model_.colour)
  {
    // Intensity path: the row's intensities less the ambient's, less the
    // background of each block, block by block.
    c.resize(static_cast<size_t>(n));
    intensityRow(image_, gy, c.data());
    if (!ambient_.empty())
    {
      a.resize(static_cast<size_t>(n));
      intensityRow(ambient_, gy, a.data());
      for (int gx = 0; gx < n; ++gx)
        c[gx] -= a[gx];
    }
    const int* level = block_level_.ptr<int>(gy / kBlock);
    for (int x0 = 0; x0 < n; x0 += kBlock)
    {
      const int lv = level[x0 / kBlock], x1 = std::min(n, x0 + kBlock);
      for (int gx = x0; gx < x1; ++gx)
        out[gx] = static_cast<int16_t>(std::min(32767, std::max(-32768, c[gx] - lv)));
    }
    return;
  }
  c.resize(3 * static_cast<size_t>(n));
  a.clear();
  pixels::decodeRow(image_, format_, gy, n, c.data());
  if (!ambient_.empty())
  {
    a.resize(c.size());
    pixels::decodeRow(ambient_, format_, gy, n, a.data());
  }
  for (int gx = 0; gx < n; ++gx)
  {
    Triple t{{c[3 * gx], c[3 * gx + 1], c[3 * gx + 2]}};
    if (!a.empty())
      for (int k = 0; k < 3; ++k)
        t.c[k] = std::max(0, t.c[k] - a[3 * gx + k]);
    out[gx] = static_cast<int16_t>(std::min(32767, std::max(-32768, colourScore(t))));
  }
}

// The intensity (1/16 DN) of every cell of row gy of m (the frame's format).
void FramePlanes::intensityRow(const cv::Mat& m, int gy, int* out) const
{
  const int n = grid_cols_;
  if (format_ == PixelFormat::kMono8)
  {
    const uint8_t* px = m.ptr<uint8_t>(gy);
    for (int gx = 0; gx < n; ++gx)
      out[gx] = 16 * px[gx];
    return;
  }
  std::vector<int>& t = decoded_triples_;
  t.resize(3 * static_cast<size_t>(n));
  pixels::decodeRow(m, format_, gy, n, t.data());
  for (int gx = 0; gx < n; ++gx)
    out[gx] = pixels::intensity16(format_, &t[3 * static_cast<size_t>(gx)]);
}

void FramePlanes::rowRuns(int gy, std::vector<Run>* runs, uint16_t* acc)
{
  if (matchedPath())
  {
    const int16_t* m = matched_.ptr<int16_t>(gy);
    for (int gx = 0; gx < grid_cols_; ++gx)
      if (m[gx] >= threshold_)
        rows::markCell(runs, gy, gx);
    return;
  }
  if (local_)
  {
    // Raw scores against each bin's threshold (the background in it), the
    // rows of the bins expanded to cells once per bin row; 16 cells at a
    // time where none passes.
    if (gy % 4 == 0 || local_row_ != gy / 4)
    {
      local_row_ = gy / 4;
      local_thr_.resize(static_cast<size_t>(grid_cols_));
      local_bg_.resize(static_cast<size_t>(grid_cols_));
      const int* thr = bin_threshold_.ptr<int>(local_row_);
      const int16_t* bg = local_background_.ptr<int16_t>(local_row_);
      for (int gx = 0; gx < grid_cols_; ++gx)
      {
        local_thr_[gx] = static_cast<int16_t>(std::min(32767, thr[gx / 4]));
        local_bg_[gx] = bg[gx / 4];
      }
    }
    const int16_t* s = local_scores_.ptr<int16_t>(gy);
    const int16_t* t = local_thr_.data();
    int gx = 0;
    for (; gx + 16 <= grid_cols_; gx += 16)
    {
      int any = 0;
      for (int k = 0; k < 16; ++k)
        any |= s[gx + k] >= t[gx + k];
      if (any)
        for (int k = 0; k < 16; ++k)
          if (s[gx + k] >= t[gx + k])
            rows::markCell(runs, gy, gx + k);
    }
    for (; gx < grid_cols_; ++gx)
      if (s[gx] >= t[gx])
        rows::markCell(runs, gy, gx);
    if (acc)
    {
      const int16_t* bg = local_bg_.data();
      for (int x = 0; x < grid_cols_; ++x)
        acc[x] = static_cast<uint16_t>(acc[x] + std::min(255, std::max(0, s[x] - bg[x])));
    }
    return;
  }
  if (fusedRowRuns(gy, runs, acc))
    return;
  int16_t* s = row_scores_.data();
  scoreRow(gy, s);
  if (acc)
    for (int gx = 0; gx < grid_cols_; ++gx)
      acc[gx] = static_cast<uint16_t>(acc[gx] + std::min(255, std::max(0, int(s[gx]))));
  // The threshold of each block of the row (one for the colour path).
  const int* block_thr = model_.colour && !local_ ? nullptr : block_threshold_.ptr<int>(gy / kBlock);
  for (int x0 = 0; x0 < grid_cols_; x0 += kBlock)
  {
    const int thr = block_thr ? block_thr[x0 / kBlock] : threshold_, x1 = std::min(grid_cols_, x0 + kBlock);
    for (int gx = x0; gx < x1; ++gx)
      if (s[gx] >= thr)
        rows::markCell(runs, gy, gx);
  }
}

bool FramePlanes::fusedRowRuns(int gy, std::vector<Run>* runs, uint16_t* acc)
{
  if (model_.colour)
    return rows::colourRowRuns(image_, ambient_, format_, model_, k_ref_, k_third_, threshold_, gy, runs, acc);
  if (!ambient_.empty())
    return false;
  if (format_ == PixelFormat::kMono8)
  {
    const int* level = block_level_.ptr<int>(gy / kBlock);
    const int* thr = block_threshold_.ptr<int>(gy / kBlock);
    rows::monoRowRuns(image_.ptr<uint8_t>(gy), grid_cols_, gy, kBlock, level, thr, runs);
    return true;
  }
  return false;
}

// ---------------------------------------------------------------------------
// The intensity path's maps.

namespace
{
// 3 x 3 grey-level erosion or dilation of an int map, edges replicated.
cv::Mat filter3x3(const cv::Mat& m, bool min)
{
  cv::Mat out(m.size(), CV_32S);
  for (int y = 0; y < m.rows; ++y)
    for (int x = 0; x < m.cols; ++x)
    {
      int v = m.at<int>(y, x);
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx)
        {
          const int q = m.at<int>(std::min(m.rows - 1, std::max(0, y + dy)), std::min(m.cols - 1, std::max(0, x + dx)));
          v = min ? std::min(v, q) : std::max(v, q);
        }
      out.at<int>(y, x) = v;
    }
  return out;
}
}  // namespace

// Background: an opening (min, then max, over 3 x 3 blocks) of the 16 x 16
// block means, so a dot (which touches at most 2 x 2 blocks) does not raise
// it. Noise: 0.886 x the mean absolute difference of horizontal neighbours
// (two rows per block), the least of 3 x 3 blocks, so neither a dot nor
// texture in one block raises it. Both in 1/16 DN.
void FramePlanes::buildIntensityMaps(const FastParams& p)
{
  const int bc = (grid_cols_ + kBlock - 1) / kBlock, br = (grid_rows_ + kBlock - 1) / kBlock;
  cv::Mat sum(br, bc, CV_64F, cv::Scalar(0)), count(br, bc, CV_64F, cv::Scalar(0));
  cv::Mat diff(br, bc, CV_64F, cv::Scalar(0)), diff_count(br, bc, CV_64F, cv::Scalar(0));
  std::vector<int> v(static_cast<size_t>(grid_cols_)), a;
  for (int gy = 0; gy < grid_rows_; ++gy)
  {
    intensityRow(image_, gy, v.data());
    if (!ambient_.empty())
    {
      a.resize(v.size());
      intensityRow(ambient_, gy, a.data());
      for (int gx = 0; gx < grid_cols_; ++gx)
        v[gx] -= a[gx];
    }
    // Integer sums per block (exact, as the doubles they are added to).
    double* row_sum = sum.ptr<double>(gy / kBlock);
    double* row_count = count.ptr<double>(gy / kBlock);
    for (int x0 = 0, bx = 0; x0 < grid_cols_; x0 += kBlock, ++bx)
    {
      const int x1 = std::min(grid_cols_, x0 + kBlock);
      int64_t block = 0;
      for (int gx = x0; gx < x1; ++gx)
        block += v[gx];
      row_sum[bx] += static_cast<double>(block);
      row_count[bx] += x1 - x0;
    }
    if (gy % (kBlock / 2) != kBlock / 4)
      continue;
    double* row_diff = diff.ptr<double>(gy / kBlock);
    double* row_diff_count = diff_count.ptr<double>(gy / kBlock);
    for (int x0 = 0, bx = 0; x0 + 1 < grid_cols_; x0 += kBlock, ++bx)
    {
      const int x1 = std::min(grid_cols_ - 1, x0 + kBlock);
      int64_t block = 0;
      for (int gx = x0; gx < x1; ++gx)
        block += std::abs(v[gx + 1] - v[gx]);
      row_diff[bx] += static_cast<double>(block);
      row_diff_count[bx] += x1 - x0;
    }
  }
  cv::Mat mean(br, bc, CV_32S), noise(br, bc, CV_32S);
  for (int y = 0; y < br; ++y)
    for (int x = 0; x < bc; ++x)
    {
      mean.at<int>(y, x) = static_cast<int>(std::lround(sum.at<double>(y, x) / std::max(1.0, count.at<double>(y, x))));
      const double d = diff_count.at<double>(y, x) > 0 ? diff.at<double>(y, x) / diff_count.at<double>(y, x) : 1e9;
      noise.at<int>(y, x) = static_cast<int>(std::min(1e9, std::ceil(0.886 * d)));
    }
  block_level_ = filter3x3(filter3x3(mean, true), false);
  noise = filter3x3(noise, true);
  block_threshold_.create(br, bc, CV_32S);
  block_peak_.create(br, bc, CV_32S);
  block_sigma_.create(br, bc, CV_32F);
  const int floor16 = 16 * p.mono_threshold;
  for (int y = 0; y < br; ++y)
    for (int x = 0; x < bc; ++x)
    {
      // At least the 8-bit quantisation's noise (1/16 DN units).
      const double n = std::max(16.0 * 0.29, static_cast<double>(std::min(noise.at<int>(y, x), 16 * 255)));
      block_sigma_.at<float>(y, x) = static_cast<float>(n);
      block_threshold_.at<int>(y, x) = std::max(floor16, static_cast<int>(std::ceil(p.intensity_snr * n)));
      // A blob's peak: intensity_peak_snr local sigmas over the background.
      block_peak_.at<int>(y, x) = std::max(16, static_cast<int>(std::ceil(p.intensity_peak_snr * n)));
    }
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
