// SpotMethod::kFast: the stages of spot_detector_fast_stages.h chained, and
// the decisions on their results: which refined candidates are plausible dots
// (acceptance tests: a dot's size, the projector's colour, staying on its
// blob) and which of them are the same dot (de-duplication). There is no
// test against the rest of the frame: the size and energy of a dot change
// with its depth (defocus, inverse square), incidence, albedo and clipping,
// so a frame's median says nothing about one dot (such tests dropped 19-21
// genuine dots per frame on textured rock). Clutter of the projector's
// colour and a dot's size is the Triangulator's to reject, by geometry.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <string>
#include <vector>

#include "structured_light_stabilizer/common/math.h"
#include "detection/fast/stages.h"

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

// A dot of the last frame (full-frame pixels): where to refine it from in
// this one (FastParams::tracked_seeds).
struct LastDot
{
  double x = 0, y = 0, sigma = 0;
  int area = 0;
  bool core = false;  // a clipped core of stage 3c, not a fit
};

void reject(SpotDetectorDebug* debug, double x, double y, const std::string& why)
{
  if (debug)
    debug->rejected.push_back({x, y, why});
}

class FastMethod : public SpotDetectionMethod
{
public:
  FastMethod() : scratch_(new RefineScratch) {}
  SpotDetectionResult detect(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                             const SpotDetectorParams& params, SpotDetectorDebug* debug,
                             SpotDetectorTimings* timings) override;
  bool regionStatistics(bool with_ambient, PixelFormat format, const cv::Size& frame, const SpotDetectorParams& params,
                        std::string* why) const override;
  void beginRegions() override
  {
    in_regions_ = true;
    ++noise_age_;
    last_dots_.swap(these_dots_);
    these_dots_.clear();
  }
  void endRegions() override { in_regions_ = false; }
  void resetStatistics() override
  {
    frame_noise_ = MatchedNoise();
    local_fallback_ = false;
    last_dots_.clear();
    these_dots_.clear();
  }

private:
  void findCandidates(const FastParams& p, SpotDetectorDebug* debug);
  std::vector<KeptSpot> refineCandidates(const FastParams& p, SpotDetectorDebug* debug, size_t max_candidates,
                                         bool split = true);
  bool seedCandidates();
  void rememberDots(const Spots& spots, const std::vector<SpotFit>& fits, const FastParams& p);

  // Scratch reused across frames (no per-frame allocation in the hot path).
  FramePlanes planes_;
  std::unique_ptr<RefineScratch> scratch_;
  ThresholdPass threshold_pass_;
  BlobLabeller labeller_;
  CoarseCandidates coarse_;
  BlobSplitter splitter_;
  ClippedCoreFinder core_finder_;
  std::vector<ClippedCore> cores_;
  std::vector<Candidate> candidates_;
  double threshold_ms_ = 0;
  // The matched path's statistics of the last whole frame (regions use them;
  // forgotten when the parameters change), that frame's size, and the region
  // frames since.
  MatchedNoise frame_noise_;
  cv::Size noise_size_;
  cv::Mat ambient8_;  // an unrounded ambient estimate, rounded for the threshold pass
  int noise_age_ = 0;
  bool in_regions_ = false;
  bool local_fallback_ = false;  // the last whole frame was scored against the local colour
  // The dots of the last frame and of this one (tracked_seeds), and where
  // this call's image lies in its frame.
  std::vector<LastDot> last_dots_, these_dots_;
  cv::Point offset_, frame_origin_;  // in the image's buffer (cv::Mat::locateROI)
  cv::Size frame_size_;              // of the last whole frame
};

// More of a whole frame's cells above the fixed greenness than a pattern of
// dots covers (at most 13 % in the tests' densest frames): the surface's own
// colour scores above the threshold.
constexpr double kFixedScoreCoverage = 0.25;

// Region frames after which the statistics of the last whole frame are
// renewed by a whole-frame search (the sun and exposure change slowly; a
// sudden change loses dots, and the planner then searches the whole frame).
constexpr int kMaxNoiseAge = 30;

bool FastMethod::regionStatistics(bool with_ambient, PixelFormat format, const cv::Size& frame,
                                  const SpotDetectorParams& params, std::string* why) const
{
  // Only the matched path (colour frames with an ambient frame) takes
  // statistics of the whole frame.
  if (!with_ambient || !hasColour(format) || params.fast.matched_sigma_px <= 0.0 ||
      !colourModel(params.projector_color, true, params.fast).colour)
    return true;
  const char* reason = !frame_noise_.valid          ? "no noise statistics of a whole frame"
                       : noise_size_ != frame       ? "frame size changed"
                       : noise_age_ >= kMaxNoiseAge ? "noise statistics renewed"
                                                    : nullptr;
  if (reason && why)
    *why = reason;
  return reason == nullptr;
}

// ---------------------------------------------------------------------------
// Acceptance tests of one refined candidate.

RefineSettings refineSettings(const FastParams& p)
{
  RefineSettings rs;
  rs.fixed_radius = p.window_radius_px;
  rs.max_sigma = p.max_sigma_px;
  rs.subtract_texture = p.subtract_rock_texture;
  rs.normalise_albedo = p.normalise_albedo;
  rs.albedo_floor_dn = p.albedo_floor_dn;
  rs.plain_radius = p.plain_radius;
  rs.plain_snr = p.plain_snr;
  rs.albedo_plane = p.albedo_plane;
  return rs;
}

// Fits the candidate; false when no fit stands. A dot on a pedestal of the
// projector's colour (an olive mineral, a neighbour's flank) grows the
// adaptive window over the pedestal: then the fit is retried from the
// strongest pixel in a small fixed window, whose border lies on the pedestal
// and subtracts it.
bool fitCandidate(const FramePlanes& planes, const Candidate& c, const FastParams& p, RefineScratch* scratch,
                  SpotFit* fit)
{
  const RefineSettings rs = refineSettings(p);
  bool ok = refineSpot(planes, rs, c.x, c.y, c.sigma0, p.window_radius_px, scratch, fit);
  if ((!ok || fit->sigma > p.max_sigma_px) && c.peak_x >= 0 && p.window_radius_px == 0)
  {
    SpotFit retry;
    // Only a real peak on the pedestal counts.
    if (refineSpot(planes, rs, c.peak_x, c.peak_y, 1.5, 5, scratch, &retry) && retry.amplitude >= p.min_peak)
    {
      *fit = retry;
      fit->on_pedestal = true;
      ok = true;
    }
  }
  return ok;
}

// The colour test (ColourTestParams); empty when the colour is the LED's.
std::string colourRejection(const SpotFit& r, const ColourTestParams& p, const ColourModel& model)
{
  const double led_ref = model.led_reference, led_third = model.led_third;
  // The red test sees the rock texture as much as the spot: off by default.
  // Red above the LED's: olive and yellow minerals (R = G) carry their own
  // red; the slack covers what rock texture alone can add.
  bool red_bad = p.max_red_excess > 0 && r.red_ratio > led_ref + p.max_red_excess + r.red_slack;
  red_bad = red_bad || (p.max_red_deficit > 0 && r.red_ratio < led_ref - p.max_red_deficit - r.red_slack);
  // A spot on a pedestal is suspect: the pedestal is often an olive or
  // yellow mineral, whose own red shows up as extra red excess.
  red_bad = red_bad || (r.on_pedestal && std::abs(r.red_ratio - led_ref) > p.max_chroma_error);
  // The third: a tolerance of the projector's own, plus what the border's
  // texture could have moved the ratio by (facets shaded in another hue,
  // grains of another colour, a demosaicked edge).
  // No excess over the border's planes at all (NaN): rejected (an olive
  // mineral wider than the window; a dot in a cast shadow between sunlit
  // facets is lost with it, measured by tools/evaluate_validation).
  if (red_bad || !std::isfinite(r.blue_ratio) || std::abs(r.blue_ratio - led_third) > p.max_chroma_error + r.blue_slack)
    return "colour: reference/signal " + std::to_string(r.red_ratio) + ", third/signal " + std::to_string(r.blue_ratio);
  return std::string();
}

// Why a fitted candidate is not a dot; empty when it is. Measures the colour
// of its added light on the way (from scratch's final window).
std::string spotRejection(const FramePlanes& planes, const Candidate& c, const FastParams& p, RefineScratch* scratch,
                          SpotFit* r)
{
  if (r->sigma < p.min_sigma_px || r->sigma > p.max_sigma_px)
    return "sigma " + std::to_string(r->sigma) + " px out of range";
  // A clipped core carries no colour, and its unclipped flanks too little
  // excess to judge by: the ring of the projector's colour that made the
  // blob vouches for it.
  if (planes.colourPath() && !r->clipped)
  {
    // The planes of the fit's own window (a failed retry may have left another's).
    const int H = (r->window.width - 1) / 2;
    const PlaneWindow& w = scratch->planes;
    if (w.cx != r->window.x + H || w.cy != r->window.y + H || w.H != H)
      planes.fillWindow(r->window.x + H, r->window.y + H, H, &scratch->planes);
    measureColour(scratch->planes, planes.model(), p.colour_test.max_texture_slack, r);
    std::string why = colourRejection(*r, p.colour_test, planes.model());
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

// A dot whose saturated core splits its candidate ring into pieces, or a
// coarse or split seed next to a blob, gives several refinements that end on
// the same dot: the one of the highest fitted peak is kept (a refinement that
// grew over the dot and its surroundings has a larger flux but a lower
// peak), the others are marked in the returned vector.
std::vector<char> markDuplicates(const std::vector<KeptSpot>& kept)
{
  std::vector<size_t> order(kept.size());
  for (size_t i = 0; i < order.size(); ++i)
    order[i] = i;
  // A spot whose colour was measured and is the projector's goes before one
  // whose colour could not be measured (a streak's fragment next to a dot),
  // then the brighter.
  const auto measured = [&](size_t i) { return std::isfinite(kept[i].fit.blue_ratio) || kept[i].fit.clipped; };
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b)
            {
              if (measured(a) != measured(b))
                return measured(a);
              return kept[a].fit.amplitude > kept[b].fit.amplitude;
            });
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
      if (detail::square(a.x - b.x) + detail::square(a.y - b.y) < lim * lim)
        drop[order[j]] = 1;
    }
  }
  return drop;
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

// The quality of each (sorted) spot, from its fit. The noise floor of 0.5 DN
// stands for quantisation on a noise-free border.
std::vector<SpotQuality> qualities(const Spots& spots, const std::vector<SpotFit>& fits)
{
  std::vector<SpotQuality> out;
  out.reserve(spots.size());
  for (const Spot& s : spots)
  {
    SpotQuality q;
    for (const SpotFit& r : fits)
    {
      if (r.x == s.x && r.y == s.y)
      {
        q.snr = static_cast<float>(r.amplitude / std::max(0.5, r.noise));
        q.sigma_px = static_cast<float>(r.sigma);
        q.clipped = r.clipped;
        q.albedo_normalised = r.normalised;
        break;
      }
    }
    out.push_back(q);
  }
  return out;
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

// Stage 3c's dots (ClippedCoreFinder: cores on which no Gaussian fit
// ended). The spots on a core's halo (within 2 r + 2 px: pieces of the ring
// that the colour score saw around the white core) give way to it.
void addClippedCores(const std::vector<ClippedCore>& cores, Spots* spots, std::vector<SpotFit>* fits)
{
  for (const ClippedCore& c : cores)
  {
    for (size_t i = spots->size(); i-- > 0;)
      if (std::hypot((*spots)[i].x - c.x, (*spots)[i].y - c.y) <= 2 * c.radius + 2)
      {
        spots->erase(spots->begin() + static_cast<long>(i));
        fits->erase(fits->begin() + static_cast<long>(i));
      }
    Spot s;
    s.x = c.x;
    s.y = c.y;
    s.area = static_cast<float>(c.pixels);
    s.intensity = static_cast<float>(c.pixels);
    SpotFit f;
    f.x = c.x;
    f.y = c.y;
    f.sigma = f.sigma_major = c.radius;
    f.amplitude = c.halo;  // the quality's SNR: the halo over a quantisation floor
    f.clipped = true;
    f.window = c.box;
    f.core = true;
    spots->push_back(s);
    fits->push_back(f);
  }
}

// ---------------------------------------------------------------------------
// The pipeline.

// The fraction of the grid's cells in the runs.
double coveredFraction(const std::vector<Run>& runs, int cols, int rows)
{
  size_t cells = 0;
  for (const Run& r : runs)
    cells += static_cast<size_t>(r.x1 - r.x0 + 1);
  return cols > 0 && rows > 0 ? static_cast<double>(cells) / (static_cast<double>(cols) * rows) : 0.0;
}

// The most candidates a frame of dots can have (FastParams::max_candidates).
size_t candidateBudget(const SpotDetectorParams& params)
{
  const size_t beams = static_cast<size_t>(params.projector_rows) * static_cast<size_t>(params.projector_cols);
  return std::max(static_cast<size_t>(params.fast.max_candidates), 10 * beams);
}

SpotDetectionResult FastMethod::detect(const cv::Mat& image, const cv::Mat& ambient, PixelFormat format,
                                       const SpotDetectorParams& params, SpotDetectorDebug* debug,
                                       SpotDetectorTimings* timings)
{
  const FastParams& p = params.fast;
  StageTimer timer;
  SpotDetectorTimings tm;
  const bool unrounded = !ambient.empty() && ambient.depth() == CV_32F;
  cv::Size buffer;
  cv::Point at;
  image.locateROI(buffer, at);
  if (!in_regions_)
  {
    these_dots_.clear();
    frame_size_ = image.size();
    frame_origin_ = at;
  }
  offset_ = at - frame_origin_;
  if (unrounded)
    ambient.convertTo(ambient8_, CV_8U);  // rounded and saturated (NaN -> 0)
  // The fixed greenness assumes that the surface scores below
  // detect_threshold (reddish rock). Where more than kFixedScoreCoverage of
  // a whole frame scores above it (grey or green rock by day, a tinted
  // light), that frame and the regions tracked after it are scored against
  // the local colour instead (FastParams::local_colour).
  FastParams fp = p;
  fp.local_colour = p.local_colour || (in_regions_ && local_fallback_);
  planes_.bind(image, unrounded ? ambient8_ : ambient, format, params.projector_color, fp,
               in_regions_ ? &frame_noise_ : nullptr, unrounded ? ambient : cv::Mat());
  if (!in_regions_ && planes_.matchedPath())
  {
    frame_noise_ = planes_.matchedNoise();
    noise_size_ = image.size();
    noise_age_ = 0;
  }
  // Regions around the last frame's dots on the fixed colour path: those
  // dots refined straight from where they were (FastParams::tracked_seeds).
  const bool seeded = in_regions_ && fp.tracked_seeds && planes_.colourPath() && !planes_.localPath() &&
                      !planes_.matchedPath() && seedCandidates();
  const size_t seeds = seeded ? candidates_.size() : 0;
  if (!seeded)
    findCandidates(fp, debug);
  else
    threshold_ms_ = 0;
  std::string note;
  if (!in_regions_)
  {
    const bool fixed = planes_.colourPath() && !planes_.localPath() && !planes_.hasAmbient();
    const double covered = fixed ? coveredFraction(threshold_pass_.runs(), planes_.cols(), planes_.rows()) : 0.0;
    local_fallback_ = covered > kFixedScoreCoverage;
    if (local_fallback_)
    {
      fp.local_colour = true;
      planes_.bind(image, cv::Mat(), format, params.projector_color, fp);
      findCandidates(fp, debug);
      char text[128];
      std::snprintf(text, sizeof text,
                    "%.0f %% of the frame above the fixed greenness: scored against the local colour", 100.0 * covered);
      note = text;
    }
  }
  tm.threshold_ms = threshold_ms_;
  tm.labelling_ms = timer.lap() - threshold_ms_;
  // More candidates than the pattern can hold (texture of the projector's
  // colour, noise, a flash): the most significant are refined, the frame is
  // never refused for them.
  const size_t budget = candidateBudget(params);
  if (candidates_.size() > budget)
  {
    note += std::string(note.empty() ? "" : "; ") + "kept the " + std::to_string(budget) + " most significant of " +
            std::to_string(candidates_.size()) +
            " candidate spots (fast.max_candidates, or 10 x the projector's beams)";
    std::stable_sort(candidates_.begin(), candidates_.end(),
                     [](const Candidate& a, const Candidate& b) { return a.significance > b.significance; });
    candidates_.resize(budget);
  }
  std::vector<KeptSpot> kept = refineCandidates(fp, debug, 2 * budget, !seeded);
  const bool all_seeded = seeded && kept.size() >= seeds;
  if (seeded && !all_seeded)
  {
    // A dot lost or changed (occluded, moved beyond its window, refused):
    // the region is searched as usual, and what it finds stands.
    if (debug)
      debug->rejected.clear();
    findCandidates(fp, debug);
    kept = refineCandidates(fp, debug, 2 * budget);
  }
  else if (seeded && debug)
    debug->seeded = static_cast<int>(seeds);
  const std::vector<char> drop = markDuplicates(kept);
  std::vector<SpotFit> fits;
  Spots spots = survivors(kept, drop, &fits);
  // A region whose last dots were all refined again holds no new white core
  // (one that appears there is the band's to find, as a new dot is).
  if (p.clipped_cores && !all_seeded)
  {
    core_finder_.find(planes_, fp, spots, &cores_);
    addClippedCores(cores_, &spots, &fits);
  }
  rememberDots(spots, fits, fp);
  tm.refine_ms = timer.lap();

  // Row-major order for readability; beams are the Triangulator's business.
  sortIntoRows(&spots, params.projector_cols, params.projector_rows, false);
  SpotDetectionResult result;
  result.quality = qualities(spots, fits);
  if (debug)
  {
    debug->candidates = static_cast<int>(candidates_.size());
    addSpotDebug(spots, fits, debug);
    for (const SpotQuality& q : result.quality)
      debug->fitted += q.clipped ? 1 : 0;
  }
  result.spots = std::move(spots);
  result.note = note;
  if (timings)
    *timings = tm;
  result.ok = true;
  return result;
}

// Stages 1-3a/b: fills candidates_ (and the blobs the splitter needs).
void FastMethod::findCandidates(const FastParams& p, SpotDetectorDebug* debug)
{
  constexpr int kBin = ThresholdPass::kBin;
  StageTimer timer;
  const bool coarse = p.coarse_threshold > 0 && planes_.colourPath() && !planes_.matchedPath() &&
                      planes_.rows() >= 2 * kBin && planes_.cols() >= 2 * kBin;
  threshold_pass_.run(&planes_, coarse);
  threshold_ms_ = timer.lap();

  const std::vector<Blob>& blobs = labeller_.label(threshold_pass_.runs(), planes_);
  candidates_.clear();
  addBlobCandidates(blobs, p, planes_, &candidates_);
  if (coarse)
  {
    const int added = coarse_.add(threshold_pass_.coarse(), p.coarse_threshold, p.max_sigma_px, planes_, &candidates_);
    if (debug)
      debug->coarse_candidates = added;
  }
}

// Stage 4 and the acceptance tests, candidate by candidate; blobs holding
// several dots append their further seeds to candidates_ on the way.
std::vector<KeptSpot> FastMethod::refineCandidates(const FastParams& p, SpotDetectorDebug* debug, size_t max_candidates,
                                                   bool split)
{
  if (split)
    splitter_.reset(planes_, threshold_pass_.runs(), labeller_.runBlob(), labeller_.blobs());
  std::vector<KeptSpot> kept;
  for (size_t ci = 0; ci < candidates_.size(); ++ci)
  {
    const Candidate c = candidates_[ci];  // a copy: new seeds grow the vector
    SpotFit r;
    const bool ok = fitCandidate(planes_, c, p, scratch_.get(), &r);
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
      const int k = planes_.scale();
      const int min_peak = planes_.peakThresholdAt(px / k, py / k, p.min_peak);
      if (fits ? splitter_.nextSeed(c, r.x, r.y, r.sigma, min_peak, p.max_sigma_px, &seed)
               : splitter_.nextSeed(c, px, py, 1.5, min_peak, p.max_sigma_px, &seed))
        if (candidates_.size() < max_candidates)  // the seeds of split blobs count too
        {
          const int gx = seed.peak_x / k, gy = seed.peak_y / k;
          seed.significance = planes_.significance(gx, gy, planes_.scoreAt(gx, gy));
          candidates_.push_back(seed);
        }
      if (again)
        continue;
    }
    if (!ok)
    {
      reject(debug, c.x, c.y, "refinement failed (no signal or at the border)");
      continue;
    }
    const std::string why = spotRejection(planes_, c, p, scratch_.get(), &r);
    if (!why.empty())
    {
      reject(debug, r.x, r.y, why);
      continue;
    }
    kept.push_back({r, c.count});
  }
  return kept;
}

// This call's dots, for the next frame's regions; not those cut by the
// region's edge, which SpotDetector::detectIn leaves out (the region next to
// it sees them whole).
void FastMethod::rememberDots(const Spots& spots, const std::vector<SpotFit>& fits, const FastParams& p)
{
  if (!p.tracked_seeds || !planes_.colourPath())
    return;
  const cv::Rect region(offset_, cv::Size(planes_.frameCols(), planes_.frameRows()));
  for (size_t i = 0; i < fits.size() && i < spots.size(); ++i)
  {
    const SpotFit& f = fits[i];
    SpotQuality q;
    q.sigma_px = static_cast<float>(f.sigma);
    Spot s = spots[i];
    s.x += offset_.x;
    s.y += offset_.y;
    if (in_regions_ && cutByRegion(s, reachOf(s, &q), region, frame_size_))
      continue;
    LastDot d;
    d.x = f.x + offset_.x;
    d.y = f.y + offset_.y;
    d.sigma = f.sigma;
    d.area = static_cast<int>(spots[i].area);
    d.core = f.core;
    these_dots_.push_back(d);
  }
}

// A region of windows around the last frame's dots (narrower than the frame:
// not the planner's band): candidates_ become those dots, to be refined
// straight from where they were, without the region's threshold pass. False
// (search the region) when it holds none of them, a clipped core of stage 3c,
// or a dot too near one of its inner edges for a whole window.
bool FastMethod::seedCandidates()
{
  candidates_.clear();
  if (planes_.frameCols() >= frame_size_.width)
    return false;
  const int cols = planes_.frameCols(), rows = planes_.frameRows();
  const cv::Rect region(offset_, cv::Size(cols, rows));
  for (const LastDot& d : last_dots_)
  {
    const double x = d.x - offset_.x, y = d.y - offset_.y;
    if (x < 0 || y < 0 || x > cols - 1 || y > rows - 1)
      continue;
    // A clipped dot's window reaches 3 sigma + 3 px, and its planes 2 px more
    // (at the frame's own edges the window is cut as in a search).
    const double reach = 3.0 * d.sigma + 6.0;
    Spot at;
    at.x = d.x;
    at.y = d.y;
    if (d.core || cutByRegion(at, reach, region, frame_size_))
      return false;
    // The same dot found in two overlapping regions of the last frame: once.
    if (std::any_of(candidates_.begin(), candidates_.end(),
                    [&](const Candidate& c) { return std::abs(c.x - x) < 1.0 && std::abs(c.y - y) < 1.0; }))
      continue;
    Candidate c{x,
                y,
                d.sigma,
                std::max(1, d.area),
                static_cast<int>(std::floor(x - reach)),
                static_cast<int>(std::floor(y - reach)),
                static_cast<int>(std::ceil(x + reach)),
                static_cast<int>(std::ceil(y + reach))};
    candidates_.push_back(c);
  }
  return !candidates_.empty();
}
}  // namespace

std::unique_ptr<SpotDetectionMethod> makeFastMethod()
{
  return std::make_unique<FastMethod>();
}

}  // namespace structured_light_stabilizer
