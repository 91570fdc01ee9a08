// Splitting a strobed camera's stream (strobe_demux.h): by the projector's
// pulse times, or by alternation with its phase checked on the images.
#include "structured_light_stabilizer/detection/strobe_demux.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace structured_light_stabilizer
{

std::string StrobeDemuxParams::validate() const
{
  if (phase != 0 && phase != 1)
    return "phase must be 0 or 1";
  if (votes < 1 || votes % 2 == 0 || votes > 99)
    return "votes must be odd, in [1, 99]";
  if (!(tolerance_s > 0.0) || !(wait_s >= 0.0) || !std::isfinite(wait_s))
    return "tolerance_s must be > 0 and wait_s >= 0";
  return "";
}

namespace
{

// One pixel in four per row and column, as float: what the vote compares.
cv::Mat decimated(const cv::Mat& image)
{
  cv::Mat small, out;
  cv::resize(image, small, cv::Size((image.cols + 3) / 4, (image.rows + 3) / 4), 0, 0, cv::INTER_NEAREST);
  small.convertTo(out, CV_32F);
  return out;
}

// 99.9th plus 0.1th percentile of a - b (float images of one size and type).
double tailBalance(const cv::Mat& a, const cv::Mat& b)
{
  const cv::Mat diff = a - b;
  const cv::Mat d = diff.reshape(1, 1);
  std::vector<float> v(d.ptr<float>(), d.ptr<float>() + d.total());
  if (v.size() < 1000)
    return 0.0;
  const size_t hi = v.size() * 999 / 1000, lo = v.size() / 1000;
  std::nth_element(v.begin(), v.begin() + hi, v.end());
  const float top = v[hi];
  std::nth_element(v.begin(), v.begin() + lo, v.end());
  return top + v[lo];
}

}  // namespace

double strobePairScore(const cv::Mat& current, const cv::Mat& previous)
{
  if (current.size() != previous.size() || current.type() != previous.type() || current.empty())
    return 0.0;
  return tailBalance(decimated(current), decimated(previous));
}

StrobeDemux::StrobeDemux(const StrobeDemuxParams& params) : params_(params), phase_(params.phase) {}

// Exposures lost between the last frame and one stamped `stamp_s`: the step
// in periods (the median of the recent steps), rounded, less one. Each stamp
// may be off its exposure by up to a quarter of a period (a step then
// differs from a whole number of periods by less than a half). Gaps of more
// than kMaxLost frames (a pause, a restart) are left to the vote.
long StrobeDemux::lostBefore(double stamp_s)
{
  constexpr size_t kSteps = 15, kMinSteps = 3;
  constexpr long kMaxLost = 30;
  if (exposure_ < 0)
    return 0;
  const double step = stamp_s - last_stamp_;
  if (!(step > 0.0) || !std::isfinite(step))
    return 0;  // a stamp that goes back (a bag looping) or repeats: no gap to count
  long lost = 0;
  if (steps_.size() >= kMinSteps)
  {
    std::vector<double> sorted(steps_.begin(), steps_.end());
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double period = sorted[sorted.size() / 2];
    const double frames = std::round(step / period);
    if (frames >= 2.0 && frames <= kMaxLost + 1)
      lost = static_cast<long>(frames) - 1;
  }
  steps_.push_back(step);
  if (steps_.size() > kSteps)
    steps_.pop_front();
  return lost;
}

bool StrobeDemux::parityOn(StrobedFrame* frame)
{
  StrobedFrame& f = *frame;
  const long lost = params_.stamp_gaps ? lostBefore(f.stamp_s) : 0;
  missed_ += lost;
  exposure_ += 1 + lost;
  last_stamp_ = f.stamp_s;
  f.exposure = exposure_;
  // The vote keeps its own (decimated) copy: the caller's image may not outlive the call.
  const cv::Mat current = params_.auto_phase ? decimated(f.image) : cv::Mat();
  // An odd number of frames lost in between: both frames of the pair have one parity.
  if (params_.auto_phase && lost % 2 == 0 && !previous_.empty() && previous_.size() == current.size() &&
      previous_.type() == current.type())
  {
    last_score_ = tailBalance(current, previous_);
    if (last_score_ != 0.0)
    {
      // The vote, in the phase's terms: the parity that this pair says is on.
      const int says_on_parity = static_cast<int>((last_score_ > 0.0 ? f.exposure : f.exposure + 1) % 2);
      vote_history_.push_back(says_on_parity);
      while (static_cast<int>(vote_history_.size()) > params_.votes)
        vote_history_.pop_front();
      // A majority of the whole window moves the phase.
      const int odd = static_cast<int>(std::count(vote_history_.begin(), vote_history_.end(), 1));
      const int even = static_cast<int>(vote_history_.size()) - odd;
      if (2 * odd > params_.votes)
        phase_ = 1;
      else if (2 * even > params_.votes)
        phase_ = 0;
    }
  }
  previous_ = current;
  return f.exposure % 2 == phase_;
}

std::vector<StrobedFrame> StrobeDemux::push(const cv::Mat& image, double stamp_s, std::vector<StrobedFrame>* dropped)
{
  StrobedFrame f{image, stamp_s, false, count_, count_};
  ++count_;
  if (params_.mode == StrobeMode::kParity)
  {
    f.projector_on = parityOn(&f);
    return {f};
  }
  waiting_.push_back(f);
  return decideWaiting(stamp_s, dropped);
}

std::vector<StrobedFrame> StrobeDemux::addPulse(double stamp_s, std::vector<StrobedFrame>* dropped)
{
  pulses_.insert(std::upper_bound(pulses_.begin(), pulses_.end(), stamp_s), stamp_s);
  while (pulses_.size() > 64)
    pulses_.pop_front();
  const double now = waiting_.empty() ? stamp_s : std::max(stamp_s, waiting_.back().stamp_s);
  return decideWaiting(now, dropped);
}

// Decides the waiting frames in order: on when a pulse is within the
// tolerance, ambient once a later pulse shows none will come; the first
// undecided one stops the queue until the pulses pass it or it times out.
std::vector<StrobedFrame> StrobeDemux::decideWaiting(double now_s, std::vector<StrobedFrame>* dropped)
{
  std::vector<StrobedFrame> out;
  while (!waiting_.empty())
  {
    StrobedFrame& f = waiting_.front();
    const bool lit = std::any_of(pulses_.begin(), pulses_.end(),
                                 [&](double p) { return std::fabs(p - f.stamp_s) <= params_.tolerance_s; });
    const bool passed = !pulses_.empty() && pulses_.back() > f.stamp_s + params_.tolerance_s;
    if (lit || passed)
    {
      f.projector_on = lit;
      out.push_back(f);
    }
    else if (now_s - f.stamp_s > params_.wait_s)
    {
      if (dropped)
        dropped->push_back(f);
    }
    else
      break;
    waiting_.pop_front();
  }
  return out;
}

}  // namespace structured_light_stabilizer
