// Tracks the rock's own texture between a reference image and the current
// one, ROS-free.
//
// Contract: images are 8-bit, one channel or three; of a 3-channel image only
// `channel` is used (the caller picks the one in which the projected dots are
// weakest: red for green dots), and only inside the tracked area. Pixel
// coordinates follow OpenCV (centres at integers), full-image coordinates in
// and out. Features are chosen once, in the reference image, inside a given
// region and away from the dots; each frame they are tracked from the
// reference image (never chained, so no drift accumulates), starting at
// positions predicted by the caller: pyramidal Lucas-Kanade for a wide
// capture range, and a sub-pixel refinement that fits a gain and an offset
// per window with the shift (brightness is not constant: vignetting,
// exposure). The dots slide over the rock and would drag a window with them:
// window pixels near a dot (reference or current) get no weight, and a
// feature centred near a current dot is dropped for the frame.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

namespace structured_light_stabilizer
{

struct TextureTrackerParams
{
  int max_features = 200;
  double quality = 0.005;  // goodFeaturesToTrack quality level
  double min_distance_px = 8.0;
  int window_px = 15;              // LK window (odd)
  int pyramid_levels = 2;          // LK levels above the base
  double dot_clearance_px = 10.0;  // minimum distance of a feature from any dot centre
  int roi_margin_px = 48;          // the tracked area is the feature region grown by this
  double max_error = 30.0;         // LK mean absolute patch error (8-bit levels)
  double smooth_sigma_px = 0.0;    // Gaussian pre-blur of both images (0 = off)
  // Final sub-pixel refinement on the full-resolution image with a gain and
  // an offset per window: the brightness of a rock point is not constant
  // across the image (natural vignetting falls by cos^4, exposure and sun
  // change), and plain Lucas-Kanade turns a gain change into a shift.
  bool photometric_refinement = true;
  int refinement_window_px = 23;  // odd; larger than the LK window: the refinement is cheaper per pixel
  int refinement_iterations = 6;
  double max_refinement_px = 1.5;  // a refinement moving further is a failure
};

class TextureTracker
{
public:
  explicit TextureTracker(const TextureTrackerParams& config = TextureTrackerParams()) : config_(config) {}

  // Chooses features in `region` of `image`, at least dot_clearance_px away
  // from every dot in `dots`. Returns the number of features kept.
  int setReference(const cv::Mat& image, int channel, const cv::Rect& region, const std::vector<cv::Point2f>& dots);

  // Keeps only the features whose flag is non-zero (e.g. those that could be
  // lifted to 3D); `keep` has one entry per feature.
  void retain(const std::vector<uint8_t>& keep);

  const std::vector<cv::Point2f>& features() const { return features_; }
  bool empty() const { return features_.empty(); }
  void clear();

  // Tracking a frame: setFrame(), then trackPyramidal() (pyramidal
  // Lucas-Kanade, a wide capture range) and/or refineAll() (the gain-and-
  // offset refinement, within about a pixel of the truth: the measurement).
  // The caller re-predicts in between, so a few pyramidal tracks suffice.
  // In both, `predicted` has one entry per feature (full-image pixels); *ok
  // flags the features tracked cleanly, window inside the image and clear of
  // `dots`; the return value is their number.
  //
  // False when `image` is unusable (empty, another size than the reference).
  bool setFrame(const cv::Mat& image, int channel);
  // Only the features whose `which` flag is set (all when `which` is empty).
  int trackPyramidal(const std::vector<cv::Point2f>& predicted, const std::vector<uint8_t>& which,
                     const std::vector<cv::Point2f>& dots, std::vector<cv::Point2f>* tracked, std::vector<uint8_t>* ok);
  // Needs photometric_refinement (otherwise nothing is tracked).
  int refineAll(const std::vector<cv::Point2f>& predicted, const std::vector<cv::Point2f>& dots,
                std::vector<cv::Point2f>* tracked, std::vector<uint8_t>* ok) const;

private:
  // Per feature, the reference window and the 4x4 inverse normal matrix of
  // the gain/offset model (fixed Jacobian: it only sets the step length, the
  // solution is unbiased whatever it is).
  struct Template
  {
    std::vector<float> value, gx, gy, mask;  // rows padded for vectorisation, mask 0 in the padding
    cv::Matx44d inverse_normal;
    bool ok = false;
  };
  // Corners of `image` (the feature region) where `mask` is set, in its coordinates.
  std::vector<cv::Point2f> findCorners(const cv::Mat& image, const cv::Mat& mask) const;
  void buildTemplates(const cv::Mat& roi_image, const std::vector<cv::Point2f>& dots);
  bool maskDots(const std::vector<cv::Point2f>& dots, const cv::Point2f& centre, std::vector<float>* mask) const;
  cv::Matx44d normalOf(const Template& t, const std::vector<float>& mask) const;
  // Refines *p (ROI coordinates) for feature i in `image` (CV_32F) with the
  // window weights `mask`; false when the window leaves the image or the
  // result jumps.
  bool refine(size_t i, const cv::Mat& image, const std::vector<float>& mask, const cv::Matx44d& inverse_normal,
              cv::Point2f* p) const;
  // p in ROI coordinates: inside the tracked area and clear of the dots; *full
  // gets the full-image position.
  bool accept(const cv::Point2f& p, const std::vector<cv::Point2f>& dots, cv::Point2f* full) const;

  // The `roi` part of `image` as one 8-bit channel (a view when possible).
  static cv::Mat channelOf(const cv::Mat& image, int channel, const cv::Rect& roi);
  cv::Mat prepare(const cv::Mat& image, int channel, const cv::Rect& roi) const;
  bool nearDot(const cv::Point2f& p, const std::vector<cv::Point2f>& dots) const;
  // Half the largest window used, plus one pixel for the gradients.
  int windowHalf() const
  {
    return std::max(config_.window_px, config_.photometric_refinement ? config_.refinement_window_px : 0) / 2 + 1;
  }

  TextureTrackerParams config_;
  cv::Size image_size_;
  cv::Rect roi_;                            // the part of the image that is tracked
  std::vector<cv::Mat> reference_pyramid_;  // of the ROI
  std::vector<cv::Point2f> features_;       // full-image coordinates in the reference
  std::vector<Template> templates_;         // one per feature with photometric_refinement
  cv::Mat frame_;                           // the current frame's ROI, tracked channel
  cv::Mat frame_float_;                     // the same as CV_32F, for the refinement
  std::vector<cv::Mat> frame_pyramid_;      // built on the first pyramidal track of a frame
};

}  // namespace structured_light_stabilizer
