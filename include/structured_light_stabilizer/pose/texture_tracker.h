// Tracks the rock's own texture between a reference image and the current
// one, ROS-free.
//
// Contract: images are 8- or 16-bit (CV_8UC1, CV_8UC3, CV_16UC1, CV_16UC3; 16-bit
// pixels MSB-aligned, as ROS's 16-bit encodings, read in 8-bit levels without
// rounding), one channel or three; of a 3-channel image only
// `channel` is used (the caller picks the one in which the projected dots are
// weakest: red for green dots), and only inside the tracked area. Pixel
// coordinates follow OpenCV (centres at integers), full-image coordinates in
// and out; covariances are in full-image pixels squared. Features are chosen
// once, in the reference image, inside a given region and away from the dots;
// each frame they are tracked from the reference image (never chained, so no
// drift accumulates), starting at positions predicted by the caller:
// pyramidal Lucas-Kanade for a wide capture range, and a sub-pixel refinement
// (the measurement) that fits, with the shift, a gain, an offset and a gain
// slope per window (brightness is not constant: vignetting, exposure).
//
// Scale and information (docs/pose_delta.md#texture): each feature's window
// lives on the pyramid level where its texture carries the most information
// (fine texture at full resolution, weak low-frequency texture on a coarse
// level whose window spans more rock). Information is measured against the
// image noise (estimated from the reference image): a window whose gradients
// are not clearly above the noise's is not a feature, however it ranks (a
// flat, textureless board has none), and each tracked feature reports the
// covariance of its shift from its own residual and gradients. A window
// whose current content does not follow its template (fitted gain far below
// one: it was noise, or is now occluded) is dropped for the frame.
// The dots slide over the rock and would drag a window with them: window
// pixels near a dot (reference or current) get no weight, and a feature
// centred near a current dot is dropped for the frame.
// Not thread-safe (one tracker's state); throws nothing.
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
  double quality = 0.005;  // corner quality level of the candidates (relative to the strongest)
  double min_distance_px = 8.0;
  int window_px = 15;              // LK window (odd)
  int pyramid_levels = 2;          // LK levels above the base
  double dot_clearance_px = 10.0;  // minimum distance of a feature from any dot centre
  int roi_margin_px = 48;          // the tracked area is the feature region grown by this
  double max_error = 30.0;         // LK mean absolute patch error (8-bit levels)
  double smooth_sigma_px = 0.0;    // Gaussian pre-blur of both images (0 = off)
  // Final sub-pixel refinement with a gain, an offset and a gain slope per
  // window: the brightness of a rock point is not constant across the image
  // (natural vignetting falls by cos^4, exposure and sun change), and plain
  // Lucas-Kanade turns a gain change into a shift; a window that sees
  // camera-fixed shading (vignetting) over weak texture is pulled towards
  // "no motion" unless the gain may vary across it.
  bool photometric_refinement = true;
  int refinement_window_px = 23;  // odd, in pixels of the feature's level
  int refinement_iterations = 6;
  double max_refinement_px = 1.5;  // in pixels of the feature's level: a refinement moving further is a failure
  // Pyramid levels of the refinement windows. Level 1 (half resolution) is
  // the finest by default: on the simulator's rock and boards the level-0
  // windows were never better than level-1 ones (texture finer than 4 px is
  // mostly defocus-blurred), and without them no full-resolution float copy
  // of the frame is made.
  int min_level = 1;
  int max_level = 2;
  // A window is a feature when its texture's gradient energy is at least
  // this times the noise's (in its weakest direction).
  double min_snr = 1.0;
  // Features whose predicted 1-sigma (full-resolution pixels) is worse are not chosen.
  double max_sigma_px = 0.5;
};

class TextureTracker
{
public:
  explicit TextureTracker(const TextureTrackerParams& config = TextureTrackerParams()) : config_(config) {}

  // 16-bit pixel values to 8-bit levels (the thresholds' unit).
  static constexpr double k16BitTo8Bit = 255.0 / 65535.0;
  // An image of a type this tracker reads (see the contract).
  static bool readable(const cv::Mat& image);

  // Chooses features in `region` of `image`, at least dot_clearance_px away
  // from every dot in `dots`. Returns the number of features kept.
  int setReference(const cv::Mat& image, int channel, const cv::Rect& region, const std::vector<cv::Point2f>& dots);

  // Keeps only the features whose flag is non-zero (e.g. those that could be
  // lifted to 3D); `keep` has one entry per feature.
  void retain(const std::vector<uint8_t>& keep);

  const std::vector<cv::Point2f>& features() const { return features_; }
  // Pyramid level of each feature's refinement window.
  const std::vector<int>& levels() const { return levels_; }
  bool empty() const { return features_.empty(); }
  void clear();
  // Noise (1-sigma, 8-bit levels) of the reference image, median over the tracked area.
  double referenceNoise() const { return reference_noise_; }

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
  // Needs photometric_refinement (otherwise nothing is tracked). `warps`
  // (optional, one per feature) is the predicted local linear map from the
  // reference image to the current one at each feature (rotation about the
  // view axis, scale, the perspective of a tilted patch): the template is
  // warped by it, so a window spanning much rock still matches. *covariance
  // (optional) gets each tracked feature's measured 2x2 covariance (px^2).
  int refineAll(const std::vector<cv::Point2f>& predicted, const std::vector<cv::Point2f>& dots,
                std::vector<cv::Point2f>* tracked, std::vector<uint8_t>* ok,
                std::vector<cv::Matx22d>* covariance = nullptr, const std::vector<cv::Matx22d>* warps = nullptr) const;

  // Noise of a pyramid level relative to the full-resolution white noise
  // sigma0 (cv::pyrDown's 5-tap kernel): the level's pixel noise is
  // value_factor * sigma0 and the variance of its central-difference gradient
  // is gradient_factor * sigma0^2. Exposed for the tests.
  struct LevelNoise
  {
    double value_factor = 1.0;
    double gradient_factor = 0.5;
  };
  static LevelNoise levelNoise(int level);

private:
  // Per feature, on its level: the reference window (rows padded for
  // vectorisation, mask 0 in the padding), the inverse of the 6x6 normal
  // matrix of the model (shift, gain, offset, gain slope; fixed Jacobian: it
  // only sets the step length, the solution is unbiased whatever it is), and
  // the expected gradient-noise energy per window sample (level pixels).
  struct Template
  {
    std::vector<float> value, gx, gy, mask;
    cv::Matx66d normal;  // over the template's own mask
    cv::Matx66d inverse_normal;
    cv::Matx66d inverse_signal;       // with the template noise's share taken out (signalInverse)
    double samples = 0.0;             // window samples with weight
    double noise_sigma0 = 0.0;        // full-resolution noise where the feature is (DN)
    double gradient_noise_var = 0.0;  // of one gradient sample on the level (DN^2)
    cv::Matx22d shift_covariance;     // full-resolution px^2 per unit residual variance (own mask)
    bool ok = false;
  };
  // A template's information: signal gradient energy (noise removed) and the
  // shift's predicted variance in full-resolution px^2 (smallest direction).
  struct Information
  {
    double signal_min = 0.0;  // smallest eigenvalue of the noise-free gradient energy (level px^-2 x DN^2)
    double noise_energy = 0.0;
    double sigma_px = 0.0;  // predicted 1-sigma of the shift, full-resolution px
  };
  struct Candidate
  {
    cv::Point2f position;  // full-image px
    int level;
    double sigma_px;
  };

  // --- selection (texture_tracker.cpp)
  std::vector<Candidate> candidates(const std::vector<cv::Point2f>& dots, const cv::Rect& feature_region) const;
  std::vector<cv::Point2f> findCorners(int level, const cv::Rect& feature_region,
                                       const std::vector<cv::Point2f>& dots) const;
  void choose(std::vector<Candidate> pool);
  // The `roi` part of `image`'s channel as CV_32F in *out (lightly blurred
  // when asked); false for an unusable image.
  bool floatChannel(const cv::Mat& image, int channel, const cv::Rect& roi, cv::Mat* scratch, cv::Mat* out) const;
  bool buildLevels(const cv::Mat& image, int channel, int first_level, int levels, std::vector<cv::Mat>* float_levels,
                   cv::Mat* half);
  // Noise map of the reference ROI: sigma0 (DN) per block (Immerkaer's operator).
  void estimateNoise(const cv::Mat& roi_image);
  double noiseAt(const cv::Point2f& roi_point) const;

  // --- templates and refinement (texture_templates.cpp)
  // Builds feature i's template at its level from the reference pyramid;
  // false when its window leaves the level or its normal matrix is singular.
  bool buildTemplate(const cv::Point2f& position, int level, const std::vector<cv::Point2f>& dots, Template* t) const;
  Information information(const Template& t, int level) const;
  bool maskDots(const std::vector<cv::Point2f>& dots, const cv::Point2f& centre, int level,
                std::vector<float>* mask) const;
  // Normal matrix of the model over the window samples with weight; *samples gets their number.
  cv::Matx66d normalOf(const Template& t, const std::vector<float>& mask, double* samples) const;
  // The same for a mask that is the template's own with some samples zeroed
  // (from the template's normal matrix, less those samples).
  cv::Matx66d maskedNormal(const Template& t, const std::vector<float>& mask, double* samples) const;
  // Feature i's template values seen through the linear map `warp` (null:
  // the template as it is will do, the warp being negligible or leaving the
  // level), from the cache while the warp has not changed by more than a
  // negligible amount since they were computed.
  const std::vector<float>* warped(size_t i, const cv::Matx22d& warp) const;
  // The template's values seen through the linear map whose inverse is
  // `inverse`, sampled from the reference level: *values. False when the
  // warped window leaves the level.
  bool warpTemplate(const Template& t, const cv::Point2f& position, int level, const cv::Matx22d& inverse,
                    std::vector<float>* values) const;
  // Refines *q (level-`level` ROI coordinates) for template t in `image`
  // (CV_32F) with the window weights `mask`; false when the window leaves
  // the image, the result jumps or the fitted gain says the window is not
  // the template's texture. *residual_ss gets the sum of squared residuals
  // left by the fitted model.
  // (`values` in place of the template's when warped).
  bool refine(const Template& t, const std::vector<float>& values, const cv::Mat& image, const std::vector<float>& mask,
              const cv::Matx66d& inverse_normal, const cv::Matx66d& inverse_signal, cv::Point2d* q,
              double* residual_ss) const;
  // Inverse of the normal matrix over `samples` window samples less the
  // template noise's share of the gradient energy (the texture's own
  // information); false when what is left is not positive.
  static bool signalInverse(const cv::Matx66d& normal, double samples, double gradient_noise_var, cv::Matx66d* inverse);
  // Covariance of the shift (full-resolution px^2) per unit residual variance.
  static cv::Matx22d shiftCovariance(const cv::Matx66d& inverse_signal, int level);
  // p in ROI coordinates: inside the tracked area with a window of `level`
  // and clear of the dots; *full gets the full-image position.
  bool accept(const cv::Point2f& p, int level, const std::vector<cv::Point2f>& dots, cv::Point2f* full) const;

  // The `roi` part of `image` as one 8-bit channel (a view when possible;
  // 16-bit images rounded to 8 bits: the Lucas-Kanade pyramid's input).
  static cv::Mat channelOf(const cv::Mat& image, int channel, const cv::Rect& roi);
  cv::Mat prepare(const cv::Mat& image, int channel, const cv::Rect& roi) const;
  bool nearDot(const cv::Point2f& p, const std::vector<cv::Point2f>& dots) const;
  // Half the largest window used at `level`, in full-resolution pixels, plus
  // one level pixel for the gradients.
  int windowHalf(int level) const;
  int refinementHalf() const { return config_.refinement_window_px / 2; }

  TextureTrackerParams config_;
  cv::Size image_size_;
  cv::Rect roi_;                            // the part of the image that is tracked
  std::vector<cv::Mat> reference_pyramid_;  // LK pyramid of the ROI (8-bit)
  std::vector<cv::Mat> reference_levels_;   // CV_32F refinement pyramid of the ROI
  cv::Mat noise_map_;                       // CV_32F sigma0 per block of kNoiseBlock pixels
  double reference_noise_ = 0.0;
  std::vector<cv::Point2f> features_;  // full-image coordinates in the reference
  std::vector<int> levels_;            // refinement level of each feature
  std::vector<Template> templates_;    // one per feature with photometric_refinement
  int used_levels_ = 0;                // 1 + the coarsest level of any feature
  int first_level_ = 0;                // the finest level of any feature
  cv::Mat frame_;                      // the current frame's ROI, tracked channel (half resolution with the refinement)
  std::vector<cv::Mat> frame_levels_;  // CV_32F refinement pyramid of the current ROI
  std::vector<cv::Mat> frame_pyramid_;  // LK pyramid (buffers kept from frame to frame)
  bool frame_pyramid_ready_ = false;    // built for the current frame (on its first pyramidal track)
  cv::Mat scratch_;                     // the tracked channel, 8-bit
  std::vector<uint16_t> row_sums_;      // one row of a pyrDown step's vertical sums
  std::vector<uint32_t> row_sums16_;    // the same for 16-bit images
  bool frame_ok_ = false;               // setFrame() succeeded for the current frame
  // Per feature: its last warped template and the inverse warp it was made with.
  struct WarpCache
  {
    cv::Matx22d inverse;
    std::vector<float> values;
    bool valid = false;
  };
  mutable std::vector<WarpCache> warp_cache_;
};

}  // namespace structured_light_stabilizer
