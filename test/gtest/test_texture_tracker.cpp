// TextureTracker's buffers never alias the caller's images: a mono frame is
// read in place, and a colour frame that follows must not write into it
// (hostile_inputs.test: a mono8 frame, then a bgr8 one, and the manager died
// of a corrupted heap, the mono message's buffer having been freed).
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/texture_tracker.h"

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
