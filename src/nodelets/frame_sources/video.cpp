// CameraDriver source "video": a video file played at ~rate, from the start
// again at its end while ~loop (default true).

#include <filesystem>
#include <system_error>

#include <opencv2/videoio.hpp>

#include "nodelets/frame_sources/frame_source.h"

namespace structured_light_stabilizer
{

namespace
{

class VideoSource : public FrameSource
{
public:
  explicit VideoSource(const SourceContext& ctx) : ctx_(ctx)
  {
    file_ = ctx.pnh.param<std::string>("video_file", "");
    loop_ = ctx.pnh.param("loop", true);
  }

  bool open(std::string* why) override
  {
    frames_in_pass_ = 0;
    if (file_.empty())
      *why = "~video_file is empty; set it to the video to play";
    else if (std::error_code ec; !std::filesystem::is_regular_file(file_, ec))
      *why = "video file '" + file_ + "' does not exist";
    else if (!capture_.open(file_) || !capture_.isOpened())
      *why = "cannot decode video file '" + file_ + "' (unknown container or codec)";
    return why->empty();
  }

  void close() override { capture_.release(); }

  std::string describe(double rate) const override
  {
    return stringf("playing '%s' at %g Hz%s", file_.c_str(), rate, loop_ ? ", looping" : "");
  }

  GrabResult grab(double /*rate*/, Frame* frame) override
  {
    auto t0 = std::chrono::steady_clock::now();
    cv::Mat raw;
    if (!read(&raw))
    {
      const GrabResult none = {GrabStatus::kLost, "video file '" + file_ + "' has no readable frames"};
      if (frames_in_pass_ == 0)
        return none;
      if (!loop_)
        return {GrabStatus::kEnd,
                "end of '" + file_ + "' after " + std::to_string(frames_in_pass_) + " frames (~loop is false)"};
      // The next pass starts on this tick: opened again, first frame read.
      std::string why;
      if (!open(&why))
        return {GrabStatus::kLost, why};
      t0 = std::chrono::steady_clock::now();
      if (!read(&raw))
        return none;
    }
    ++frames_in_pass_;
    if (!ctx_.stamp(&frame->stamp))
      return {GrabStatus::kSkip, ""};
    frame->processing_ms = millisecondsSince(t0);
    frame->image = asPublished(raw, &frame->encoding);
    return {GrabStatus::kFrame, ""};
  }

private:
  // Next frame; at the end or on an error the capture is released.
  bool read(cv::Mat* raw)
  {
    if (capture_.read(*raw) && !raw->empty())
      return true;
    capture_.release();
    return false;
  }

  SourceContext ctx_;
  std::string file_;
  bool loop_ = true;
  cv::VideoCapture capture_;
  int frames_in_pass_ = 0;
};

}  // namespace

std::unique_ptr<FrameSource> makeVideoSource(const SourceContext& ctx)
{
  return std::make_unique<VideoSource>(ctx);
}

}  // namespace structured_light_stabilizer
