// Rendering of the rock pixels: robust ray casts on a coarse pixel lattice,
// then per sample either Newton refinement from the interpolated depth (the
// fast path, in float) or, where that is not safe, a robust cast of its own.
#include "sim/render/rock_render.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>

#include "structured_light_stabilizer/common/math.h"
#include "sim/render/target_board.h"

namespace structured_light_stabilizer
{
namespace sim
{

namespace
{

// Coarse lattice of robust casts, every kCoarseStep samples.
constexpr int kCoarseStep = 8;
// A lattice cell whose corner ray parameters spread more than this (per unit
// of the ray direction's z, i.e. in metres of depth) straddles a silhouette
// or an edge: its pixels get a robust cast each.
constexpr double kCoarseSpreadM = 0.05;

// Per-sample state of a row on the fast path.
enum : uint8_t
{
  kConverged = 0,
  kMoreNewton = 1,
  kRobust = 2,
};

// Per-row working arrays, one set per worker thread.
struct RowScratch
{
  std::vector<float> s, dx, dy, dz, vig;
  std::vector<uint8_t> state;
  explicit RowScratch(int n) : s(n), dx(n), dy(n), dz(n), vig(n), state(n) {}
};

// The bilinear height field in float, as the Newton steps read it. Built as a
// local in each pass: a local copy stays in registers, whereas members would
// be reloaded after every store to the row (they might alias).
struct FloatHeightField
{
  FloatHeightField(const RockSurface& rock, const Eigen::Vector3d& o)
    : ox(static_cast<float>(o.x())),
      oy(static_cast<float>(o.y())),
      oz(static_cast<float>(o.z())),
      ic(static_cast<float>(1.0 / rock.cell)),
      gx0(static_cast<float>(rock.x0)),
      gy0(static_cast<float>(rock.y0)),
      nxf(static_cast<float>(rock.nx)),
      nyf(static_cast<float>(rock.ny)),
      hs(rock.hs.data()),
      stride(rock.nx + 1)
  {
  }

  // One Newton step along the ray o + s (dx, dy, dz) on the bilinear patch
  // under it: false when the point is off the grid, the ray grazes, or it is
  // more than 5 cm from the surface (*step_out = 0 then).
  bool newton(float dx, float dy, float dz, float s, float* step_out) const
  {
    const float gxf = (ox + s * dx - gx0) * ic, gyf = (oy + s * dy - gy0) * ic;
    const bool inside = gxf >= 0.0f && gyf >= 0.0f && gxf < nxf && gyf < nyf;
    const int ci = inside ? static_cast<int>(gxf) : 0, cj = inside ? static_cast<int>(gyf) : 0;
    const float tx = gxf - ci, ty = gyf - cj;
    const float* r0 = hs + 4 * (cj * stride + ci) + 3;
    const float* r1 = r0 + 4 * stride;
    const float h00 = r0[0], h10 = r0[4], h01 = r1[0], h11 = r1[4];
    const float a = h00 + tx * (h10 - h00), b = h01 + tx * (h11 - h01);
    const float gap = a + ty * (b - a) - (oz + s * dz);
    const float slope = (((h10 - h00) * (1.0f - ty) + (h11 - h01) * ty) * dx + (b - a) * dy) * ic - dz;
    const bool good = inside && slope < -1e-6f && std::abs(gap) <= 0.05f;
    *step_out = good ? gap / slope : 0.0f;
    return good;
  }

  float ox, oy, oz, ic, gx0, gy0, nxf, nyf;
  const float* hs;  // sunlit B, G, R and height per vertex
  int stride;       // vertices per grid row
};

// The sunlit reflectance grid read at rock-frame points, in float.
struct SunlitGrid
{
  explicit SunlitGrid(const RockSurface& rock)
    : ic(static_cast<float>(1.0 / rock.cell)),
      gx0(static_cast<float>(rock.x0)),
      gy0(static_cast<float>(rock.y0)),
      hs(rock.hs.data()),
      stride(rock.nx + 1),
      nx(rock.nx),
      ny(rock.ny)
  {
  }

  // Bilinear B, G, R (and h) at (px, py) times scale, into out[0..3].
  void at(float px, float py, float scale, float* out) const
  {
    const float gxf = (px - gx0) * ic, gyf = (py - gy0) * ic;
    const int ci = std::min(std::max(static_cast<int>(gxf), 0), nx - 1);
    const int cj = std::min(std::max(static_cast<int>(gyf), 0), ny - 1);
    const float tx = gxf - ci, ty = gyf - cj;
    blend(4 * (cj * stride + ci), (1 - tx) * (1 - ty) * scale, tx * (1 - ty) * scale, (1 - tx) * ty * scale,
          tx * ty * scale, out);
  }

  // The four vertices of the cell whose first vertex is at float `offset`
  // of hs, weighted (w00, w10, w01, w11), into out[0..3]: one 4-lane
  // register per vertex (B, G, R, h).
  void blend(size_t offset, float w00, float w10, float w01, float w11, float* out) const
  {
    const float* p00 = hs + offset;
    const float* p01 = p00 + 4 * stride;
    const cv::v_float32x4 r = cv::v_load(p00) * cv::v_setall_f32(w00) + cv::v_load(p00 + 4) * cv::v_setall_f32(w10) +
                              cv::v_load(p01) * cv::v_setall_f32(w01) + cv::v_load(p01 + 4) * cv::v_setall_f32(w11);
    cv::v_store(out, r);
  }

  float ic, gx0, gy0;
  const float* hs;
  int stride, nx, ny;
};

class RockSampleRenderer
{
public:
  RockSampleRenderer(const RockSurface& rock, const RockSampling& sampling, const CameraModel& cam,
                     const FrameGeometry& g, double sun, bool vignetting)
    : rock_(rock),
      sampling_(sampling),
      cam_(cam),
      g_(g),
      sun_(sun),
      vignetting_(vignetting),
      sample_offset_(0.5 * (sampling.sub - 1)),
      ncx_((sampling.rw - 1 + kCoarseStep - 1) / kCoarseStep + 1),
      ncy_((sampling.rh - 1 + kCoarseStep - 1) / kCoarseStep + 1),
      lattice_(ncx_ >= 2 && ncy_ >= 2),
      coarse_(static_cast<size_t>(ncx_) * ncy_, detail::kNaN)
  {
  }

  // Fills `rows` (radiance) and, unless nullptr, `hits` (x, y, scale; x NaN
  // where not on the height field): sampling.rh rows of sampling.stride()
  // floats each.
  void render(float* rows, float* hits)
  {
    if (lattice_)
      castCoarseLattice();
    const size_t stride = sampling_.stride();
    cv::parallel_for_(cv::Range(0, sampling_.rh),
                      [&](const cv::Range& range)
                      {
                        RowScratch scratch(sampling_.rw);
                        for (int j = range.start; j < range.end; ++j)
                          renderRow(j, rows + stride * j, hits ? hits + stride * j : nullptr, &scratch);
                      });
  }

private:
  int coarsePos(int i, int n) const { return std::min(i * kCoarseStep, n - 1); }
  void normalized(int i, int j, double* x, double* y) const;
  void castCoarseLattice();
  void robustSample(int u, int v, float* out) const;
  void renderRow(int v, float* row, float* hits, RowScratch* scratch) const;
  void interpolateDepth(int v, RowScratch* scratch) const;
  void computeRays(int v, RowScratch* scratch) const;
  void refineDepth(RowScratch* scratch) const;
  void shadeRow(int v, float* row, float* hits, RowScratch* scratch) const;

  const RockSurface& rock_;
  const RockSampling& sampling_;
  const CameraModel& cam_;
  const FrameGeometry& g_;
  const double sun_;
  const bool vignetting_;
  const double sample_offset_;
  const int ncx_, ncy_;         // coarse lattice size
  const bool lattice_;          // false for frames too small for a lattice: every sample is robust
  std::vector<double> coarse_;  // ray parameter per lattice point, NaN on a miss or a wall
};

// Normalised image coordinates of rock sample (i, j).
void RockSampleRenderer::normalized(int i, int j, double* x, double* y) const
{
  if (!sampling_.ray_lut.empty())
  {
    const float* p = &sampling_.ray_lut[2 * (static_cast<size_t>(j) * sampling_.rw + i)];
    *x = p[0];
    *y = p[1];
  }
  else
  {
    *x = (sampling_.sub * i + sample_offset_ - cam_.cx) / cam_.fx;
    *y = (sampling_.sub * j + sample_offset_ - cam_.cy) / cam_.fy;
  }
}

void RockSampleRenderer::castCoarseLattice()
{
  cv::parallel_for_(cv::Range(0, ncy_),
                    [&](const cv::Range& range)
                    {
                      for (int j = range.start; j < range.end; ++j)
                      {
                        for (int i = 0; i < ncx_; ++i)
                        {
                          double x, y, s;
                          bool wall;
                          normalized(coarsePos(i, sampling_.rw), coarsePos(j, sampling_.rh), &x, &y);
                          const Eigen::Vector3d d = g_.R * Eigen::Vector3d(x, y, 1.0);
                          if (rock_.cast(g_.o, d, &s, &wall) && !wall)
                            coarse_[static_cast<size_t>(j) * ncx_ + i] = s;
                        }
                      }
                    });
}

// Robust path of one sample: its own ray cast, in double.
void RockSampleRenderer::robustSample(int u, int v, float* out) const
{
  double xn, yn;
  normalized(u, v, &xn, &yn);
  const Eigen::Vector3d& o = g_.o;
  const Eigen::Vector3d d = g_.R * Eigen::Vector3d(xn, yn, 1.0);
  double scale = sun_;
  if (vignetting_)
  {
    const double q = 1.0 + xn * xn + yn * yn;
    scale /= q * q;
  }
  double s;
  bool wall;
  if (rock_.cast(o, d, &s, &wall))
  {
    float rad[3];
    rock_.lookup3(rock_.sunlit, o.x() + s * d.x(), o.y() + s * d.y(), rad);
    if (wall)
      scale *= 0.5;  // side walls face away from the sun more often than not
    for (int c = 0; c < 3; ++c)
      out[c] = static_cast<float>(rad[c] * scale);
  }
  else
  {
    for (int c = 0; c < 3; ++c)
      out[c] = static_cast<float>(kBackgroundBgr[c] * (rock_.sky + 0.5) * scale);
  }
}

// Fast path: the depth interpolated in a lattice cell whose corners agree,
// refined by Newton on the bilinear height field, in float (1e-7 m is far
// below the 4 mm texture cell); everything else takes the robust path. Simple
// passes over the row with few, predictable branches, so that the samples'
// latency chains (load, divide) overlap.
void RockSampleRenderer::renderRow(int v, float* row, float* hits, RowScratch* scratch) const
{
  if (!lattice_)
  {
    for (int u = 0; u < sampling_.rw; ++u)
    {
      robustSample(u, v, row + 3 * u);
      if (hits)
        hits[3 * u] = detail::kNaN;
    }
    return;
  }
  interpolateDepth(v, scratch);
  computeRays(v, scratch);
  refineDepth(scratch);
  shadeRow(v, row, hits, scratch);
}

// Ray parameter of each sample of row v interpolated from the coarse lattice;
// cells whose corners disagree (or miss: NaN fails the test) go robust.
void RockSampleRenderer::interpolateDepth(int v, RowScratch* scratch) const
{
  const int Wr = sampling_.rw, Hr = sampling_.rh;
  const int j = std::min(v / kCoarseStep, ncy_ - 2);
  const int cv0 = coarsePos(j, Hr), cv1 = coarsePos(j + 1, Hr);
  const double fy = cv1 > cv0 ? static_cast<double>(v - cv0) / (cv1 - cv0) : 0.0;
  float* S = scratch->s.data();
  uint8_t* state = scratch->state.data();
  for (int i = 0; i + 1 < ncx_; ++i)
  {
    const int u0 = coarsePos(i, Wr), u1 = coarsePos(i + 1, Wr);
    const int uend = i + 2 == ncx_ ? u1 : u1 - 1;
    const double* c0 = &coarse_[static_cast<size_t>(j) * ncx_ + i];
    const double* c1 = c0 + ncx_;
    const double smin = std::min(std::min(c0[0], c0[1]), std::min(c1[0], c1[1]));
    const double smax = std::max(std::max(c0[0], c0[1]), std::max(c1[0], c1[1]));
    const bool smooth = smax - smin <= kCoarseSpreadM;
    const float sa = smooth ? static_cast<float>(c0[0] + fy * (c1[0] - c0[0])) : 1.0f;
    const float sd = smooth ? static_cast<float>(c0[1] + fy * (c1[1] - c0[1])) - sa : 0.0f;
    const float inv_len = u1 > u0 ? 1.0f / static_cast<float>(u1 - u0) : 0.0f;
    for (int u = u0; u <= uend; ++u)
    {
      S[u] = sa + static_cast<float>(u - u0) * inv_len * sd;
      state[u] = smooth ? kConverged : kRobust;
    }
  }
}

// Ray direction (rock frame) and radiance scale (sun, vignetting) of each
// sample of row v.
void RockSampleRenderer::computeRays(int v, RowScratch* scratch) const
{
  const Eigen::Matrix3d& R = g_.R;
  const float Rf[9] = {static_cast<float>(R(0, 0)), static_cast<float>(R(0, 1)), static_cast<float>(R(0, 2)),
                       static_cast<float>(R(1, 0)), static_cast<float>(R(1, 1)), static_cast<float>(R(1, 2)),
                       static_cast<float>(R(2, 0)), static_cast<float>(R(2, 1)), static_cast<float>(R(2, 2))};
  const float sunf = static_cast<float>(sun_);
  const float ifx = static_cast<float>(sampling_.sub / cam_.fx);
  const float fcx = static_cast<float>((cam_.cx - sample_offset_) / sampling_.sub);
  const bool vig = vignetting_, use_lut = !sampling_.ray_lut.empty();
  const int Wr = sampling_.rw;
  const float yn_row = static_cast<float>((sampling_.sub * v + sample_offset_ - cam_.cy) / cam_.fy);
  const float* lut_row = use_lut ? &sampling_.ray_lut[2 * static_cast<size_t>(v) * Wr] : nullptr;
  float* DX = scratch->dx.data();
  float* DY = scratch->dy.data();
  float* DZ = scratch->dz.data();
  float* VG = scratch->vig.data();
  for (int u = 0; u < Wr; ++u)
  {
    const float xn = use_lut ? lut_row[2 * u] : (static_cast<float>(u) - fcx) * ifx;
    const float yn = use_lut ? lut_row[2 * u + 1] : yn_row;
    DX[u] = Rf[0] * xn + Rf[1] * yn + Rf[2];
    DY[u] = Rf[3] * xn + Rf[4] * yn + Rf[5];
    DZ[u] = Rf[6] * xn + Rf[7] * yn + Rf[8];
    const float q = 1.0f + xn * xn + yn * yn;
    VG[u] = vig ? sunf / (q * q) : sunf;
  }
}

// Newton from the interpolated depth. One step is enough almost everywhere
// (the next would move the point by < 1e-4 m); the rest get up to three more,
// then the robust path.
void RockSampleRenderer::refineDepth(RowScratch* scratch) const
{
  const FloatHeightField field(rock_, g_.o);
  const int Wr = sampling_.rw;
  float* S = scratch->s.data();
  const float* DX = scratch->dx.data();
  const float* DY = scratch->dy.data();
  const float* DZ = scratch->dz.data();
  uint8_t* state = scratch->state.data();
  for (int u = 0; u < Wr; ++u)
  {
    float step;
    const bool good = field.newton(DX[u], DY[u], DZ[u], S[u], &step);
    S[u] -= step;
    const uint8_t next = good ? (std::abs(step) < 5e-4f ? kConverged : kMoreNewton) : kRobust;
    state[u] = std::max(state[u], next);
  }
  for (int u = 0; u < Wr; ++u)
  {
    if (state[u] != kMoreNewton)
      continue;
    state[u] = kRobust;  // unless it converges within three more steps
    for (int n = 0; n < 3; ++n)
    {
      float step;
      if (!field.newton(DX[u], DY[u], DZ[u], S[u], &step))
        break;
      S[u] -= step;
      if (std::abs(step) < 5e-4f)
      {
        state[u] = kConverged;
        break;
      }
    }
  }
}

// Radiance of each converged sample from the interleaved sunlit grid; the
// others (and points off the rock) take the robust path. With `hits`, each
// sample's point and scale (x NaN for the robust ones).
void RockSampleRenderer::shadeRow(int v, float* row, float* hits, RowScratch* scratch) const
{
  const FloatHeightField field(rock_, g_.o);
  const SunlitGrid grid(rock_);
  const float half_w = static_cast<float>(rock_.half_w), half_h = static_cast<float>(rock_.half_h);
  const int Wr = sampling_.rw;
  const float* S = scratch->s.data();
  const float* DX = scratch->dx.data();
  const float* DY = scratch->dy.data();
  const float* VG = scratch->vig.data();
  const uint8_t* state = scratch->state.data();
  for (int u = 0; u < Wr; ++u)
  {
    float* out = row + 3 * u;
    const float px = field.ox + S[u] * DX[u], py = field.oy + S[u] * DY[u];
    const bool fast = state[u] == kConverged && std::abs(px) <= half_w && std::abs(py) <= half_h;
    if (hits)
    {
      hits[3 * u] = fast ? px : detail::kNaN;
      hits[3 * u + 1] = py;
      hits[3 * u + 2] = VG[u];
    }
    if (!fast)
    {
      robustSample(u, v, out);
      continue;
    }
    // All four lanes (B, G, R, h) in one go; the fourth lands on the next
    // pixel's B, which is written after it (rows have one float of slack).
    grid.at(px, py, VG[u], out);
  }
}

// Bilinear upsampling weights of n pixels from `samples` samples, clamped at
// the borders.
void upsampleTable(int n, int samples, int sub, std::vector<int>* i0, std::vector<int>* i1, std::vector<float>* w)
{
  const double offset = 0.5 * (sub - 1);
  i0->resize(n);
  i1->resize(n);
  w->resize(n);
  for (int u = 0; u < n; ++u)
  {
    const double x = (u - offset) / sub;
    int a = static_cast<int>(std::floor(x));
    double f = x - a;
    if (a < 0)
    {
      a = 0;
      f = 0.0;
    }
    if (a >= samples - 1)
    {
      a = samples - 1;
      f = 0.0;
    }
    (*i0)[u] = a;
    (*i1)[u] = std::min(a + 1, samples - 1);
    (*w)[u] = static_cast<float>(f);
  }
}

}  // namespace

RockSampling::RockSampling(const CameraModel& cam, int subsample) : sub(subsample)
{
  rw = (cam.width + sub - 1) / sub;
  rh = (cam.height + sub - 1) / sub;
  const double offset = 0.5 * (sub - 1);
  if (cam.hasDistortion())
  {
    ray_lut.resize(2 * static_cast<size_t>(rw) * rh);
    for (int j = 0; j < rh; ++j)
      for (int i = 0; i < rw; ++i)
      {
        const Eigen::Vector2d n = cam.normalize(cv::Point2d(sub * i + offset, sub * j + offset));
        float* p = &ray_lut[2 * (static_cast<size_t>(j) * rw + i)];
        p[0] = static_cast<float>(n.x());
        p[1] = static_cast<float>(n.y());
      }
  }
  upsampleTable(cam.width, rw, sub, &up_i0, &up_i1, &up_wx);
  upsampleTable(cam.height, rh, sub, &up_j0, &up_j1, &up_wy);
}

// The two sample rows are blended first (a plain loop that vectorises), then
// along the row; sub = 2 has fixed weights 1/4, 3/4.
void RockSampling::upsampleRow(const float* __restrict samples, int v, int width, float* __restrict L,
                               float* __restrict T) const
{
  const size_t row_stride = stride();
  const int n3 = 3 * width, nr3 = 3 * rw;
  const float* A = samples + row_stride * up_j0[v];
  if (sub == 1)
  {
    std::memcpy(L, A, sizeof(float) * n3);
    return;
  }
  const float* B = samples + row_stride * up_j1[v];
  const float wy = up_wy[v];
  for (int k = 0; k < nr3; ++k)
    T[k] = A[k] + wy * (B[k] - A[k]);
  int u = 0;
  if (sub == 2)
  {
    // Pixel 0 sits left of sample 0 (clamped); pixels 2i+1, 2i+2 lie at
    // 1/4 and 3/4 between samples i and i+1; an even width ends on a clamp.
    for (int c = 0; c < 3; ++c)
      L[c] = T[c];
    const int pairs = (width - 1) / 2;
    for (int i = 0; i < pairs; ++i)
    {
      const float* t0 = T + 3 * i;
      float* l = L + 3 * (2 * i + 1);
      for (int c = 0; c < 3; ++c)
      {
        l[c] = 0.75f * t0[c] + 0.25f * t0[3 + c];
        l[3 + c] = 0.25f * t0[c] + 0.75f * t0[3 + c];
      }
    }
    u = 1 + 2 * pairs;
  }
  for (; u < width; ++u)
  {
    const int a = 3 * up_i0[u], b = 3 * up_i1[u];
    const float wx = up_wx[u];
    for (int c = 0; c < 3; ++c)
      L[3 * u + c] = T[a + c] + wx * (T[b + c] - T[a + c]);
  }
}

// Samples farther apart than this on the rock (m) straddle a step or a
// silhouette: the pixels between them keep the radiance blend.
constexpr float kMaxHitGapM = 0.01f;

void RockSampling::sharpenRow(const RockSurface& rock, const float* __restrict hits, int v, int width,
                              float* __restrict L, float* __restrict T) const
{
  const size_t row_stride = stride();
  const float* A = hits + row_stride * up_j0[v];
  const float* B = hits + row_stride * up_j1[v];
  const float wy = up_wy[v];
  // The two sample rows blended; NaN (off the height field) and far-apart
  // pairs give NaN.
  for (int i = 0; i < rw; ++i)
  {
    const float* a = A + 3 * i;
    const float* b = B + 3 * i;
    const bool near = std::abs(b[0] - a[0]) <= kMaxHitGapM && std::abs(b[1] - a[1]) <= kMaxHitGapM;
    float* t = T + 3 * i;
    t[0] = near ? a[0] + wy * (b[0] - a[0]) : detail::kNaN;
    t[1] = a[1] + wy * (b[1] - a[1]);
    t[2] = a[2] + wy * (b[2] - a[2]);
  }
  // Each pixel's point and scale (x NaN where the blend stays), then the
  // grid read four pixels at a time: their cells and weights in SIMD, the
  // four vertices of each as one register each.
  static thread_local std::vector<float> P;
  P.resize(3 * static_cast<size_t>(width) + 12);
  float* const PX = P.data();
  float* const PY = PX + width + 4;
  float* const PS = PY + width + 4;
  for (int u = 0; u < width; ++u)
  {
    const float* a = T + 3 * up_i0[u];
    const float* b = T + 3 * up_i1[u];
    const bool near = std::abs(b[0] - a[0]) <= kMaxHitGapM && std::abs(b[1] - a[1]) <= kMaxHitGapM;
    const float wx = up_wx[u];
    PX[u] = near ? a[0] + wx * (b[0] - a[0]) : detail::kNaN;  // NaN fails `near` too
    PY[u] = near ? a[1] + wx * (b[1] - a[1]) : 0.0f;
    PS[u] = near ? a[2] + wx * (b[2] - a[2]) : 0.0f;
  }
  const SunlitGrid grid(rock);
  const cv::v_float32x4 gx0 = cv::v_setall_f32(grid.gx0), gy0 = cv::v_setall_f32(grid.gy0);
  const cv::v_float32x4 ic = cv::v_setall_f32(grid.ic), one = cv::v_setall_f32(1.0f);
  const cv::v_float32x4 stride4 = cv::v_setall_f32(4.0f * grid.stride);
  const cv::v_int32x4 zero = cv::v_setzero_s32(), imax_x = cv::v_setall_s32(grid.nx - 1),
                      imax_y = cv::v_setall_s32(grid.ny - 1);
  int u = 0;
  for (; u + 4 <= width; u += 4)
  {
    const cv::v_float32x4 px = cv::v_load(PX + u), py = cv::v_load(PY + u), sc = cv::v_load(PS + u);
    const cv::v_float32x4 gxf = (px - gx0) * ic, gyf = (py - gy0) * ic;
    const cv::v_int32x4 ci = cv::v_min(cv::v_max(cv::v_trunc(gxf), zero), imax_x);
    const cv::v_int32x4 cj = cv::v_min(cv::v_max(cv::v_trunc(gyf), zero), imax_y);
    const cv::v_float32x4 tx = gxf - cv::v_cvt_f32(ci), ty = gyf - cv::v_cvt_f32(cj);
    // Grid offsets in floats (exact below 2^24: grids of up to 2048^2 cells).
    const cv::v_float32x4 off = cv::v_cvt_f32(cj) * stride4 + cv::v_cvt_f32(ci) * cv::v_setall_f32(4.0f);
    float w[4][4], o[4], x[4];
    cv::v_store(w[0], (one - tx) * (one - ty) * sc);
    cv::v_store(w[1], tx * (one - ty) * sc);
    cv::v_store(w[2], (one - tx) * ty * sc);
    cv::v_store(w[3], tx * ty * sc);
    cv::v_store(o, off);
    cv::v_store(x, px);
    for (int k = 0; k < 4; ++k)
    {
      if (std::isnan(x[k]))
        continue;
      float out[4];
      grid.blend(static_cast<size_t>(o[k]), w[0][k], w[1][k], w[2][k], w[3][k], out);
      float* l = L + 3 * (u + k);
      l[0] = out[0];
      l[1] = out[1];
      l[2] = out[2];
    }
  }
  for (; u < width; ++u)
  {
    if (std::isnan(PX[u]))
      continue;
    float out[4];
    grid.at(PX[u], PY[u], PS[u], out);
    for (int c = 0; c < 3; ++c)
      L[3 * u + c] = out[c];
  }
}

RockSamples renderRockSamples(const RockSurface& rock, const RockSampling& sampling, const SensorParams& sensor,
                              const FrameGeometry& g, double sun)
{
  static thread_local std::vector<float> buffer, hit_buffer;
  buffer.resize(sampling.stride() * sampling.rh);
  // Plain pointers: inside the parallel body, `buffer` would name the
  // worker thread's own (empty) instance.
  RockSamples out;
  float* const rows = buffer.data();
  out.radiance = rows;
  if (rock.board)
  {
    renderBoardSamples(rock, sampling, sensor, g, sun, rows);
    return out;
  }
  float* hits = nullptr;
  if (sampling.sub > 1)
  {
    hit_buffer.resize(buffer.size());
    hits = hit_buffer.data();
    out.hits = hits;
  }
  RockSampleRenderer(rock, sampling, sensor.camera, g, sun, sensor.natural_vignetting).render(rows, hits);
  return out;
}

}  // namespace sim
}  // namespace structured_light_stabilizer
