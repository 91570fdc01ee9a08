// The command line of the calibrate_projector tool (tools/calibrate_projector.cpp),
// in the core so that the tests run it in-process.
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <map>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "structured_light_stabilizer/calibration/chessboard_calibration.h"
#include "structured_light_stabilizer/calibration/projector_calibration.h"
#include "structured_light_stabilizer/calibration/projector_calibrator.h"
#include "cli/calibrate_projector_cli.h"

namespace fs = std::filesystem;

namespace structured_light_stabilizer
{

namespace
{

enum Exit
{
  kOk = 0,
  kUsage = 1,
  kCameraInfo = 2,
  kImage = 3,
  kTooFewViews = 4,
  kBeamNotSeen = 5,
  kNoFullView = 6,
  kFit = 7,
  kWrite = 8,
};

void usage(std::ostream& os)
{
  os << "usage: calibrate_projector --images DIR --camera-info FILE.yaml --board COLSxROWS --square METRES\n"
        "                           --output projector.yaml [--rows R --cols C] [--margin METRES]\n"
        "                           [--projector-color green|red|blue|nir|white] [--model auto|central|per-beam]\n"
        "                           [--report FILE.png]\n"
        "  --board       inner corners of the chessboard, OpenCV's convention (a 11 x 9 squares board is 10x8)\n"
        "  --square      side of a square in metres\n"
        "  --margin      white printed margin around the squares that dots may use (m, default 0)\n"
        "  --rows/--cols the projector's pattern (default 10 x 10)\n"
        "  Exit status: 0 done, 1 usage, 2 camera_info, 3 unreadable image, 4 fewer than two views with the\n"
        "  board, 5 a beam seen in fewer than two views, 6 no view with the whole pattern, 7 fit failed,\n"
        "  8 cannot write.\n";
}

bool isImageFile(const fs::path& p)
{
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".bmp" || ext == ".tif" || ext == ".tiff" ||
         ext == ".pgm" || ext == ".ppm";
}

// --name value pairs; false on a malformed command line.
bool parseArgs(const std::vector<std::string>& argv, std::map<std::string, std::string>* args, std::ostream& err)
{
  static const std::vector<std::string> known = {"--images",          "--camera-info", "--board", "--square",
                                                 "--output",          "--rows",        "--cols",  "--margin",
                                                 "--projector-color", "--model",       "--report"};
  for (size_t i = 0; i < argv.size(); ++i)
  {
    const std::string a = argv[i];
    if (a == "-h" || a == "--help")
      return false;
    if (std::find(known.begin(), known.end(), a) == known.end() || i + 1 >= argv.size())
    {
      err << "calibrate_projector: unknown option or missing value: " << a << "\n";
      return false;
    }
    (*args)[a] = argv[++i];
  }
  for (const char* required : {"--images", "--camera-info", "--board", "--square", "--output"})
    if (!args->count(required))
    {
      err << "calibrate_projector: " << required << " is required\n";
      return false;
    }
  return true;
}

bool toNumber(const std::string& s, double* v)
{
  char* end = nullptr;
  *v = std::strtod(s.c_str(), &end);
  return end && *end == '\0' && !s.empty();
}

// The calibration's settings from the arguments; false with a message.
bool paramsFromArgs(const std::map<std::string, std::string>& args, ChessboardCalibrationParams* p, std::ostream& err)
{
  double square = 0.0, v = 0.0;
  if (!parseBoardSize(args.at("--board"), &p->board.cols, &p->board.rows))
  {
    err << "calibrate_projector: --board must be COLSxROWS inner corners (e.g. 10x8), got '" << args.at("--board")
        << "'\n";
    return false;
  }
  if (!toNumber(args.at("--square"), &square) || !(square > 0.0))
  {
    err << "calibrate_projector: --square must be a positive number of metres\n";
    return false;
  }
  p->board.square_m = square;
  if (args.count("--margin") && (!toNumber(args.at("--margin"), &p->board.margin_m) || p->board.margin_m < 0.0))
  {
    err << "calibrate_projector: --margin must be >= 0 metres\n";
    return false;
  }
  for (const auto& [name, field] : {std::pair<std::string, int*>{"--rows", &p->rows}, {"--cols", &p->cols}})
  {
    if (!args.count(name))
      continue;
    if (!toNumber(args.at(name), &v) || v < 2 || v != static_cast<int>(v))
    {
      err << "calibrate_projector: " << name << " must be an integer >= 2\n";
      return false;
    }
    *field = static_cast<int>(v);
  }
  const std::string colour = args.count("--projector-color") ? args.at("--projector-color") : "green";
  if (!channelsForProjectorColor(colour, &p->dot_channel, &p->board_channel))
  {
    err << "calibrate_projector: unknown --projector-color '" << colour << "'\n";
    return false;
  }
  const std::string model = args.count("--model") ? args.at("--model") : "auto";
  static const std::map<std::string, ProjectorModel> models = {{"auto", ProjectorModel::kChosenByData},
                                                               {"central", ProjectorModel::kCentral},
                                                               {"per-beam", ProjectorModel::kPerBeam}};
  if (!models.count(model))
  {
    err << "calibrate_projector: --model must be auto, central or per-beam\n";
    return false;
  }
  p->fit.model = models.at(model);
  return true;
}

int exitFor(CalibrationFailure f)
{
  switch (f)
  {
    case CalibrationFailure::kTooFewViews:
      return kTooFewViews;
    case CalibrationFailure::kBeamNotSeen:
      return kBeamNotSeen;
    case CalibrationFailure::kNoFullView:
      return kNoFullView;
    case CalibrationFailure::kBadInput:
      return kUsage;
    default:
      return kFit;
  }
}

}  // namespace

int calibrateProjectorMain(const std::vector<std::string>& argv, std::ostream& out, std::ostream& err)
{
  std::map<std::string, std::string> args;
  ChessboardCalibrationParams params;
  if (!parseArgs(argv, &args, err) || !paramsFromArgs(args, &params, err))
  {
    usage(err);
    return kUsage;
  }
  CameraModel camera;
  std::string why;
  if (!loadCameraModelYaml(args["--camera-info"], &camera, &why))
  {
    err << "calibrate_projector: camera_info: " << why << "\n";
    return kCameraInfo;
  }
  std::vector<fs::path> files;
  std::error_code ec;
  for (fs::directory_iterator it(args["--images"], ec), end; !ec && it != end; it.increment(ec))
    if (it->is_regular_file() && isImageFile(it->path()))
      files.push_back(it->path());
  if (ec)
  {
    err << "calibrate_projector: cannot read the folder '" << args["--images"] << "': " << ec.message() << "\n";
    return kImage;
  }
  std::sort(files.begin(), files.end());
  // Every file is read first: an unreadable one stops the tool before the
  // (slow) analysis of the others.
  std::vector<cv::Mat> images;
  for (const fs::path& f : files)
  {
    images.push_back(cv::imread(f.string(), cv::IMREAD_UNCHANGED));
    if (images.back().empty())
    {
      err << "calibrate_projector: cannot read the image '" << f.string() << "'\n";
      return kImage;
    }
  }
  std::vector<ChessboardView> views;
  for (size_t k = 0; k < files.size(); ++k)
  {
    out << "view " << k << ": " << files[k].filename().string() << " ..." << std::endl;
    views.push_back(analyseChessboardView(images[k], files[k].filename().string(), camera, params));
  }
  const ChessboardCalibrationResult res = calibrateFromChessboardViews(camera, views, params);
  out << res.report();
  const std::string png =
      args.count("--report") ? args["--report"] : fs::path(args["--output"]).replace_extension(".png").string();
  if (!cv::imwrite(png, drawCalibrationReport(res, params.board)))
    err << "calibrate_projector: cannot write the report '" << png << "'\n";
  if (!res.ok)
  {
    err << "calibrate_projector: " << res.error << "\n";
    return exitFor(res.failure);
  }
  if (!saveProjectorCalibration(args["--output"], res.fit.calibration, &why))
  {
    err << "calibrate_projector: " << why << "\n";
    return kWrite;
  }
  out << "written " << args["--output"] << " and " << png << "\n";
  return kOk;
}

}  // namespace structured_light_stabilizer
