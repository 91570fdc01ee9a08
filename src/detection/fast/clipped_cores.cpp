// Stage 3c: dots with a clipped white core (ClippedCoreFinder, stages.h).
#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "detection/fast/stages.h"
#include "detection/inputs/pixels.h"

namespace structured_light_stabilizer
{
namespace fast_detector
{

namespace
{
constexpr double kHaloErrors = 5.0;
// A spot this close to a core's centroid (the larger of kAgreePx and
// kAgreeRadii core radii) is the Gaussian fit's dot on it; a spot farther
// inside a core is a fit on a piece of the ring around a core wider than a
// Gaussian of max_sigma_px explains.
constexpr double kAgreePx = 2.0, kAgreeRadii = 0.25;
// The cells next to a clipped core carry its white (demosaicking; JPEG's
// chroma at half resolution): the halo is measured beyond this gap. Without
// it, 2 of the 6 red dots of test/data/real failed the colour test
// (reference at 0.73 of the signal).
constexpr int kHaloGap = 1;
// Seeds of cores on every kSeedStep-th cell of every kSeedStep-th row (the
// scan reads those rows of the frame once more, after the threshold pass).
constexpr int kSeedStep = 3;

// Whether any byte of a raw 8-bit row reaches the level: a cheap first look
// (vectorised, at memory speed) that skips rows without a clipped sample of
// any channel.
bool anyByteAtLeast(const uint8_t* p, int n, int level)
{
  constexpr int kChunk = 64;
  int i = 0;
  for (; i + kChunk <= n; i += kChunk)
  {
    uint8_t m = 0;
    for (int j = 0; j < kChunk; ++j)
      m = p[i + j] > m ? p[i + j] : m;
    if (m >= level)
      return true;
  }
  for (; i < n; ++i)
    if (p[i] >= level)
      return true;
  return false;
}

bool interleaved8(PixelFormat f)
{
  return f == PixelFormat::kBgr8 || f == PixelFormat::kRgb8 || f == PixelFormat::kBgra8 || f == PixelFormat::kRgba8;
}

// Per channel: the samples' median (the halo's background, robust to other
// dots and texture in the outer ring).
double median(std::vector<int>* v)
{
  if (v->empty())
    return 0.0;
  const size_t mid = v->size() / 2;
  std::nth_element(v->begin(), v->begin() + static_cast<long>(mid), v->end());
  return (*v)[mid];
}
}  // namespace

void ClippedCoreFinder::bind(const FramePlanes& planes)
{
  planes_ = &planes;
  sat_ = planes.saturation();
  direct_ = interleaved8(planes.format());
  const pixels::Interleaved layout = pixels::interleavedLayout(planes.format());
  const int offsets[3] = {layout.r, layout.g, layout.b};
  bytes_ = layout.bytes;
  offset_ = offsets[planes.model().signal];
}

bool ClippedCoreFinder::clipped(int gx, int gy) const
{
  if (direct_)
    return planes_->image().ptr<uint8_t>(gy)[gx * bytes_ + offset_] >= sat_;
  int rgb[3];
  pixels::decodeCell(planes_->image(), planes_->format(), gx, gy, rgb);
  return rgb[planes_->model().signal] >= sat_;
}

void ClippedCoreFinder::find(const FramePlanes& planes, const FastParams& p, const Spots& spots,
                             std::vector<ClippedCore>* cores)
{
  cores->clear();
  if (!planes.colourPath() || planes.hasAmbient() || planes.cols() < 8 || planes.rows() < 8)
    return;
  bind(planes);
  seedCores();
  mergeCores();
  // The halo test, of the cores on which no Gaussian fit ended.
  for (ClippedCore& c : merged_)
  {
    const double agree = std::max(kAgreePx, kAgreeRadii * c.radius);
    if (std::none_of(spots.begin(), spots.end(),
                     [&](const Spot& s) { return std::hypot(s.x - c.x, s.y - c.y) <= agree; }) &&
        haloPasses(p, &c))
      cores->push_back(c);
  }
}

void ClippedCoreFinder::seedCores()
{
  const FramePlanes& planes = *planes_;
  const int cols = planes.cols(), rows = planes.rows(), k = planes.scale();
  // Kept at the largest frame seen (the tracked regions differ in size
  // every frame); all zero between calls.
  if (visited_.rows < rows || visited_.cols < cols)
    visited_ = cv::Mat::zeros(std::max(rows, visited_.rows), std::max(cols, visited_.cols), CV_8U);
  const cv::Mat& image = planes.image();
  row_.resize(static_cast<size_t>(3 * cols));
  found_.clear();
  touched_.clear();
  constexpr int kSpan = 64 * kSeedStep;  // cells skipped at once where no byte of theirs clips
  for (int gy = 0; gy < rows; gy += kSeedStep)
  {
    // The signal of every kSeedStep-th cell: read straight from 8-bit
    // interleaved rows, else decoded (Bayer rows only where a raw sample
    // clips).
    const uint8_t* raw = image.ptr<uint8_t>(k * gy);
    if (direct_ || isBayer(planes.format()))
    {
      const int n = static_cast<int>(image.cols * image.elemSize());
      if (!anyByteAtLeast(raw, n, sat_) && (k == 1 || !anyByteAtLeast(image.ptr<uint8_t>(k * gy + 1), n, sat_)))
        continue;
    }
    if (!direct_)
      pixels::decodeRow(image, planes.format(), gy, cols, row_.data());
    for (int g0 = 0; g0 < cols; g0 += kSpan)
    {
      if (direct_ && !anyByteAtLeast(raw + g0 * bytes_, std::min(kSpan, cols - g0) * bytes_, sat_))
        continue;
      for (int gx = g0; gx < std::min(cols, g0 + kSpan); gx += kSeedStep)
      {
        const int signal = direct_ ? raw[gx * bytes_ + offset_] : row_[3 * gx + planes.model().signal];
        if (signal >= sat_ && !visited_.at<uint8_t>(gy, gx))
          fillCore(gx, gy);
      }
    }
  }
  for (const cv::Point& c : touched_)
    visited_.at<uint8_t>(c.y, c.x) = 0;
}

void ClippedCoreFinder::fillCore(int gx, int gy)
{
  const FramePlanes& planes = *planes_;
  const int cols = planes.cols(), rows = planes.rows(), k = planes.scale();
  const size_t max_cells = std::max<size_t>(16, static_cast<size_t>(rows) * static_cast<size_t>(cols) / 64);
  // Flood fill of the 8-connected clipped cells.
  cells_.clear();
  stack_.assign(1, cv::Point(gx, gy));
  visited_.at<uint8_t>(gy, gx) = 1;
  touched_.push_back(cv::Point(gx, gy));
  while (!stack_.empty())
  {
    const cv::Point c = stack_.back();
    stack_.pop_back();
    cells_.push_back(c);
    for (int dy = -1; dy <= 1; ++dy)
      for (int dx = -1; dx <= 1; ++dx)
      {
        const int x = c.x + dx, y = c.y + dy;
        if (x < 0 || y < 0 || x >= cols || y >= rows || visited_.at<uint8_t>(y, x))
          continue;
        visited_.at<uint8_t>(y, x) = 1;
        touched_.push_back(cv::Point(x, y));
        if (clipped(x, y))
          stack_.push_back(cv::Point(x, y));
      }
  }
  if (cells_.size() < 3 || cells_.size() > max_cells)
    return;
  double sx = 0, sy = 0;
  int x0 = cols, y0 = rows, x1 = -1, y1 = -1;
  for (const cv::Point& c : cells_)
  {
    sx += c.x;
    sy += c.y;
    x0 = std::min(x0, c.x);
    x1 = std::max(x1, c.x);
    y0 = std::min(y0, c.y);
    y1 = std::max(y1, c.y);
  }
  ClippedCore core;
  const double n = static_cast<double>(cells_.size());
  core.x = planes.toPixel(sx / n);
  core.y = planes.toPixel(sy / n);
  core.pixels = static_cast<int>(cells_.size()) * k * k;
  core.radius = std::sqrt(core.pixels / M_PI);
  core.box = cv::Rect(k * x0, k * y0, k * (x1 - x0 + 1), k * (y1 - y0 + 1));
  found_.push_back(core);
}

// One dot, several cores: merged (area-weighted), the larger first.
void ClippedCoreFinder::mergeCores()
{
  std::sort(found_.begin(), found_.end(),
            [](const ClippedCore& a, const ClippedCore& b) { return a.pixels > b.pixels; });
  merged_.clear();
  for (const ClippedCore& c : found_)
  {
    const auto joins = [&](const ClippedCore& m)
    { return std::hypot(c.x - m.x, c.y - m.y) < std::max(c.radius, m.radius); };
    const auto m = std::find_if(merged_.begin(), merged_.end(), joins);
    if (m == merged_.end())
    {
      merged_.push_back(c);
      continue;
    }
    const double w = static_cast<double>(c.pixels) / (c.pixels + m->pixels);
    m->x += w * (c.x - m->x);
    m->y += w * (c.y - m->y);
    m->pixels += c.pixels;
    m->radius = std::sqrt(m->pixels / M_PI);
    m->box |= c.box;
  }
}

bool ClippedCoreFinder::haloPasses(const FastParams& p, ClippedCore* c)
{
  const FramePlanes& planes = *planes_;
  const ColourModel& model = planes.model();
  const int k = planes.scale();
  // The core's clipped cells around it (other clipped cores in reach count
  // as core too), and its bands (chessboard distance): the halo from
  // kHaloGap to d + kHaloGap cells of the core, the background from 2 d to
  // 4 d beyond the gap.
  const int d = std::max(2, static_cast<int>(std::lround(c->radius / (4.0 * k))));
  const int D = 4 * d + kHaloGap + 1;
  const cv::Rect roi = cv::Rect(c->box.x / k - D, c->box.y / k - D, (c->box.width + k - 1) / k + 2 * D,
                                (c->box.height + k - 1) / k + 2 * D) &
                       cv::Rect(0, 0, planes.cols(), planes.rows());
  mask_.create(roi.size(), CV_8U);
  for (int y = 0; y < roi.height; ++y)
    for (int x = 0; x < roi.width; ++x)
      mask_.at<uint8_t>(y, x) = clipped(roi.x + x, roi.y + y) ? 255 : 0;
  const auto square = [](int half)
  { return cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * half + 1, 2 * half + 1)); };
  cv::dilate(mask_, inner_, square(kHaloGap));
  cv::dilate(mask_, near_, square(d + kHaloGap));
  cv::dilate(mask_, mid_, square(2 * d + kHaloGap));
  cv::dilate(mask_, far_, square(4 * d + kHaloGap));
  // At most about 8000 samples in all (cells on a lattice of this step).
  const int step = std::max(1, static_cast<int>(std::sqrt(roi.area() / 8000.0)));
  double ring[3] = {0, 0, 0}, ring_ss = 0;  // sums; the signal's sum of squares
  int ring_n = 0;
  for (auto& s : samples_)
    s.clear();
  for (int y = 0; y < roi.height; y += step)
    for (int x = 0; x < roi.width; x += step)
    {
      const bool in_ring = near_.at<uint8_t>(y, x) && !inner_.at<uint8_t>(y, x);
      const bool in_bg = far_.at<uint8_t>(y, x) && !mid_.at<uint8_t>(y, x);
      if (!in_ring && !in_bg)
        continue;
      int rgb[3];
      pixels::decodeCell(planes.image(), planes.format(), roi.x + x, roi.y + y, rgb);
      for (int ch = 0; ch < 3; ++ch)
      {
        if (in_ring)
          ring[ch] += rgb[ch];
        else
          samples_[ch].push_back(rgb[ch]);
      }
      if (in_ring)
      {
        ++ring_n;
        ring_ss += static_cast<double>(rgb[model.signal]) * rgb[model.signal];
      }
    }
  if (ring_n < 4 || samples_[0].size() < 4)
    return false;
  // The signal's excess must also stand kHaloErrors standard errors above
  // chance (a speck of clipped noise has a ring of a few noisy samples).
  const std::vector<int>& bg = samples_[model.signal];
  double bg_mean = 0, bg_ss = 0;
  for (int v : bg)
  {
    bg_mean += v;
    bg_ss += static_cast<double>(v) * v;
  }
  bg_mean /= static_cast<double>(bg.size());
  const double bg_var = std::max(0.0, bg_ss / static_cast<double>(bg.size()) - bg_mean * bg_mean);
  const double ring_mean = ring[model.signal] / ring_n;
  const double ring_var = std::max(0.0, ring_ss / ring_n - ring_mean * ring_mean);
  const double error = std::sqrt(ring_var / ring_n + bg_var / static_cast<double>(bg.size()));
  for (int ch = 0; ch < 3; ++ch)
    c->excess[ch] = ring[ch] / ring_n - median(&samples_[ch]);
  const double es = c->excess[model.signal];
  c->halo = es;
  const double ref = c->excess[model.reference], third = c->excess[model.third];
  const double max_red_excess = p.colour_test.max_red_excess;
  const bool ref_ok =
      max_red_excess > 0 ? ref <= (model.led_reference + max_red_excess) * es : model.reference_weight * ref <= es;
  return es >= p.min_peak && es >= kHaloErrors * error && ref_ok && third <= es;
}

}  // namespace fast_detector
}  // namespace structured_light_stabilizer
