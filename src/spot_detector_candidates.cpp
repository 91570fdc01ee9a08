// Stages 1-3 of the fast method: where dots may be (see
// spot_detector_fast_stages.h).
#include <algorithm>
#include <cmath>

#include <opencv2/core/hal/intrin.hpp>

#include "spot_detector_fast_stages.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

PixelScore::PixelScore(PixelFormat format, double red_weight)
  : layout(layoutOf(format)),
    k256(static_cast<int>(std::lround(red_weight * 256.0))),
    mono(format == PixelFormat::kMono8)
{
}

// ---------------------------------------------------------------------------
// Stage 1: threshold pass.

namespace
{
inline void markPixel(std::vector<Run>* runs, int y, int x)
{
  if (!runs->empty() && runs->back().y == y && runs->back().x1 == x - 1)
    runs->back().x1 = x;
  else
    runs->push_back({y, x, x});
}

#if CV_SIMD128
// k * r / 256 for 16 pixels, through 16-bit lanes.
inline cv::v_uint8x16 scaleRed(const cv::v_uint8x16& r, const cv::v_uint16x8& k)
{
  cv::v_uint16x8 lo, hi;
  cv::v_expand(r, lo, hi);
  return cv::v_pack(cv::v_shr<8>(cv::v_mul_wrap(lo, k)), cv::v_shr<8>(cv::v_mul_wrap(hi, k)));
}
#endif

// Candidate pixels of one row, appended as runs. A block of 16 pixels
// without a candidate costs a deinterleaving load, a few multiply/max/
// saturating-subtract operations and one test. kRedFirst: byte 0 is red
// (rgb8, rgba8). acc (may be null) accumulates every pixel's score, for the
// coarse pass.
template <int kChannels, bool kRedFirst>
void rowRuns(const uint8_t* row, int width, int y, int threshold, int k256, std::vector<Run>* runs, uint16_t* acc)
{
  int x = 0;
#if CV_SIMD128
  const cv::v_uint8x16 vthr = cv::v_setall_u8(static_cast<uint8_t>(threshold));
  const cv::v_uint16x8 vk = cv::v_setall_u16(static_cast<uint16_t>(k256));
  alignas(16) uint8_t hit[16];
  for (; x + 16 <= width; x += 16)
  {
    cv::v_uint8x16 s;
    if (kChannels == 1)
    {
      s = cv::v_load(row + x);
    }
    else
    {
      cv::v_uint8x16 c0, c1, c2, c3;
      if (kChannels == 3)
        cv::v_load_deinterleave(row + 3 * x, c0, c1, c2);
      else
        cv::v_load_deinterleave(row + 4 * x, c0, c1, c2, c3);
      const cv::v_uint8x16& r = kRedFirst ? c0 : c2;
      const cv::v_uint8x16& b = kRedFirst ? c2 : c0;
      s = c1 - cv::v_max(scaleRed(r, vk), b);  // saturating
    }
    if (acc)
    {
      cv::v_uint16x8 lo, hi;
      cv::v_expand(s, lo, hi);
      cv::v_store(acc + x, cv::v_load(acc + x) + lo);
      cv::v_store(acc + x + 8, cv::v_load(acc + x + 8) + hi);
    }
    const cv::v_uint8x16 m = s >= vthr;
    if (!cv::v_check_any(m))
      continue;
    cv::v_store(hit, m);
    for (int i = 0; i < 16; ++i)
      if (hit[i])
        markPixel(runs, y, x + i);
  }
#endif
  const PixelLayout L = kRedFirst ? PixelLayout{0, 1, 2, kChannels} : PixelLayout{2, 1, 0, kChannels};
  for (; x < width; ++x)
  {
    const uint8_t* px = row + kChannels * x;
    const int score = kChannels == 1 ? int(px[0]) : greenness(px, L, k256);
    if (acc)
      acc[x] = static_cast<uint16_t>(acc[x] + score);
    if (score >= threshold)
      markPixel(runs, y, x);
  }
}

using RowPass = void (*)(const uint8_t*, int, int, int, int, std::vector<Run>*, uint16_t*);

RowPass rowPassFor(PixelFormat format)
{
  switch (format)
  {
    case PixelFormat::kBgr8:
      return &rowRuns<3, false>;
    case PixelFormat::kRgb8:
      return &rowRuns<3, true>;
    case PixelFormat::kBgra8:
      return &rowRuns<4, false>;
    case PixelFormat::kRgba8:
      return &rowRuns<4, true>;
    case PixelFormat::kMono8:
      break;
  }
  return &rowRuns<1, false>;
}
}  // namespace

void ThresholdPass::run(const cv::Mat& image, PixelFormat format, int threshold, int k256, bool coarse)
{
  runs_.clear();
  if (coarse)
  {
    coarse_.create(image.rows / kBin, image.cols / kBin, CV_8UC1);
    column_sums_.assign(static_cast<size_t>(image.cols) + 16, 0);
  }
  const RowPass row_pass = rowPassFor(format);
  for (int y = 0; y < image.rows; ++y)
  {
    uint16_t* score_row = coarse && y / kBin < coarse_.rows ? column_sums_.data() : nullptr;
    row_pass(image.ptr<uint8_t>(y), image.cols, y, threshold, k256, &runs_, score_row);
    if (score_row && y % kBin == kBin - 1)
    {
      uint8_t* out = coarse_.ptr<uint8_t>(y / kBin);
      uint16_t* a = column_sums_.data();
      for (int i = 0; i < coarse_.cols; ++i, a += kBin)
        out[i] = static_cast<uint8_t>((a[0] + a[1] + a[2] + a[3] + kBin * kBin / 2) / (kBin * kBin));
      std::fill(column_sums_.begin(), column_sums_.end(), 0);
    }
  }
}

// ---------------------------------------------------------------------------
// Stage 2: runs -> blobs.

namespace
{
int findRoot(std::vector<int>& parent, int i)
{
  while (parent[i] != i)
  {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

// Joins the runs of one row [begin, end) with the touching runs (8-connected)
// of the row above, [prev_begin, prev_end). Both are sorted by x0.
void joinRows(const std::vector<Run>& runs, int prev_begin, int prev_end, int begin, int end, std::vector<int>* parent)
{
  int j = prev_begin;
  for (int k = begin; k < end; ++k)
  {
    while (j < prev_end && runs[j].x1 < runs[k].x0 - 1)
      ++j;
    for (int m = j; m < prev_end && runs[m].x0 <= runs[k].x1 + 1; ++m)
    {
      const int a = findRoot(*parent, k), b = findRoot(*parent, m);
      if (a != b)
        (*parent)[std::max(a, b)] = std::min(a, b);
    }
  }
}

void addRun(const Run& run, const cv::Mat& image, const PixelScore& score, Blob* b)
{
  const uint8_t* row = image.ptr<uint8_t>(run.y);
  for (int x = run.x0; x <= run.x1; ++x)
  {
    const int s = score.at(row + x * score.layout.step);
    ++b->count;
    b->sum += s;
    b->sx += double(s) * x;
    b->sy += double(s) * run.y;
    if (s > b->peak)
    {
      b->peak = s;
      b->peak_x = x;
      b->peak_y = run.y;
    }
  }
  b->x0 = std::min(b->x0, run.x0);
  b->x1 = std::max(b->x1, run.x1);
  b->y0 = std::min(b->y0, run.y);
  b->y1 = std::max(b->y1, run.y);
}
}  // namespace

const std::vector<Blob>& BlobLabeller::label(const std::vector<Run>& runs, const cv::Mat& image,
                                             const PixelScore& score)
{
  const int n = static_cast<int>(runs.size());
  parent_.resize(n);
  for (int i = 0; i < n; ++i)
    parent_[i] = i;
  int prev_begin = 0, prev_end = 0;
  for (int i = 0; i < n;)
  {
    const int y = runs[i].y;
    int row_end = i;
    while (row_end < n && runs[row_end].y == y)
      ++row_end;
    if (prev_end > prev_begin && runs[prev_begin].y == y - 1)
      joinRows(runs, prev_begin, prev_end, i, row_end, &parent_);
    prev_begin = i;
    prev_end = row_end;
    i = row_end;
  }
  root_blob_.assign(n, -1);
  run_blob_.resize(n);
  blobs_.clear();
  for (int i = 0; i < n; ++i)
  {
    const int r = findRoot(parent_, i);
    if (root_blob_[r] < 0)
    {
      root_blob_[r] = static_cast<int>(blobs_.size());
      blobs_.emplace_back();
    }
    run_blob_[i] = root_blob_[r];
    addRun(runs[i], image, score, &blobs_[root_blob_[r]]);
  }
  return blobs_;
}

// ---------------------------------------------------------------------------
// Stage 3: candidates.

void addBlobCandidates(const std::vector<Blob>& blobs, const FastParams& p, bool mono,
                       std::vector<Candidate>* candidates)
{
  for (size_t k = 0; k < blobs.size(); ++k)
  {
    const Blob& b = blobs[k];
    if (b.count < p.min_pixels || (!mono && b.peak < p.min_peak) || !(b.sum > 0))
      continue;  // noise: not worth a line in the debug output
    // First guess of sigma from the candidate area: a Gaussian exceeds a
    // threshold within ~2 sigma of its centre for typical peak/threshold ratios.
    const double radius = 0.5 * std::max(b.x1 - b.x0 + 1, b.y1 - b.y0 + 1);
    candidates->push_back({b.sx / b.sum, b.sy / b.sum, std::min(std::max(0.5 * radius, 1.0), p.max_sigma_px), b.count,
                           b.x0, b.y0, b.x1, b.y1, b.peak_x, b.peak_y, static_cast<int>(k)});
  }
}

namespace
{
// Moments and bounds of one 8-connected region of the coarse mask, in cells.
struct CellRegion
{
  double sum = 0, sx = 0, sy = 0;
  int area = 0, x0, x1, y0, y1;
};

// Flood fill from (x, y) (set in mask, cleared on the way): cheaper than a
// labelling pass that writes a label per cell, as the mask is nearly empty.
CellRegion floodCells(const cv::Mat& coarse, cv::Mat* mask, int x, int y, std::vector<cv::Point>* stack)
{
  CellRegion c;
  c.x0 = c.x1 = x;
  c.y0 = c.y1 = y;
  stack->assign(1, cv::Point(x, y));
  mask->at<uint8_t>(y, x) = 0;
  while (!stack->empty())
  {
    const cv::Point q = stack->back();
    stack->pop_back();
    const double w = coarse.at<uint8_t>(q.y, q.x);
    c.sum += w;
    c.sx += w * q.x;
    c.sy += w * q.y;
    ++c.area;
    c.x0 = std::min(c.x0, q.x);
    c.x1 = std::max(c.x1, q.x);
    c.y0 = std::min(c.y0, q.y);
    c.y1 = std::max(c.y1, q.y);
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
      {
        const int nx = q.x + dx, ny = q.y + dy;
        if (nx >= 0 && ny >= 0 && nx < mask->cols && ny < mask->rows && mask->at<uint8_t>(ny, nx))
        {
          mask->at<uint8_t>(ny, nx) = 0;
          stack->emplace_back(nx, ny);
        }
      }
  }
  return c;
}
}  // namespace

int CoarseCandidates::add(const cv::Mat& coarse, int threshold, double max_sigma_px, std::vector<Candidate>* candidates)
{
  constexpr int kBin = ThresholdPass::kBin;
  cv::compare(coarse, cv::Scalar(threshold), mask_, cv::CMP_GE);
  // Cells already explained by a full-resolution candidate are skipped.
  for (const Candidate& c : *candidates)
  {
    const cv::Rect cells(c.x0 / kBin - 1, c.y0 / kBin - 1, c.x1 / kBin - c.x0 / kBin + 3,
                         c.y1 / kBin - c.y0 / kBin + 3);
    mask_(cells & cv::Rect(0, 0, mask_.cols, mask_.rows)).setTo(0);
  }
  const size_t before = candidates->size();
  for (int y = 0; y < mask_.rows; ++y)
  {
    const uint8_t* row = mask_.ptr<uint8_t>(y);
    for (int x = 0; x < mask_.cols; ++x)
    {
      if (!row[x])
        continue;
      const CellRegion c = floodCells(coarse, &mask_, x, y, &stack_);
      const double cx = (c.sx / c.sum + 0.5) * kBin - 0.5, cy = (c.sy / c.sum + 0.5) * kBin - 0.5;
      const double extent = kBin * std::max(c.x1 - c.x0 + 1, c.y1 - c.y0 + 1);
      candidates->push_back({cx, cy, std::min(std::max(0.25 * extent, 1.5), max_sigma_px), c.area * kBin * kBin,
                             (c.x0 - 1) * kBin, (c.y0 - 1) * kBin, (c.x1 + 2) * kBin, (c.y1 + 2) * kBin, -1, -1, -1});
    }
  }
  return static_cast<int>(candidates->size() - before);
}

// ---------------------------------------------------------------------------
// Stage 3c: further dots of a blob.

void BlobSplitter::reset(const cv::Mat& image, const PixelScore& score, const std::vector<Run>& runs,
                         const std::vector<int>& run_blob, const std::vector<Blob>& blobs)
{
  image_ = &image;
  score_ = &score;
  runs_ = &runs;
  blobs_ = &blobs;
  const int n = static_cast<int>(runs.size());
  run_start_.assign(blobs.size() + 2, 0);
  for (int i = 0; i < n; ++i)
    ++run_start_[run_blob[i] + 2];
  for (size_t k = 1; k <= blobs.size(); ++k)
    run_start_[k + 1] += run_start_[k];
  run_list_.resize(n);
  for (int i = 0; i < n; ++i)
    run_list_[run_start_[run_blob[i] + 1]++] = i;  // run_start_[k] ends as blob k's first run
  if (discs_.size() < blobs.size())
    discs_.resize(blobs.size());
  for (size_t k = 0; k < blobs.size(); ++k)
    discs_[k].clear();
}

bool BlobSplitter::explained(int blob, double x, double y) const
{
  bool inside = false;
  for (const cv::Vec3d& d : discs_[blob])
    inside = inside || std::hypot(x - d[0], y - d[1]) < d[2];
  return inside;
}

// A dot stands out of the blob around it: the median greenness on a ring of
// `radius` (2 sigma: the frame's dots share a size) is at most half its peak
// g. Noise maxima on a bright rock bridge and points on a dot's flank do not
// (a flank has the dot on one side of its ring); each would cost a
// refinement that leads nowhere or back to a dot already found.
bool BlobSplitter::prominent(int x, int y, int g, int radius, int min_peak) const
{
  const int R = radius, Rd = static_cast<int>(std::lround(R * M_SQRT1_2));
  const int ring_dx[8] = {R, -R, 0, 0, Rd, Rd, -Rd, -Rd}, ring_dy[8] = {0, 0, R, -R, Rd, -Rd, Rd, -Rd};
  int v[8];
  for (int k = 0; k < 8; ++k)
    v[k] = std::max(0, score_->greennessAt(*image_, x + ring_dx[k], y + ring_dy[k]));
  std::sort(v, v + 8);
  return 2 * g - (v[3] + v[4]) >= 2 * std::max(min_peak, g / 2);
}

bool BlobSplitter::nextSeed(const Candidate& c, double x, double y, double s, int min_peak, double max_sigma_px,
                            Candidate* seed)
{
  std::vector<cv::Vec3d>& disc = discs_[c.blob];
  disc.emplace_back(x, y, std::max(3.0 * s, 4.0) + 1.0);
  const Blob& b = (*blobs_)[c.blob];
  // Small blobs are one dot (a cheap early out for nearly every blob).
  if (std::max(b.x1 - b.x0, b.y1 - b.y0) + 1 <= 2 * disc.back()[2] || disc.size() > 8)
    return false;
  const int radius = std::max(2, static_cast<int>(std::lround(2.0 * s)));
  int best = min_peak - 1, bx = -1, by = -1;
  for (int ri = run_start_[c.blob]; ri < run_start_[c.blob + 1]; ++ri)
  {
    const Run& run = (*runs_)[run_list_[ri]];
    for (int px = run.x0; px <= run.x1; ++px)
    {
      bool inside = false;
      for (const cv::Vec3d& d : disc)
        inside = inside || (px - d[0]) * (px - d[0]) + (run.y - d[1]) * (run.y - d[1]) < d[2] * d[2];
      if (inside)
        continue;
      const int g = score_->greennessAt(*image_, px, run.y);
      if (g <= best)
        continue;
      bool local_max = true;
      for (int dy = -1; dy <= 1 && local_max; ++dy)
        for (int dx = -1; dx <= 1 && local_max; ++dx)
          local_max = (dx == 0 && dy == 0) || score_->greennessAt(*image_, px + dx, run.y + dy) <= g;
      if (local_max && prominent(px, run.y, g, radius, min_peak))
      {
        best = g;
        bx = px;
        by = run.y;
      }
    }
  }
  if (bx < 0)
    return false;
  *seed = c;
  seed->x = bx;
  seed->y = by;
  seed->sigma0 = std::min(std::max(s, 1.0), max_sigma_px);
  seed->peak_x = bx;
  seed->peak_y = by;
  seed->seed = true;
  return true;
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
