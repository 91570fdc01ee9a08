"""Packs the renders of one scene (render.py's EXRs and truth.json) into the
committed validation set: 16-bit PNGs of the noise-free linear passes and a
truth.yaml with every beam's light centroid, measured on the projector-only
pass.

    OPENCV_IO_ENABLE_OPENEXR=1 /usr/bin/python3 tools/validation/pack.py \
        --spec tools/validation/scenes.yaml --scene grey_a --renders /tmp/vs \
        --out test/data/validation [--check /tmp/vs2]

--check DIR: the same scene's projector passes rendered with other sampling
seeds (render.py --seed-offset 1 --passes proj): prints how far the light
centroids move between the two, the truth's Monte Carlo precision.

Stored per frame, the scene's region of interest (README.md):
 - the ambient passes as the colour sensor's RGGB mosaic (each pixel its own
   channel of the render, R at even column and row of the full frame), the
   four sites deinterleaved into quadrants [R, G(odd x); G(odd y), B] so
   that PNG's predictors see smooth planes: f<k>_sun.png and f<k>_sky.png on
   projector frames, f<k>_day.png (sun + the day's sky) on projector-off
   frames, f<k>_sun.png on board views;
 - f<k>_proj.png: the projector's light on the rock's green albedo, one
   channel, every pixel (projector frames).
A PNG count times the frame's `scale` of that pass is Blender's linear
radiance; the steps are 1/4 DN (the projector 1/8 DN) at the exposures the
lighting cases use, well below the camera's noise (README.md).
"""
import argparse
import json
import math
import os
import sys

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import geometry as G  # noqa: E402

STEP_DN = {"sun": 1 / 4.0, "sky": 1 / 4.0, "day": 1 / 4.0, "proj": 1 / 8.0}
# The stored region: the rendered one cut to the dots' bounding box at the
# first projector frame plus this margin (px; even offsets and sizes).
MARGIN_PX = 12


def read_pass(d, k, name):
    path = os.path.join(d, "f%d_%s_0001.exr" % (k, name))
    im = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if im is None:
        raise SystemExit("pack: cannot read %s" % path)
    return im[..., :3].astype(np.float64)  # B, G, R


def mosaic(bgr):
    """RGGB mosaic of a B, G, R image whose (0, 0) is an R site, as the
    deinterleaved quadrants [R, G(odd x, even y); G(even x, odd y), B]."""
    r = bgr[0::2, 0::2, 2]
    g1 = bgr[0::2, 1::2, 1]
    g2 = bgr[1::2, 0::2, 1]
    b = bgr[1::2, 1::2, 0]
    return np.block([[r, g1], [g2, b]])


def crop_box(fr, beams):
    """The stored region inside the rendered one (render ROI coordinates):
    the visible dots' light at the first projector frame plus MARGIN_PX."""
    x0, y0, w, h = fr["roi"]
    pts = np.array([b["light_centroid"] for b in beams if "light_centroid" in b]) - [x0, y0]
    a = np.floor(pts.min(0) - MARGIN_PX).astype(int) // 2 * 2
    b = (np.ceil(pts.max(0) + MARGIN_PX).astype(int) + 1) // 2 * 2
    a = np.maximum(a, 0)
    b = np.minimum(b, [w, h])
    return int(a[0]), int(a[1]), int(b[0] - a[0]), int(b[1] - a[1])


def light_centroid(proj, px, radius, iterations=4):
    """Intensity-weighted centroid of the projector's light in a disc of
    `radius` px, recentred on itself; pixel centres at integers (ROI
    coordinates). Returns (x, y, sum, peak, sigma_px, touches_edge)."""
    h, w = proj.shape
    c = np.array(px, float)
    for _ in range(iterations):
        x0, x1 = int(math.floor(c[0] - radius)), int(math.ceil(c[0] + radius)) + 1
        y0, y1 = int(math.floor(c[1] - radius)), int(math.ceil(c[1] + radius)) + 1
        edge = x0 < 0 or y0 < 0 or x1 > w or y1 > h
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
        if x1 <= x0 or y1 <= y0:
            return None
        ys, xs = np.mgrid[y0:y1, x0:x1]
        win = proj[y0:y1, x0:x1]
        inside = (xs - c[0]) ** 2 + (ys - c[1]) ** 2 <= radius * radius
        wgt = np.where(inside, win, 0.0)
        s = wgt.sum()
        if s <= 0:
            return None
        c = np.array([(wgt * xs).sum() / s, (wgt * ys).sum() / s])
    var = ((wgt * ((xs - c[0]) ** 2 + (ys - c[1]) ** 2)).sum() / s) / 2.0
    return c[0], c[1], float(s), float(win[inside].max()), math.sqrt(var), edge


def under_dot(img, proj, c, peak, radius):
    """Mean of `img` where the dot's light is at least half its peak."""
    h, w = proj.shape
    x0, x1 = max(int(c[0] - radius), 0), min(int(c[0] + radius) + 2, w)
    y0, y1 = max(int(c[1] - radius), 0), min(int(c[1] + radius) + 2, h)
    m = proj[y0:y1, x0:x1] >= 0.5 * peak
    return float(img[y0:y1, x0:x1][m].mean()) if m.any() else float("nan")


def write_png(path, img, scale):
    q = np.round(img / scale)
    if q.max() > 65535:
        raise SystemExit("pack: %s: %.0f counts do not fit 16 bits" % (path, q.max()))
    cv2.imwrite(path, np.clip(q, 0, 65535).astype(np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return os.path.getsize(path)


def plain(x):
    """Lists, dicts and Python floats (8 significant digits) for YAML."""
    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [plain(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float("%.8g" % x)
    return x


def lighting(spec_light, sun, sky, beams):
    """DN (8-bit scale) per linear unit of each pass for the lighting cases,
    from a projector frame of the scene (README.md, "Lighting"):
    day: the sun plus the sky at `sky_fraction` of the sun on sunlit rock,
    exposed so that the sunlit rock's 99th percentile (green) is
    `rock_dn`; the projector so that the median over the sunlit visible dots
    of dot peak / rock under it is `dot_to_rock`. dusk: the sky alone, the
    dots' median peak at `dot_dn` and `dot_to_rock` x the rock under them.
    night: the dusk projector, the sky at 1/500 of dusk."""
    g_sun, g_sky = sun[..., 1], sky[..., 1]
    lit = g_sun > 0.25 * np.percentile(g_sun, 99)
    r = spec_light["day"]["sky_fraction"] * np.median(g_sun[lit]) / np.median(g_sky[lit])
    k_day = spec_light["day"]["rock_dn"] / np.percentile(g_sun + r * g_sky, 99)
    dots = [b for b in beams if b.get("visible") and "light_peak" in b and not b["window_cut"]]
    sunlit = [b for b in dots if b["sun_under_dot"] > 0.25 * np.percentile(g_sun, 99)]
    q = np.median([b["light_peak"] / (b["sun_under_dot"] + r * b["sky_under_dot"]) for b in sunlit])
    k_proj_day = spec_light["day"]["dot_to_rock"] * k_day / q
    k_proj_dusk = spec_light["dusk"]["dot_dn"] / np.median([b["light_peak"] for b in dots])
    q = np.median([b["light_peak"] / b["sky_under_dot"] for b in dots])
    k_sky_dusk = k_proj_dusk * q / spec_light["dusk"]["dot_to_rock"]
    return {"day": {"sun": k_day, "sky": r * k_day, "proj": k_proj_day},
            "dusk": {"sun": 0.0, "sky": k_sky_dusk, "proj": k_proj_dusk},
            "night": {"sun": 0.0, "sky": k_sky_dusk / 500.0, "proj": k_proj_dusk}}


def board_lighting(spec_light, sun, proj_peaks):
    """The board views' exposure: white squares (the sun pass's 99th
    percentile, green) at white_dn; the projector so that the dots' median
    peak is dot_to_white x that (most dots lie on white)."""
    white = np.percentile(sun[..., 1], 99)
    k = spec_light["white_dn"] / white
    kp = spec_light["dot_to_white"] * spec_light["white_dn"] / np.median(proj_peaks)
    return {"board": {"sun": k, "sky": 0.0, "proj": kp}}


def beam_entries(fr, proj, sun, sky, radius, other):
    x0, y0 = fr["roi"][:2]
    beams = []
    for b, bt in enumerate(fr["beams"]):
        out = {"beam": b, "hit": bt["hit"]}
        if bt["hit"]:
            out["visible"] = bt["visible"]
            out["point_camera"] = bt["camera"]
            out["pixel"] = bt["pixel"]
            lc = light_centroid(proj, (bt["pixel"][0] - x0, bt["pixel"][1] - y0), radius)
            if lc is not None:
                cx, cy, s, peak, sig, edge = lc
                out["light_centroid"] = [cx + x0, cy + y0]
                out["light_sum"] = s
                out["light_peak"] = peak
                out["light_sigma_px"] = sig
                out["window_cut"] = bool(edge)
                out["sun_under_dot"] = under_dot(sun[..., 1], proj, (cx, cy), peak, radius)
                out["sky_under_dot"] = under_dot(sky[..., 1], proj, (cx, cy), peak, radius) if sky is not None else 0.0
                if other is not None:
                    lo = light_centroid(other, (bt["pixel"][0] - x0, bt["pixel"][1] - y0), radius)
                    out["check_shift_px"] = math.hypot(lo[0] - cx, lo[1] - cy) if lo else float("nan")
        beams.append(out)
    return beams


def stored_centroid_shift(path, roi, beams, radius):
    """How far the light centroids move when read from the stored PNG (its
    quantisation and cut) instead of the render, per visible beam (px)."""
    q = cv2.imread(path, cv2.IMREAD_UNCHANGED).astype(np.float64)
    out = []
    for b in beams:
        if b.get("visible") and "light_centroid" in b:
            c = light_centroid(q, (b["light_centroid"][0] - roi[0], b["light_centroid"][1] - roi[1]), radius)
            if c is not None and not c[5]:
                out.append(math.hypot(c[0] + roi[0] - b["light_centroid"][0], c[1] + roi[1] - b["light_centroid"][1]))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spec", required=True)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--renders", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--check", default=None)
    a = ap.parse_args()
    with open(a.spec) as f:
        spec = yaml.safe_load(f)
    sd = next(s for s in spec["scenes"] if s["name"] == a.scene)
    cam = G.Camera(spec["camera"])
    src = os.path.join(a.renders, a.scene)
    truth_in = {}
    for name in sorted(os.listdir(src)):
        if name.startswith("truth") and name.endswith(".json"):
            with open(os.path.join(src, name)) as f:
                for fr in json.load(f)["frames"]:
                    truth_in[fr["index"]] = fr
    out_dir = os.path.join(a.out, a.scene)
    os.makedirs(out_dir, exist_ok=True)
    radius = 6.5 * float(sd["beam_sigma_rad"]) * cam.fx + 1.0
    board = sd["kind"] == "board"
    check = os.path.join(a.check, a.scene) if a.check else None
    # Pass 1: the truth of every projector frame, the lighting from the first.
    beams_of, light = {}, None
    for k in sorted(truth_in):
        fr = truth_in[k]
        if not fr["projector"]:
            continue
        sun = read_pass(src, k, "sun")
        sky = None if board else read_pass(src, k, "sky")
        proj = read_pass(src, k, "proj")[..., 1]  # green: the rock's albedo at the projector's wavelength
        other = read_pass(check, k, "proj")[..., 1] if check else None
        beams_of[k] = beam_entries(fr, proj, sun, sky, radius, other)
        if light is None:
            if board:
                peaks = [b["light_peak"] for b in beams_of[k] if "light_peak" in b]
                light = board_lighting(spec["board_lighting"], sun, peaks)
            else:
                light = lighting(spec["lighting"], sun, sky, beams_of[k])
    first = min(beams_of)
    x0, y0, w, h = truth_in[first]["roi"]
    bx, by, bw, bh = (0, 0, w, h) if board else crop_box(truth_in[first], beams_of[first])
    roi = [x0 + bx, y0 + by, bw, bh]

    def cut(img):
        return img[by:by + bh, bx:bx + bw]

    if board:
        use = {"sun": light["board"]["sun"], "proj": light["board"]["proj"]}
    else:
        use = {"sun": light["day"]["sun"], "sky": max(light["day"]["sky"], light["dusk"]["sky"]),
               "day": light["day"]["sun"], "proj": max(light["day"]["proj"], light["dusk"]["proj"])}
    # Pass 2: the images.
    frames_out, total, quant_shift = [], 0, []
    for k in sorted(truth_in):
        fr = truth_in[k]
        entry = {"index": k, "t": fr["t"], "projector": fr["projector"]}
        T = np.array(fr["T_world_camera"])
        entry["T_camera_world"] = np.linalg.inv(T).tolist()
        if "T_world_board" in fr:
            entry["T_camera_board"] = (np.linalg.inv(T) @ np.array(fr["T_world_board"])).tolist()
        if fr["roi"] != truth_in[first]["roi"]:
            raise SystemExit("pack: frame %d was rendered with another region" % k)
        sun = cut(read_pass(src, k, "sun"))
        if board:
            planes = {"sun": mosaic(sun)}
        elif fr["projector"]:
            planes = {"sun": mosaic(sun), "sky": mosaic(cut(read_pass(src, k, "sky")))}
        else:
            r = light["day"]["sky"] / light["day"]["sun"]
            planes = {"day": mosaic(sun + r * cut(read_pass(src, k, "sky")))}
        if fr["projector"]:
            planes["proj"] = cut(read_pass(src, k, "proj")[..., 1])
            entry["beams"] = beams_of[k]
        scales = {}
        for name, img in planes.items():
            scales[name] = STEP_DN[name] / use[name]
            total += write_png(os.path.join(out_dir, "f%d_%s.png" % (k, name)), img, scales[name])
        if fr["projector"]:
            quant_shift.extend(stored_centroid_shift(os.path.join(out_dir, "f%d_proj.png" % k), roi, beams_of[k],
                                                     radius))
        entry["scale"] = scales
        frames_out.append(entry)
    shifts = [b.pop("check_shift_px") for fr in frames_out for b in fr.get("beams", []) if "check_shift_px" in b]
    doc = {"scene": a.scene, "kind": sd["kind"], "camera": {"width": cam.width, "height": cam.height,
           "K": cam.K().tolist()}, "roi": roi, "samples": sd.get("samples"), "centroid_window_px": radius,
           "beam_sigma_rad": float(sd["beam_sigma_rad"]), "lighting": light, "frames": frames_out}
    if board:
        doc["board"] = {"inner_corners": sd["board"], "square_m": sd["square_m"], "margin_m": sd["margin_m"]}
    with open(os.path.join(out_dir, "truth.yaml"), "w") as f:
        f.write("# Generated by tools/validation/pack.py from the renders of tools/validation/render.py\n"
                "# (scenes.yaml); units and frames: test/data/validation/README.md.\n")
        yaml.safe_dump(plain(doc), f, default_flow_style=None, sort_keys=False, width=120)
    print("pack: %s: %d frames, %.0f kB of PNG" % (a.scene, len(frames_out), total / 1024.0))
    if quant_shift:
        print("pack: light centroids of the stored (quantised, cut) projector pass against the render's: "
              "RMS %.5f px, max %.5f px" % (math.sqrt(np.mean(np.square(quant_shift))), max(quant_shift)))
    if shifts:
        print("pack: light centroids of the two renders: RMS %.4f px, max %.4f px (%d beams)"
              % (math.sqrt(np.nanmean(np.square(shifts))), np.nanmax(shifts), len(shifts)))


main()
