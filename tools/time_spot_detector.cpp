// time_spot_detector: the fast SpotDetector's thread CPU per frame on frames
// read from PNG files, so that detectors of other versions of this package
// can be timed on identical frames in one run
// (scripts/compare_detector_cost, docs/performance.md#spotdetector).
//
//   time_spot_detector --write DIR   renders benchmark_spot_detector's
//                                    whole-frame frames into DIR: full_0..7.png
//                                    (about half the dots clipped) and
//                                    dim_0..7.png (dots 0.3 x as bright)
//   time_spot_detector PREFIX [REPEATS=25]
//                                    detects PREFIX_0.png .. PREFIX_7.png
//                                    REPEATS times on one thread and prints
//                                    the median and p90 thread CPU per frame
//
// Built with -DSLS_TIME_ONLY it needs only SpotDetector's public API of an
// older version (detect(image, PixelFormat::kBgr8)), not the simulator.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "structured_light_stabilizer/detection/spot_detector.h"
#ifndef SLS_TIME_ONLY
#include "support/benchmark_frames.h"
#endif

using namespace structured_light_stabilizer;

namespace
{
constexpr int kFrames = 8;

double threadCpuMs()
{
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

#ifndef SLS_TIME_ONLY
// benchmark_spot_detector's whole-frame frames, the dots at full brightness
// and 0.3 x as bright.
int writeFrames(const std::string& dir)
{
  for (double brightness : {1.0, 0.3})
    for (int i = 0; i < kFrames; ++i)
    {
      const std::string name = dir + (brightness < 1.0 ? "/dim_" : "/full_") + std::to_string(i) + ".png";
      if (!cv::imwrite(name, Simulator(test::benchmarkFrameParams(i, brightness)).render(0.1 * i).image))
      {
        std::fprintf(stderr, "cannot write %s\n", name.c_str());
        return 1;
      }
    }
  return 0;
}
#endif
}  // namespace

int main(int argc, char** argv)
{
  if (argc < 2)
  {
    std::fprintf(stderr, "usage: time_spot_detector --write DIR | PREFIX [REPEATS]\n");
    return 2;
  }
  const std::string first = argv[1];
  if (first == "--write")
  {
#ifndef SLS_TIME_ONLY
    return argc > 2 ? writeFrames(argv[2]) : 2;
#else
    std::fprintf(stderr, "built with SLS_TIME_ONLY: no simulator\n");
    return 2;
#endif
  }
  cv::setNumThreads(1);
  const int repeats = argc > 2 ? std::max(1, std::atoi(argv[2])) : 25;
  std::vector<cv::Mat> frames;
  for (int i = 0; i < kFrames; ++i)
  {
    frames.push_back(cv::imread(first + "_" + std::to_string(i) + ".png", cv::IMREAD_COLOR));
    if (frames.back().empty())
    {
      std::fprintf(stderr, "cannot read %s_%d.png\n", first.c_str(), i);
      return 1;
    }
  }
  SpotDetector detector;
  std::vector<double> ms;
  double spots = 0;
  for (int r = 0; r < repeats; ++r)
    for (const cv::Mat& f : frames)
    {
      const double t0 = threadCpuMs();
      const SpotDetectionResult result = detector.detect(f, PixelFormat::kBgr8);
      ms.push_back(threadCpuMs() - t0);
      spots += static_cast<double>(result.spots.size());
    }
  std::sort(ms.begin(), ms.end());
  std::printf("median %.3f ms, p90 %.3f ms thread CPU per frame, %.1f spots/frame (%zu detections)\n",
              ms[ms.size() / 2], ms[ms.size() * 9 / 10], spots / static_cast<double>(ms.size()), ms.size());
  return 0;
}
