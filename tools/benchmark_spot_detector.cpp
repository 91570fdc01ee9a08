// Benchmark of the SpotDetector: the study's baseline chain and the fast
// detector on the same 1024 x 1024 bgr8 frames in one run, single core
// (pinned when the OS allows, cv::setNumThreads(1)). Prints the median and
// 90th percentile ms per frame of each method, their ratio, and the
// baseline's per-stage breakdown.
//
// usage: benchmark_spot_detector [frames=40] [repeats=5]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#ifdef __linux__
#include <sched.h>
#endif

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/spot_detector.h"
#include "../test/gtest/synthetic_dots.h"

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
}  // namespace

int main(int argc, char** argv)
{
  const int frames = argc > 1 ? std::max(1, std::atoi(argv[1])) : 40;
  const int repeats = argc > 2 ? std::max(1, std::atoi(argv[2])) : 5;

  bool pinned = false;
#ifdef __linux__
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0)
  {
    for (int c = 0; c < CPU_SETSIZE; ++c)
    {
      if (CPU_ISSET(c, &set))
      {
        cpu_set_t one;
        CPU_ZERO(&one);
        CPU_SET(c, &one);
        pinned = sched_setaffinity(0, sizeof(one), &one) == 0;
        break;
      }
    }
  }
#endif
  cv::setNumThreads(1);

  // Frames: 10 x 10 dots (sigma 2 px) on textured reddish rock in moderate
  // sun, with clutter, varied per frame.
  std::vector<cv::Mat> images;
  for (int i = 0; i < std::min(frames, 8); ++i)
  {
    synthetic_dots::Config cfg;
    cfg.sigma_px = 1.5 + 0.5 * (i % 4);
    cfg.sun = i % 2 ? 0.3 : 1.0;
    cfg.green_specks = 20;
    cfg.olive_minerals = 20;
    cfg.green_blobs = 5;
    cfg.seed = 1000 + i;
    images.push_back(synthetic_dots::render(cfg).image);
  }
  std::printf("frames: %d distinct synthetic 1024x1024 bgr8 frames, %d detections per method, %s\n",
              static_cast<int>(images.size()), frames * repeats,
              pinned ? "pinned to one core" : "NOT pinned (sched_setaffinity failed)");

  SpotDetectorParams pb;
  pb.method = SpotMethod::kBaseline;
  SpotDetectorParams pf;
  pf.method = SpotMethod::kFast;
  SpotDetector baseline(pb), fast(pf);

  std::vector<double> tb, tf, blur, hsv, in_range, opening, labelling, centroids, sort, f_thr, f_lab, f_ref;
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
      spots_b += baseline.detect(im, PixelFormat::kBgr8, nullptr, &t).spots.size();
      tb.push_back(t.total_ms);
      blur.push_back(t.blur_ms);
      hsv.push_back(t.hsv_ms);
      in_range.push_back(t.in_range_ms);
      opening.push_back(t.opening_ms);
      labelling.push_back(t.labelling_ms);
      centroids.push_back(t.centroids_ms);
      sort.push_back(t.sort_ms);
      spots_f += fast.detect(im, PixelFormat::kBgr8, nullptr, &t).spots.size();
      tf.push_back(t.total_ms);
      f_thr.push_back(t.threshold_ms);
      f_lab.push_back(t.labelling_ms);
      f_ref.push_back(t.refine_ms);
    }
  }
  const double n = static_cast<double>(tb.size());
  std::printf("baseline: median %.3f ms/frame (p90 %.3f), %.1f spots/frame\n", median(tb), percentile(tb, 0.9),
              spots_b / n);
  std::printf("  stages (median ms): blur %.3f, HSV %.3f, inRange %.3f, opening %.3f, labelling %.3f, "
              "centroids %.3f, row sort %.3f\n",
              median(blur), median(hsv), median(in_range), median(opening), median(labelling), median(centroids),
              median(sort));
  std::printf("fast:     median %.3f ms/frame (p90 %.3f), %.1f spots/frame\n", median(tf), percentile(tf, 0.9),
              spots_f / n);
  std::printf("  stages (median ms): threshold pass %.3f, labelling %.3f, refine %.3f\n", median(f_thr),
              median(f_lab), median(f_ref));
  std::printf("ratio baseline/fast (medians): %.1fx\n", median(tb) / median(tf));
  return 0;
}
