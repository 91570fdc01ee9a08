// Stages 1-3 of the fast method: where dots may be (see
// spot_detector_fast_stages.h). Grid coordinates (FramePlanes) up to the
// candidates, which are in pixels of the full frame.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <limits>

#include "detection/fast/stages.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

// ---------------------------------------------------------------------------
// Stage 1: threshold pass.

void ThresholdPass::run(FramePlanes* planes, bool coarse)
{
  runs_.clear();
  const int cols = planes->cols(), rows = planes->rows();
  if (coarse)
  {
    coarse_.create(rows / kBin, cols / kBin, CV_8UC1);
    column_sums_.assign(static_cast<size_t>(cols) + 16, 0);
  }
  for (int y = 0; y < rows; ++y)
  {
    uint16_t* score_row = coarse && y / kBin < coarse_.rows ? column_sums_.data() : nullptr;
    planes->rowRuns(y, &runs_, score_row);
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

// scores: room for the run's cells.
void addRun(const Run& run, const FramePlanes& planes, int* scores, Blob* b)
{
  planes.scoreRun(run.y, run.x0, run.x1, scores);
  for (int x = run.x0; x <= run.x1; ++x)
  {
    const int s = scores[x - run.x0];
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

const std::vector<Blob>& BlobLabeller::label(const std::vector<Run>& runs, const FramePlanes& planes)
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
    scores_.resize(std::max<size_t>(scores_.size(), runs[i].x1 - runs[i].x0 + 1));
    addRun(runs[i], planes, scores_.data(), &blobs_[root_blob_[r]]);
  }
  return blobs_;
}

// ---------------------------------------------------------------------------
// Stage 3: candidates.

void addBlobCandidates(const std::vector<Blob>& blobs, const FastParams& p, const FramePlanes& planes,
                       std::vector<Candidate>* candidates)
{
  const int k = planes.scale();
  const int min_count = std::max(1, p.min_pixels / (k * k));
  for (size_t i = 0; i < blobs.size(); ++i)
  {
    const Blob& b = blobs[i];
    if (b.count < min_count || b.peak < planes.peakThresholdAt(b.peak_x, b.peak_y, p.min_peak) || !(b.sum > 0))
      continue;  // noise: not worth a line in the debug output
    // First guess of sigma from the candidate area: a Gaussian exceeds a
    // threshold within ~2 sigma of its centre for typical peak/threshold ratios.
    const double radius = 0.5 * k * std::max(b.x1 - b.x0 + 1, b.y1 - b.y0 + 1);
    Candidate c{planes.toPixel(b.sx / b.sum),
                planes.toPixel(b.sy / b.sum),
                std::min(std::max(0.5 * radius, 1.0), p.max_sigma_px),
                b.count * k * k,
                k * b.x0,
                k * b.y0,
                k * b.x1 + k - 1,
                k * b.y1 + k - 1};
    c.peak_x = static_cast<int>(std::lround(planes.toPixel(b.peak_x)));
    c.peak_y = static_cast<int>(std::lround(planes.toPixel(b.peak_y)));
    c.blob = static_cast<int>(i);
    c.significance = planes.significance(b.peak_x, b.peak_y, b.peak);
    candidates->push_back(c);
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

int CoarseCandidates::add(const cv::Mat& coarse, int threshold, double max_sigma_px, const FramePlanes& planes,
                          std::vector<Candidate>* candidates)
{
  // Block size in pixels of the full frame (candidates are in pixels).
  const int kBin = ThresholdPass::kBin * planes.scale();
  if (planes.localPath())
    cv::compare(coarse, planes.coarseThresholds(), mask_, cv::CMP_GE);
  else
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
      // A bin's mean has a quarter of a cell's noise.
      const int bin = ThresholdPass::kBin;
      candidates->back().significance =
          planes.significance(static_cast<int>(c.sx / c.sum) * bin, static_cast<int>(c.sy / c.sum) * bin,
                              bin * c.sum / c.area);
    }
  }
  return static_cast<int>(candidates->size() - before);
}

// ---------------------------------------------------------------------------
// Stage 3c: further dots of a blob.

void BlobSplitter::reset(const FramePlanes& planes, const std::vector<Run>& runs, const std::vector<int>& run_blob,
                         const std::vector<Blob>& blobs)
{
  planes_ = &planes;
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
  if (peaks_.size() < blobs.size())
    peaks_.resize(blobs.size());
  peaks_min_.assign(blobs.size(), std::numeric_limits<int>::max());
  for (size_t k = 0; k < blobs.size(); ++k)
    discs_[k].clear();
}

// Discs are kept in grid units; the callers speak pixels of the full frame.
bool BlobSplitter::explained(int blob, double x, double y) const
{
  const double k = planes_->scale(), off = 0.5 * (k - 1);
  const double gx = (x - off) / k, gy = (y - off) / k;
  bool inside = false;
  for (const cv::Vec3d& d : discs_[blob])
    inside = inside || std::hypot(gx - d[0], gy - d[1]) < d[2];
  return inside;
}

// A dot stands out of the blob around it: the median score on a ring of
// `radius` (2 sigma: the frame's dots share a size) is at most half its peak
// g. Noise maxima on a bright rock bridge and points on a dot's flank do not
// (a flank has the dot on one side of its ring); each would cost a
// refinement that leads nowhere or back to a dot already found.
bool BlobSplitter::prominent(int gx, int gy, int g, int radius, int min_peak) const
{
  const int R = radius, Rd = static_cast<int>(std::lround(R * M_SQRT1_2));
  const int ring_dx[8] = {R, -R, 0, 0, Rd, Rd, -Rd, -Rd}, ring_dy[8] = {0, 0, R, -R, Rd, -Rd, Rd, -Rd};
  int v[8];
  for (int k = 0; k < 8; ++k)
    v[k] = std::max(0, planes_->scoreAt(gx + ring_dx[k], gy + ring_dy[k]));
  std::sort(v, v + 8);
  return 2 * g - (v[3] + v[4]) >= 2 * std::max(min_peak, g / 2);
}

// Scores of cells gx0..gx1 of row gy into out[0..]: -1 outside the grid, as scoreAt.
void BlobSplitter::rowScores(int gy, int gx0, int gx1, int* out) const
{
  const int cols = planes_->cols();
  if (gy < 0 || gy >= planes_->rows())
  {
    std::fill(out, out + (gx1 - gx0 + 1), -1);
    return;
  }
  const int a = std::max(gx0, 0), b = std::min(gx1, cols - 1);
  std::fill(out, out + (a - gx0), -1);
  if (a <= b)
    planes_->scoreRun(gy, a, b, out + (a - gx0));
  std::fill(out + (std::max(a, b + 1) - gx0), out + (gx1 - gx0 + 1), -1);
}

const std::vector<BlobSplitter::Peak>& BlobSplitter::peaksOf(int blob, int min_peak)
{
  std::vector<Peak>& peaks = peaks_[blob];
  if (peaks_min_[blob] <= min_peak)
    return peaks;
  peaks.clear();
  for (int ri = run_start_[blob]; ri < run_start_[blob + 1]; ++ri)
  {
    const Run& run = (*runs_)[run_list_[ri]];
    // The run's row and the rows above and below it, one cell wider each side.
    const int n = run.x1 - run.x0 + 3;
    row_scores_.resize(3 * static_cast<size_t>(n));
    int* const above = row_scores_.data();
    int* const row = above + n;
    int* const below = row + n;
    rowScores(run.y, run.x0 - 1, run.x1 + 1, row);
    bool rows_read = false;
    for (int px = run.x0; px <= run.x1; ++px)
    {
      const int k = px - run.x0 + 1, g = row[k];
      if (g < min_peak || row[k - 1] > g || row[k + 1] > g)
        continue;
      if (!rows_read)
      {
        rowScores(run.y - 1, run.x0 - 1, run.x1 + 1, above);
        rowScores(run.y + 1, run.x0 - 1, run.x1 + 1, below);
        rows_read = true;
      }
      if (std::max({above[k - 1], above[k], above[k + 1], below[k - 1], below[k], below[k + 1]}) <= g)
        peaks.push_back({px, run.y, g});
    }
  }
  std::stable_sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) { return a.g > b.g; });
  peaks_min_[blob] = min_peak;
  return peaks;
}

// The strongest prominent local maximum outside the discs, the first in scan
// order among equal scores: the first such in peaksOf's list.
bool BlobSplitter::nextSeed(const Candidate& c, double x, double y, double s, int min_peak, double max_sigma_px,
                            Candidate* seed)
{
  const double k = planes_->scale(), off = 0.5 * (k - 1);
  std::vector<cv::Vec3d>& disc = discs_[c.blob];
  disc.emplace_back((x - off) / k, (y - off) / k, (std::max(3.0 * s, 4.0) + 1.0) / k);
  const Blob& b = (*blobs_)[c.blob];
  // Small blobs are one dot (a cheap early out for nearly every blob).
  if (std::max(b.x1 - b.x0, b.y1 - b.y0) + 1 <= 2 * disc.back()[2] || disc.size() > 8)
    return false;
  const int radius = std::max(2, static_cast<int>(std::lround(2.0 * s / k)));
  int bx = -1, by = -1;
  for (const Peak& p : peaksOf(c.blob, min_peak))
  {
    if (p.g < min_peak)
      break;
    bool inside = false;
    for (const cv::Vec3d& d : disc)
      inside = inside || (p.x - d[0]) * (p.x - d[0]) + (p.y - d[1]) * (p.y - d[1]) < d[2] * d[2];
    if (!inside && prominent(p.x, p.y, p.g, radius, min_peak))
    {
      bx = p.x;
      by = p.y;
      break;
    }
  }
  if (bx < 0)
    return false;
  *seed = c;
  seed->x = planes_->toPixel(bx);
  seed->y = planes_->toPixel(by);
  seed->sigma0 = std::min(std::max(s, 1.0), max_sigma_px);
  seed->peak_x = static_cast<int>(std::lround(seed->x));
  seed->peak_y = static_cast<int>(std::lround(seed->y));
  seed->seed = true;
  return true;
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
