#pragma once
// Where to look for the dots in the next frame: work proportional to the
// dots, not to the frame. The dots are fixed to the projector,
// which is rigid with the camera, so from one frame to the next a dot moves
// in the image only as far as the depth under it changes (the rig's motion
// along its rows slides it along its epipolar line): a window around each dot
// of the last frame, widened by `track_margin_px`, holds it. A full-width band swept
// down the frame (`track_band_rows` a frame) finds dots that appear (an occluder
// leaving, a dot coming into view), and a full search runs at the start, after
// a refused frame, when the frame size changes, and when more dots than
// `max(2, 10 %)` of the last frame's vanish from their windows in one frame
// (a motion faster than the margin).
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "structured_light_stabilizer/detection/spot_detector.h"

namespace structured_light_stabilizer
{

struct SpotSearchParams
{
#define SLS_PARAMS_STRUCT SpotSearchParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/detection/spot_search_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"

  std::string validate() const;
  std::vector<std::string> sanitize();
};

// Regions cut from a frame of `frame` size: clipped to the frame, widened to
// multiples of 8 px (a Bayer cell, a yuv422 pixel pair and the fast method's
// coarse blocks stay whole, so a region finds what a full search finds
// there), and merged where one box over two costs at most a quarter more
// pixels than the two.
std::vector<cv::Rect> mergeSearchRegions(const std::vector<cv::Rect>& regions, const cv::Size& frame);

class SpotSearchPlanner
{
public:
  explicit SpotSearchPlanner(const SpotSearchParams& params = SpotSearchParams());

  // New parameters; the next frame is a full search.
  std::vector<std::string> setParams(const SpotSearchParams& params);
  const SpotSearchParams& params() const { return params_; }
  void reset();

  // The regions to search in the next frame of this size (SpotDetector::
  // detectIn); empty: the whole frame.
  std::vector<cv::Rect> plan(const cv::Size& frame);
  // The next plan() is a full search, for this reason (e.g. the detector's
  // statistics of a whole frame are due: SpotDetector::hasRegionStatistics).
  void requestFullSearch(const std::string& why);
  // The result of the frame planned last.
  void update(const SpotDetectionResult& result);

  bool lastWasFull() const { return last_full_; }
  long fullSearches() const { return full_searches_; }
  long frames() const { return frames_; }
  // Why the last full search ran ("start", "lost 12 of 100 dots", ...).
  const std::string& lastFullReason() const { return full_reason_; }

private:
  SpotSearchParams params_;
  cv::Size frame_;
  std::vector<cv::Point2d> dots_;  // the last frame's dots
  std::vector<double> radius_;     // their windows' half sizes without the margin
  bool need_full_ = true;
  bool last_full_ = false;
  int band_ = 0;
  int since_full_ = 0;
  long full_searches_ = 0, frames_ = 0;
  std::string full_reason_ = "start";
};

}  // namespace structured_light_stabilizer
