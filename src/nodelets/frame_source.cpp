#include "frame_source.h"

#include <cstdarg>
#include <cstdio>

#include <opencv2/imgproc.hpp>

namespace structured_light_stabilizer
{

namespace
{

struct SourceEntry
{
  const char* name;  // the ~source value
  std::unique_ptr<FrameSource> (*make)(const SourceContext&);
};

// Every source the driver knows, in the order the messages list them.
const SourceEntry kSources[] = {
    {"sim", &makeSimSource},
    {"device", &makeDeviceSource},
    {"video", &makeVideoSource},
    {"images", &makeImagesSource},
};

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

std::unique_ptr<FrameSource> makeFrameSource(const std::string& name, const SourceContext& ctx)
{
  for (const SourceEntry& s : kSources)
    if (name == s.name)
      return s.make(ctx);
  return nullptr;
}

cv::Mat toBgr8(const cv::Mat& in)
{
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
  cv::Mat out;
  if (eight.channels() == 1)
    cv::cvtColor(eight, out, cv::COLOR_GRAY2BGR);
  else if (eight.channels() == 4)
    cv::cvtColor(eight, out, cv::COLOR_BGRA2BGR);
  else
    out = eight;
  return out;
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
