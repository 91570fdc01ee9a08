// Which frames of a strobed camera have the projector on (docs/daylight.md
// #a-real-camera-with-a-strobe-output). A camera whose strobe output fires
// the projector on every second exposure sends one stream; the
// StrobeDemux nodelet splits it into camera/image_raw (projector on) and
// camera/image_ambient (projector off) with this classifier:
//  - by trigger: the projector's driver reports each pulse's time (e.g. a
//    sensor_msgs/TimeReference per pulse); a frame stamped within
//    `tolerance_s` of a pulse is on, a frame that the pulses have passed
//    without one is ambient, a frame the pulses have not reached yet waits
//    (up to `wait_s`, then it is dropped: no pulse information);
//  - by parity: frames alternate; the phase is fixed (`phase` 0: the first
//    frame is on) or found from the images (`auto_phase`): the difference
//    of an on-frame and the ambient frame before it has a bright positive
//    tail (the dots) and no matching negative one, so each consecutive pair
//    votes, and the phase follows the majority of the last `votes` pairs
//    (a dropped frame flips the alternation; the votes flip it back). With
//    `stamp_gaps`, a gap in the stamps counts the exposures that never
//    arrived (a stamp step in frame periods, rounded, less one; the period is
//    the median of the last 15 steps, and each stamp may be off its exposure
//    by up to a quarter period), so a frame lost in transit or by the
//    camera keeps the alternation without a vote; a pair with an odd number
//    of frames lost between them has one parity and does not vote.
//
// Contract: images of any type OpenCV can subtract (one stream keeps one
// type and size); stamps in seconds. Frames come out in the order they went
// in, each with the image header it came with (not a copy: in trigger mode
// the caller keeps the data alive until the frame comes out; the parity vote
// keeps its own decimated copy). Not thread-safe; one per stream.
#pragma once

#include <deque>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace structured_light_stabilizer
{

enum class StrobeMode
{
  kParity,
  kTrigger,
};

struct StrobeDemuxParams
{
  StrobeMode mode = StrobeMode::kParity;
  // Parity.
  int phase = 0;           // 0: the first frame is on, 1: the second
  bool auto_phase = true;  // correct the phase from the images
  int votes = 9;           // pairs in the vote (odd)
  bool stamp_gaps = true;  // count the exposures missing between stamps
  // Trigger.
  double tolerance_s = 0.005;  // |frame stamp - pulse time| for a frame lit by that pulse
  double wait_s = 0.5;         // how long a frame waits for the pulse times to pass it

  std::string validate() const;  // empty when usable
};

struct StrobedFrame
{
  cv::Mat image;
  double stamp_s = 0.0;
  bool projector_on = false;
  int index = 0;  // order of arrival
  // Parity: the exposure's number, arrivals plus the frames the stamp gaps
  // say were lost (= index without stamp_gaps); trigger mode: index.
  long exposure = 0;
};

class StrobeDemux
{
public:
  explicit StrobeDemux(const StrobeDemuxParams& params = StrobeDemuxParams());

  // A frame in; the frames decided so far out, in arrival order (none, this
  // one, or older ones that waited for pulse times). *dropped: frames given
  // up (trigger mode, no pulse information within wait_s).
  std::vector<StrobedFrame> push(const cv::Mat& image, double stamp_s, std::vector<StrobedFrame>* dropped = nullptr);
  // Trigger mode: a projector pulse at this time (s).
  std::vector<StrobedFrame> addPulse(double stamp_s, std::vector<StrobedFrame>* dropped = nullptr);

  // Parity: the phase in force (0: even exposures on) and the last pair's score.
  int phase() const { return phase_; }
  double lastScore() const { return last_score_; }
  // Parity with stamp_gaps: exposures counted as lost so far.
  long missedExposures() const { return missed_; }

private:
  std::vector<StrobedFrame> decideWaiting(double now_s, std::vector<StrobedFrame>* dropped);
  bool parityOn(StrobedFrame* f);
  long lostBefore(double stamp_s);

  StrobeDemuxParams params_;
  int phase_ = 0;
  int count_ = 0;
  long exposure_ = -1;        // parity: the last frame's exposure number
  double last_stamp_ = 0.0;   // parity: the last frame's stamp (valid once exposure_ >= 0)
  std::deque<double> steps_;  // parity: the last positive stamp steps (s)
  long missed_ = 0;           // parity: exposures counted as lost from the stamps
  cv::Mat previous_;          // decimated copy of the last frame (parity vote)
  double last_score_ = 0.0;
  std::deque<int> vote_history_;  // +1: the pair says "this frame is on"
  std::deque<StrobedFrame> waiting_;
  std::deque<double> pulses_;  // recent pulse times, sorted
};

// Score of a consecutive pair (current minus previous): > 0 when the current
// frame has the projector on. The 99.9th percentile of the difference plus
// its 0.1th (one sample in four per row and column).
double strobePairScore(const cv::Mat& current, const cv::Mat& previous);

}  // namespace structured_light_stabilizer
