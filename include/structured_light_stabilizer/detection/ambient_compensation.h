// The ambient image of a strobed pair, aligned to the on-frame's time
// (docs/daylight.md#strobing). A camera with a strobe output takes the
// projector-on frames between projector-off ("ambient") frames; the rig
// moves between them, so the ambient frame nearest in time does not sit
// where the on-frame's rock does. compensateAmbient() takes two ambient
// frames (before and after the on-frame, or two before it) and gives the
// rock's image at the on-frame's time: the image motion between the two
// (a homography, estimated from the rock's texture or given, e.g. from
// PoseDelta's motion and the rock's depth) raised to the fraction of the
// interval where the on-frame lies, each frame warped there and the two
// blended. The SpotDetector subtracts it from the on-frame (~strobe).
//
// Contract: images of one size and type, CV_8UC1/3/4 or CV_16UC1/3 (Bayer
// mosaics: set AmbientCompensationParams::layout; each colour phase is
// warped on its own sites). Stamps in seconds (any epoch, the same for all).
// Never throws on bad input: valid = false and status says why. Pure
// function, any thread.
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace structured_light_stabilizer
{

struct AmbientFrame
{
  cv::Mat image;  // projector off
  double stamp_s = 0.0;
};

enum class AmbientLayout
{
  kInterleaved,  // mono or packed colour
  kBayerRggb,
  kBayerBggr,
  kBayerGbrg,
  kBayerGrbg,
};

enum class AmbientMotion
{
  kNearest,     // the nearer ambient frame as it is
  kBlend,       // the two blended by time, no warping (no motion model)
  kHomography,  // warped along the image motion between the two, then blended
};

struct AmbientCompensationParams
{
  AmbientMotion motion = AmbientMotion::kHomography;
  AmbientLayout layout = AmbientLayout::kInterleaved;
  // Ambient frames farther than this from the on-frame are not used (s).
  double max_gap_s = 0.25;
  // When both frames lie on one side of the on-frame, extrapolate the motion
  // up to this many intervals beyond the nearer one (0: use it as it is).
  double max_extrapolation = 1.0;
  // Motion estimation: a grid of grid x grid points tracked by pyramidal
  // Lucas-Kanade from one frame to the other, a homography fitted to them
  // (RANSAC, threshold in px). Fewer than min_points tracked: blend instead.
  // 16 x 16 points for the homography's 8 parameters: against 24 x 24 the
  // estimate's error to the true ambient moved by at most 0.001 DN
  // (test_ambient_compensation) for 0.44 x the tracking's cost.
  // Two pyramid levels above the (binned) base follow a motion of about 40
  // tracking pixels (80 px of the frame when binned) between the two; with
  // three the estimate's error moved by at most 7e-5 DN (the same tests) for
  // 1.27 x the tracking's cost.
  int grid = 16;
  int window_px = 21;
  int pyramid_levels = 2;
  double ransac_threshold_px = 0.5;
  int min_points = 40;
  // Track on the grey image binned 2 x 2 (as a Bayer mosaic always is): a
  // quarter of the pixels for the pyramid and its gradients, which are most
  // of the tracking's cost; the motion is fitted to a few hundred points, so
  // its error stays well below the bilinear warp's (test_ambient_compensation).
  bool half_resolution_tracking = true;
  // The parts of the on-frame that will be read (SpotDetector::detectIn's
  // merged regions); empty: the whole frame. Only these are warped and
  // blended (interleaved layouts; a Bayer mosaic is compensated whole);
  // elsewhere the estimate's image is undefined.
  std::vector<cv::Rect> regions;
  // 8-bit interleaved inputs: the estimate as CV_32F with their channels,
  // the blend unrounded (SpotDetector::detect reads it so). Rounding the
  // blend to 8 bits adds 0.29 DN RMS, which on a camera whose noise is below
  // a DN (the recommended rig's at 8 bits) is most of the estimate's error:
  // 0.376 DN RMS rounded, 0.237 DN unrounded, against 0.357 DN for one
  // projector-off frame at the on-frame's own time (green, the strobed bag's
  // scene; docs/daylight.md). Other inputs: their own type. A nearest-frame
  // estimate is that frame as it is.
  bool unrounded = false;
};

struct AmbientEstimate
{
  cv::Mat image;  // the inputs' size and type (CV_32F with `unrounded`), aligned to the on-frame; empty when !valid
  bool valid = false;
  std::string status;  // what was done, or why nothing could be
  // Noise variance of `image` relative to one ambient frame's: (1-w)^2 + w^2
  // for a blend at fraction w (bilinear warping lowers it further). The
  // difference on - image has var_on + noise_variance_scale * var_ambient.
  double noise_variance_scale = 1.0;
  double fraction = 0.0;                       // w: where the on-frame lies, 0 at frame a, 1 at frame b
  cv::Matx33d motion_ab = cv::Matx33d::eye();  // homography a -> b (full-resolution pixels)
  int points_used = 0;                         // inliers of the homography fit
  double residual_px = 0.0;                    // their RMS residual
};

// The tracking pyramids of the last call's two ambient frames, kept for the
// next: in a strobed stream each projector-off frame lies between two
// projector-on frames and is compensated with both, so its grey image and
// pyramid are built once. An entry is reused for a frame of the same stamp,
// size and type with the same tracking parameters (a frame's pixels must not
// change under one stamp). One per stream; not thread-safe.
struct AmbientTrackingCache
{
  struct Entry
  {
    double stamp_s = 0.0;
    cv::Size size;
    int type = -1;
    AmbientLayout layout = AmbientLayout::kInterleaved;
    bool half_resolution = true;
    int window_px = 0, pyramid_levels = 0;
    double scale = 1.0;            // tracking image pixels per frame pixel
    std::vector<cv::Mat> pyramid;  // cv::buildOpticalFlowPyramid's, with gradients
  };
  Entry entries[2];
  // The last two estimates' images, each written over by a later call once
  // nothing else holds it (a fresh 12 MB float frame costs the kernel a page
  // fault for every 4 kB page the blend touches: 600-3000 per frame). Two,
  // because a SpotDetector keeps its last frame's ambient until the next.
  cv::Mat images[2];
  int next_image = 0;  // the slot a new buffer goes to
  cv::Mat warped[2];   // scratch: the two frames warped, region by region
};

// cache (optional): reuses the pyramid of a frame seen in the last call, and
// the last estimate's image buffer once the caller has let go of it.
AmbientEstimate compensateAmbient(double on_stamp_s, const AmbientFrame& a, const AmbientFrame& b,
                                  const AmbientCompensationParams& params = AmbientCompensationParams(),
                                  const cv::Matx33d* motion_hint = nullptr, AmbientTrackingCache* cache = nullptr);

// H^w for a homography near the identity (matrix logarithm and exponential,
// normalised to det 1): the motion over a fraction w of the interval. All NaN
// when H is no motion (det H <= 0 or not finite: singular, or a reflection).
cv::Matx33d homographyPower(const cv::Matx33d& H, double w);

// The homography from the rig's motion over the interval and the rock's
// mean plane (n^T X = d in the first frame's camera frame, n unit, d > 0):
// x_b ~ K (R + t n^T / d) K^-1 x_a, with X_b = R X_a + t (PoseDelta's
// convention). For a motion hint from PoseDelta's estimate.
cv::Matx33d planeHomography(const cv::Matx33d& K, const cv::Matx33d& R, const cv::Vec3d& t, const cv::Vec3d& n,
                            double d);

}  // namespace structured_light_stabilizer
