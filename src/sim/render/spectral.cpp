#include "sim/render/spectral.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

enum Band
{
  kB = 0,
  kG = 1,
  kR = 2,
  kNirBand = 3,
};

// Relative response of the B, G, R pixels of a colour (Bayer, IR-cut)
// sensor to a narrow-band source, the channel it is meant for at 1: typical
// of the colour filter arrays of machine-vision CMOS sensors (blue and red
// filters leak a little into green, green into blue more than into red).
constexpr float kBlue450[3] = {1.0f, 0.12f, 0.02f};
constexpr float kGreen520[3] = {0.22f, 1.0f, 0.08f};
constexpr float kRed638[3] = {0.03f, 0.10f, 1.0f};

void narrowBand(const float response[3], Band band, CameraSpectrum* s)
{
  for (int c = 0; c < 3; ++c)
    s->dot_mix[c][band] = response[c];
}

}  // namespace

CameraSpectrum cameraSpectrum(ProjectorColor color, SensorOutput output)
{
  CameraSpectrum s;
  s.mono = isMonochrome(output);
  if (s.mono)
  {
    // One channel: the dot's own band at response 1 (white: the sunlit mix).
    s.primary = 1;
    for (int c = 0; c < 3; ++c)
    {
      switch (color)
      {
        case ProjectorColor::kGreen:
          s.dot_mix[c][kG] = 1.0f;
          break;
        case ProjectorColor::kRed:
          s.dot_mix[c][kR] = 1.0f;
          break;
        case ProjectorColor::kBlue:
          s.dot_mix[c][kB] = 1.0f;
          break;
        case ProjectorColor::kNir:
          s.dot_mix[c][kNirBand] = 1.0f;
          break;
        case ProjectorColor::kWhite:
          for (int k = 0; k < 3; ++k)
            s.dot_mix[c][k] = s.mono_weights[k];
          break;
      }
    }
    return s;
  }
  switch (color)
  {
    case ProjectorColor::kGreen:
      narrowBand(kGreen520, kG, &s);
      s.primary = 1;
      break;
    case ProjectorColor::kRed:
      narrowBand(kRed638, kR, &s);
      s.primary = 2;
      break;
    case ProjectorColor::kBlue:
      narrowBand(kBlue450, kB, &s);
      s.primary = 0;
      break;
    case ProjectorColor::kNir:
      break;  // refused by validate(): the IR-cut filter
    case ProjectorColor::kWhite:
      // Each channel sees its own band, like sunlight.
      for (int c = 0; c < 3; ++c)
        s.dot_mix[c][c] = 1.0f;
      s.primary = 1;
      break;
  }
  return s;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
