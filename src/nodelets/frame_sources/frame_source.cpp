#include "nodelets/frame_sources/frame_source.h"

#include <cstdarg>
#include <cstdio>

#include <boost/shared_ptr.hpp>
#include <opencv2/imgproc.hpp>
#include <pluginlib/class_loader.hpp>
#include <sensor_msgs/image_encodings.h>

namespace structured_light_stabilizer
{

namespace
{

struct SourceEntry
{
  const char* name;  // the ~source value
  std::unique_ptr<FrameSource> (*make)(const SourceContext&);  // built in, or
  const char* plugin;  // the FrameSourceFactory plugin that makes it
};

// Every source the driver knows, in the order the messages list them.
const SourceEntry kSources[] = {
    {"sim", nullptr, "structured_light_stabilizer/SimFrameSource"},
    {"device", &makeDeviceSource, nullptr},
    {"video", &makeVideoSource, nullptr},
    {"images", &makeImagesSource, nullptr},
};

FrameSourceHandle builtIn(std::unique_ptr<FrameSource> source)
{
  return FrameSourceHandle(source.release(), [](FrameSource* s) { delete s; });
}

FrameSourceHandle fromPlugin(const char* plugin, const SourceContext& ctx)
{
  // Destroyed in reverse order: the factory before its loader.
  struct Loaded
  {
    std::unique_ptr<pluginlib::ClassLoader<FrameSourceFactory>> loader;
    boost::shared_ptr<FrameSourceFactory> factory;
  };
  auto loaded = std::make_shared<Loaded>();
  try
  {
    loaded->loader = std::make_unique<pluginlib::ClassLoader<FrameSourceFactory>>(
        "structured_light_stabilizer", "structured_light_stabilizer::FrameSourceFactory");
    loaded->factory = loaded->loader->createInstance(plugin);
  }
  catch (const std::exception& e)  // pluginlib::PluginlibException and class_loader's
  {
    ctx.error(stringf("the source's plugin %s could not be loaded (%s)", plugin, e.what()));
    return nullptr;
  }
  std::unique_ptr<FrameSource> source = loaded->factory->make(ctx);
  if (!source)
    return nullptr;
  return FrameSourceHandle(source.release(), [loaded](FrameSource* s) { delete s; });
}

}  // namespace

std::string frameSourceNames()
{
  std::string names;
  for (const SourceEntry& s : kSources)
    names += (names.empty() ? "" : ", ") + std::string(s.name);
  return names;
}

bool isFrameSource(const std::string& name)
{
  for (const SourceEntry& s : kSources)
    if (name == s.name)
      return true;
  return false;
}

FrameSourceHandle makeFrameSource(const std::string& name, const SourceContext& ctx)
{
  for (const SourceEntry& s : kSources)
    if (name == s.name)
      return s.make ? builtIn(s.make(ctx)) : fromPlugin(s.plugin, ctx);
  return nullptr;
}

cv::Mat asPublished(const cv::Mat& in, std::string* encoding)
{
  if (in.type() == CV_8UC1 || in.type() == CV_16UC1)
  {
    *encoding = in.depth() == CV_8U ? "mono8" : "mono16";
    return in;
  }
  *encoding = in.channels() == 1 ? "mono8" : "bgr8";
  if (in.type() == CV_8UC3)
    return in;
  cv::Mat eight = in;
  if (in.depth() != CV_8U)
  {
    // 16-bit: full scale to full scale; anything else: its maximum to 255.
    double lo, hi;
    cv::minMaxLoc(in.reshape(1), &lo, &hi);
    const double scale = in.depth() == CV_16U ? 255.0 / 65535.0 : (hi > 0 ? 255.0 / hi : 1.0);
    in.convertTo(eight, CV_8U, scale);
  }
  if (eight.channels() == 4)
  {
    cv::Mat out;
    cv::cvtColor(eight, out, cv::COLOR_BGRA2BGR);
    return out;
  }
  if (eight.channels() == 2)  // grey + alpha (png)
  {
    cv::Mat grey;
    cv::extractChannel(eight, grey, 0);
    *encoding = "mono8";
    return grey;
  }
  return eight;
}

bool applyWindow(const cv::Mat& full, const std::string& encoding, const SensorWindow& window, cv::Mat* out,
                 std::string* why)
{
  if (window.isFullSensor(full.cols, full.rows))
  {
    *out = full;
    return true;
  }
  *why = window.validate(full.cols, full.rows);
  if (!why->empty())
  {
    *why = "the sensor window (~binning_x/y, ~roi_*) does not fit the " + std::to_string(full.cols) + "x" +
           std::to_string(full.rows) + " frame: " + *why;
    return false;
  }
  const bool mosaic = sensor_msgs::image_encodings::isBayer(encoding) || encoding == "yuv422" ||
                      encoding == "yuv422_yuy2" || encoding == "uyvy" || encoding == "yuyv";
  if (mosaic && (window.binning_x > 1 || window.binning_y > 1 || window.x_offset % 2 || window.y_offset % 2))
  {
    *why = "a " + encoding + " frame cannot be binned in software, nor cut at an odd offset (bin in the camera)";
    return false;
  }
  const cv::Rect roi = window.roi(full.cols, full.rows);
  const cv::Size size = window.imageSize(full.cols, full.rows);
  const cv::Mat cut = full(cv::Rect(roi.x, roi.y, size.width * window.binning_x, size.height * window.binning_y));
  if (window.binning_x == 1 && window.binning_y == 1)
    *out = cut.clone();
  else
    cv::resize(cut, *out, size, 0, 0, cv::INTER_AREA);  // integer factors: the mean of each block
  return true;
}

std::string stringf(const char* format, ...)
{
  char text[1024];
  va_list args;
  va_start(args, format);
  std::vsnprintf(text, sizeof(text), format, args);
  va_end(args);
  return text;
}

double millisecondsSince(const std::chrono::steady_clock::time_point& t0)
{
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace structured_light_stabilizer
