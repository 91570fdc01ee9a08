#include "projector_dots.h"

#include <algorithm>
#include <cmath>

#include <Eigen/LU>

#include "optics.h"
#include "structured_light_stabilizer/detail/math.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

using detail::kNaN;
using detail::kPi;

// dot_to_sun_ratio refers to a beam of this divergence hitting the rock at
// this distance at normal incidence; a narrower beam concentrates the same
// power on a smaller footprint.
constexpr double kRefBeamSigmaRad = LightingParams::kReferenceBeamSigmaRad;
constexpr double kRefDistanceM = LightingParams::kReferenceDistanceM;

// Relative response of the B, G, R pixels of a Bayer sensor to 520 nm light:
// mostly green, with the usual cross-talk into blue and a little into red.
constexpr double kDotResponseBgr[3] = {0.22, 1.0, 0.08};

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
// tangent plane, then through the projection. *cos_i: cosine of the incidence.
Eigen::Matrix2d unitFootprint(const BeamRay& beam, const RockSurface& rock, const FrameGeometry& g,
                              const CameraModel& cam, const DotHit& hit, double* cos_i)
{
  const Eigen::Vector3d n = g.T_cr.linear() * rock.normal(hit.X_rock.x(), hit.X_rock.y());
  const Eigen::Vector3d bd = beam.direction;
  *cos_i = std::max(0.02, -n.dot(bd));
  const Eigen::Matrix3d M = Eigen::Matrix3d::Identity() - bd * n.transpose() / n.dot(bd);
  const Eigen::Matrix3d C = M * (Eigen::Matrix3d::Identity() - bd * bd.transpose()) * M.transpose();
  const Eigen::Matrix<double, 2, 3> J = projectionJacobian(cam, hit.X);
  return J * C * J.transpose();
}

}  // namespace

void renderDots(const SimulatorParams& params, const ProjectorCalibration& projector, const RockSurface& rock,
                const FrameGeometry& g, SimFrame* frame, std::vector<Splat>* splats)
{
  const SensorParams& sc = params.sensor;
  const LightingParams& light = params.lighting;
  const CameraModel& cam = sc.camera;
  const int nb = projector.beamCount();
  frame->points.assign(nb, Eigen::Vector3d::Constant(kNaN));
  frame->pixels.assign(nb, cv::Point2d(kNaN, kNaN));
  frame->blur_sigma_px.assign(nb, kNaN);
  frame->visible.assign(nb, 0);
  frame->peak_dn.assign(nb, 0.0);
  const double sigma_diff_px = diffractionSigmaPx(sc, params.projector.wavelength_nm);
  const double dot_gain = light.dot_to_sun_ratio * LightingParams::kSunFullScaleDn * light.exposure *
                          params.projector.power_scale * kRefDistanceM * kRefDistanceM * kRefBeamSigmaRad *
                          kRefBeamSigmaRad;
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
    const Eigen::Matrix2d G = unitFootprint(beam, rock, g, cam, hit, &cos_i);
    const double sigma_beam = params.projector.beam_sigma_rad * hit.s;
    const double z_blur = defocusSigmaPx(sc, hit.X.z());
    const Eigen::Matrix2d S =
        sigma_beam * sigma_beam * G +
        (z_blur * z_blur + sigma_diff_px * sigma_diff_px + kPixelBoxVariance) * Eigen::Matrix2d::Identity();
    // Energy of the dot in the image: peak radiance (ratio * sunlit * cos_i *
    // (d_ref/d)^2 * (sigma_ref/sigma)^2) times the footprint area 2 pi
    // sqrt(det(sigma^2 d^2 G)); the beam's sigma and distance cancel.
    float refl[3];
    rock.lookup3(rock.refl, hit.X_rock.x(), hit.X_rock.y(), refl);
    const double energy =
        dot_gain * refl[1] * cos_i * 2.0 * kPi * std::sqrt(std::max(0.0, G.determinant())) * vignetting(sc, hit.X);
    const double peak = energy / (2.0 * kPi * std::sqrt(S.determinant()));
    frame->peak_dn[b] = peak;
    frame->blur_sigma_px[b] = std::sqrt(0.5 * S.trace());
    Splat sp;
    sp.cx = hit.pixel.x;
    sp.cy = hit.pixel.y;
    for (int c = 0; c < 3; ++c)
      sp.value[c] = static_cast<float>(peak * kDotResponseBgr[c]);
    if (peak > 0.0 && setSplatShape(&sp, S, 50.0, cam.height))  // exp(-25): below any DN
      splats->push_back(sp);
  }
}

}  // namespace sim
}  // namespace structured_light_stabilizer
