#include "structured_light_stabilizer/beam_tracker.h"

namespace structured_light_stabilizer
{

const TriangulationResult* BeamTracker::priorFor(const std::shared_ptr<const Triangulator>& triangulator,
                                                 double stamp_s) const
{
  const double gap = stamp_s - previous_stamp_s_;
  const bool usable =
      params_.use_tracking && owner_ && owner_ == triangulator && gap > 0.0 && gap <= params_.reset_gap_s;
  return usable ? &previous_ : nullptr;
}

TriangulationResult BeamTracker::process(const std::shared_ptr<const Triangulator>& triangulator, const Spots& spots,
                                         double stamp_s)
{
  TriangulationResult result = triangulator->process(spots, priorFor(triangulator, stamp_s));
  if (params_.use_tracking)
  {
    owner_ = triangulator;
    previous_ = result;
    previous_stamp_s_ = stamp_s;
  }
  else
  {
    reset();
  }
  return result;
}

void BeamTracker::reset()
{
  owner_.reset();
  previous_ = TriangulationResult();
}

}  // namespace structured_light_stabilizer
