// CameraDriver source "images": the image files of a folder, in name order,
// at ~rate; the folder is listed again for each pass while ~loop (default
// true), so files may be added or removed while it plays.
#include <algorithm>
#include <cctype>
#include <filesystem>
#include <system_error>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "nodelets/frame_sources/frame_source.h"

namespace structured_light_stabilizer
{

namespace
{

bool isImageFile(const std::filesystem::path& p)
{
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  static const std::vector<std::string> known = {".png",  ".jpg", ".jpeg", ".bmp", ".tif",
                                                 ".tiff", ".ppm", ".pgm",  ".pnm", ".webp"};
  return std::find(known.begin(), known.end(), ext) != known.end();
}

// The image files of `dir`, sorted; empty with *why when there are none.
std::vector<std::string> listImages(const std::string& dir, std::string* why)
{
  std::vector<std::string> files;
  std::error_code ec;
  if (dir.empty())
  {
    *why = "~image_dir is empty; set it to a folder of images";
    return files;
  }
  if (!std::filesystem::is_directory(dir, ec))
  {
    *why = "image folder '" + dir + "' does not exist or is not a folder";
    return files;
  }
  for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec))
    if (std::filesystem::is_regular_file(it->path(), ec) && isImageFile(it->path()))
      files.push_back(it->path().string());
  std::sort(files.begin(), files.end());
  if (files.empty())
    *why = "image folder '" + dir + "' contains no images (png, jpg, bmp, tif, ppm, pgm, webp)";
  return files;
}

class ImagesSource : public FrameSource
{
public:
  explicit ImagesSource(const SourceContext& ctx) : ctx_(ctx)
  {
    dir_ = ctx.pnh.param<std::string>("image_dir", "");
    loop_ = ctx.pnh.param("loop", true);
    preload_ = ctx.pnh.param("preload", false);
  }

  bool open(std::string* why) override
  {
    files_ = listImages(dir_, why);
    next_ = 0;
    published_in_pass_ = 0;
    backed_off_ = false;
    // ~preload: every image decoded once, here, and published from memory
    // (as a live camera's frames: no decoding in the frame loop). The
    // folder is then not listed again.
    if (preload_ && !files_.empty() && loaded_.empty())
    {
      for (const std::string& f : files_)
      {
        cv::Mat m = read(f);
        if (m.empty())
          continue;
        std::string encoding;
        cv::Mat published = asPublished(m, &encoding);
        loaded_.push_back({published, encoding});
      }
      if (loaded_.empty())
      {
        *why = "none of the " + std::to_string(files_.size()) + " images of '" + dir_ + "' could be read";
        return false;
      }
    }
    return !files_.empty();
  }

  std::string describe(double rate) const override
  {
    return stringf("playing %zu images from '%s' at %g Hz%s", files_.size(), dir_.c_str(), rate,
                   loop_ ? ", looping" : "");
  }

  GrabResult grab(double /*rate*/, Frame* frame) override
  {
    if (!loaded_.empty())
      return grabLoaded(frame);
    if (next_ == files_.size())
    {
      if (!loop_)
        return {GrabStatus::kEnd,
                "published the " + std::to_string(files_.size()) + " images of '" + dir_ + "' once (~loop is false)"};
      // Every file of the pass failed: do not spin on them.
      if (published_in_pass_ == 0 && !backed_off_)
      {
        backed_off_ = true;
        return {GrabStatus::kBackOff, ""};
      }
      std::string why;
      if (!open(&why))
        return {GrabStatus::kLost, why};
    }
    const std::string& path = files_[next_++];
    const auto t0 = std::chrono::steady_clock::now();
    const cv::Mat raw = read(path);
    if (raw.empty())
      return {GrabStatus::kSkip, "cannot read image '" + path + "' (unreadable or not an image); skipped"};
    if (!ctx_.stamp(&frame->stamp))
      return {GrabStatus::kSkip, ""};
    ++published_in_pass_;
    frame->processing_ms = millisecondsSince(t0);
    frame->image = asPublished(raw, &frame->encoding);
    return {GrabStatus::kFrame, ""};
  }

private:
  GrabResult grabLoaded(Frame* frame)
  {
    if (next_ >= loaded_.size())
    {
      if (!loop_)
        return {GrabStatus::kEnd, "published the " + std::to_string(loaded_.size()) + " preloaded images of '" +
                                      dir_ + "' once (~loop is false)"};
      next_ = 0;
    }
    if (!ctx_.stamp(&frame->stamp))
      return {GrabStatus::kSkip, ""};
    const Loaded& l = loaded_[next_++];
    frame->processing_ms = 0.0;
    frame->image = l.image;  // shared, read-only: the driver copies it into the message
    frame->encoding = l.encoding;
    return {GrabStatus::kFrame, ""};
  }

  // The file's pixels; empty when it is not a readable image.
  static cv::Mat read(const std::string& path)
  {
    try
    {
      return cv::imread(path, cv::IMREAD_UNCHANGED);
    }
    catch (const cv::Exception&)
    {
      return cv::Mat();
    }
  }

  SourceContext ctx_;
  std::string dir_;
  bool loop_ = true;
  std::vector<std::string> files_;
  size_t next_ = 0;  // index in files_ of the next frame
  int published_in_pass_ = 0;
  bool backed_off_ = false;  // the wait after a pass of unreadable files is done
  bool preload_ = false;
  struct Loaded
  {
    cv::Mat image;
    std::string encoding;
  };
  std::vector<Loaded> loaded_;  // ~preload: the folder's images, decoded
};

}  // namespace

std::unique_ptr<FrameSource> makeImagesSource(const SourceContext& ctx)
{
  return std::make_unique<ImagesSource>(ctx);
}

}  // namespace structured_light_stabilizer
