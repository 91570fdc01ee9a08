// The closed loop's figures on the loop model (test/support/closed_loop_model.h:
// disturbance + arm model + controller, camera estimates = truth + the
// measured PoseDelta noise delivered after a latency; with the IMU, the
// simulated IMU and InertialFusion in the loop), docs/stabilization.md:
//  1. |S(f)|: residual RMS / disturbance RMS for a sine on every axis
//     (noise-free, 0.02 mm and 0.01 mrad RMS: far from the arm's 1 m/s^2 even
//     at 14 Hz, so the loop is linear),
//     camera only and with the IMU side by side, the bandwidth where |S|
//     first reaches 1/sqrt(2) and the peak;
//  2. the default (Mars) disturbance, the Earth analogue in wind and the
//     vibration-heavy arm, closed against open loop, over several seeds, and
//     the stabilised image's residual at the dots.
//
// Usage: benchmark_stabilization [key=value ...]
//   rate=30          camera frame rate (Hz)
//   latency=0.025    exposure to estimate delivered (s), + jitter=0.06 (uniform)
//   imu_latency=0.001  IMU sample to command (s)
//   seeds=5          seeds per scenario (1..seeds; the gtests hold out others)
//   noise=study|lockstep  the estimate's noise: 0.2 mm and 0.008 deg per axis
//                    (the study's full-resolution chain), or what PoseDelta
//                    gave in lockstep on the 512 x 512 ROI at 120 Hz (0.07 mm,
//                    0.0016 deg per axis plus its 0.3 mrad tx-ry/ty-rx ambiguity)
//   duration=30      s after the lock per scenario run
//   curve=1 scenarios=1  what to run
//   csv=FILE         the |S| table as CSV (frequency_hz, camera_only, with_imu)
//   camera.<param>=v / imu.<param>=v  a controller parameter of the camera-only
//                    loop (default: the .def defaults) or of the fused loop
//                    (default: fusedLoopControllerParams(), config/stabilize_imu.yaml)
#include <cmath>
#include <complex>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "structured_light_stabilizer/calibration/camera_model.h"
#include "support/closed_loop_model.h"

using namespace structured_light_stabilizer;
using namespace sls_test;

namespace
{

struct Setup
{
  StabilizationControllerParams camera_control;
  StabilizationControllerParams imu_control = fusedLoopControllerParams();
  ArmModelParams arm;
  LoopModelParams loop;
  int seeds = 5;
  bool curve = true, scenarios = true;
  bool curve_noise = false;  // the curve with the estimate's noise (a larger sine: 1 mm, 0.5 mrad)
  std::string csv;
};

// |S(f)| of the translation: residual over disturbance for a sine at f on every axis.
double rejection(const Setup& s, bool imu, double f)
{
  RigMotionParams m;
  LoopModelParams lp = s.loop;
  lp.imu = imu;
  if (s.curve_noise)
  {
    // Above the estimate's noise, below the arm's 1 m/s^2: 0.5 mm / f (Hz)
    // RMS, as config/disturbance_probe.yaml's tones.
    m.vibration_translation_rms_m = 0.0005 / std::max(1.0, f);
    m.vibration_rotation_rms_rad = 0.00025 / std::max(1.0, f);
    lp.imu_params = ImuModelParams();
  }
  else
  {
    m.vibration_translation_rms_m = 0.00002;
    m.vibration_rotation_rms_rad = 0.00001;
    lp.noise_translation_m = lp.noise_rotation_rad = lp.noise_ambiguity_rad = 0.0;
    lp.imu_params.gyro_noise_density = lp.imu_params.accel_noise_density = 0.0;
    lp.imu_params.gyro_bias_random_walk = lp.imu_params.accel_bias_random_walk = 0.0;
  }
  m.vibration_min_hz = m.vibration_max_hz = f;
  // Long enough for several periods after the transient.
  const double settle = std::max(2.0, 2.0 / f);
  lp.duration_s = settle + std::max(imu ? 4.0 : 10.0, 5.0 / f);
  const auto samples = runLoop(m, imu ? s.imu_control : s.camera_control, s.arm, lp);
  if (!s.curve_noise)
    return loopRms(samples, true, settle, true).translation_m / loopRms(samples, false, settle, true).translation_m;
  // With noise: the DFT at f (the estimate's noise spreads over the band; the
  // loop's response is at f), translation axes summed.
  std::complex<double> closed[3], open[3];
  for (const LoopSample& x : samples)
    if (x.t >= settle)
      for (int a = 0; a < 3; ++a)
      {
        const std::complex<double> w = std::exp(std::complex<double>(0.0, -2.0 * M_PI * f * x.t));
        closed[a] += x.closed[a] * w;
        open[a] += x.open[a] * w;
      }
  double pc = 0.0, po = 0.0;
  for (int a = 0; a < 3; ++a)
    pc += std::norm(closed[a]), po += std::norm(open[a]);
  return std::sqrt(pc / po);
}

struct CurveFigures
{
  double bandwidth = 0.0, peak = 0.0, peak_f = 0.0;
};

void note(CurveFigures* c, double f, double r, double previous_f, double previous_r)
{
  // Bandwidth: where |S| first reaches 1/sqrt(2), interpolated on log f.
  const double edge = 1.0 / std::sqrt(2.0);
  if (c->bandwidth == 0.0 && r >= edge && previous_f > 0.0)
    c->bandwidth =
        std::exp(std::log(previous_f) + (std::log(f) - std::log(previous_f)) * (edge - previous_r) / (r - previous_r));
  if (r > c->peak)
    c->peak = r, c->peak_f = f;
}

void curve(const Setup& s)
{
  const double freqs[] = {0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0, 1.2, 1.5, 2.0, 2.5,
                          3.0,  4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 14.0};
  std::printf("|S(f)|, translation (sine on every axis, no estimate noise): residual / disturbance RMS\n");
  std::printf("  f (Hz)  camera only (%.0f Hz)  with IMU (%.0f Hz)\n", s.loop.rate_hz, s.loop.imu_params.rate_hz);
  std::ofstream out;
  if (!s.csv.empty())
  {
    out.open(s.csv);
    out << "frequency_hz,camera_only,with_imu\n";
  }
  CurveFigures cam, imu;
  double pf = 0.0, pc = 0.0, pi = 0.0;
  for (double f : freqs)
  {
    const double rc = rejection(s, false, f), ri = rejection(s, true, f);
    std::printf("  %6.2f  %19.3f  %16.3f\n", f, rc, ri);
    if (out)
      out << f << "," << rc << "," << ri << "\n";
    note(&cam, f, rc, pf, pc);
    note(&imu, f, ri, pf, pi);
    pf = f, pc = rc, pi = ri;
  }
  std::printf("camera only: bandwidth (|S| = 0.71) %.2f Hz, peak %.2f at %.2f Hz\n", cam.bandwidth, cam.peak, cam.peak_f);
  std::printf("with IMU:    bandwidth (|S| = 0.71) %.2f Hz, peak %.2f at %.2f Hz\n", imu.bandwidth, imu.peak, imu.peak_f);
}

void scenario(const Setup& s, bool imu, const char* name, RigMotionParams m)
{
  std::printf("%s, %s (%.0f s after the lock), per seed: open-loop mm deg -> closed-loop mm deg (ratio); image px\n",
              name, imu ? "with IMU" : "camera only", s.loop.duration_s);
  double worst_t = 0.0, worst_r = 0.0, worst_px = 0.0;
  for (int seed = 1; seed <= s.seeds; ++seed)
  {
    m.seed = seed;
    LoopModelParams lp = s.loop;
    lp.imu = imu;
    lp.noise_seed = 100 + seed;
    lp.imu_params.seed = 500 + seed;
    const LoopRun run = runLoopFull(m, imu ? s.imu_control : s.camera_control, s.arm, lp);
    const auto& samples = run.samples;
    // The fused estimate against the truth (what the loop can hold at best).
    double fused_sq = 0.0;
    int fused_n = 0;
    for (const LoopFused& f : run.fused)
      if (f.estimate.valid)
      {
        fused_sq += offsetOf(f.truth * f.estimate.transform.inverse()).head<3>().squaredNorm();
        ++fused_n;
      }
    const LoopRms c = loopRms(samples, true);
    const LoopRms o = loopRms(samples, false);
    const double rt = c.translation_m / o.translation_m, rr = c.rotation_rad / o.rotation_rad;
    const double f_px = CameraModel::studyDesign().fx;
    const double px = imageResidualPx(samples, f_px, true, 0.5), open_px = imageResidualPx(samples, f_px, false, 0.5);
    worst_t = std::max(worst_t, rt);
    worst_r = std::max(worst_r, rr);
    worst_px = std::max(worst_px, px);
    std::printf("  seed %d: %6.3f mm %6.4f deg -> %6.3f mm %6.4f deg (%.3f, %.3f); image %.3f px (open loop %.2f px)",
                seed, o.translation_m * 1e3, o.rotation_rad * 180.0 / M_PI, c.translation_m * 1e3,
                c.rotation_rad * 180.0 / M_PI, rt, rr, px, open_px);
    if (fused_n > 0)
      std::printf("; fused estimate error %.3f mm", std::sqrt(fused_sq / fused_n) * 1e3);
    std::printf("\n");
  }
  std::printf("  worst ratio: translation %.3f, rotation %.3f; worst image residual %.3f px\n", worst_t, worst_r,
              worst_px);
}

bool setFlag(Setup* s, const std::string& key, const std::string& value)
{
  double v = 0.0;
  const bool number = params::parseInto(value, &v);
  if (key.rfind("camera.", 0) == 0)
    return s->camera_control.set(key.substr(7), value);
  if (key.rfind("imu.", 0) == 0)
    return s->imu_control.set(key.substr(4), value);
  if (key == "csv")
    return (s->csv = value, true);
  if (key == "noise" && (value == "study" || value == "lockstep"))
  {
    const bool lockstep = value == "lockstep";
    s->loop.noise_translation_m = lockstep ? 0.00007 : 0.0002;
    s->loop.noise_rotation_rad = lockstep ? 0.000028 : 0.00014;
    s->loop.noise_ambiguity_rad = lockstep ? 0.0003 : 0.0;
    return true;
  }
  if (!number)
    return false;
  if (key == "rate")
    s->loop.rate_hz = v;
  else if (key == "latency")
    s->loop.latency_s = v;
  else if (key == "jitter")
    s->loop.latency_jitter_s = v;
  else if (key == "imu_latency")
    s->loop.imu_latency_s = v;
  else if (key == "seeds")
    s->seeds = static_cast<int>(v);
  else if (key == "duration")
    s->loop.duration_s = v;
  else if (key == "curve")
    s->curve = v != 0.0;
  else if (key == "curve_noise")
    s->curve_noise = v != 0.0;
  else if (key == "scenarios")
    s->scenarios = v != 0.0;
  else
    return false;
  return true;
}

}  // namespace

int main(int argc, char** argv)
{
  Setup s;
  s.loop.latency_s = 0.025;
  s.loop.latency_jitter_s = 0.06;
  for (int i = 1; i < argc; ++i)
  {
    const std::string arg = argv[i];
    const auto eq = arg.find('=');
    if (eq == std::string::npos || !setFlag(&s, arg.substr(0, eq), arg.substr(eq + 1)))
    {
      std::fprintf(stderr, "benchmark_stabilization: unknown or malformed argument '%s' (see the usage at the top of "
                           "tools/benchmark_stabilization.cpp)\n", arg.c_str());
      return 2;
    }
  }
  for (const StabilizationControllerParams* c : {&s.camera_control, &s.imu_control})
    if (!c->validate().empty())
    {
      std::fprintf(stderr, "benchmark_stabilization: %s\n", c->validate().c_str());
      return 2;
    }
  std::printf("loop model: camera %.0f Hz, latency %.0f ms + 0-%.0f ms, estimate noise %.2f mm %.4f deg per axis; arm "
              "delay %.0f ms + lag %.1f Hz; IMU %.0f Hz, %.1f ms to the command\n",
              s.loop.rate_hz, s.loop.latency_s * 1e3, s.loop.latency_jitter_s * 1e3, s.loop.noise_translation_m * 1e3,
              s.loop.noise_rotation_rad * 180.0 / M_PI, s.arm.delay_s * 1e3, s.arm.bandwidth_hz,
              s.loop.imu_params.rate_hz, s.loop.imu_latency_s * 1e3);
  for (const auto& c : {std::make_pair("camera only", &s.camera_control), std::make_pair("with IMU", &s.imu_control)})
    std::printf("controller, %s: kp %.1f %.1f, ki %.1f %.1f, compensation %s (arm_delay %.0f ms), limits %.0f mm/s "
                "%.1f m/s^2, %.2f rad/s %.1f rad/s^2\n",
                c.first, c.second->kp_translation, c.second->kp_rotation, c.second->ki_translation,
                c.second->ki_rotation, c.second->latency_compensation ? "on" : "off", c.second->arm_delay * 1e3,
                c.second->max_linear_velocity * 1e3, c.second->max_linear_acceleration,
                c.second->max_angular_velocity, c.second->max_angular_acceleration);
  if (s.curve)
    curve(s);
  if (!s.scenarios)
    return 0;
  for (bool imu : {false, true})
  {
    scenario(s, imu, "default disturbance (Mars)", roverArmDisturbance());
    scenario(s, imu, "Earth analogue in wind", earthWindDisturbance());
    scenario(s, imu, "vibration-heavy (1-8 Hz, 3 mm, 0.3 deg RMS per axis)", vibrationHeavyDisturbance());
  }
  return 0;
}
