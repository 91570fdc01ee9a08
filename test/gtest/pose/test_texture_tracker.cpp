// TextureTracker's buffers never alias the caller's images: a mono frame is
// read in place, and a colour frame that follows must not write into it
// (hostile_inputs.test: a mono8 frame, then a bgr8 one, and the manager died
// of a corrupted heap, the mono message's buffer having been freed).
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/pose/texture_tracker.h"

namespace sls = structured_light_stabilizer;

namespace
{
// A smooth random texture (features 2-4 px), 8-bit, three channels.
cv::Mat texture(int seed)
{
  cv::RNG rng(seed);
  cv::Mat noise(480, 640, CV_32FC3);
  rng.fill(noise, cv::RNG::UNIFORM, 0.0, 255.0);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 2.0);
  cv::Mat out;
  cv::normalize(noise, noise, 20.0, 235.0, cv::NORM_MINMAX);
  noise.convertTo(out, CV_8UC3);
  return out;
}

cv::Mat channel(const cv::Mat& bgr, int c)
{
  cv::Mat one;
  cv::extractChannel(bgr, one, c);
  return one;
}
}  // namespace

TEST(TextureTracker, AMonoFrameIsNotWrittenByTheColourFrameAfterIt)
{
  sls::TextureTracker tracker;
  const cv::Mat reference = texture(1);
  ASSERT_GT(tracker.setReference(reference, 2, cv::Rect(0, 0, reference.cols, reference.rows), {}), 0);
  const cv::Mat mono = channel(texture(2), 2);
  const cv::Mat mono_before = mono.clone();
  ASSERT_TRUE(tracker.setFrame(mono, 2));
  ASSERT_TRUE(tracker.setFrame(texture(3), 2));
  EXPECT_EQ(cv::norm(mono, mono_before, cv::NORM_INF), 0.0) << "the colour frame was written into the mono frame";
}

// The same sequence with the mono frame freed in between, as a ROS message
// is: under ASan (the test command's sanitizer run) a write into it is a
// heap-use-after-free.
TEST(TextureTracker, AFreedMonoFrameIsNotTouched)
{
  sls::TextureTracker tracker;
  const cv::Mat reference = texture(4);
  ASSERT_GT(tracker.setReference(reference, 2, cv::Rect(0, 0, reference.cols, reference.rows), {}), 0);
  {
    const cv::Mat mono = channel(texture(5), 2);
    ASSERT_TRUE(tracker.setFrame(mono, 2));
  }
  EXPECT_TRUE(tracker.setFrame(texture(6), 2));
}

// A 16-bit frame (CV_16UC3 / CV_16UC1, MSB-aligned as ROS's bgr16 and mono16)
// is read in 8-bit levels without rounding: an 8-bit texture scaled by 257
// gives the 8-bit tracker's features and tracks to 1e-3 px, and 16-bit
// detail below one 8-bit level is kept, not rounded away.
TEST(TextureTracker, SixteenBitFramesAreReadAtFullDepth)
{
  const cv::Mat reference = texture(7), frame = texture(8);
  cv::Mat reference16, frame16;
  reference.convertTo(reference16, CV_16UC3, 257.0);
  frame.convertTo(frame16, CV_16UC3, 257.0);
  const cv::Rect all(0, 0, reference.cols, reference.rows);
  for (const bool mono : {false, true})
  {
    const cv::Mat r8 = mono ? channel(reference, 2) : reference, f8 = mono ? channel(frame, 2) : frame;
    const cv::Mat r16 = mono ? channel(reference16, 2) : reference16, f16 = mono ? channel(frame16, 2) : frame16;
    sls::TextureTracker t8, t16;
    ASSERT_GT(t8.setReference(r8, 2, all, {}), 0);
    ASSERT_EQ(t16.setReference(r16, 2, all, {}), static_cast<int>(t8.features().size())) << "mono " << mono;
    EXPECT_NEAR(t16.referenceNoise(), t8.referenceNoise(), 1e-3 + 1e-3 * t8.referenceNoise());
    ASSERT_TRUE(t8.setFrame(f8, 2));
    ASSERT_TRUE(t16.setFrame(f16, 2));
    std::vector<cv::Point2f> a, b;
    std::vector<uint8_t> ok_a, ok_b;
    const int na = t8.refineAll(t8.features(), {}, &a, &ok_a);
    const int nb = t16.refineAll(t16.features(), {}, &b, &ok_b);
    ASSERT_EQ(na, nb) << "mono " << mono;
    double worst = 0.0;
    for (size_t k = 0; k < a.size(); ++k)
      if (ok_a[k] && ok_b[k])
        worst = std::max(worst, static_cast<double>(cv::norm(a[k] - b[k])));
    EXPECT_LT(worst, 1e-3) << "mono " << mono;
  }
  // Noise below one 8-bit level is measured on the 16 bits: rounding the
  // same frame to 8 bits adds its 0.29 levels RMS to the estimate.
  // The texture unrounded (float), plus the noise, in 16 bits.
  cv::RNG rng(9);
  cv::Mat smooth(480, 640, CV_32F), noise(480, 640, CV_32F), faint16, faint8;
  rng.fill(smooth, cv::RNG::UNIFORM, 0.0, 255.0);
  cv::GaussianBlur(smooth, smooth, cv::Size(0, 0), 2.0);
  cv::normalize(smooth, smooth, 20.0 * 257.0, 235.0 * 257.0, cv::NORM_MINMAX);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 0.3 * 257.0);
  cv::Mat sum = smooth + noise;
  sum.convertTo(faint16, CV_16U);
  faint16.convertTo(faint8, CV_8U, 1.0 / 257.0);
  sls::TextureTracker n16, n8;
  ASSERT_GT(n16.setReference(faint16, 0, all, {}), 0);
  ASSERT_GT(n8.setReference(faint8, 0, all, {}), 0);
  std::cout << "[ MEASURE ] noise 0.3 levels: estimated " << n16.referenceNoise() << " from 16 bits, "
            << n8.referenceNoise() << " from the same frame in 8 bits\n";
  EXPECT_LT(n16.referenceNoise(), 0.85 * n8.referenceNoise());
}
