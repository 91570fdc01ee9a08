"""Small line plots drawn with OpenCV (matplotlib is not a dependency of the
package): axes with linear or logarithmic scales, ticks, a title, a legend,
several series per panel; a Figure is a white canvas of panels written as a
PNG. Used by nodes/stabilize_monitor.py (docs/stabilization.md)."""
import math

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
BLACK = (0, 0, 0)
GREY = (200, 200, 200)
# BGR colours of the series, in order.
COLOURS = [(40, 40, 220), (200, 110, 20), (30, 150, 30), (150, 40, 150), (0, 140, 220)]


def _nice_ticks(lo, hi, count=5):
    """About `count` round tick values spanning [lo, hi]."""
    if not hi > lo:
        return [lo]
    raw = (hi - lo) / max(1, count)
    magnitude = 10 ** math.floor(math.log10(raw))
    step = min((m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw), default=raw)
    first = math.ceil(lo / step) * step
    return [first + i * step for i in range(int(math.floor((hi - first) / step + 1e-9)) + 1)]


def _label(v):
    if v == 0:
        return "0"
    if abs(v) >= 1000 or abs(v) < 0.01:
        return "%.0e" % v
    return ("%.3f" % v).rstrip("0").rstrip(".")


class Axes:
    """One panel: pixel rectangle (x, y, w, h) inside the figure's canvas."""

    def __init__(self, canvas, rect, title, xlabel, ylabel, xlog=False, ylog=False):
        self.canvas, self.title, self.xlabel, self.ylabel = canvas, title, xlabel, ylabel
        x, y, w, h = rect
        # Room for the tick labels on the left and below.
        self.x0, self.y0, self.w, self.h = x + 70, y + 28, w - 90, h - 70
        self.xlog, self.ylog = xlog, ylog
        self.series = []  # (xs, ys, label, colour)
        self.vlines = []  # (x, label)
        self.hlines = []  # (y, label)

    def plot(self, xs, ys, label, colour=None):
        xs, ys = np.asarray(xs, float), np.asarray(ys, float)
        colour = colour if colour is not None else COLOURS[len(self.series) % len(COLOURS)]
        self.series.append((xs, ys, label, colour))

    def vline(self, x, label):
        self.vlines.append((x, label))

    def hline(self, y, label):
        self.hlines.append((y, label))

    def _limits(self, values, log):
        v = np.concatenate([np.asarray(a, float).ravel() for a in values]) if values else np.zeros(1)
        v = v[np.isfinite(v)]
        if log:
            v = v[v > 0]
        if v.size == 0:
            return (1.0, 10.0) if log else (-1.0, 1.0)
        lo, hi = float(v.min()), float(v.max())
        if log:
            return 10 ** math.floor(math.log10(lo)), 10 ** math.ceil(math.log10(hi) + 1e-12)
        if hi - lo < 1e-12:
            lo, hi = lo - 1.0, hi + 1.0
        pad = 0.05 * (hi - lo)
        return lo - pad, hi + pad

    def _to_px(self, v, lo, hi, log, start, size, flip):
        if log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v, lo, hi = np.log10(v), math.log10(lo), math.log10(hi)
        f = (np.asarray(v, float) - lo) / (hi - lo)
        return start + (1.0 - f) * size if flip else start + f * size

    def draw(self):
        c = self.canvas
        xl = self._limits([s[0] for s in self.series] + [[v[0] for v in self.vlines]], self.xlog)
        yl = self._limits([s[1] for s in self.series] + [[v[0] for v in self.hlines]], self.ylog)
        x0, y0, w, h = self.x0, self.y0, self.w, self.h
        cv2.rectangle(c, (x0, y0), (x0 + w, y0 + h), BLACK, 1)
        cv2.putText(c, self.title, (x0 + 10, y0 - 10), FONT, 0.5, BLACK, 1, cv2.LINE_AA)
        cv2.putText(c, self.xlabel, (x0 + w // 2 - 4 * len(self.xlabel), y0 + h + 38), FONT, 0.42, BLACK, 1, cv2.LINE_AA)
        cv2.putText(c, self.ylabel, (x0 - 66, y0 - 10), FONT, 0.38, BLACK, 1, cv2.LINE_AA)
        self._ticks(xl, yl)
        for x, label in self.vlines:
            px = int(self._to_px(x, xl[0], xl[1], self.xlog, x0, w, False))
            cv2.line(c, (px, y0), (px, y0 + h), (90, 90, 90), 1, cv2.LINE_AA)
            cv2.putText(c, label, (min(px + 4, x0 + w - 8 * len(label)), y0 + 14), FONT, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
        for y, label in self.hlines:
            py = int(self._to_px(y, yl[0], yl[1], self.ylog, y0, h, True))
            cv2.line(c, (x0, py), (x0 + w, py), (90, 90, 90), 1, cv2.LINE_AA)
            cv2.putText(c, label, (x0 + 4, py - 4), FONT, 0.4, (60, 60, 60), 1, cv2.LINE_AA)
        for i, (xs, ys, label, colour) in enumerate(self.series):
            ok = np.isfinite(xs) & np.isfinite(ys)
            if self.xlog:
                ok &= xs > 0
            if self.ylog:
                ok &= ys > 0
            px = self._to_px(xs[ok], xl[0], xl[1], self.xlog, x0, w, False)
            py = self._to_px(ys[ok], yl[0], yl[1], self.ylog, y0, h, True)
            pts = np.stack([px, py], axis=1).round().astype(np.int32).reshape(-1, 1, 2)
            if len(pts) > 1:
                cv2.polylines(c, [pts], False, colour, 1, cv2.LINE_AA)
            ly = y0 + 16 + 16 * i
            cv2.line(c, (x0 + w - 190, ly - 4), (x0 + w - 165, ly - 4), colour, 2)
            cv2.putText(c, label, (x0 + w - 160, ly), FONT, 0.4, BLACK, 1, cv2.LINE_AA)

    def _ticks(self, xl, yl):
        c, x0, y0, w, h = self.canvas, self.x0, self.y0, self.w, self.h
        xs = self._log_ticks(xl) if self.xlog else _nice_ticks(*xl)
        ys = self._log_ticks(yl) if self.ylog else _nice_ticks(*yl)
        for v in xs:
            px = int(self._to_px(v, xl[0], xl[1], self.xlog, x0, w, False))
            if x0 <= px <= x0 + w:
                cv2.line(c, (px, y0), (px, y0 + h), GREY, 1)
                cv2.putText(c, _label(v), (px - 12, y0 + h + 16), FONT, 0.38, BLACK, 1, cv2.LINE_AA)
        for v in ys:
            py = int(self._to_px(v, yl[0], yl[1], self.ylog, y0, h, True))
            if y0 <= py <= y0 + h:
                cv2.line(c, (x0, py), (x0 + w, py), GREY, 1)
                cv2.putText(c, _label(v), (x0 - 62, py + 4), FONT, 0.38, BLACK, 1, cv2.LINE_AA)
        cv2.rectangle(c, (x0, y0), (x0 + w, y0 + h), BLACK, 1)

    @staticmethod
    def _log_ticks(limits):
        lo, hi = int(round(math.log10(limits[0]))), int(round(math.log10(limits[1])))
        return [10.0 ** e for e in range(lo, hi + 1)]


class Figure:
    """A white canvas split into a grid of panels (Axes), written as a PNG."""

    def __init__(self, width, height, title):
        self.canvas = np.full((height, width, 3), 255, np.uint8)
        self.axes = []
        cv2.putText(self.canvas, title, (20, 26), FONT, 0.6, BLACK, 1, cv2.LINE_AA)

    def add(self, rect, title, xlabel, ylabel, xlog=False, ylog=False):
        ax = Axes(self.canvas, (rect[0], rect[1] + 30, rect[2], rect[3]), title, xlabel, ylabel, xlog, ylog)
        self.axes.append(ax)
        return ax

    def save(self, path):
        for ax in self.axes:
            ax.draw()
        if not cv2.imwrite(path, self.canvas):
            raise IOError("cannot write %s" % path)


def rejection_curve(csv_path, png_path, title="rejection curve of the loop model (benchmark_stabilization)"):
    """Draws the CSV of benchmark_stabilization (frequency_hz,
    translation_ratio, rotation_ratio) as |S(f)| on log-log axes."""
    data = np.loadtxt(csv_path, delimiter=",", skiprows=1, ndmin=2)
    fig = Figure(900, 560, title)
    ax = fig.add((0, 0, 900, 520), "residual / disturbance RMS for a sine", "frequency (Hz)", "|S|", xlog=True, ylog=True)
    ax.plot(data[:, 0], data[:, 1], "translation")
    ax.plot(data[:, 0], data[:, 2], "rotation")
    ax.hline(1.0 / math.sqrt(2.0), "0.71 (bandwidth)")
    ax.hline(1.0, "1: no rejection")
    fig.save(png_path)


if __name__ == "__main__":
    import sys
    if len(sys.argv) != 3:
        sys.exit("usage: python3 -m structured_light_stabilizer.plot CURVE.csv OUT.png")
    rejection_curve(sys.argv[1], sys.argv[2])
