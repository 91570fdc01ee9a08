"""Geometry of the validation scenes, plain numpy (no Blender): the rig's
motion, the rock's height field and albedo, the chessboard print, the
projector's transmission mask. render.py builds the Blender scene from these
and pack.py reads the same definitions; nothing here comes from the
package's simulator.

Frames: the scene ("world") frame is the rock's: x right, y down, z away
from the camera at the reference pose (the camera optical frame at t = 0
before its tilt). The rig frame is the camera optical frame (REP-103: x
right, y down, z forward); Blender's camera looks along its local -z with y
up, so its local axes are the optical frame's rotated by pi about x.
Units: metres, radians, seconds.
"""
import math

import numpy as np
import yaml

# ---------------------------------------------------------------------------
# Small rotation helpers.


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def exp_so3(w):
    """Rotation matrix of a rotation vector (Rodrigues)."""
    w = np.asarray(w, float)
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def iso(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


# Optical frame -> Blender camera local frame (a rotation by pi about x).
OPTICAL_TO_BLENDER_CAMERA = iso(rot_x(math.pi), np.zeros(3))

# ---------------------------------------------------------------------------
# Camera and projector.


class Camera:
    """The study's camera: a pinhole with a thin lens (Blender's depth of
    field), principal point at the sensor's centre, no distortion."""

    def __init__(self, spec):
        self.width = int(spec["width"])
        self.height = int(spec["height"])
        self.pixel_m = float(spec["pixel_m"])
        self.focal_m = float(spec["focal_m"])
        self.aperture_m = float(spec["aperture_m"])
        self.focus_m = float(spec["focus_m"])
        self.fx = self.focal_m / self.pixel_m
        # OpenCV convention: pixel centres at integers, so the sensor's
        # centre (Blender's principal point) is at (W - 1) / 2.
        self.cx = (self.width - 1) / 2.0
        self.cy = (self.height - 1) / 2.0

    def K(self):
        return np.array([[self.fx, 0, self.cx], [0, self.fx, self.cy], [0, 0, 1.0]])

    def project(self, p_cam):
        p = np.asarray(p_cam, float)
        return np.array([self.fx * p[..., 0] / p[..., 2] + self.cx, self.fx * p[..., 1] / p[..., 2] + self.cy]).T


def load_projector(path):
    """Beams (origin, unit direction) in the camera optical frame, row-major."""
    with open(path) as f:
        doc = yaml.safe_load(f)
    beams = []
    for b in doc["beams"]:
        d = np.array(b["direction"], float)
        beams.append((np.array(b["origin"], float), d / np.linalg.norm(d)))
    return int(doc["rows"]), int(doc["cols"]), beams


class Motion:
    """The rig's pose: T_world_rig(t) = T0 * [exp(w t + a sin(2 pi f t)), v t + b sin(2 pi f t)],
    the increments in the reference rig frame (a drift plus a slow sway)."""

    def __init__(self, spec, distance_m):
        tilt = spec.get("tilt_rad", [0.0, 0.0])
        R0 = rot_x(tilt[0]) @ rot_y(tilt[1])
        self.T0 = iso(R0, np.array([0.0, 0.0, -distance_m]))
        self.v = np.array(spec.get("velocity_mps", [0, 0, 0]), float)
        self.w = np.array(spec.get("angular_radps", [0, 0, 0]), float)
        self.b = np.array(spec.get("sway_m", [0, 0, 0]), float)
        self.a = np.array(spec.get("sway_rad", [0, 0, 0]), float)
        self.f = float(spec.get("sway_hz", 0.0))

    def world_from_rig(self, t):
        s = math.sin(2 * math.pi * self.f * t)
        return self.T0 @ iso(exp_so3(self.w * t + self.a * s), self.v * t + self.b * s)


# ---------------------------------------------------------------------------
# The rock: a height field z = h(x, y) in the world frame (z away from the
# camera), relief at three scales, flat-shaded facets of grid/2-grid size.


def _smooth_noise(rng, n, corr_px):
    """Gaussian-correlated noise of unit RMS on an n x n grid (FFT filter)."""
    white = rng.standard_normal((n, n))
    fx = np.fft.fftfreq(n)
    k2 = fx[:, None] ** 2 + fx[None, :] ** 2
    filt = np.exp(-2 * (math.pi * corr_px) ** 2 * k2)
    out = np.real(np.fft.ifft2(np.fft.fft2(white) * filt))
    return out / out.std()


def rock_mesh(spec, seed):
    """Vertices (N x 3, world) and triangles (M x 3) of the rock.

    Large scale: a few boulders (Gaussian bumps, 5-12 cm high) and a steep
    ledge (occlusion, cast shadows); medium: correlated noise of 3 cm
    correlation (relief_3cm_m RMS) and of 8 mm (relief_8mm_m); fine: every
    vertex jittered by facet_jitter_m in depth and 0.6 mm in the plane on a
    3 mm grid, the cells' diagonals chosen at random: flat facets of 2-4 mm
    whose normals spread by about 7 deg RMS at the default 0.25 mm.
    """
    rng = np.random.default_rng(seed)
    size = float(spec.get("size_m", 1.2))
    step = float(spec.get("facet_m", 0.003))
    n = int(round(size / step)) + 1
    xs = (np.arange(n) - (n - 1) / 2) * step
    X, Y = np.meshgrid(xs, xs)  # [row = y][col = x]
    H = np.zeros_like(X)
    # Boulders: bumps towards the camera (negative z).
    for _ in range(int(spec.get("boulders", 6))):  # noqa: the draws below stay in this order (seeded scenes)
        cx, cy = rng.uniform(-0.35, 0.35, 2)
        r = rng.uniform(0.08, 0.22)
        amp = rng.uniform(0.05, 0.12)
        H -= amp * np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / (2 * r * r))
    # A ledge: a steep step of a few cm along a tilted line (occludes beams
    # from the camera and shadows them from the sun).
    ledge = spec.get("ledge", {"height_m": 0.05, "x_m": 0.12, "slope": 0.3, "width_m": 0.006})
    if ledge:
        d = X - ledge["x_m"] - ledge["slope"] * Y
        H += ledge["height_m"] * 0.5 * (1 + np.tanh(d / ledge["width_m"]))
    H += float(spec.get("relief_3cm_m", 0.004)) * _smooth_noise(rng, n, 0.03 / step / 2.0)
    H += float(spec.get("relief_8mm_m", 0.0008)) * _smooth_noise(rng, n, 0.008 / step / 2.0)
    # Fine facets: jitter each vertex.
    Xj = X + rng.uniform(-0.2, 0.2, X.shape) * step
    Yj = Y + rng.uniform(-0.2, 0.2, Y.shape) * step
    Hj = H + rng.normal(0.0, float(spec.get("facet_jitter_m", 0.00025)), H.shape)
    verts = np.stack([Xj.ravel(), Yj.ravel(), Hj.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    flip = rng.random(a.shape) < 0.5
    t1 = np.where(flip[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(flip[:, None], np.stack([a, d, c], 1), np.stack([b, d, c], 1))
    tris = np.concatenate([t1, t2])
    uvs = np.stack([(X.ravel() / size) + 0.5, 0.5 - (Y.ravel() / size)], axis=1)  # v up = -y
    return verts, tris, uvs


def rock_albedo(spec, seed, texel_m=0.001):
    """Albedo image (float RGB, linear: the sensor's channels under
    sunlight; its orientation on the rock does not matter): Voronoi grains of
    1-3 cm (each its own brightness and a little hue), a large-scale
    variation and a fine speckle."""
    import cv2

    rng = np.random.default_rng(seed + 7)
    size = float(spec.get("size_m", 1.2))
    n = int(round(size / texel_m))
    grain = float(spec.get("grain_m", 0.02))
    count = int(size * size / (grain * grain))
    seeds = np.zeros((n, n), np.uint8) + 255
    pts = rng.integers(0, n, (count, 2))
    seeds[pts[:, 1], pts[:, 0]] = 0
    _, labels = cv2.distanceTransformWithLabels(seeds, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    ncell = labels.max() + 1
    spread = float(spec["albedo_spread"])
    bright = np.exp(rng.normal(0.0, spread, ncell))
    hue = rng.normal(0.0, float(spec.get("hue_spread", 0.04)), (ncell, 2))
    big = np.exp(0.5 * spread * _smooth_noise(rng, n, 0.15 / texel_m / 2))
    fine = 1.0 + float(spec.get("speckle", 0.08)) * _smooth_noise(rng, n, 0.6)
    shade = bright[labels] * big * fine
    mean = np.array(spec["albedo_rgb"], float)
    img = np.empty((n, n, 3), np.float32)
    img[..., 0] = mean[0] * shade * (1 + hue[labels, 0])
    img[..., 1] = mean[1] * shade
    img[..., 2] = mean[2] * shade * (1 + hue[labels, 1])
    # Keep the brightness distribution's median at the stated mean.
    img *= 1.0 / np.median(shade)
    return np.clip(img, 0.01, 0.95)


# ---------------------------------------------------------------------------
# The chessboard print: cols x rows inner corners, OpenCV's convention (the
# package's): corner (i, j) at (i s, j s, 0) in the board frame, x along a
# row, y down, z into the board; the square at corner (-1, -1) black.


def board_print(spec, seed, texel_m=0.0005):
    rng = np.random.default_rng(seed)
    cols, rows = spec["board"]
    s = float(spec["square_m"])
    margin = float(spec["margin_m"])
    w = (cols + 1) * s + 2 * margin
    h = (rows + 1) * s + 2 * margin
    nx, ny = int(round(w / texel_m)), int(round(h / texel_m))
    # Texel (row j, column i) centre in board coordinates: row j at y, so
    # image row 0 is the board's smallest y (render.py maps v = (y - y0) / h).
    xc = (np.arange(nx) + 0.5) * texel_m - margin - s
    yc = (np.arange(ny) + 0.5) * texel_m - margin - s
    i = np.floor(xc / s).astype(int)
    j = np.floor(yc / s).astype(int)
    inside_x = (i >= -1) & (i <= cols - 1)
    inside_y = (j >= -1) & (j <= rows - 1)
    black = ((i[None, :] + j[:, None]) % 2 == 0) & inside_x[None, :] & inside_y[:, None]
    refl = np.where(black, float(spec["black"]), float(spec["white"])).astype(np.float32)
    img = np.repeat(refl[..., None], 3, axis=2)
    img[..., 0] *= 1.02  # paper: a touch warm
    img[..., 2] *= 0.96
    # Bright specks on the print (dust, paint flecks): 1-2 mm, some tinted.
    specks = []
    for _ in range(int(spec.get("specks", 6))):
        x = rng.uniform(-s, cols * s)
        y = rng.uniform(-s, rows * s)
        r = rng.uniform(0.0005, 0.001)
        tint = np.array([rng.uniform(0.6, 1.0), rng.uniform(0.8, 1.0), rng.uniform(0.4, 1.0)])
        cx, cy = (x + margin + s) / texel_m, (y + margin + s) / texel_m
        yy, xx = np.mgrid[0:ny, 0:nx]
        m = (xx + 0.5 - cx) ** 2 + (yy + 0.5 - cy) ** 2 <= (r / texel_m) ** 2
        img[m] = 0.9 * tint
        specks.append([x, y, r])
    return img, (w, h), (-margin - s, -margin - s), specks


def board_pose(view):
    """T_world_board for a board view: its inner-corner centre at `distance`
    on the reference camera's axis plus `offset`, rotated Rx Ry Rz."""
    R = rot_x(view["tilt_rad"][0]) @ rot_y(view["tilt_rad"][1]) @ rot_z(view.get("roll_rad", 0.0))
    return R


# ---------------------------------------------------------------------------
# The projector: a point source behind a transmission mask (a gobo). Beam k
# leaves in direction d_k with an angular profile: an elliptical Gaussian
# core (sigma_rad, axis ratio 1.15, orientation per beam) plus a halo of
# `halo` of the energy at twice the sigma, cut smoothly between 5 and 6 core
# sigmas so that every beam's light is its own. The profile is a function of
# the direction's tangent-plane coordinates about d_k, point-symmetric, so
# the light leaves centred on the beam's axis.


class Mask:
    def __init__(self, beams, sigma_rad, seed, distance_m=0.05, texels=2048, halo=0.05):
        o = beams[0][0]
        mean = np.mean([d for _, d in beams], axis=0)
        self.normal = mean / np.linalg.norm(mean)
        self.origin = o
        self.distance = distance_m
        helper = np.array([0.0, 1.0, 0.0])
        e1 = np.cross(helper, self.normal)
        self.e1 = e1 / np.linalg.norm(e1)
        self.e2 = np.cross(self.normal, self.e1)
        self.centre = o + distance_m * self.normal
        # Tangent coordinates on the mask plane of every beam, and the extent.
        q = []
        for ob, d in beams:
            s = distance_m / d.dot(self.normal)
            p = ob + s * d - self.centre
            q.append((p.dot(self.e1), p.dot(self.e2)))
        q = np.array(q)
        reach = 7 * sigma_rad * distance_m * 1.3
        self.half = float(np.max(np.abs(q)) + reach)
        self.texels = texels
        self.sigma_rad = sigma_rad
        rng = np.random.default_rng(seed + 99)
        T = np.zeros((texels, texels), np.float32)
        texel = 2 * self.half / texels
        for k, (ob, d) in enumerate(beams):
            phi = rng.uniform(0, math.pi)
            a_axis = math.cos(phi) * self.e1 + math.sin(phi) * self.e2
            a_axis = a_axis - a_axis.dot(d) * d
            a_axis /= np.linalg.norm(a_axis)
            b_axis = np.cross(d, a_axis)
            sa, sb = sigma_rad * math.sqrt(1.15), sigma_rad / math.sqrt(1.15)
            ci = int((q[k, 0] + self.half) / texel)
            cj = int((q[k, 1] + self.half) / texel)
            r = int(math.ceil(6.5 * sigma_rad * distance_m * 1.3 / texel)) + 2
            i0, i1 = max(ci - r, 0), min(ci + r + 1, texels)
            j0, j1 = max(cj - r, 0), min(cj + r + 1, texels)
            u = (np.arange(i0, i1) + 0.5) * texel - self.half
            v = (np.arange(j0, j1) + 0.5) * texel - self.half
            P = self.centre + u[None, :, None] * self.e1 + v[:, None, None] * self.e2  # [j][i]
            w = P - ob
            w /= np.linalg.norm(w, axis=2, keepdims=True)
            along = w @ d
            al = (w @ a_axis) / along
            be = (w @ b_axis) / along
            core = np.exp(-0.5 * ((al / sa) ** 2 + (be / sb) ** 2))
            rr = np.sqrt(al * al + be * be) / sigma_rad
            halo_t = halo / (1 - halo) / 4.0 * np.exp(-0.5 * (rr / 2.0) ** 2)  # 4 = area ratio of 2 x sigma
            taper = np.clip(6.0 - rr, 0.0, 1.0)
            taper = 0.5 - 0.5 * np.cos(math.pi * taper)
            T[j0:j1, i0:i1] += ((core + halo_t) * taper / (1.0 + halo / (1 - halo) / 4.0)).astype(np.float32)
        self.T = np.clip(T, 0.0, 1.0)

    def quad(self, extent=10.0):
        """The plane's corners in the rig frame (counter-clockwise) and their
        UVs: the plane reaches `extent` x its distance each way (it must stop
        every other direction in front of the projector), the texture only
        its centre (opaque beyond: the image node clips to black)."""
        c, h = self.centre, extent * self.distance
        f = h / self.half
        corners = [c - h * self.e1 - h * self.e2, c + h * self.e1 - h * self.e2, c + h * self.e1 + h * self.e2,
                   c - h * self.e1 + h * self.e2]
        uvs = [(0.5 - f / 2, 0.5 - f / 2), (0.5 + f / 2, 0.5 - f / 2), (0.5 + f / 2, 0.5 + f / 2),
               (0.5 - f / 2, 0.5 + f / 2)]
        return corners, uvs
