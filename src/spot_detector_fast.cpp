// SpotMethod::kFast: the stages of spot_detector_fast_stages.h chained, and
// the decisions on their results: which refined candidates are dots
// (acceptance tests), which of them are the same dot (de-duplication), and
// which disagree with the rest of the frame (frame checks).
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "structured_light_stabilizer/detail/math.h"
#include "spot_detector_fast_stages.h"

namespace structured_light_stabilizer
{

namespace
{
using namespace fast_detector;

// A refined candidate that passed the acceptance tests.
struct KeptSpot
{
  SpotFit fit;
  int pixels;  // candidate pixels behind it
};

void reject(SpotDetectorDebug* debug, double x, double y, const std::string& why)
{
  if (debug)
    debug->rejected.push_back({x, y, why});
}

class FastMethod : public SpotDetectionMethod
{
public:
  SpotDetectionResult detect(const cv::Mat& image, PixelFormat format, const SpotDetectorParams& params,
                             SpotDetectorDebug* debug, SpotDetectorTimings* timings) override;

private:
  void findCandidates(const cv::Mat& image, PixelFormat format, const FastParams& p, const PixelScore& score,
                      SpotDetectorDebug* debug, SpotDetectorTimings* tm, StageTimer* timer);
  std::vector<KeptSpot> refineCandidates(const cv::Mat& image, const FastParams& p, const PixelScore& score,
                                         SpotDetectorDebug* debug);

  // Scratch reused across frames (no per-frame allocation in the hot path).
  ThresholdPass threshold_pass_;
  BlobLabeller labeller_;
  CoarseCandidates coarse_;
  BlobSplitter splitter_;
  std::vector<Candidate> candidates_;
};

// ---------------------------------------------------------------------------
// Acceptance tests of one refined candidate.

// Fits the candidate; false when no fit stands. A dot on a green-ish
// pedestal (an olive mineral, a neighbour's flank) grows the adaptive window
// over the pedestal: then the fit is retried from the strongest pixel in a
// small fixed window, whose border lies on the pedestal and subtracts it.
bool fitCandidate(const cv::Mat& image, const Candidate& c, const FastParams& p, const PixelScore& score, SpotFit* fit)
{
  const PixelLayout& L = score.layout;
  const int red_ch = score.mono || !p.subtract_rock_texture ? -1 : L.r;
  bool ok = refineSpot(image, L.step, L.g, red_ch, c.x, c.y, c.sigma0, p.window_radius_px, p.max_sigma_px, fit);
  if ((!ok || fit->sigma > p.max_sigma_px) && c.peak_x >= 0 && p.window_radius_px == 0)
  {
    SpotFit retry;
    // Only a real peak on the pedestal counts.
    if (refineSpot(image, L.step, L.g, red_ch, c.peak_x, c.peak_y, 1.5, 5, p.max_sigma_px, &retry) &&
        gaussianAmplitude(retry) >= p.min_peak)
    {
      *fit = retry;
      fit->on_pedestal = true;
      ok = true;
    }
  }
  return ok;
}

// The colour test (ColourTestParams); empty when the colour is the LED's.
std::string colourRejection(const SpotFit& r, const ColourTestParams& p)
{
  // The red test sees the rock texture as much as the spot: off by default.
  // Red above the LED's: olive and yellow minerals (R = G) carry their own
  // red; the slack covers what rock texture alone can add.
  bool red_bad = p.max_red_excess > 0 && r.red_ratio > p.led_red_ratio + p.max_red_excess + r.red_slack;
  red_bad = red_bad || (p.max_red_deficit > 0 && r.red_ratio < p.led_red_ratio - p.max_red_deficit - r.red_slack);
  // A spot on a pedestal is suspect: the pedestal is often an olive or
  // yellow mineral, whose own red shows up as extra red excess.
  red_bad = red_bad || (r.on_pedestal && std::abs(r.red_ratio - p.led_red_ratio) > p.max_chroma_error);
  if (!std::isfinite(r.blue_ratio) || red_bad || std::abs(r.blue_ratio - p.led_blue_ratio) > p.max_chroma_error)
    return "colour: red/green " + std::to_string(r.red_ratio) + ", blue/green " + std::to_string(r.blue_ratio);
  return std::string();
}

// Why a fitted candidate is not a dot; empty when it is. Sets r->clipped and
// the colour ratios.
std::string spotRejection(const cv::Mat& image, const Candidate& c, const FastParams& p, const PixelScore& score,
                          SpotFit* r)
{
  if (r->sigma < p.min_sigma_px || r->sigma > p.max_sigma_px)
    return "sigma " + std::to_string(r->sigma) + " px out of range";
  // A clipped core carries no colour, and its unclipped flanks too little
  // excess to judge by: the green ring that made the blob vouches for it.
  const PixelLayout& L = score.layout;
  const uint8_t* core =
      image.ptr<uint8_t>(static_cast<int>(std::lround(r->y))) + static_cast<int>(std::lround(r->x)) * L.step;
  const bool clipped =
      core[L.r] >= p.saturation_level || core[L.g] >= p.saturation_level || core[L.b] >= p.saturation_level;
  // The fit's weight channel clipped (red alone clips on bright sunlit rock
  // and leaves the dot's shape intact).
  r->clipped = core[L.g] >= p.saturation_level;
  if (!score.mono && !clipped)
  {
    const ColourTestParams& colour = p.colour_test;
    measureColour(image, L, p.saturation_level, colour.led_red_ratio, colour.led_blue_ratio, r);
    std::string why = colourRejection(*r, colour);
    if (!why.empty())
      return why;
  }
  // The centroid must stay on its blob: a refinement that wandered off to a
  // neighbour is not this blob's dot.
  if (r->x < c.x0 - 2 || r->x > c.x1 + 2 || r->y < c.y0 - 2 || r->y > c.y1 + 2)
    return "refinement left its blob";
  return std::string();
}

// ---------------------------------------------------------------------------
// De-duplication and frame checks.

// A dot whose saturated core splits its candidate ring into pieces gives
// several blobs that refine to the same centre: the strongest is kept, the
// others are marked in the returned vector.
std::vector<char> markDuplicates(const std::vector<KeptSpot>& kept)
{
  std::vector<size_t> order(kept.size());
  for (size_t i = 0; i < order.size(); ++i)
    order[i] = i;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return kept[a].fit.flux > kept[b].fit.flux; });
  std::vector<char> drop(kept.size(), 0);
  for (size_t i = 0; i < order.size(); ++i)
  {
    if (drop[order[i]])
      continue;
    const SpotFit& a = kept[order[i]].fit;
    for (size_t j = i + 1; j < order.size(); ++j)
    {
      const SpotFit& b = kept[order[j]].fit;
      const double lim = std::max(2.0, 1.5 * std::max(a.sigma, b.sigma));
      if (std::hypot(a.x - b.x, a.y - b.y) < lim)
        drop[order[j]] = 1;
    }
  }
  return drop;
}

// Peak contrast and energy relative to the local background. The +4 DN
// keeps both finite at night (no background) without letting noise in the
// background decide.
double contrast(const SpotFit& r)
{
  return gaussianAmplitude(r) / (std::max(0.0, r.background) + 4.0);
}

double energy(const SpotFit& r)
{
  return r.flux / (std::max(0.0, r.background) + 4.0);
}

// The frame's medians of sigma, contrast and energy (upper medians). A
// clipped core widens the fitted sigma and shortens the flux: the medians
// come from unclipped spots when there are enough of them (skip_clipped),
// and clipped spots then skip the size and energy tests.
struct FrameMedians
{
  double sigma = 0, contrast = 0, energy = 0;
  bool skip_clipped = false;
};

FrameMedians frameMedians(const std::vector<KeptSpot>& kept, const std::vector<size_t>& alive)
{
  FrameMedians m;
  int unclipped = 0;
  for (size_t i : alive)
    unclipped += kept[i].fit.clipped ? 0 : 1;
  m.skip_clipped = unclipped >= 3;
  std::vector<double> sig, con, ene;
  for (size_t i : alive)
  {
    if (m.skip_clipped && kept[i].fit.clipped)
      continue;
    sig.push_back(kept[i].fit.sigma);
    con.push_back(contrast(kept[i].fit));
    ene.push_back(energy(kept[i].fit));
  }
  m.sigma = detail::medianInPlace(sig.begin(), sig.end());
  m.contrast = detail::medianInPlace(con.begin(), con.end());
  m.energy = std::max(1e-9, detail::medianInPlace(ene.begin(), ene.end()));
  return m;
}

// Why a spot disagrees with the frame (FrameCheckParams); empty when it fits.
std::string frameRejection(const SpotFit& r, const FrameMedians& med, const FrameCheckParams& p)
{
  const bool shape_known = !(med.skip_clipped && r.clipped);
  const double sr = r.sigma / med.sigma, er = energy(r) / med.energy;
  // A dot on a slope is foreshortened across the slope only: below the
  // sigma floor, a spot whose long axis keeps the frame's size (at least
  // halfway from the floor to the median) is such a dot; a speck is small
  // both ways (measured: foreshortened dots 0.96-0.97, the closest speck
  // 0.92 of the median, with a mean sigma of 0.88-0.90).
  const bool foreshortened = r.sigma_major / med.sigma >= 0.5 * (1.0 + p.min_sigma_fraction);
  const bool too_small = p.min_sigma_fraction > 0 && sr < p.min_sigma_fraction && !foreshortened;
  const bool off_size =
      (p.size_band_low > 0 && sr < p.size_band_low) || (p.size_band_high > 0 && sr > p.size_band_high);
  const bool off_energy =
      (p.energy_band_low > 0 && er < p.energy_band_low) || (p.energy_band_high > 0 && er > p.energy_band_high);
  if (shape_known && (too_small || (p.max_sigma_factor > 0 && sr > p.max_sigma_factor)))
    return "sigma " + std::to_string(r.sigma) + " px far from the frame's median " + std::to_string(med.sigma);
  if (p.max_contrast_factor > 0 && contrast(r) > p.max_contrast_factor * med.contrast)
    return "contrast " + std::to_string(contrast(r)) + " above " + std::to_string(p.max_contrast_factor) +
           " x the frame's median " + std::to_string(med.contrast);
  if (shape_known && p.min_energy_fraction > 0 && er < p.min_energy_fraction)
    return "energy " + std::to_string(er) + " x the frame's median: not lit by the projector";
  if (shape_known && off_size && off_energy)
    return "both size (" + std::to_string(sr) + ") and energy (" + std::to_string(er) + ") off the frame's medians";
  return std::string();
}

// Frame-level consistency (see FrameCheckParams): outliers from the frame's
// median size and energy are clutter. Marks them in drop; only when enough
// spots survived the de-duplication to make the medians meaningful.
void frameChecks(const std::vector<KeptSpot>& kept, const FrameCheckParams& p, std::vector<char>* drop,
                 SpotDetectorDebug* debug)
{
  std::vector<size_t> alive;
  for (size_t i = 0; i < kept.size(); ++i)
    if (!(*drop)[i])
      alive.push_back(i);
  if (static_cast<int>(alive.size()) < std::max(1, p.consistency_min_spots))
    return;
  const FrameMedians medians = frameMedians(kept, alive);
  for (size_t i : alive)
  {
    const std::string why = frameRejection(kept[i].fit, medians, p);
    if (!why.empty())
    {
      (*drop)[i] = 1;
      reject(debug, kept[i].fit.x, kept[i].fit.y, why);
    }
  }
}

// The spots not dropped, in the order found, and their fits.
Spots survivors(const std::vector<KeptSpot>& kept, const std::vector<char>& drop, std::vector<SpotFit>* fits)
{
  Spots spots;
  for (size_t i = 0; i < kept.size(); ++i)
  {
    if (drop[i])
      continue;
    Spot s;
    s.x = kept[i].fit.x;
    s.y = kept[i].fit.y;
    s.area = static_cast<float>(kept[i].pixels);
    s.intensity = static_cast<float>(kept[i].fit.flux);
    spots.push_back(s);
    fits->push_back(kept[i].fit);
  }
  return spots;
}

// Per-spot debug data in the order of the (sorted) spots.
void addSpotDebug(const Spots& spots, const std::vector<SpotFit>& fits, SpotDetectorDebug* debug)
{
  for (const Spot& s : spots)
  {
    for (const SpotFit& r : fits)
    {
      if (r.x == s.x && r.y == s.y)
      {
        debug->windows.push_back(r.window);
        debug->sigmas_px.push_back(r.sigma);
        debug->chroma.emplace_back(r.red_ratio, r.blue_ratio);
        break;
      }
    }
  }
}

// ---------------------------------------------------------------------------
// The pipeline.

SpotDetectionResult FastMethod::detect(const cv::Mat& image, PixelFormat format, const SpotDetectorParams& params,
                                       SpotDetectorDebug* debug, SpotDetectorTimings* timings)
{
  const FastParams& p = params.fast;
  StageTimer timer;
  SpotDetectorTimings tm;
  const PixelScore score(format, p.red_weight);
  findCandidates(image, format, p, score, debug, &tm, &timer);
  const std::vector<KeptSpot> kept = refineCandidates(image, p, score, debug);
  std::vector<char> drop = markDuplicates(kept);
  frameChecks(kept, p.frame_checks, &drop, debug);
  std::vector<SpotFit> fits;
  Spots spots = survivors(kept, drop, &fits);
  tm.refine_ms = timer.lap();

  // Row-major order for readability; beams are the Triangulator's business.
  sortIntoRows(&spots, params.projector_cols, params.projector_rows, false);
  if (debug)
  {
    debug->candidates = static_cast<int>(candidates_.size());
    addSpotDebug(spots, fits, debug);
  }
  SpotDetectionResult result;
  result.spots = std::move(spots);
  if (timings)
    *timings = tm;
  result.ok = true;
  return result;
}

// Stages 1-3a/b: fills candidates_ (and the blobs the splitter needs).
void FastMethod::findCandidates(const cv::Mat& image, PixelFormat format, const FastParams& p, const PixelScore& score,
                                SpotDetectorDebug* debug, SpotDetectorTimings* tm, StageTimer* timer)
{
  constexpr int kBin = ThresholdPass::kBin;
  const bool coarse = p.coarse_threshold > 0 && !score.mono && image.rows >= 2 * kBin && image.cols >= 2 * kBin;
  threshold_pass_.run(image, format, score.mono ? p.mono_threshold : p.detect_threshold, score.k256, coarse);
  tm->threshold_ms = timer->lap();

  const std::vector<Blob>& blobs = labeller_.label(threshold_pass_.runs(), image, score);
  candidates_.clear();
  addBlobCandidates(blobs, p, score.mono, &candidates_);
  if (coarse)
  {
    const int added = coarse_.add(threshold_pass_.coarse(), p.coarse_threshold, p.max_sigma_px, &candidates_);
    if (debug)
      debug->coarse_candidates = added;
  }
  tm->labelling_ms = timer->lap();
}

// Stage 4 and the acceptance tests, candidate by candidate; blobs holding
// several dots append their further seeds to candidates_ on the way.
std::vector<KeptSpot> FastMethod::refineCandidates(const cv::Mat& image, const FastParams& p, const PixelScore& score,
                                                   SpotDetectorDebug* debug)
{
  const bool split = !score.mono;
  if (split)
    splitter_.reset(image, score, threshold_pass_.runs(), labeller_.runBlob(), labeller_.blobs());
  std::vector<KeptSpot> kept;
  for (size_t ci = 0; ci < candidates_.size(); ++ci)
  {
    const Candidate c = candidates_[ci];  // a copy: new seeds grow the vector
    SpotFit r;
    const bool ok = fitCandidate(image, c, p, score, &r);
    if (split && c.blob >= 0)
    {
      // A seed on a dot's pedestal (a mineral, a bright rock bridge) can
      // climb to a dot of its blob already refined: that one stands.
      const bool again = c.seed && ok && splitter_.explained(c.blob, r.x, r.y);
      // A fit out of the sigma range explains no more than its seed pixel.
      const bool fits = ok && !again && r.sigma >= p.min_sigma_px && r.sigma <= p.max_sigma_px;
      const int px = c.peak_x >= 0 ? c.peak_x : static_cast<int>(std::lround(c.x));
      const int py = c.peak_y >= 0 ? c.peak_y : static_cast<int>(std::lround(c.y));
      Candidate seed;
      if (fits ? splitter_.nextSeed(c, r.x, r.y, r.sigma, p.min_peak, p.max_sigma_px, &seed)
               : splitter_.nextSeed(c, px, py, 1.5, p.min_peak, p.max_sigma_px, &seed))
        candidates_.push_back(seed);
      if (again)
        continue;
    }
    if (!ok)
    {
      reject(debug, c.x, c.y, "refinement failed (no signal or at the border)");
      continue;
    }
    const std::string why = spotRejection(image, c, p, score, &r);
    if (!why.empty())
    {
      reject(debug, r.x, r.y, why);
      continue;
    }
    kept.push_back({r, c.count});
  }
  return kept;
}
}  // namespace

std::unique_ptr<SpotDetectionMethod> makeFastMethod()
{
  return std::make_unique<FastMethod>();
}

}  // namespace structured_light_stabilizer
