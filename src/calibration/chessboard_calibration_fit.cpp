// calibrateFromChessboardViews and its report (chessboard_calibration.h):
// the views' beam numbers, the joint fit, the tables.
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>

#include <Eigen/Dense>

#include "calibration/calibration_geometry.h"
#include "structured_light_stabilizer/calibration/chessboard_calibration.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{

namespace
{

// Each labelled dot of a view back-projected onto its board (camera frame),
// with its relative label.
struct LabelledPoint
{
  int row = 0, col = 0;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
};

std::vector<LabelledPoint> boardPoints(const CameraModel& camera, const ChessboardView& view)
{
  std::vector<LabelledPoint> out;
  for (size_t k = 0; k < view.dots.size(); ++k)
  {
    if (!view.grid.labelled[k])
      continue;
    const Eigen::Vector2d n = camera.normalize(cv::Point2d(view.dots[k].x, view.dots[k].y));
    LabelledPoint lp;
    lp.row = view.grid.row[k];
    lp.col = view.grid.col[k];
    if (detail::linePlaneHit(view.board.pose, Eigen::Vector3d::Zero(), Eigen::Vector3d(n.x(), n.y(), 1.0), &lp.p))
      out.push_back(lp);
  }
  return out;
}

// How well the beams' lines meet, with the views' points numbered by their
// offsets (beam -> its board points): the RMS distance of the lines from
// their least-squares common point plus the lines' own misfit (metres);
// +inf with fewer than three lines.
double meetingScore(const std::vector<std::vector<Eigen::Vector3d>>& per_beam)
{
  std::vector<BeamRay> lines;
  double misfit2 = 0.0;
  int misfit_n = 0;
  for (const auto& pts : per_beam)
  {
    if (pts.size() < 2)
      continue;
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : pts)
      mean += p / static_cast<double>(pts.size());
    Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
    for (const auto& p : pts)
      S += (p - mean) * (p - mean).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
    BeamRay line;
    line.origin = mean;
    line.direction = es.eigenvectors().col(2);
    lines.push_back(line);
    if (pts.size() > 2)
    {
      misfit2 += es.eigenvalues()(0) + es.eigenvalues()(1);
      misfit_n += static_cast<int>(pts.size()) - 2;
    }
  }
  Eigen::Vector3d c;
  if (lines.size() < 3 || !detail::closestPointToLines(lines, &c))
    return std::numeric_limits<double>::infinity();
  double d2 = 0.0;
  for (const BeamRay& l : lines)
    d2 += detail::square(detail::distanceToLine(c, l));
  return std::sqrt(d2 / lines.size() + (misfit_n > 0 ? misfit2 / misfit_n : 0.0));
}

void addPoints(const std::vector<LabelledPoint>& pts, int ro, int co, int rows, int cols,
               std::vector<std::vector<Eigen::Vector3d>>* per_beam)
{
  for (const LabelledPoint& lp : pts)
  {
    const int r = lp.row + ro, c = lp.col + co;
    if (r >= 0 && r < rows && c >= 0 && c < cols)
      (*per_beam)[r * cols + c].push_back(lp.p);
  }
}

// Gives every usable view without a known offset the one whose lines meet
// best with the numbered views, when the next best is offset_margin times
// worse; the others are marked unusable with the reason.
void resolveOffsets(const CameraModel& camera, const ChessboardCalibrationParams& params,
                    std::vector<ChessboardView>* views)
{
  const int rows = params.rows, cols = params.cols;
  std::vector<std::vector<LabelledPoint>> pts(views->size());
  for (size_t v = 0; v < views->size(); ++v)
    if ((*views)[v].usable)
      pts[v] = boardPoints(camera, (*views)[v]);
  for (bool progress = true; progress;)
  {
    progress = false;
    std::vector<std::vector<Eigen::Vector3d>> known(rows * cols);
    for (size_t v = 0; v < views->size(); ++v)
      if ((*views)[v].usable && (*views)[v].offset_known)
        addPoints(pts[v], (*views)[v].row_offset, (*views)[v].col_offset, rows, cols, &known);
    for (size_t v = 0; v < views->size(); ++v)
    {
      ChessboardView& view = (*views)[v];
      if (!view.usable || view.offset_known)
        continue;
      double best = std::numeric_limits<double>::infinity(), second = best;
      int best_r = 0, best_c = 0;
      for (int ro = -view.grid.min_row; ro + view.grid.max_row < rows; ++ro)
        for (int co = -view.grid.min_col; co + view.grid.max_col < cols; ++co)
        {
          std::vector<std::vector<Eigen::Vector3d>> trial = known;
          addPoints(pts[v], ro, co, rows, cols, &trial);
          const double s = meetingScore(trial);
          if (s < best)
          {
            second = best;
            best = s;
            best_r = ro;
            best_c = co;
          }
          else
          {
            second = std::min(second, s);
          }
        }
      if (std::isfinite(best) && second >= params.offset_margin * best)
      {
        view.offset_known = true;
        view.row_offset = best_r;
        view.col_offset = best_c;
        progress = true;
        break;  // the numbered set changed: score the others against it
      }
    }
  }
  for (ChessboardView& view : *views)
    if (view.usable && !view.offset_known)
    {
      view.usable = false;
      view.why = "part of the pattern is off the board or hidden, and no beam numbering of its " +
                 std::to_string(view.grid.count) + " dots fits the other views clearly";
    }
}

JointFitView jointFitView(const ChessboardView& view, const BoardParams& board, int cols)
{
  JointFitView jv;
  jv.pose = view.board.pose;
  for (size_t k = 0; k < view.board.corners.size(); ++k)
    if (view.board.corner_used[k])
    {
      jv.corner_board.push_back(board.corner(static_cast<int>(k)));
      jv.corner_px.push_back(view.board.corners[k]);
    }
  for (size_t k = 0; k < view.dots.size(); ++k)
  {
    const int beam = view.beamOf(k, cols);
    if (beam < 0)
      continue;
    jv.dot_beam.push_back(beam);
    jv.dot_px.emplace_back(view.dots[k].x, view.dots[k].y);
    jv.dot_sigma_px.push_back(view.dots[k].sigma_xy_px);
  }
  return jv;
}

// Beams seen in fewer than two of the used views, named.
std::string unseenBeams(const std::vector<JointFitView>& jvs, int rows, int cols)
{
  std::vector<int> count(rows * cols, 0);
  for (const JointFitView& jv : jvs)
  {
    std::vector<char> seen(rows * cols, 0);
    for (int b : jv.dot_beam)
      seen[b] = 1;
    for (int b = 0; b < rows * cols; ++b)
      count[b] += seen[b];
  }
  std::ostringstream s;
  int n = 0;
  for (int b = 0; b < rows * cols; ++b)
    if (count[b] < 2)
    {
      if (n++ < 8)
        s << (n > 1 ? ", " : "") << "beam " << b << " (row " << b / cols << ", col " << b % cols << ") in " << count[b];
    }
  if (n > 8)
    s << " and " << n - 8 << " more";
  return n == 0 ? "" : s.str() + " view(s); every beam needs two or more views with its dot on the board";
}

}  // namespace

ChessboardCalibrationResult calibrateFromChessboardViews(const CameraModel& camera, std::vector<ChessboardView> views,
                                                         const ChessboardCalibrationParams& params)
{
  ChessboardCalibrationResult res;
  res.views = std::move(views);
  res.error = params.validate();
  if (res.error.empty())
    res.error = camera.validate();
  if (!res.error.empty())
  {
    res.failure = CalibrationFailure::kBadInput;
    return res;
  }
  const auto usable = [&]
  { return std::count_if(res.views.begin(), res.views.end(), [](const ChessboardView& v) { return v.usable; }); };
  const bool any_full = std::any_of(res.views.begin(), res.views.end(),
                                    [](const ChessboardView& v) { return v.usable && v.offset_known; });
  if (usable() >= 2 && !any_full)
  {
    res.failure = CalibrationFailure::kNoFullView;
    res.error = "no view shows the whole " + std::to_string(params.rows) + " x " + std::to_string(params.cols) +
                " pattern on the board, so the beams cannot be numbered: add a view with every dot on the print";
    return res;
  }
  resolveOffsets(camera, params, &res.views);
  std::vector<JointFitView> jvs;
  for (size_t v = 0; v < res.views.size(); ++v)
    if (res.views[v].usable)
    {
      res.views[v].used = true;
      res.fit_views.push_back(static_cast<int>(v));
      jvs.push_back(jointFitView(res.views[v], params.board, params.cols));
    }
  if (jvs.size() < 2)
  {
    res.failure = CalibrationFailure::kTooFewViews;
    res.error = std::to_string(jvs.size()) + " usable view(s) of " + std::to_string(res.views.size()) +
                ": at least two views with the board and its dots are needed (see the table)";
    return res;
  }
  res.error = unseenBeams(jvs, params.rows, params.cols);
  if (!res.error.empty())
  {
    res.failure = CalibrationFailure::kBeamNotSeen;
    return res;
  }
  res.fit = fitProjectorJoint(camera, params.rows, params.cols, jvs, params.fit);
  if (!res.fit.ok)
  {
    res.failure = CalibrationFailure::kFitFailed;
    res.error = res.fit.error;
    return res;
  }
  res.ok = true;
  return res;
}

std::string ChessboardCalibrationResult::report() const
{
  std::ostringstream s;
  s << std::fixed << std::setprecision(3);
  s << "view  board  corners  dots: found labelled used  offset  corner rms  dot rms  noise x  name / status\n";
  for (size_t v = 0; v < views.size(); ++v)
  {
    const ChessboardView& view = views[v];
    const auto it = std::find(fit_views.begin(), fit_views.end(), static_cast<int>(v));
    const int f = it == fit_views.end() ? -1 : static_cast<int>(it - fit_views.begin());
    const bool fitted = ok && f >= 0;
    s << std::setw(4) << v << "  " << (view.board.found ? "yes  " : "no   ") << "  " << std::setw(3)
      << (view.board.found ? std::count(view.board.corner_used.begin(), view.board.corner_used.end(), 1) : 0)
      << "      " << std::setw(5) << view.dots.size() << " " << std::setw(8) << view.grid.count << " " << std::setw(4)
      << (fitted ? fit.views[f].dots_used : 0) << "  " << (view.offset_known ? "known " : "-     ") << "  ";
    if (fitted)
      s << std::setw(7) << fit.views[f].corner_rms_px << " px  " << std::setw(5) << fit.views[f].dot_rms_px << " px  "
        << std::setw(5) << std::setprecision(1) << fit.views[f].dot_scale << std::setprecision(3) << "  ";
    else
      s << "      -        -        -    ";
    s << view.name << (view.why.empty() ? "" : ": " + view.why) << "\n";
  }
  if (!ok)
  {
    s << "calibration failed: " << error << "\n";
    return s.str();
  }
  const int cols = fit.calibration.cols;
  s << "beam  row col  views  rms px  from centre mm  sigma mm\n";
  for (size_t b = 0; b < fit.beams.size(); ++b)
    s << std::setw(4) << b << "  " << std::setw(3) << b / cols << " " << std::setw(3) << b % cols << "  "
      << std::setw(5) << fit.beams[b].views << "  " << std::setw(6) << fit.beams[b].rms_px << "  " << std::setw(14)
      << fit.beams[b].centre_distance_m * 1e3 << "  " << std::setw(8) << fit.beams[b].sigma_m * 1e3 << "\n";
  // The worst outliers by name (most are bright, clipped dots a few tenths
  // of a pixel off: rejected because their own sigma is small).
  std::vector<JointFitOutlier> worst = fit.outliers;
  std::sort(worst.begin(), worst.end(),
            [](const JointFitOutlier& a, const JointFitOutlier& b) { return a.residual_px > b.residual_px; });
  for (size_t k = 0; k < worst.size() && k < 10; ++k)
    s << "outlier: view " << fit_views[worst[k].view] << ", "
      << (worst[k].beam >= 0 ? "beam " + std::to_string(worst[k].beam) : "a corner") << ", " << worst[k].residual_px
      << " px off\n";
  if (worst.size() > 10)
    s << "... and " << worst.size() - 10 << " more outlier(s) up to " << worst[10].residual_px << " px\n";
  double worst_sigma = 0.0;
  for (const JointFitBeamReport& b : fit.beams)
    worst_sigma = std::max(worst_sigma, b.sigma_m);
  s << "model: " << projectorModelName(fit.model) << " (F = " << fit.f_statistic << "), centre [" << fit.centre.x()
    << ", " << fit.centre.y() << ", " << fit.centre.z() << "] m; " << fit_views.size() << " of " << views.size()
    << " views used, " << fit.outliers.size() << " outlier(s); worst ray sigma " << worst_sigma * 1e3 << " mm at "
    << fit.reference_depth_m << " m\n";
  return s.str();
}

}  // namespace structured_light_stabilizer
