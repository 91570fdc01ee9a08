// Tracking-prior state of one stream of frames, ROS-free.
//
// Contract: frames of ONE camera arrive in order, each with its spots and
// its stamp (seconds, any epoch, the same clock for the whole stream). Each
// frame is processed by the Triangulator it is handed; the previous frame's
// result is passed to it as the tracking prior (Triangulator::process with
// `previous`) only when all of these hold:
//  - use_tracking is on (off: nothing is kept, every frame stands alone);
//  - the previous result was made by the same Triangulator object (a new
//    calibration, camera model or params means a new object, whose beams
//    need not be the old ones);
//  - the stamps increase, by no more than tracking_reset_gap (a gap or a stamp
//    going backwards, e.g. a bag looping, means the dots may have moved
//    anywhere).
// The Triangulator itself falls back to the single-frame solution when too
// few beams persisted. A beam whose dot is missing keeps, for up to
// memory_frames frames, the position the prior predicted for it
// (TriangulationResult::predicted) as its prior: a spurious spot on its
// segment is still refused while the dot is away (with only the last frame,
// a dot missing twice in a row lost that protection). Not thread-safe: one tracker per stream, guarded by
// the caller when several threads feed it.
#pragma once

#include <memory>

#include "structured_light_stabilizer/common/spot.h"
#include "structured_light_stabilizer/triangulation/triangulator.h"

namespace structured_light_stabilizer
{

struct BeamTrackerParams
{
#define SLS_PARAMS_STRUCT BeamTrackerParams
#define SLS_PARAMS_DEF "structured_light_stabilizer/triangulation/beam_tracker_params.def"
#include "structured_light_stabilizer/common/params_struct.inc"
};

class BeamTracker
{
public:
  explicit BeamTracker(const BeamTrackerParams& params = BeamTrackerParams()) : params_(params) {}

  // Takes effect from the next frame; turning use_tracking off forgets the
  // previous frame at that frame.
  void setParams(const BeamTrackerParams& params) { params_ = params; }
  const BeamTrackerParams& params() const { return params_; }

  // Identifies and triangulates the spots of the frame at `stamp_s` with
  // `triangulator` (not null), with the previous frame's result as the prior
  // when the rules above allow, and keeps the result for the next frame.
  // Throws what Triangulator::process throws (the state is then unchanged).
  TriangulationResult process(const std::shared_ptr<const Triangulator>& triangulator, const Spots& spots,
                              double stamp_s);

  // The prior the next frame at `stamp_s` from `triangulator` would get
  // (nullptr = none).
  const TriangulationResult* priorFor(const std::shared_ptr<const Triangulator>& triangulator, double stamp_s) const;

  // Forgets the previous frame.
  void reset();

private:
  // Gives the beams missing from the last result their predicted point
  // while their age allows.
  void remember(bool had_prior);

  BeamTrackerParams params_;
  std::shared_ptr<const Triangulator> owner_;  // made the previous result; null = none kept
  TriangulationResult previous_;               // the last result, with the remembered predictions as points
  std::vector<int> age_;  // per beam: frames since its dot was seen (remembered while <= memory_frames)
  double previous_stamp_s_ = 0.0;
};

}  // namespace structured_light_stabilizer
