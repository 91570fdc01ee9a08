// Chessboard pose and the dots on the board, against the independent
// renderer of test/support/chessboard_scene.h: corners and pose against the
// true pose, dot centres against the true hit points (on white, on black,
// straddling an edge), recall of the dots on the print.
#include <cmath>
#include <iostream>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "structured_light_stabilizer/calibration/board_dots.h"
#include "structured_light_stabilizer/calibration/chessboard.h"
#include "structured_light_stabilizer/calibration/dot_grid.h"
#include "support/chessboard_scene.h"
#include "support/triangulator_scene.h"

using namespace structured_light_stabilizer;

namespace
{

struct ViewStats
{
  int on_print = 0, found = 0, wrong = 0;
  double sum2 = 0.0, sum2_edge = 0.0, sum2_black = 0.0;
  double sum2_white = 0.0;
  int n_edge = 0, n_black = 0, n_white = 0;
  double worst = 0.0;
  double pull2 = 0.0;  // (error / fitted sigma)^2 per axis
};

// Whether a dot's whole fitting window (+- 12 px) lies on the print: the
// dots the finder is asked to find (nearer the print's border the albedo
// under the window is unknown).
bool inScope(const CameraModel& cam, const BoardParams& board, const Eigen::Isometry3d& pose, const cv::Point2d& h)
{
  for (int k = 0; k < 4; ++k)
  {
    Eigen::Vector2d b;
    const cv::Point2d corner(h.x + (k % 2 ? 12 : -12), h.y + (k / 2 ? 12 : -12));
    if (!pixelToBoard(cam, pose, corner, &b) || std::isnan(boardAlbedo(board, true, 0.5, b.x(), b.y())))
      return false;
  }
  return true;
}

// Dots of one rendered view matched to the true hit pixels (1.5 px).
void scoreView(const CameraModel& cam, const BoardParams& board, const std::vector<BoardDot>& dots,
               const sls_test::ChessboardSceneTruth& truth, ViewStats* s)
{
  for (const cv::Point2d& h : truth.hit_pixels)
    s->on_print += std::isfinite(h.x) && inScope(cam, board, truth.pose, h);
  for (const BoardDot& d : dots)
  {
    double best = 1e9;
    for (const cv::Point2d& h : truth.hit_pixels)
      if (std::isfinite(h.x))
        best = std::min(best, std::hypot(d.x - h.x, d.y - h.y));
    if (best > 1.5)
    {
      std::cout << "  not a dot: " << d.x << ", " << d.y << " (" << best << " px from the nearest hit), snr " << d.snr
                << ", sigma " << d.sigma_px << ", amplitude " << d.amplitude << ", fit rms " << d.fit_rms << "\n";
      ++s->wrong;
      continue;
    }
    ++s->found;
    s->sum2 += best * best;
    if (d.black_fraction <= 0.1)
    {
      s->sum2_white += best * best;
      ++s->n_white;
    }
    s->pull2 += best * best / (2.0 * d.sigma_xy_px * d.sigma_xy_px);
    s->worst = std::max(s->worst, best);
    if (d.black_fraction > 0.1 && d.black_fraction < 0.9)
    {
      s->sum2_edge += best * best;
      ++s->n_edge;
    }
    else if (d.black_fraction >= 0.9)
    {
      s->sum2_black += best * best;
      ++s->n_black;
    }
  }
}

// Worst distance (mm) between the detected and the true board's corners in
// the camera frame; the board may be numbered from either end (a 10 x 8
// board is symmetric under a half turn).
double worstPoseErrorMm(const BoardParams& board, const Eigen::Isometry3d& detected, const Eigen::Isometry3d& truth)
{
  double worst = 0.0;
  for (int k = 0; k < board.cornerCount(); ++k)
  {
    const Eigen::Vector3d a = detected * board.corner(k);
    worst = std::max(worst, 1e3 * std::min((a - truth * board.corner(k)).norm(),
                                           (a - truth * board.corner(board.cornerCount() - 1 - k)).norm()));
  }
  return worst;
}

}  // namespace

TEST(BoardDots, PoseAndDotCentresOnTiltedBoards)
{
  const CameraModel cam = CameraModel::studyDesign();
  const ProjectorCalibration proj = sls_test::simLikeProjector(0.087);
  sls_test::ChessboardSceneParams sp;
  ViewStats st;
  double worst_pose_mm = 0.0, worst_corner_rms = 0.0;
  const double views[][3] = {{1.3, 0.3, -0.2}, {1.5, -0.25, 0.3}, {1.6, 0.1, 0.1}};
  for (int v = 0; v < 3; ++v)
  {
    sp.seed = 11 + v;
    const Eigen::Isometry3d pose = sls_test::boardPoseFacing(sp.board, views[v][0], views[v][1], views[v][2]);
    sls_test::ChessboardSceneTruth truth;
    const cv::Mat bgr = sls_test::renderChessboardScene(cam, proj, sp, pose, &truth);
    std::vector<cv::Mat> ch;
    cv::split(bgr, ch);
    const ChessboardDetection det = detectChessboard(ch[2], cam, sp.board);
    ASSERT_TRUE(det.found) << det.why;
    const double pose_mm = worstPoseErrorMm(sp.board, det.pose, pose);
    worst_pose_mm = std::max(worst_pose_mm, pose_mm);
    worst_corner_rms = std::max(worst_corner_rms, det.corner_rms_px);
    BoardDotReport rep;
    const std::vector<BoardDot> dots = findBoardDots(ch[1], 255.0, cam, sp.board, det, BoardDotParams(), &rep);
    std::cout << "[ MEASURE ] view " << v << ": corners rms " << det.corner_rms_px << " px, pose worst " << pose_mm
              << " mm, black ratio " << rep.black_ratio << (rep.black_ratio_measured ? " (measured)" : "") << ", psf "
              << rep.psf_sigma_px << " px, noise " << rep.noise_dn << " / " << rep.noise_black_dn << " DN, candidates "
              << rep.candidates << ", rejected " << rep.rejected << ", dots " << dots.size() << "\n";
    scoreView(cam, sp.board, dots, truth, &st);
    for (const cv::Point2d& h : truth.hit_pixels)
    {
      bool seen = false;
      for (const BoardDot& d : dots)
        seen |= std::hypot(d.x - h.x, d.y - h.y) < 1.5;
      if (std::isfinite(h.x) && !seen && inScope(cam, sp.board, truth.pose, h))
        std::cout << "  missed the dot at " << h.x << ", " << h.y << "\n";
    }
  }
  const double rms = std::sqrt(st.sum2 / std::max(1, st.found));
  std::cout << "[ MEASURE ] dots " << st.found << " / " << st.on_print << " on the print, " << st.wrong
            << " not a dot; centre RMS " << rms << " px (worst " << st.worst << "), on white "
            << std::sqrt(st.sum2_white / std::max(1, st.n_white)) << " px (" << st.n_white << "), straddling an edge "
            << std::sqrt(st.sum2_edge / std::max(1, st.n_edge)) << " px (" << st.n_edge << "), on black "
            << std::sqrt(st.sum2_black / std::max(1, st.n_black)) << " px (" << st.n_black
            << "), error over the fitted sigma " << std::sqrt(st.pull2 / std::max(1, st.found)) << " RMS\n";
  // Every dot in scope found (a dot nearer the print's border than its
  // window may be found too), none that is not a dot.
  EXPECT_GE(st.found, st.on_print);
  EXPECT_EQ(st.wrong, 0);
  // Centres: on white the dots are bright (0.03 px is the bound for
  // smooth albedo); on black they are 16x dimmer, so noise-limited (about
  // 0.13 px at this brightness: 0.8 x noise / peak per axis); a dot cut by
  // an edge loses part of its light. The fitted sigma must describe the
  // error (the joint fit weighs each dot by it).
  EXPECT_LT(std::sqrt(st.sum2_white / std::max(1, st.n_white)), 0.03);
  EXPECT_LT(std::sqrt(st.sum2_edge / std::max(1, st.n_edge)), 0.2);
  EXPECT_LT(std::sqrt(st.sum2_black / std::max(1, st.n_black)), 0.3);
  EXPECT_LT(std::sqrt(st.pull2 / std::max(1, st.found)), 1.5);
  EXPECT_GT(st.n_white, 50);
  EXPECT_GT(st.n_edge, 20);
  EXPECT_GT(st.n_black, 50);
  EXPECT_LT(worst_pose_mm, 0.3);
  EXPECT_LT(worst_corner_rms, 0.1);
}

TEST(BoardDots, DistortedLens)
{
  // A rational_polynomial lens (barrel, k1 = -0.3): the pose is fitted on
  // the distorted corners, the print's albedo rendered through the lens.
  CameraModel cam = CameraModel::studyDesign();
  cam.distortion = DistortionModel::kRationalPolynomial;
  cam.D = {-0.3, 0.1, 0.0004, -0.0002, 0.01, -0.15, 0.05, 0.005};
  const ProjectorCalibration proj = sls_test::simLikeProjector(0.087);
  sls_test::ChessboardSceneParams sp;
  sp.seed = 21;
  const Eigen::Isometry3d pose = sls_test::boardPoseFacing(sp.board, 1.4, -0.25, 0.2);
  sls_test::ChessboardSceneTruth truth;
  const cv::Mat bgr = sls_test::renderChessboardScene(cam, proj, sp, pose, &truth);
  std::vector<cv::Mat> ch;
  cv::split(bgr, ch);
  const ChessboardDetection det = detectChessboard(ch[2], cam, sp.board);
  ASSERT_TRUE(det.found) << det.why;
  const double pose_mm = worstPoseErrorMm(sp.board, det.pose, pose);
  BoardDotReport rep;
  const std::vector<BoardDot> dots = findBoardDots(ch[1], 255.0, cam, sp.board, det, BoardDotParams(), &rep);
  ViewStats st;
  scoreView(cam, sp.board, dots, truth, &st);
  std::cout << "[ MEASURE ] rational_polynomial lens: corners rms " << det.corner_rms_px << " px, pose worst "
            << pose_mm << " mm, dots " << st.found << " / " << st.on_print << ", on white "
            << std::sqrt(st.sum2_white / std::max(1, st.n_white)) << " px RMS\n";
  EXPECT_LT(pose_mm, 0.3);
  EXPECT_GE(st.found, st.on_print);
  EXPECT_LT(std::sqrt(st.sum2_white / std::max(1, st.n_white)), 0.03);
  // A faint spot that is not a dot may be fitted; the pattern's grid must
  // leave it out (every true dot labelled, no other spot).
  std::vector<Eigen::Vector2d> px;
  for (const BoardDot& d : dots)
  {
    const Eigen::Vector2d n = cam.normalize(cv::Point2d(d.x, d.y));
    px.emplace_back(cam.fx * n.x() + cam.cx, cam.fy * n.y() + cam.cy);
  }
  const DotGrid grid = labelDotGrid(px);
  int labelled_wrong = 0;
  for (size_t k = 0; k < dots.size(); ++k)
  {
    double best = 1e9;
    for (const cv::Point2d& h : truth.hit_pixels)
      if (std::isfinite(h.x))
        best = std::min(best, std::hypot(dots[k].x - h.x, dots[k].y - h.y));
    labelled_wrong += grid.labelled[k] && best > 1.5;
  }
  EXPECT_LE(st.wrong, 2);
  EXPECT_EQ(labelled_wrong, 0);
  EXPECT_EQ(grid.count, st.found);
}
