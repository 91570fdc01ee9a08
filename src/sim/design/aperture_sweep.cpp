// The study's figure 2.2: diameter of confusion and diffraction spots versus
// the aperture, as numbers (CSV) and as a plot.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "sim/design/scene_model.h"

namespace structured_light_stabilizer
{

using namespace scene;

ApertureSweep apertureSweep(const SceneInputs& in, int steps, int wavelength_count)
{
  in.validate();
  if (steps < 2 || wavelength_count < 1)
    fail("apertureSweep", "needs steps >= 2 and wavelength_count >= 1");
  ApertureSweep sw;
  for (int k = 0; k < wavelength_count; ++k)
  {
    const double u = wavelength_count == 1 ? 1.0 : static_cast<double>(k) / (wavelength_count - 1);
    sw.wavelengths_m.push_back(in.wavelength_min_m + u * (in.wavelength_max_m - in.wavelength_min_m));
  }
  for (int i = 0; i < steps; ++i)
  {
    ApertureSweepRow r;
    r.aperture_m = in.sweep_aperture_min_m + (in.sweep_aperture_max_m - in.sweep_aperture_min_m) * i / (steps - 1);
    r.doc_m = diameterOfConfusion(in, r.aperture_m, in.distance_max_m);
    for (double wl : sw.wavelengths_m)
      r.diffraction_m.push_back(diffractionSpot(in, r.aperture_m, wl));
    sw.rows.push_back(r);
  }
  return sw;
}

std::string apertureSweepCsv(const ApertureSweep& sw)
{
  std::ostringstream os;
  os << "aperture_mm,doc_um";
  for (double wl : sw.wavelengths_m)
    os << ",diffraction_" << std::lround(wl * 1e9) << "nm_um";
  os << "\n";
  char buf[64];
  for (const auto& r : sw.rows)
  {
    std::snprintf(buf, sizeof(buf), "%.4f,%.5f", r.aperture_m * 1e3, r.doc_m * 1e6);
    os << buf;
    for (double d : r.diffraction_m)
    {
      std::snprintf(buf, sizeof(buf), ",%.5f", d * 1e6);
      os << buf;
    }
    os << "\n";
  }
  return os.str();
}

namespace
{

// The plot area of the figure and its axes: aperture in mm across, spot
// diameter in um up (0 to ymax, a multiple of 5 above every curve and the pixel).
class SweepPlot
{
public:
  SweepPlot(const SceneInputs& in, const ApertureSweep& sw, int width, int height)
    : in_(in),
      sw_(sw),
      img_(height, width, CV_8UC3, cv::Scalar(255, 255, 255)),
      x0_(sw.rows.front().aperture_m * 1e3),
      x1_(sw.rows.back().aperture_m * 1e3),
      pw_(width - kLeft - kRight),
      ph_(height - kTop - kBottom)
  {
    double ymax = in.pixel_size_m * 1e6;
    for (const auto& r : sw.rows)
    {
      ymax = std::max(ymax, r.doc_m * 1e6);
      for (double d : r.diffraction_m)
        ymax = std::max(ymax, d * 1e6);
    }
    ymax_ = std::ceil(ymax / 5.0) * 5.0;
  }

  void drawAxes();
  void drawReferenceLines();
  void drawCurves();
  void drawLegend();
  const cv::Mat& image() const { return img_; }

private:
  static constexpr int kLeft = 90, kRight = 30, kTop = 50, kBottom = 70;
  static constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

  int px(double x_mm) const { return kLeft + static_cast<int>(std::lround((x_mm - x0_) / (x1_ - x0_) * pw_)); }
  int py(double y_um) const { return kTop + ph_ - static_cast<int>(std::lround(y_um / ymax_ * ph_)); }
  // Diffraction curves from blue (short wavelengths) to red.
  cv::Scalar wavelengthColour(size_t k) const
  {
    const size_t n = sw_.wavelengths_m.size();
    const double u = n == 1 ? 1.0 : static_cast<double>(k) / (n - 1);
    return cv::Scalar(255 * (1 - u), 150 * std::sin(u * kPi), 255 * u);
  }
  void polyline(const std::function<double(const ApertureSweepRow&)>& f, const cv::Scalar& colour);

  const cv::Scalar black_{0, 0, 0}, grey_{215, 215, 215};
  const cv::Scalar pixel_colour_{0, 150, 0}, aperture_colour_{120, 120, 120};
  const SceneInputs& in_;
  const ApertureSweep& sw_;
  cv::Mat img_;
  double x0_, x1_, ymax_ = 0.0;
  int pw_, ph_;  // plot area, px
};

// Grid, ticks, frame, axis labels and title.
void SweepPlot::drawAxes()
{
  const int height = img_.rows;
  const double xstep = (x1_ - x0_) > 3.0 ? 0.5 : 0.25;
  for (double x = std::ceil(x0_ / xstep) * xstep; x <= x1_ + 1e-9; x += xstep)
  {
    cv::line(img_, {px(x), kTop}, {px(x), kTop + ph_}, grey_, 1);
    cv::line(img_, {px(x), kTop + ph_}, {px(x), kTop + ph_ + 6}, black_, 1);
    char b[16];
    std::snprintf(b, sizeof(b), "%.1f", x);
    cv::putText(img_, b, {px(x) - 14, kTop + ph_ + 24}, kFont, 0.5, black_, 1, cv::LINE_AA);
  }
  const double ystep = ymax_ > 40 ? 10.0 : 5.0;
  for (double y = 0; y <= ymax_ + 1e-9; y += ystep)
  {
    cv::line(img_, {kLeft, py(y)}, {kLeft + pw_, py(y)}, grey_, 1);
    cv::line(img_, {kLeft - 6, py(y)}, {kLeft, py(y)}, black_, 1);
    char b[16];
    std::snprintf(b, sizeof(b), "%.0f", y);
    cv::putText(img_, b, {kLeft - 40, py(y) + 5}, kFont, 0.5, black_, 1, cv::LINE_AA);
  }
  cv::rectangle(img_, {kLeft, kTop}, {kLeft + pw_, kTop + ph_}, black_, 1);
  cv::putText(img_, "aperture diameter Dsr [mm]", {kLeft + pw_ / 2 - 120, height - 20}, kFont, 0.6, black_, 1,
              cv::LINE_AA);
  cv::Mat ylabel(30, 260, CV_8UC3, cv::Scalar(255, 255, 255));
  cv::putText(ylabel, "spot diameter [um]", {30, 21}, kFont, 0.6, black_, 1, cv::LINE_AA);
  cv::rotate(ylabel, ylabel, cv::ROTATE_90_COUNTERCLOCKWISE);
  if (ylabel.rows <= height && ylabel.cols <= kLeft)
    ylabel.copyTo(img_(cv::Rect(2, kTop + ph_ / 2 - ylabel.rows / 2, ylabel.cols, ylabel.rows)));
  char title[160];
  std::snprintf(title, sizeof(title), "Diameter of confusion (r = %.1f m, focus %.1f m) and diffraction spots",
                in_.distance_max_m, in_.focus_distance_m);
  cv::putText(img_, title, {kLeft, 30}, kFont, 0.6, black_, 1, cv::LINE_AA);
}

// The pixel size (dashed across) and the chosen aperture (dashed up).
void SweepPlot::drawReferenceLines()
{
  for (int x = kLeft; x < kLeft + pw_; x += 16)
    cv::line(img_, {x, py(in_.pixel_size_m * 1e6)}, {std::min(x + 10, kLeft + pw_), py(in_.pixel_size_m * 1e6)},
             pixel_colour_, 2);
  const double dsr = in_.aperture_diameter_m * 1e3;
  if (dsr >= x0_ && dsr <= x1_)
  {
    for (int y = kTop; y < kTop + ph_; y += 12)
      cv::line(img_, {px(dsr), y}, {px(dsr), std::min(y + 6, kTop + ph_)}, aperture_colour_, 2);
    char b[48];
    std::snprintf(b, sizeof(b), "Dsr = %.2f mm", dsr);
    cv::putText(img_, b, {px(dsr) + 6, kTop + 18}, kFont, 0.5, aperture_colour_, 1, cv::LINE_AA);
  }
}

void SweepPlot::polyline(const std::function<double(const ApertureSweepRow&)>& f, const cv::Scalar& colour)
{
  const cv::Rect clip(kLeft, kTop, pw_ + 1, ph_ + 1);
  for (size_t i = 1; i < sw_.rows.size(); ++i)
  {
    cv::Point a(px(sw_.rows[i - 1].aperture_m * 1e3), py(f(sw_.rows[i - 1])));
    cv::Point b(px(sw_.rows[i].aperture_m * 1e3), py(f(sw_.rows[i])));
    if (cv::clipLine(clip, a, b))
      cv::line(img_, a, b, colour, 2, cv::LINE_AA);
  }
}

// DoC in black, diffraction spots blue to red.
void SweepPlot::drawCurves()
{
  polyline([](const ApertureSweepRow& r) { return r.doc_m * 1e6; }, black_);
  for (size_t k = 0; k < sw_.wavelengths_m.size(); ++k)
    polyline([k](const ApertureSweepRow& r) { return r.diffraction_m[k] * 1e6; }, wavelengthColour(k));
}

// Top right, where the curves are low.
void SweepPlot::drawLegend()
{
  const int lx = kLeft + pw_ - 230;
  int ly = kTop + 20;
  const int n = static_cast<int>(sw_.wavelengths_m.size() + 2);
  cv::rectangle(img_, {lx - 10, ly - 15}, {kLeft + pw_ - 8, ly + 22 * n - 8}, cv::Scalar(255, 255, 255), cv::FILLED);
  cv::rectangle(img_, {lx - 10, ly - 15}, {kLeft + pw_ - 8, ly + 22 * n - 8}, black_, 1);
  auto entry = [&](const std::string& text, const cv::Scalar& col)
  {
    cv::line(img_, {lx, ly - 4}, {lx + 30, ly - 4}, col, 2, cv::LINE_AA);
    cv::putText(img_, text, {lx + 40, ly + 1}, kFont, 0.5, black_, 1, cv::LINE_AA);
    ly += 22;
  };
  entry("diameter of confusion", black_);
  for (size_t k = 0; k < sw_.wavelengths_m.size(); ++k)
    entry("diffraction, " + std::to_string(std::lround(sw_.wavelengths_m[k] * 1e9)) + " nm", wavelengthColour(k));
  entry("pixel " + num(in_.pixel_size_m * 1e6) + " um", pixel_colour_);
}

}  // namespace

cv::Mat renderApertureSweep(const SceneInputs& in, const ApertureSweep& sw, int width, int height)
{
  if (width < 300 || height < 200)
    fail("renderApertureSweep", "image too small (need at least 300 x 200)");
  if (sw.rows.size() < 2)
    fail("renderApertureSweep", "empty sweep");
  SweepPlot plot(in, sw, width, height);
  plot.drawAxes();
  plot.drawReferenceLines();
  plot.drawCurves();
  plot.drawLegend();
  return plot.image();
}

}  // namespace structured_light_stabilizer
