// The closed loop's figures on the loop model (test/support/closed_loop_model.h:
// disturbance + arm model + controller, estimates = truth + measured noise
// delivered after a latency), docs/stabilization.md "Measured":
//  1. the rejection curve: residual RMS / disturbance RMS for a sine of each
//     frequency (translation and rotation), noise-free, i.e. |S(f)| of the
//     loop, and the bandwidth where it crosses 1/sqrt(2);
//  2. the default disturbance (roverArmDisturbance) over several seeds, and
//     the vibration-heavy example (1-8 Hz, several mm), closed
//     against open loop.
//
// Usage: benchmark_stabilization [latency_s (0.025)] [jitter_s (0.06)]
//          [compensation 0|1 (0)] [kp (5)] [ki (5)] [csv_file ("" = none)]
// Latency: exposure to command, here 25 ms + a uniform 0-60 ms, what
// stabilize.launch measured (median 25-30 ms, 95th percentile 77-130 ms).
// The CSV holds the rejection curve (frequency_hz, translation_ratio,
// rotation_ratio); `python3 -m structured_light_stabilizer.plot CSV PNG`
// draws it.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "support/closed_loop_model.h"

using namespace structured_light_stabilizer;
using namespace sls_test;

namespace
{

struct Setup
{
  StabilizationControllerParams control;
  ArmModelParams arm;
  LoopModelParams loop;
};

// |S(f)|: residual over disturbance for a sine at f on every axis.
void rejection(const Setup& s, double f, double* translation, double* rotation)
{
  RigMotionParams m;
  m.vibration_translation_rms_m = 0.001;
  m.vibration_rotation_rms_rad = 0.0005;
  m.vibration_min_hz = m.vibration_max_hz = f;
  LoopModelParams lp = s.loop;
  lp.noise_translation_m = lp.noise_rotation_rad = 0.0;
  // Long enough for several periods after the transient.
  const double settle = std::max(3.0, 2.0 / f);
  lp.duration_s = settle + std::max(10.0, 5.0 / f);
  const auto samples = runLoop(m, s.control, s.arm, lp);
  const LoopRms closed = loopRms(samples, true, settle, true);
  const LoopRms open = loopRms(samples, false, settle, true);
  *translation = closed.translation_m / open.translation_m;
  *rotation = closed.rotation_rad / open.rotation_rad;
}

void curve(const Setup& s, const std::string& csv)
{
  const double freqs[] = {0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.7, 0.85, 1.0,  1.2,
                          1.5,  2.0, 2.5,  3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 14.0};
  std::printf("rejection curve (sine on every axis, no estimate noise): residual / disturbance RMS\n");
  std::printf("  f (Hz)  translation  rotation\n");
  std::ofstream out;
  if (!csv.empty())
  {
    out.open(csv);
    out << "frequency_hz,translation_ratio,rotation_ratio\n";
  }
  double previous_f = 0.0, previous_r = 0.0, bandwidth = 0.0, peak = 0.0, peak_f = 0.0;
  for (double f : freqs)
  {
    double rt = 0.0, rr = 0.0;
    rejection(s, f, &rt, &rr);
    std::printf("  %6.2f  %11.3f  %8.3f\n", f, rt, rr);
    if (out)
      out << f << "," << rt << "," << rr << "\n";
    // Bandwidth: where |S| first reaches 1/sqrt(2), interpolated on log f.
    const double edge = 1.0 / std::sqrt(2.0);
    if (bandwidth == 0.0 && rt >= edge && previous_f > 0.0)
      bandwidth = std::exp(std::log(previous_f) +
                           (std::log(f) - std::log(previous_f)) * (edge - previous_r) / (rt - previous_r));
    if (rt > peak)
      peak = rt, peak_f = f;
    previous_f = f;
    previous_r = rt;
  }
  std::printf("bandwidth (|S| = 0.71): %.2f Hz; largest amplification %.2f at %.2f Hz\n", bandwidth, peak, peak_f);
}

void scenario(const Setup& s, const char* name, RigMotionParams m, int seeds)
{
  std::printf("%s (%.0f s after the lock), per seed: open-loop mm deg -> closed-loop mm deg (ratio)\n", name,
              s.loop.duration_s);
  double worst_t = 0.0, worst_r = 0.0;
  for (int seed = 1; seed <= seeds; ++seed)
  {
    m.seed = seed;
    LoopModelParams lp = s.loop;
    lp.noise_seed = 100 + seed;
    const auto samples = runLoop(m, s.control, s.arm, lp);
    const LoopRms c = loopRms(samples, true);
    const LoopRms o = loopRms(samples, false);
    const double rt = c.translation_m / o.translation_m, rr = c.rotation_rad / o.rotation_rad;
    worst_t = std::max(worst_t, rt);
    worst_r = std::max(worst_r, rr);
    std::printf("  seed %d: %6.3f mm %6.4f deg -> %6.3f mm %6.4f deg (%.3f, %.3f)\n", seed, o.translation_m * 1e3,
                o.rotation_rad * 180.0 / M_PI, c.translation_m * 1e3, c.rotation_rad * 180.0 / M_PI, rt, rr);
  }
  std::printf("  worst ratio: translation %.3f, rotation %.3f\n", worst_t, worst_r);
}

}  // namespace

int main(int argc, char** argv)
{
  Setup s;
  s.loop.latency_s = argc > 1 ? std::atof(argv[1]) : 0.025;
  s.loop.latency_jitter_s = argc > 2 ? std::atof(argv[2]) : 0.06;
  s.control.latency_compensation = argc > 3 && std::atoi(argv[3]) != 0;
  if (argc > 4)
    s.control.kp_translation = s.control.kp_rotation = std::atof(argv[4]);
  if (argc > 5)
    s.control.ki_translation = s.control.ki_rotation = std::atof(argv[5]);
  const std::string csv = argc > 6 ? argv[6] : "";
  s.control.arm_delay = s.arm.delay_s + 1.0 / (2.0 * M_PI * s.arm.bandwidth_hz);
  std::printf(
      "loop model: %.0f Hz frames, latency %.0f ms + 0-%.0f ms, arm delay %.0f ms + lag %.1f Hz, kp %.1f ki %.1f, "
      "compensation %s; estimate noise %.2f mm %.4f deg per axis\n",
      s.loop.rate_hz, s.loop.latency_s * 1e3, s.loop.latency_jitter_s * 1e3, s.arm.delay_s * 1e3, s.arm.bandwidth_hz,
      s.control.kp_translation, s.control.ki_translation, s.control.latency_compensation ? "on" : "off",
      s.loop.noise_translation_m * 1e3, s.loop.noise_rotation_rad * 180.0 / M_PI);
  curve(s, csv);
  scenario(s, "default disturbance (roverArmDisturbance)", roverArmDisturbance(), 5);
  // The same rover on Earth in a 5-10 m/s wind (air 60x denser): sway 1 mm
  // and 0.2 mrad, structural vibration 0.1 mm and 0.05 mrad RMS per axis.
  RigMotionParams windy = roverArmDisturbance();
  windy.jitter_translation_m = 0.001;
  windy.jitter_rotation_rad = 0.0002;
  windy.vibration_translation_rms_m = 0.0001;
  windy.vibration_rotation_rms_rad = 0.00005;
  scenario(s, "Earth analogue in wind (sway 1 mm, vibration 0.1 mm RMS)", windy, 5);
  // The example of a vibration-heavy arm: 1-8 Hz, 3 mm and 0.3 deg RMS per axis.
  RigMotionParams heavy = roverArmDisturbance();
  heavy.vibration_translation_rms_m = 0.003;
  heavy.vibration_rotation_rms_rad = 0.3 * M_PI / 180.0;
  heavy.vibration_min_hz = 1.0;
  heavy.vibration_max_hz = 8.0;
  scenario(s, "vibration-heavy (1-8 Hz, 3 mm, 0.3 deg RMS per axis)", heavy, 3);
  return 0;
}
