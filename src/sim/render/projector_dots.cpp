#include "sim/render/projector_dots.h"

#include <algorithm>
#include <cmath>

#include <Eigen/LU>

#include "sim/render/brightness.h"
#include "sim/render/optics.h"
#include "sim/render/spectral.h"
#include "structured_light_stabilizer/common/math.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

using detail::kNaN;
using detail::kPi;

// Where a beam meets the rock, seen from the camera.
struct DotHit
{
  double s = 0.0;          // beam parameter (unit direction: metres from the projector)
  Eigen::Vector3d X_rock;  // rock frame
  Eigen::Vector3d X;       // camera frame
  cv::Point2d pixel;       // distorted pixel
};

// False when the beam misses the rock (or only meets a side wall), or its
// dot is behind the camera, outside the image or hidden by the rock.
bool castBeam(const BeamRay& beam, const RockSurface& rock, const FrameGeometry& g, const CameraModel& cam, DotHit* hit)
{
  const Eigen::Vector3d ob = g.T_rc * beam.origin, db = g.R * beam.direction;
  double s;
  bool wall;
  if (!rock.cast(ob, db, &s, &wall) || wall)
    return false;
  hit->s = s;
  hit->X_rock = ob + s * db;
  hit->X = g.T_cr * hit->X_rock;
  if (!(hit->X.z() > 0.0))
    return false;
  const cv::Point2d p = cam.project(hit->X);
  hit->pixel = p;
  return p.x >= 0.0 && p.y >= 0.0 && p.x <= cam.width - 1 && p.y <= cam.height - 1 &&
         !occludedFromCamera(rock, g, hit->X_rock);
}

// Footprint of the beam in the image for unit sigma * distance: its
// cross-section (isotropic about the beam) pushed along the beam onto the
// tangent plane (normal n, camera frame), then through the projection
// (Jacobian J). *cos_i: cosine of the incidence.
Eigen::Matrix2d unitFootprint(const BeamRay& beam, const Eigen::Vector3d& n, const Eigen::Matrix<double, 2, 3>& J,
                              double* cos_i)
{
  const Eigen::Vector3d bd = beam.direction;
  *cos_i = std::max(0.02, -n.dot(bd));
  const Eigen::Matrix3d M = Eigen::Matrix3d::Identity() - bd * n.transpose() / n.dot(bd);
  const Eigen::Matrix3d C = M * (Eigen::Matrix3d::Identity() - bd * bd.transpose()) * M.transpose();
  return J * C * J.transpose();
}

// The per-pixel albedo of a dot (splat.h, DotAlbedo): image offsets mapped to
// the tangent plane of the hit point (normal n, camera frame) and on to rock
// (x, y); A: the beam's footprint, S: the whole dot (px^2).
DotAlbedo dotAlbedo(const FrameGeometry& g, const DotHit& hit, const Eigen::Vector3d& n,
                    const Eigen::Matrix<double, 2, 3>& J, const Eigen::Matrix2d& A, const Eigen::Matrix2d& S)
{
  DotAlbedo da;
  da.x0 = hit.X_rock.x();
  da.y0 = hit.X_rock.y();
  Eigen::Matrix<double, 3, 2> T;
  T.col(0) = n.unitOrthogonal();
  T.col(1) = n.cross(T.col(0));
  const Eigen::Matrix2d JT = J * T;
  if (!(std::abs(JT.determinant()) > 1e-12))
    return da;                                                      // seen edge-on: the reflectance of the hit point
  const Eigen::Matrix2d L = (g.R * T * JT.inverse()).topRows<2>();  // image px -> rock (x, y)
  const Eigen::Matrix2d Si = S.inverse();
  const Eigen::Matrix2d K = L * A * Si;
  const Eigen::Matrix2d blur = L * (A - A * Si * A) * L.transpose();
  da.K[0] = K(0, 0);
  da.K[1] = K(0, 1);
  da.K[2] = K(1, 0);
  da.K[3] = K(1, 1);
  da.blur_x = std::sqrt(std::max(0.0, blur(0, 0)));
  da.blur_y = std::sqrt(std::max(0.0, blur(1, 1)));
  return da;
}

// What the per-pixel incidence needs (splat.h, DotAlbedo::Incidence), in
// the rock frame and grid units; b: the beam's direction (rock frame). The
// tangent plane is the one of the footprint (the smooth normal at the hit).
void setIncidence(const RockSurface& rock, const FrameGeometry& g, const DotHit& hit, const Eigen::Vector3d& b,
                  double cos_i, double sigma_beam, DotAlbedo* da)
{
  DotAlbedo::Incidence& inc = da->inc;
  const Eigen::Vector3d view = (hit.X_rock - g.o).normalized();
  const Eigen::Vector3d n = rock.normal(hit.X_rock.x(), hit.X_rock.y());  // (gx, gy, -1) / |.|
  const double gx = -n.x() / n.z(), gy = -n.y() / n.z();
  const Eigen::Vector3d w = view - view.dot(b) * b;  // the view ray across the beam
  for (int k = 0; k < 3; ++k)
  {
    inc.beam[k] = static_cast<float>(b[k]);
    inc.view[k] = static_cast<float>(view[k]);
  }
  inc.inv_cos_hit = static_cast<float>(1.0 / cos_i);
  inc.z = static_cast<float>(hit.X_rock.z() * rock.inv_cell);
  inc.gx = static_cast<float>(gx);
  inc.gy = static_cast<float>(gy);
  inc.omega[0] = static_cast<float>(w.x() + w.z() * gx);
  inc.omega[1] = static_cast<float>(w.y() + w.z() * gy);
  inc.ww = static_cast<float>(w.squaredNorm());
  const double sigma_grid = sigma_beam * rock.inv_cell;
  inc.inv_sigma2 = static_cast<float>(1.0 / (sigma_grid * sigma_grid));
  da->incidence = true;
}

}  // namespace

void renderDots(const SimulatorParams& params, const ProjectorCalibration& projector, const RockSurface& rock,
                const FrameGeometry& g, SimFrame* frame, std::vector<Splat>* splats, std::vector<DotAlbedo>* albedo)
{
  const SensorParams& sc = params.sensor;
  const CameraModel& cam = sc.camera;
  const int nb = projector.beamCount();
  frame->points.assign(nb, Eigen::Vector3d::Constant(kNaN));
  frame->pixels.assign(nb, cv::Point2d(kNaN, kNaN));
  frame->blur_sigma_px.assign(nb, kNaN);
  frame->visible.assign(nb, 0);
  frame->peak_dn.assign(nb, 0.0);
  const double sigma_diff_px = diffractionSigmaPx(sc, params.projector.wavelength_nm);
  const double dot_gain = dotGain(params);
  const CameraSpectrum spectrum = cameraSpectrum(params.projector.color, sc.output);
  for (int b = 0; b < nb; ++b)
  {
    const BeamRay& beam = projector.beams[b];
    DotHit hit;
    if (!castBeam(beam, rock, g, cam, &hit))
      continue;
    frame->points[b] = hit.X;
    frame->pixels[b] = hit.pixel;
    frame->visible[b] = 1;

    double cos_i;
    const Eigen::Vector3d n = g.T_cr.linear() * rock.normal(hit.X_rock.x(), hit.X_rock.y());
    const Eigen::Matrix<double, 2, 3> J = projectionJacobian(cam, hit.X);
    const Eigen::Matrix2d G = unitFootprint(beam, n, J, &cos_i);
    const double sigma_beam = params.projector.beam_sigma_rad * hit.s;
    const double z_blur = defocusSigmaPx(sc, hit.X.z());
    const Eigen::Matrix2d A = sigma_beam * sigma_beam * G;
    const Eigen::Matrix2d S =
        A + (z_blur * z_blur + sigma_diff_px * sigma_diff_px + kPixelBoxVariance) * Eigen::Matrix2d::Identity();
    // Energy of the dot in the image per unit reflectance: peak irradiance
    // (ratio * sun * cos_i * (d_ref/d)^2 * (sigma_ref/sigma)^2) times the
    // footprint area 2 pi sqrt(det(sigma^2 d^2 G)); the beam's sigma and
    // distance cancel. The reflectance and the incidence's change across
    // the footprint come per pixel (DotAlbedo).
    const double energy =
        dot_gain * cos_i * 2.0 * kPi * std::sqrt(std::max(0.0, G.determinant())) * vignetting(sc, hit.X);
    const double amplitude = energy / (2.0 * kPi * std::sqrt(S.determinant()));
    DotAlbedo da = dotAlbedo(g, hit, n, J, A, S);
    if (!rock.board && !rock.planar)
      setIncidence(rock, g, hit, g.R * beam.direction, cos_i, sigma_beam, &da);
    std::copy(&spectrum.dot_mix[0][0], &spectrum.dot_mix[0][0] + 12, &da.mix[0][0]);
    da.g_lookup = std::min(1e-3, 0.02 / std::max(amplitude, 1e-9));
    da.prepareGrid(rock);
    da.factors(rock, 0.0, 0.0, da.f0);
    frame->peak_dn[b] = amplitude * da.f0[spectrum.primary];
    frame->blur_sigma_px[b] = std::sqrt(0.5 * S.trace());
    Splat sp;
    sp.cx = hit.pixel.x;
    sp.cy = hit.pixel.y;
    for (int c = 0; c < 3; ++c)
      sp.value[c] = static_cast<float>(amplitude);
    sp.albedo = static_cast<int>(albedo->size());
    sp.beam = b;
    // The splat ends where the dot falls below 0.005 DN, but not before
    // exp(-12.5) of its peak (what the second moments of a faint dot see) nor
    // after exp(-25).
    const double brightest =
        amplitude * std::max({da.mix[0][0], da.mix[0][1], da.mix[0][2], da.mix[0][3], da.mix[1][0], da.mix[1][1],
                              da.mix[1][2], da.mix[1][3], da.mix[2][0], da.mix[2][1], da.mix[2][2], da.mix[2][3]});
    const double q_max = std::min(50.0, std::max(25.0, 2.0 * std::log(brightest / 0.005)));
    if (amplitude > 0.0 && setSplatShape(&sp, S, q_max, cam.height))
    {
      splats->push_back(sp);
      albedo->push_back(da);
    }
  }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
