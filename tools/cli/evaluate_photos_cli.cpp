// evaluate_photos: the SpotDetector on real photographs of projected dots
// against hand-checked labels (test/data/real/README.md): per image the
// recall (labelled dots with a spot within the tolerance, one to one), the
// precision (spots that match a label), the numbers of labels and spots, and
// the matched spots' RMS distance from their labels; then the pooled line
// (sums over the images) and the mean of the per-image recalls and
// precisions. A frame the detector refuses counts as one without spots.
//
//   evaluate_photos --photos DIR [--labels DIR] [--half tuning|heldout|all]
//                   [--projector-color green|red|blue|nir|white] [--method fast|baseline]
//                   [--param NAME=VALUE]... [--tolerance PX] [--only NAME[,NAME...]]
//                   [--overlay DIR] [--list-spots] [--why]
//
// --photos: the folder the labels' `image:` paths are relative to (the
// photographs are not in the repository; README says how to fetch them).
// --labels: the label folder (default test/data/real/labels, relative to
// the current directory: run it from the repository's root).
// --half: which labels to run (default all). --projector-color overrides each
// label's projector_color; --method and --param NAME=VALUE set any
// SpotDetectorParams field through its set() (nested groups too, e.g.
// --param min_peak=20); the detector otherwise runs with its defaults.
// --tolerance: match distance in px (default 3; a label file's tolerance_px
// overrides it for that image, for dots whose clipped core is tens of px
// wide). --only: run these label names only. --overlay DIR: writes
// DIR/<name>.png, the photo with the labels as green circles, the spots as red
// crosses (matched ones yellow), regions of interest cyan and ignored
// rectangles grey. --list-spots: prints every spot with its match. --why:
// per image the detector's candidates and why it dropped the rest (its
// SpotDetectorDebug: the reasons, counted, and how many dropped candidates lay
// within the tolerance of a labelled dot).
//
// Label file (YAML, one per image): image, encoding (bgr8 | rgb8 | mono8 |
// mono16; the file is converted to it), projector_color, half, optional
// rois [[x, y, w, h], ...] (only these are labelled: spots and labels
// outside every roi are not counted), optional ignore [[x, y, w, h], ...]
// (neither counted inside), optional tolerance_px, optional projector_dots
// (how many dots the projector throws, as its user would configure
// projector_rows x projector_cols: the detector keeps at most 10 x that many
// candidates), dots [[x, y], ...] in pixels, OpenCV convention (pixel centres
// at integers).
#include <algorithm>
#include <cstdarg>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ostream>
#include <string>
#include <vector>

#include <dirent.h>
#include <sys/stat.h>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <yaml-cpp/yaml.h>

#include "cli/evaluate_photos_cli.h"
#include "structured_light_stabilizer/detection/spot_detector.h"

using namespace structured_light_stabilizer;

namespace
{

// printf into a stream (the tool's output goes to the caller's streams).
__attribute__((format(printf, 2, 3))) void say(std::ostream& o, const char* fmt, ...)
{
  va_list ap;
  va_start(ap, fmt);
  va_list again;
  va_copy(again, ap);
  const int n = std::vsnprintf(nullptr, 0, fmt, ap);
  va_end(ap);
  std::string text(static_cast<size_t>(std::max(n, 0)) + 1, '\0');
  std::vsnprintf(&text[0], text.size(), fmt, again);
  va_end(again);
  text.resize(static_cast<size_t>(std::max(n, 0)));
  o << text;
}

struct Label
{
  std::string name, image, encoding, projector_color, half;
  std::vector<cv::Rect2d> rois, ignore;
  std::vector<cv::Point2d> dots;
  double tolerance_px = 0.0;  // 0: the command line's
  int projector_dots = 0;     // the pattern's dots (projector_rows x projector_cols); 0: the detector's default
};

struct Options
{
  std::string photos, labels = "test/data/real/labels", half = "all", projector_color, overlay;
  std::vector<std::string> params, only;
  std::string method;
  double tolerance = 3.0;
  bool list_spots = false, why = false;
};

void usage(std::ostream& err)
{
  say(err,
      "usage: evaluate_photos --photos DIR [--labels DIR] [--half tuning|heldout|all]\n"
      "                       [--projector-color C] [--method fast|baseline] [--param NAME=VALUE]...\n"
      "                       [--tolerance PX] [--only NAME[,NAME...]] [--overlay DIR] [--list-spots] [--why]\n");
}

std::vector<cv::Rect2d> rects(const YAML::Node& node)
{
  std::vector<cv::Rect2d> out;
  if (node)
    for (const auto& r : node)
      out.emplace_back(r[0].as<double>(), r[1].as<double>(), r[2].as<double>(), r[3].as<double>());
  return out;
}

Label readLabel(const std::string& path, const std::string& name)
{
  const YAML::Node y = YAML::LoadFile(path);
  Label l;
  l.name = name;
  l.image = y["image"].as<std::string>();
  l.encoding = y["encoding"].as<std::string>();
  l.projector_color = y["projector_color"].as<std::string>();
  l.half = y["half"].as<std::string>();
  l.rois = rects(y["rois"]);
  l.ignore = rects(y["ignore"]);
  if (y["tolerance_px"])
    l.tolerance_px = y["tolerance_px"].as<double>();
  if (y["projector_dots"])
    l.projector_dots = y["projector_dots"].as<int>();
  for (const auto& d : y["dots"])
    l.dots.emplace_back(d[0].as<double>(), d[1].as<double>());
  return l;
}

// A rectangle [x, y, w, h] of pixels covers x - 0.5 <= px < x + w - 0.5 (pixel
// centres at integers).
bool inRect(const cv::Rect2d& r, double x, double y)
{
  return x >= r.x - 0.5 && x < r.x + r.width - 0.5 && y >= r.y - 0.5 && y < r.y + r.height - 0.5;
}

bool counted(const Label& l, double x, double y)
{
  if (!l.rois.empty() &&
      std::none_of(l.rois.begin(), l.rois.end(), [&](const cv::Rect2d& r) { return inRect(r, x, y); }))
    return false;
  return std::none_of(l.ignore.begin(), l.ignore.end(), [&](const cv::Rect2d& r) { return inRect(r, x, y); });
}

// The photo in the label's encoding; empty with *why set when it cannot be.
cv::Mat loadAs(const std::string& path, const std::string& encoding, PixelFormat* format, std::string* why)
{
  cv::Mat im = cv::imread(path, cv::IMREAD_UNCHANGED);
  if (im.empty())
  {
    *why = "cannot read " + path;
    return {};
  }
  if (!pixelFormatFromEncoding(encoding, format))
  {
    *why = "encoding " + encoding + " is not one the detector reads";
    return {};
  }
  if (im.depth() == CV_16U && matDepth(*format) == CV_8U)
    im.convertTo(im, CV_8U, 1.0 / 257.0);
  const int want = channelCount(*format);
  if (im.channels() == 4 && want == 3)
    cv::cvtColor(im, im, cv::COLOR_BGRA2BGR);
  else if (im.channels() == 4 && want == 1)
    cv::cvtColor(im, im, cv::COLOR_BGRA2GRAY);
  else if (im.channels() == 3 && want == 1)
    cv::cvtColor(im, im, cv::COLOR_BGR2GRAY);
  else if (im.channels() == 1 && want == 3)
    cv::cvtColor(im, im, cv::COLOR_GRAY2BGR);
  if (*format == PixelFormat::kRgb8)
    cv::cvtColor(im, im, cv::COLOR_BGR2RGB);
  if (im.type() != matType(*format))
  {
    *why = "cannot convert " + path + " to " + encoding;
    return {};
  }
  return im;
}

// One to one within tol: the closest pairs first. match[i] = label index of
// spot i, or -1.
std::vector<int> matchSpots(const Spots& spots, const std::vector<cv::Point2d>& dots, double tol)
{
  struct Pair
  {
    double d;
    int s, l;
  };
  std::vector<Pair> pairs;
  for (int s = 0; s < static_cast<int>(spots.size()); ++s)
    for (int l = 0; l < static_cast<int>(dots.size()); ++l)
    {
      const double d = std::hypot(spots[s].x - dots[l].x, spots[s].y - dots[l].y);
      if (d <= tol)
        pairs.push_back({d, s, l});
    }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) { return a.d < b.d; });
  std::vector<int> match(spots.size(), -1);
  std::vector<bool> taken(dots.size(), false);
  for (const Pair& p : pairs)
    if (match[p.s] < 0 && !taken[p.l])
    {
      match[p.s] = p.l;
      taken[p.l] = true;
    }
  return match;
}

void drawOverlay(const std::string& path, const cv::Mat& image, PixelFormat format, const Label& l, const Spots& spots,
                 const std::vector<int>& match, std::ostream& err)
{
  cv::Mat v = toBgr(image, format).clone();
  const int r = std::max(5, std::max(v.cols, v.rows) / 300), thick = std::max(1, r / 6);
  constexpr int kShift = 4;
  auto P = [](double x, double y)
  {
    return cv::Point(static_cast<int>(std::lround(x * (1 << kShift))),
                     static_cast<int>(std::lround(y * (1 << kShift))));
  };
  for (const auto& q : l.rois)
    cv::rectangle(v, P(q.x - 0.5, q.y - 0.5), P(q.x + q.width - 0.5, q.y + q.height - 0.5), {255, 255, 0}, thick,
                  cv::LINE_AA, kShift);
  for (const auto& q : l.ignore)
    cv::rectangle(v, P(q.x - 0.5, q.y - 0.5), P(q.x + q.width - 0.5, q.y + q.height - 0.5), {128, 128, 128}, thick,
                  cv::LINE_AA, kShift);
  for (const auto& d : l.dots)
    cv::circle(v, P(d.x, d.y), r << kShift, {0, 255, 0}, thick, cv::LINE_AA, kShift);
  for (size_t i = 0; i < spots.size(); ++i)
  {
    const cv::Scalar c = match[i] >= 0 ? cv::Scalar(0, 255, 255) : cv::Scalar(0, 0, 255);
    const double a = 0.7 * r;
    cv::line(v, P(spots[i].x - a, spots[i].y), P(spots[i].x + a, spots[i].y), c, thick, cv::LINE_AA, kShift);
    cv::line(v, P(spots[i].x, spots[i].y - a), P(spots[i].x, spots[i].y + a), c, thick, cv::LINE_AA, kShift);
  }
  if (!cv::imwrite(path, v))
    say(err, "evaluate_photos: cannot write %s\n", path.c_str());
}

std::vector<std::string> split(const std::string& s, char sep)
{
  std::vector<std::string> out;
  size_t a = 0;
  while (a <= s.size())
  {
    const size_t b = s.find(sep, a);
    out.push_back(s.substr(a, b == std::string::npos ? std::string::npos : b - a));
    if (b == std::string::npos)
      break;
    a = b + 1;
  }
  return out;
}

// The command line into *o; -1 to go on, else the exit status.
int parseOptions(const std::vector<std::string>& args, Options* o, std::ostream& err)
{
  for (size_t i = 0; i < args.size(); ++i)
  {
    const std::string& k = args[i];
    if (k == "--list-spots" || k == "--why")
    {
      (k == "--why" ? o->why : o->list_spots) = true;
      continue;
    }
    if (k == "-h" || k == "--help")
    {
      usage(err);
      return 0;
    }
    if (i + 1 >= args.size())
    {
      say(err, "evaluate_photos: %s needs a value\n", k.c_str());
      usage(err);
      return 2;
    }
    const std::string& v = args[++i];
    if (k == "--photos")
      o->photos = v;
    else if (k == "--labels")
      o->labels = v;
    else if (k == "--half")
      o->half = v;
    else if (k == "--projector-color")
      o->projector_color = v;
    else if (k == "--method")
      o->method = v;
    else if (k == "--param")
      o->params.push_back(v);
    else if (k == "--tolerance")
      o->tolerance = std::atof(v.c_str());
    else if (k == "--only")
      o->only = split(v, ',');
    else if (k == "--overlay")
      o->overlay = v;
    else
    {
      say(err, "evaluate_photos: unknown option %s\n", k.c_str());
      usage(err);
      return 2;
    }
  }
  if (o->photos.empty() || (o->half != "all" && o->half != "tuning" && o->half != "heldout"))
  {
    usage(err);
    return 2;
  }
  return -1;
}

// The parameters common to every image; the projector colour follows each
// label unless --projector-color is given. False (said why) on a bad value.
bool baseParams(const Options& o, SpotDetectorParams* base, std::ostream& err)
{
  if (!o.method.empty() && !base->set("method", o.method))
  {
    say(err, "evaluate_photos: unknown method %s\n", o.method.c_str());
    return false;
  }
  if (!o.projector_color.empty() && !base->set("projector_color", o.projector_color))
  {
    say(err, "evaluate_photos: unknown projector colour %s\n", o.projector_color.c_str());
    return false;
  }
  for (const std::string& p : o.params)
  {
    const size_t eq = p.find('=');
    if (eq == std::string::npos || !base->set(p.substr(0, eq), p.substr(eq + 1)))
    {
      say(err, "evaluate_photos: --param %s: no SpotDetectorParams field takes it\n", p.c_str());
      return false;
    }
  }
  return true;
}

// The label files of a folder, sorted; false (said why) when it cannot be read.
bool labelFiles(const std::string& folder, std::vector<std::string>* files, std::ostream& err)
{
  DIR* dir = opendir(folder.c_str());
  if (!dir)
  {
    say(err, "evaluate_photos: cannot open the label folder %s\n", folder.c_str());
    return false;
  }
  while (const dirent* e = readdir(dir))
  {
    const std::string f = e->d_name;
    if (f.size() > 5 && f.compare(f.size() - 5, 5, ".yaml") == 0)
      files->push_back(f);
  }
  closedir(dir);
  std::sort(files->begin(), files->end());
  return true;
}

// --why: the detector's reasons for dropping candidates in the labelled part,
// counted with their numbers left out ("sigma N px out of range"); "near a
// dot": dropped within the tolerance of a label.
void printWhy(const SpotDetectorDebug& debug, const Label& l, const std::vector<cv::Point2d>& dots, double tol,
              std::ostream& out)
{
  auto kind = [](const std::string& s)
  {
    std::string k;
    for (size_t i = 0; i < s.size();)
      if (std::isdigit(static_cast<unsigned char>(s[i])) ||
          (s[i] == '-' && i + 1 < s.size() && std::isdigit(static_cast<unsigned char>(s[i + 1]))))
      {
        while (i < s.size() &&
               (std::isdigit(static_cast<unsigned char>(s[i])) || s[i] == '.' || s[i] == '-' || s[i] == 'e'))
          ++i;
        k += 'N';
      }
      else
        k += s[i++];
    return k;
  };
  std::vector<std::pair<std::string, std::pair<int, int>>> reasons;
  for (const auto& rej : debug.rejected)
  {
    if (!counted(l, rej.x, rej.y))
      continue;
    const SpotDetectorDebug::Rejection r{rej.x, rej.y, kind(rej.reason)};
    const bool near = std::any_of(dots.begin(), dots.end(),
                                  [&](const cv::Point2d& d) { return std::hypot(d.x - r.x, d.y - r.y) <= tol; });
    auto it = std::find_if(reasons.begin(), reasons.end(), [&](const auto& e) { return e.first == r.reason; });
    if (it == reasons.end())
      it = reasons.insert(reasons.end(), {r.reason, {0, 0}});
    ++it->second.first;
    it->second.second += near;
  }
  std::sort(reasons.begin(), reasons.end(),
            [](const auto& a, const auto& b) { return a.second.first > b.second.first; });
  say(out, "  candidates %d (coarse %d), fitted %d; dropped in the labelled part:%s\n", debug.candidates,
      debug.coarse_candidates, debug.fitted, reasons.empty() ? " none" : "");
  for (const auto& e : reasons)
    say(out, "    %5d (%d near a dot) %s\n", e.second.first, e.second.second, e.first.c_str());
}

// The pooled counts over the photos evaluated.
struct Tally
{
  int images = 0, failed = 0, precision_images = 0;
  long labels = 0, spots = 0, matched = 0;
  double sum_recall = 0, sum_precision = 0;
};

// One label file: its photo detected, matched and printed, added to *t.
void evaluateOne(const Options& o, const SpotDetectorParams& base, const std::string& f, Tally* t, std::ostream& out,
                 std::ostream& err)
{
  const std::string name = f.substr(0, f.size() - 5);
  if (!o.only.empty() && std::find(o.only.begin(), o.only.end(), name) == o.only.end())
    return;
  Label l;
  try
  {
    l = readLabel(o.labels + "/" + f, name);
  }
  catch (const std::exception& e)
  {
    say(err, "evaluate_photos: %s: %s\n", f.c_str(), e.what());
    ++t->failed;
    return;
  }
  if (o.half != "all" && l.half != o.half)
    return;
  PixelFormat format;
  std::string why;
  const cv::Mat image = loadAs(o.photos + "/" + l.image, l.encoding, &format, &why);
  if (image.empty())
  {
    say(err, "evaluate_photos: %s: %s\n", name.c_str(), why.c_str());
    ++t->failed;
    return;
  }
  SpotDetectorParams p = base;
  if (o.projector_color.empty() && !p.set("projector_color", l.projector_color))
  {
    say(err, "evaluate_photos: %s: unknown projector_color %s\n", name.c_str(), l.projector_color.c_str());
    ++t->failed;
    return;
  }
  if (l.projector_dots > 0)
  {
    // The pattern as its user configures it: a square of at least that many beams.
    const int side = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(l.projector_dots))));
    p.projector_rows = side;
    p.projector_cols = side;
  }
  SpotDetector detector(p);
  const auto t0 = std::chrono::steady_clock::now();
  SpotDetectorDebug debug;
  const SpotDetectionResult result = detector.detect(image, format, o.why ? &debug : nullptr);
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  // A refused frame is a detector failure on a real photo: it counts, with
  // no spots.
  if (!result.ok)
    say(out, "%-30s refused by the detector: %s\n", name.c_str(), result.error.c_str());
  // Only what lies in the labelled part of the photo counts.
  Spots spots;
  for (const Spot& s : result.ok ? result.spots : Spots())
    if (counted(l, s.x, s.y))
      spots.push_back(s);
  std::vector<cv::Point2d> dots;
  for (const auto& d : l.dots)
    if (counted(l, d.x, d.y))
      dots.push_back(d);
  const double tol = l.tolerance_px > 0 ? l.tolerance_px : o.tolerance;
  const std::vector<int> match = matchSpots(spots, dots, tol);
  int matched = 0;
  double sq = 0;
  for (size_t i = 0; i < spots.size(); ++i)
    if (match[i] >= 0)
    {
      ++matched;
      const cv::Point2d e = cv::Point2d(spots[i].x, spots[i].y) - dots[match[i]];
      sq += e.dot(e);
    }
  const double recall = dots.empty() ? 1.0 : static_cast<double>(matched) / dots.size();
  const double precision = spots.empty() ? 1.0 : static_cast<double>(matched) / spots.size();
  char off[32] = "-", prec[32] = "-";
  if (!spots.empty())
    std::snprintf(prec, sizeof prec, "%.3f", precision);
  if (matched > 0)
    std::snprintf(off, sizeof off, "%.2f", std::sqrt(sq / matched));
  say(out, "%-30s %-7s %-6s %-6s %5zu %5zu %5d %7.3f %7s %6s %8.1f%s\n", name.c_str(), l.half.c_str(),
      l.encoding.c_str(), projectorColorName(p.projector_color), dots.size(), spots.size(), matched, recall, prec, off,
      ms, tol != o.tolerance ? " (tolerance_px)" : "");
  if (o.list_spots)
    for (size_t i = 0; i < spots.size(); ++i)
      say(out, "  spot %8.2f %8.2f area %7.1f %s\n", spots[i].x, spots[i].y, spots[i].area,
          match[i] >= 0 ? "matched" : "unmatched");
  if (o.why)
    printWhy(debug, l, dots, tol, out);
  ++t->images;
  t->labels += static_cast<long>(dots.size());
  t->spots += static_cast<long>(spots.size());
  t->matched += matched;
  t->sum_recall += recall;
  if (!spots.empty())
  {
    t->sum_precision += precision;
    ++t->precision_images;
  }
  if (!o.overlay.empty())
    drawOverlay(o.overlay + "/" + name + ".png", image, format, l, spots, match, err);
}

}  // namespace

namespace structured_light_stabilizer
{

int evaluatePhotosMain(const std::vector<std::string>& args, std::ostream& out, std::ostream& err)
{
  Options o;
  const int parsed = parseOptions(args, &o, err);
  if (parsed >= 0)
    return parsed;
  SpotDetectorParams base;
  std::vector<std::string> files;
  if (!baseParams(o, &base, err) || !labelFiles(o.labels, &files, err))
    return 2;
  if (!o.overlay.empty())
    mkdir(o.overlay.c_str(), 0755);

  say(out, "evaluate_photos: method %s, tolerance %.1f px, half %s%s%s\n", spotMethodName(base.method), o.tolerance,
      o.half.c_str(), o.projector_color.empty() ? "" : ", projector_color ", o.projector_color.c_str());
  for (const std::string& p : o.params)
    say(out, "evaluate_photos: --param %s\n", p.c_str());
  {
    SpotDetectorParams check = base;  // the detector sanitizes its parameters: say what it changes
    for (const std::string& c : check.sanitize())
      say(out, "evaluate_photos: the detector changes a parameter: %s\n", c.c_str());
  }
  say(out, "%-30s %-7s %-6s %-6s %5s %5s %5s %7s %7s %6s %8s\n", "image", "half", "enc", "color", "label", "spots",
      "match", "recall", "precis", "rms_px", "ms");
  Tally t;
  for (const std::string& f : files)
    evaluateOne(o, base, f, &t, out, err);
  say(out,
      "pooled: %d images, %ld labels, %ld spots, %ld matched: recall %.3f precision %.3f; "
      "per-image mean recall %.3f, mean precision %.3f (%d images with spots)\n",
      t.images, t.labels, t.spots, t.matched, t.labels ? static_cast<double>(t.matched) / t.labels : 0.0,
      t.spots ? static_cast<double>(t.matched) / t.spots : 0.0, t.images ? t.sum_recall / t.images : 0.0,
      t.precision_images ? t.sum_precision / t.precision_images : 0.0, t.precision_images);
  if (t.failed)
    say(out, "evaluate_photos: %d label file(s) not evaluated (see above)\n", t.failed);
  return t.failed ? 1 : 0;
}

}  // namespace structured_light_stabilizer
