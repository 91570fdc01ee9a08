// Benchmark of the SpotDetector: the study's baseline chain and the fast
// detector on the same 1024 x 1024 bgr8 simulator frames (10 x 10 dots,
// textured rock, clutter; several sun levels and dot sizes, the study's
// brightness: about half the dots clipped) in one run, single core (pinned
// when the OS allows, cv::setNumThreads(1)). Prints the median and 90th
// percentile ms per frame of each method, their ratio, and the per-stage
// breakdown of both; then the fast method's thread CPU time per input kind
// on the same scenes: bgr8 with dimmer dots (few clipped), bayer_rggb8, mono8
// (NIR), bgr8 with a projector-off frame. Also the tracked detection with the
// refinement's accuracy terms switched off, what each costs and buys.
//
// Before the textured-rock physics and the input kinds (integrate2 994be93,
// same frames, thread CPU): fast
// 1.7-2.3 ms per frame; see docs/performance.md for the figures after.
//
// usage: benchmark_spot_detector [frames=40] [repeats=5]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#ifdef __linux__
#include <sched.h>
#endif
#include <time.h>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/detection/ambient_compensation.h"
#include "structured_light_stabilizer/sim/design/radiometry.h"
#include "support/benchmark_frames.h"
#include "structured_light_stabilizer/sim/render/simulator.h"
#include "structured_light_stabilizer/detection/spot_detector.h"
#include "structured_light_stabilizer/detection/spot_search_planner.h"

using namespace structured_light_stabilizer;

namespace
{
double percentile(std::vector<double> v, double q)
{
  if (v.empty())
    return 0.0;
  std::sort(v.begin(), v.end());
  const size_t i = std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5));
  return v[i];
}

double median(const std::vector<double>& v)
{
  return percentile(v, 0.5);
}

// CPU time of this thread (ms): on a shared machine, unlike wall time, it
// does not count the time other processes held the core.
double threadCpuMs()
{
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}
}  // namespace

// One input kind: frames of the benchmark's scenes rendered for it, and the
// fast method's median thread CPU per frame.
struct InputKind
{
  const char* name;
  const char* output;
  ProjectorColor color;
  double brightness;  // dot_to_sun_ratio factor (1: the study's)
  bool ambient;
  double sun;  // < 0: the benchmark's 0.5 and 1 alternately
};

void benchmarkInputs(int detections)
{
  const InputKind kinds[] = {
      {"bgr8, dots 0.3 x (few clipped)", "bgr8", ProjectorColor::kGreen, 0.3, false, -1},
      {"bgr8 + projector-off frame", "bgr8", ProjectorColor::kGreen, 1.0, true, -1},
      {"bgr16 (12 bits) + projector-off frame", "bgr16", ProjectorColor::kGreen, 1.0, true, -1},
      {"bayer_rggb8", "bayer_rggb8", ProjectorColor::kGreen, 1.0, false, -1},
      {"mono8, NIR, by night", "mono8", ProjectorColor::kNir, 1.0, false, 0.0},
      {"mono8, NIR, by day + projector-off frame", "mono8", ProjectorColor::kNir, 1.0, true, -1},
      // Texture bumps of a dot's size and brightness are candidates in one
      // mono frame by day: hundreds per frame on the simulator's rock.
      {"mono8, NIR, by day", "mono8", ProjectorColor::kNir, 1.0, false, -1},
  };
  for (const InputKind& k : kinds)
  {
    std::vector<cv::Mat> images, ambients;
    for (int i = 0; i < 4; ++i)
    {
      // The study's brightness, as the frames above (the simulator's default,
      // the recommended rig's corrected radiometry, makes one-frame dots by
      // day too dim to find: 9 of 100 at 0.3 x).
      SimulatorParams cfg = studySimulatorParams();
      sensorOutputFromEncoding(k.output, &cfg.sensor.output);
      cfg.sensor.output_bits = 12;  // the 16-bit outputs: the recommended rig's converter
      cfg.projector.color = k.color;
      cfg.projector.wavelength_nm = nominalWavelengthNm(k.color);
      cfg.lighting.sun_level = k.sun >= 0 ? k.sun : (i % 2 ? 1.0 : 0.5);
      cfg.lighting.dot_to_sun_ratio *= k.brightness;
      cfg.clutter.green_specks = 20;
      cfg.clutter.olive_minerals = 20;
      cfg.rock.seed = 1000 + i;
      const Simulator sim(cfg);
      images.push_back(sim.render(0.1 * i).image);
      FrameRequest off;
      off.projector_on = false;
      ambients.push_back(k.ambient ? sim.render(0.1 * i, off).image : cv::Mat());
    }
    PixelFormat format;
    pixelFormatFromEncoding(k.output, &format);
    SpotDetectorParams p;
    p.projector_color = k.color;
    SpotDetector det(p);
    std::vector<double> cpu;
    size_t spots = 0;
    for (int r = 0; r < detections; ++r)
    {
      const size_t i = static_cast<size_t>(r) % images.size();
      const double c0 = threadCpuMs();
      spots += det.detect(images[i], ambients[i], format).spots.size();
      cpu.push_back(threadCpuMs() - c0);
    }
    std::printf("fast, %-32s median %.3f ms thread CPU (p90 %.3f), %.1f spots/frame\n", k.name, median(cpu),
                percentile(cpu, 0.9), static_cast<double>(spots) / detections);
  }
}

// Recall and centroid RMS of `spots` against the frame's true dot pixels
// (a dot counts as found with a spot within 2 px), accumulated.
struct TruthScore
{
  size_t dots = 0, found = 0, frames = 0, false_spots = 0;  // false: no visible dot within 2 px
  double sq = 0.0;
  void add(const SimFrame& frame, const Spots& spots)
  {
    ++frames;
    for (const Spot& s : spots)
    {
      bool near = false;
      for (size_t b = 0; b < frame.pixels.size() && !near; ++b)
        near = frame.visible[b] && std::hypot(s.x - frame.pixels[b].x, s.y - frame.pixels[b].y) < 2.0;
      false_spots += near ? 0 : 1;
    }
    for (size_t b = 0; b < frame.pixels.size(); ++b)
    {
      if (!frame.visible[b])
        continue;
      ++dots;
      double best = 2.0;
      for (const Spot& s : spots)
        best = std::min(best, std::hypot(s.x - frame.pixels[b].x, s.y - frame.pixels[b].y));
      if (best < 2.0)
      {
        ++found;
        sq += best * best;
      }
    }
  }
  double recall() const { return dots ? static_cast<double>(found) / dots : 0.0; }
  double rms() const { return found ? std::sqrt(sq / found) : 0.0; }
  double falsePerFrame() const { return frames ? static_cast<double>(false_spots) / frames : 0.0; }
};

// The tracking sequences' scene: the study's brightness, half sun, clutter,
// the rig jittering 2 mm.
SimulatorParams trackingScene()
{
  SimulatorParams cfg = studySimulatorParams();
  cfg.lighting.sun_level = 0.5;
  cfg.clutter.green_specks = 20;
  cfg.clutter.olive_minerals = 20;
  cfg.rock.seed = 1100;
  cfg.motion.jitter_translation_m = 0.002;
  return cfg;
}

// One frame of the nodelet's tracking loop: the planner's windows (a full
// search while the detector has no noise statistics for them), the detection
// in them, the planner updated. ambient(regions): the frame's projector-off
// light in those windows (an empty Mat: none).
template <typename Ambient>
SpotDetectionResult detectTracked(SpotDetector* detector, SpotSearchPlanner* planner, const cv::Mat& im, bool strobed,
                                  Ambient ambient, std::vector<cv::Rect>* regions)
{
  if (!detector->hasRegionStatistics(strobed, PixelFormat::kBgr8, im.size()))
    planner->requestFullSearch("noise statistics");
  *regions = planner->plan(im.size());
  const SpotDetectionResult result = detector->detectIn(im, ambient(*regions), PixelFormat::kBgr8, *regions);
  planner->update(result);
  return result;
}

// Tracking: a 30 Hz sequence of one scene (the rig jittering 2 mm), the
// baseline, the fast method searching every frame in full, and the fast
// method in the windows of SpotSearchPlanner (the nodelet's default), on the
// same frames; recall and centroid RMS of the three against the truth.
// strobed: dim dots (0.3 x) with their projector-off frames, the fast method
// detecting on the difference (its matched filter thresholded by the noise of
// the last whole frame when tracking); the baseline on the on-frames alone.
void benchmarkTracking(int frames, int repeats, bool strobed)
{
  SimulatorParams cfg = trackingScene();
  if (strobed)
    cfg.lighting.dot_to_sun_ratio *= 0.3;  // dim dots: what strobing is for
  const Simulator sim(cfg);
  // Strobed: a 30 Hz camera, projector-on frames at 15 Hz between
  // projector-off frames; each on-frame's ambient is compensated from the
  // off-frames before and after it (as the nodelet does, timed with the
  // detection): the whole frame for a full search, the searched regions when
  // tracking; each projector-off frame's tracking pyramid, and the buffers,
  // are kept for the next on-frame (AmbientTrackingCache: one per detector,
  // as each nodelet has its own).
  const double period = strobed ? 1.0 / 15.0 : 1.0 / 30.0;
  std::vector<SimFrame> seq;
  std::vector<AmbientFrame> offs;  // offs[k] before on-frame k, offs[k + 1] after it
  FrameRequest off;
  off.projector_on = false;
  for (int i = 0; i < frames; ++i)
  {
    const double t = i * period;
    seq.push_back(sim.render(t));
    if (strobed)
      offs.push_back({sim.render(t - 1.0 / 30.0, off).image, t - 1.0 / 30.0});
  }
  if (strobed)
    offs.push_back({sim.render(frames * period - 1.0 / 30.0, off).image, frames * period - 1.0 / 30.0});
  AmbientTrackingCache cache, full_cache;  // one per detector's stream, as in the nodelet
  const auto ambientOf = [&](size_t k, const std::vector<cv::Rect>& regions, AmbientTrackingCache* c)
  {
    if (!strobed)
      return cv::Mat();
    AmbientCompensationParams ap;
    ap.regions = regions;
    ap.unrounded = true;  // as the nodelet
    return compensateAmbient(k * period, offs[k], offs[k + 1], ap, nullptr, c).image;
  };
  SpotDetectorParams pb;
  pb.method = SpotMethod::kBaseline;
  SpotDetector baseline(pb), full, tracked;
  SpotSearchPlanner planner;
  std::vector<double> cpu_b, cpu_f, cpu_t, cpu_ta;  // cpu_ta: the tracked frames' ambient compensation
  TruthScore score_b, score_f, score_t;
  size_t searched = 0;
  for (int r = 0; r < repeats; ++r)
  {
    planner.reset();
    for (size_t k = 0; k < seq.size(); ++k)
    {
      const SimFrame& frame = seq[k];
      const cv::Mat& im = frame.image;
      double c0 = threadCpuMs();
      const SpotDetectionResult b = baseline.detect(im, PixelFormat::kBgr8);
      cpu_b.push_back(threadCpuMs() - c0);
      score_b.add(frame, b.spots);
      c0 = threadCpuMs();
      const SpotDetectionResult f = full.detect(im, ambientOf(k, {}, &full_cache), PixelFormat::kBgr8);
      cpu_f.push_back(threadCpuMs() - c0);
      c0 = threadCpuMs();
      std::vector<cv::Rect> regions;
      const SpotDetectionResult t = detectTracked(
          &tracked, &planner, im, strobed,
          [&](const std::vector<cv::Rect>& in)
          {
            const double a0 = threadCpuMs();
            const cv::Mat amb = ambientOf(k, in.empty() ? in : mergeSearchRegions(in, im.size()), &cache);
            cpu_ta.push_back(threadCpuMs() - a0);
            return amb;
          },
          &regions);
      cpu_t.push_back(threadCpuMs() - c0);
      for (const cv::Rect& g : regions)
        searched += static_cast<size_t>(g.area());
      searched += regions.empty() ? im.total() : 0;
      score_f.add(frame, f.spots);
      score_t.add(frame, t.spots);
    }
  }
  const double n = static_cast<double>(cpu_t.size());
  std::printf(
      "tracking%s, %d frames at %.0f Hz x %d: baseline %.3f ms, fast full search %.3f ms, fast tracked %.3f ms "
      "thread CPU (median; tracked p90 %.3f); %ld full searches; %.1f %% of the pixels searched\n",
      strobed ? " (strobed bgr8, dots 0.3 x; the fast method with the projector-off frames compensated to each "
                "frame's time, compensation included)"
              : "",
      frames, 1.0 / period, repeats, median(cpu_b), median(cpu_f), median(cpu_t), percentile(cpu_t, 0.9),
      planner.fullSearches(), 100.0 * searched / (n * seq.front().image.total()));
  if (strobed)
    std::printf("  of the tracked frames' cost, the ambient compensation %.3f ms (median; p90 %.3f)\n", median(cpu_ta),
                percentile(cpu_ta, 0.9));
  std::printf(
      "  against the truth: full search recall %.4f, centroid RMS %.4f px; tracked recall %.4f, %.4f px; "
      "the study's chain recall %.4f, %.4f px\n",
      score_f.recall(), score_f.rms(), score_t.recall(), score_t.rms(), score_b.recall(), score_b.rms());
  std::printf("  ratio baseline/fast: %.1fx full search, %.1fx tracked (median thread CPU)\n",
              median(cpu_b) / median(cpu_f), median(cpu_b) / median(cpu_t));
}

// What the refinement's accuracy terms cost and buy: the tracked
// detection of the 30 Hz sequence with the rock's texture subtraction and the
// albedo normalisation each switched off, and with every region searched
// (tracked_seeds off); thread CPU per tracked frame, false spots and
// centroid RMS against the truth. The variants run interleaved, frame by
// frame, so that the machine's load falls on all alike.
void benchmarkRefinementTerms(int frames, int repeats)
{
  const Simulator sim(trackingScene());
  std::vector<SimFrame> seq;
  for (int i = 0; i < frames; ++i)
    seq.push_back(sim.render(i / 30.0));
  struct Variant
  {
    const char* name;
    bool subtract, normalise, tracked_seeds;
  };
  const Variant variants[] = {{"as shipped", true, true, true},
                              {"every region searched (no seeds)", true, true, false},
                              {"without the rock's texture subtracted", false, true, true},
                              {"without the albedo normalisation", true, false, true},
                              {"without both", false, false, true}};
  constexpr int kVariants = sizeof(variants) / sizeof(variants[0]);
  std::vector<SpotDetector> detectors;
  std::vector<SpotSearchPlanner> planners(kVariants);
  for (const Variant& v : variants)
  {
    SpotDetectorParams p;
    p.fast.subtract_rock_texture = v.subtract;
    p.fast.normalise_albedo = v.normalise;
    p.fast.tracked_seeds = v.tracked_seeds;
    detectors.emplace_back(p);
  }
  std::vector<std::vector<double>> cpu(kVariants);
  std::vector<TruthScore> score(kVariants);
  for (int r = 0; r < repeats; ++r)
  {
    for (SpotSearchPlanner& planner : planners)
      planner.reset();
    for (const SimFrame& frame : seq)
      for (int v = 0; v < kVariants; ++v)
      {
        const double c0 = threadCpuMs();
        std::vector<cv::Rect> regions;
        const SpotDetectionResult t = detectTracked(
            &detectors[v], &planners[v], frame.image, false, [](const std::vector<cv::Rect>&) { return cv::Mat(); },
            &regions);
        if (!regions.empty())
          cpu[v].push_back(threadCpuMs() - c0);
        score[v].add(frame, t.spots);
      }
  }
  std::printf(
      "refinement terms, tracked, %d frames at 30 Hz x %d (thread CPU median per tracked frame; against "
      "the truth):\n",
      frames, repeats);
  for (int v = 0; v < kVariants; ++v)
    std::printf("  %-40s %.3f ms, recall %.4f, centroid RMS %.4f px, %.2f false spots/frame\n", variants[v].name,
                median(cpu[v]), score[v].recall(), score[v].rms(), score[v].falsePerFrame());
}

// Pins the process to the first core it may run on; false when the OS refuses.
bool pinToOneCore()
{
#ifdef __linux__
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) != 0)
    return false;
  for (int c = 0; c < CPU_SETSIZE; ++c)
  {
    if (CPU_ISSET(c, &set))
    {
      cpu_set_t one;
      CPU_ZERO(&one);
      CPU_SET(c, &one);
      return sched_setaffinity(0, sizeof(one), &one) == 0;
    }
  }
#endif
  return false;
}

// The benchmark's bgr8 frames: dot sigma 1.5-4 px, sun 0.5 and 1, clutter.
std::vector<cv::Mat> benchmarkFrames(int count)
{
  std::vector<cv::Mat> images;
  for (int i = 0; i < count; ++i)
    images.push_back(Simulator(test::benchmarkFrameParams(i)).render(0.1 * i).image);
  return images;
}

int main(int argc, char** argv)
{
  const int frames = argc > 1 ? std::max(1, std::atoi(argv[1])) : 40;
  const int repeats = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;

  const bool pinned = pinToOneCore();
  // Frames rendered before the pinning matters (the simulator uses threads).
  const std::vector<cv::Mat> images = benchmarkFrames(std::min(frames, 8));
  cv::setNumThreads(1);
  std::printf(
      "frames: %d distinct simulator frames 1024x1024 bgr8 (dot sigma 1.5-4 px, sun 0.5 and 1, clutter), "
      "%d detections per method, %s, cv::setNumThreads(1)\n",
      static_cast<int>(images.size()), frames * repeats,
      pinned ? "pinned to one core" : "NOT pinned (sched_setaffinity failed)");

  SpotDetectorParams pb;
  pb.method = SpotMethod::kBaseline;
  SpotDetectorParams pf;
  pf.method = SpotMethod::kFast;
  SpotDetector baseline(pb), fast(pf);

  std::vector<double> cpu_b, cpu_f, tb, tf, blur, hsv, in_range, opening, labelling, centroids, sort, f_thr, f_lab,
      f_ref;
  size_t spots_b = 0, spots_f = 0;
  // Warm-up (allocations, page faults).
  for (const cv::Mat& im : images)
  {
    baseline.detect(im, PixelFormat::kBgr8);
    fast.detect(im, PixelFormat::kBgr8);
  }
  for (int r = 0; r < repeats; ++r)
  {
    for (int i = 0; i < frames; ++i)
    {
      const cv::Mat& im = images[i % images.size()];
      SpotDetectorTimings t;
      // Interleaved so that both methods see the same cache and clock state.
      double c0 = threadCpuMs();
      spots_b += baseline.detect(im, PixelFormat::kBgr8, nullptr, &t).spots.size();
      cpu_b.push_back(threadCpuMs() - c0);
      tb.push_back(t.total_ms);
      blur.push_back(t.blur_ms);
      hsv.push_back(t.hsv_ms);
      in_range.push_back(t.in_range_ms);
      opening.push_back(t.opening_ms);
      labelling.push_back(t.labelling_ms);
      centroids.push_back(t.centroids_ms);
      sort.push_back(t.sort_ms);
      c0 = threadCpuMs();
      spots_f += fast.detect(im, PixelFormat::kBgr8, nullptr, &t).spots.size();
      cpu_f.push_back(threadCpuMs() - c0);
      tf.push_back(t.total_ms);
      f_thr.push_back(t.threshold_ms);
      f_lab.push_back(t.labelling_ms);
      f_ref.push_back(t.refine_ms);
    }
  }
  const double n = static_cast<double>(tb.size());
  std::printf("baseline: median %.3f ms/frame wall (p90 %.3f, min %.3f), %.3f ms thread CPU, %.1f spots/frame\n",
              median(tb), percentile(tb, 0.9), percentile(tb, 0.0), median(cpu_b), spots_b / n);
  std::printf(
      "  stages (median ms): blur %.3f, HSV %.3f, inRange %.3f, opening %.3f, labelling %.3f, "
      "centroids %.3f, row sort %.3f\n",
      median(blur), median(hsv), median(in_range), median(opening), median(labelling), median(centroids), median(sort));
  std::printf("fast:     median %.3f ms/frame wall (p90 %.3f, min %.3f), %.3f ms thread CPU, %.1f spots/frame\n",
              median(tf), percentile(tf, 0.9), percentile(tf, 0.0), median(cpu_f), spots_f / n);
  std::printf("  stages (median ms): SIMD threshold pass %.3f, labelling + coarse pass %.3f, refine + tests %.3f\n",
              median(f_thr), median(f_lab), median(f_ref));
  std::printf("ratio baseline/fast: %.1fx (median wall), %.1fx (min wall), %.1fx (median thread CPU)\n",
              median(tb) / median(tf), percentile(tb, 0.0) / percentile(tf, 0.0), median(cpu_b) / median(cpu_f));
  benchmarkTracking(std::max(frames, 30), repeats, false);
  benchmarkTracking(std::max(frames, 30), repeats, true);
  benchmarkRefinementTerms(std::max(frames, 30), repeats);
  benchmarkInputs(frames * repeats);
  return 0;
}
