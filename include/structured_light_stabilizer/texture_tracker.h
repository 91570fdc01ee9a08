// Tracks the rock's own texture between a reference image and the current
// one, ROS-free.
//
// Contract: images are 8-bit, one channel or three; of a 3-channel image only
// `channel` is used (the caller picks the one in which the projected dots are
// weakest: red for green dots), and only inside the tracked area. Pixel
// coordinates follow OpenCV (centres at integers), full-image coordinates in
// and out. Features are chosen once, in the reference image, inside a given
// region and away from the dots; each frame they are tracked with pyramidal
// Lucas-Kanade from the reference image, starting at positions predicted by
// the caller (the last pose estimate), so no drift accumulates. A feature is
// dropped for the frame when it lands near a dot of the current image, because
// the dots slide over the rock and would drag the window with them.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

namespace structured_light_stabilizer
{

struct TextureTrackerConfig
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
};

class TextureTracker
{
public:
  explicit TextureTracker(const TextureTrackerConfig& config = TextureTrackerConfig()) : config_(config) {}

  // Chooses features in `region` of `image`, at least dot_clearance_px away
  // from every dot in `dots`. Returns the number of features kept.
  int setReference(const cv::Mat& image, int channel, const cv::Rect& region, const std::vector<cv::Point2f>& dots);

  // Keeps only the features whose flag is non-zero (e.g. those that could be
  // lifted to 3D); `keep` has one entry per feature.
  void retain(const std::vector<uint8_t>& keep);

  const std::vector<cv::Point2f>& features() const { return features_; }
  bool empty() const { return features_.empty(); }
  void clear();

  // Tracks every feature into `image` (same size as the reference), starting
  // at `predicted` (one per feature). *ok flags the features tracked cleanly
  // and clear of `dots`. Returns the number of such features.
  int track(const cv::Mat& image, int channel, const std::vector<cv::Point2f>& predicted,
            const std::vector<cv::Point2f>& dots, std::vector<cv::Point2f>* tracked, std::vector<uint8_t>* ok) const;

private:
  // The `roi` part of `image` as one 8-bit channel (a view when possible).
  static cv::Mat channelOf(const cv::Mat& image, int channel, const cv::Rect& roi);
  cv::Mat prepare(const cv::Mat& image, int channel, const cv::Rect& roi) const;
  bool nearDot(const cv::Point2f& p, const std::vector<cv::Point2f>& dots) const;

  TextureTrackerConfig config_;
  cv::Size image_size_;
  cv::Rect roi_;                            // the part of the image that is tracked
  std::vector<cv::Mat> reference_pyramid_;  // of the ROI
  std::vector<cv::Point2f> features_;       // full-image coordinates in the reference
};

}  // namespace structured_light_stabilizer
