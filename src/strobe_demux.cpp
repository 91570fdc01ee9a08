// Splitting a strobed camera's stream (strobe_demux.h): by the projector's
// pulse times, or by alternation with its phase checked on the images.
#include "structured_light_stabilizer/strobe_demux.h"

#include <algorithm>
#include <cmath>

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

double strobePairScore(const cv::Mat& current, const cv::Mat& previous)
{
  if (current.size() != previous.size() || current.type() != previous.type() || current.empty())
    return 0.0;
  std::vector<float> d;
  d.reserve(static_cast<size_t>(current.total() / 16 * current.channels()) + 16);
  cv::Mat a, b;
  current.convertTo(a, CV_32F);
  previous.convertTo(b, CV_32F);
  const int n = a.channels();
  for (int r = 0; r < a.rows; r += 4)
  {
    const float *pa = a.ptr<float>(r), *pb = b.ptr<float>(r);
    for (int c = 0; c < a.cols; c += 4)
      for (int k = 0; k < n; ++k)
        d.push_back(pa[c * n + k] - pb[c * n + k]);
  }
  const size_t hi = d.size() * 999 / 1000, lo = d.size() / 1000;
  std::nth_element(d.begin(), d.begin() + hi, d.end());
  const float top = d[hi];
  std::nth_element(d.begin(), d.begin() + lo, d.end());
  return top + d[lo];
}

StrobeDemux::StrobeDemux(const StrobeDemuxParams& params) : params_(params), phase_(params.phase) {}

bool StrobeDemux::parityOn(const StrobedFrame& f)
{
  if (params_.auto_phase && !previous_.empty())
  {
    last_score_ = strobePairScore(f.image, previous_);
    if (last_score_ != 0.0)
    {
      // The vote, in the phase's terms: the parity that this pair says is on.
      const int says_on_parity = (last_score_ > 0.0 ? f.index : f.index + 1) % 2;
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
  previous_ = f.image;
  return f.index % 2 == phase_;
}

std::vector<StrobedFrame> StrobeDemux::push(const cv::Mat& image, double stamp_s, std::vector<StrobedFrame>* dropped)
{
  StrobedFrame f{image, stamp_s, false, count_++};
  if (params_.mode == StrobeMode::kParity)
  {
    f.projector_on = parityOn(f);
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
