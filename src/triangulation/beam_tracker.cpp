#include "structured_light_stabilizer/triangulation/beam_tracker.h"

namespace structured_light_stabilizer
{

const TriangulationResult* BeamTracker::priorFor(const std::shared_ptr<const Triangulator>& triangulator,
                                                 double stamp_s) const
{
  const double gap = stamp_s - previous_stamp_s_;
  const bool usable =
      params_.use_tracking && owner_ && owner_ == triangulator && gap > 0.0 && gap <= params_.tracking_reset_gap;
  return usable ? &previous_ : nullptr;
}

TriangulationResult BeamTracker::process(const std::shared_ptr<const Triangulator>& triangulator, const Spots& spots,
                                         double stamp_s)
{
  const TriangulationResult* prior = priorFor(triangulator, stamp_s);
  TriangulationResult result = triangulator->process(spots, prior);
  if (params_.use_tracking)
  {
    owner_ = triangulator;
    previous_ = result;
    previous_stamp_s_ = stamp_s;
    remember(prior != nullptr);
  }
  else
  {
    reset();
  }
  return result;
}

void BeamTracker::remember(bool had_prior)
{
  const size_t n = previous_.points.size();
  if (!had_prior || age_.size() != n)
    age_.assign(n, 0);
  for (size_t b = 0; b < n; ++b)
  {
    if (previous_.points[b].allFinite())
    {
      age_[b] = 0;
    }
    else if (b < previous_.predicted.size() && previous_.predicted[b].allFinite() && age_[b] < params_.memory_frames)
    {
      previous_.points[b] = previous_.predicted[b];
      ++age_[b];
    }
  }
}

void BeamTracker::reset()
{
  owner_.reset();
  previous_ = TriangulationResult();
  age_.clear();
}

}  // namespace structured_light_stabilizer
