#!/usr/bin/env python3
"""Stabilisation monitor (stabilize.launch, docs/stabilization.md): records the
simulator's truth of the closed loop and, after ~duration seconds, prints two
lines exactly in this form, last

  stabilization: open-loop A mm B deg RMS, closed-loop C mm D deg RMS
  image: residual motion E px RMS at the dots, open loop F px

writes the plot (~plot, PNG), the figures (~stats_file, YAML; ~stats,
diagnostic_msgs/DiagnosticStatus, latched, its message the two lines) and
the time series (~series_file, CSV), then ends the launch (~exit) as Ctrl-C would: SIGINT to its roslaunch,
a clean exit with status 0.

A, B: RMS of the translation norm and of the rotation angle of
sim/ground_truth/disturbance, the disturbance's own offset from the locked pose
(what the camera does with the arm still: the open loop of the same seed, same
simulated times and lock). C, D: the same of sim/ground_truth/offset, the
camera's true offset from the locked pose with the arm commanded (with
controller:=false the arm stays still and C, D equal A, B). Both topics start
at the frame after the PoseDelta's lock; time counts from the first of them.

E, F (~image): the rock at the dots, in pixels of the published image. The
dots are the true beam hit points of the locked frame
(sim/ground_truth/points); E compares, for each frame the ImageStabilizer
warped (stabilizer/image_stabilized/pose: the pose it used), where the
truth puts each of them (sim/ground_truth/offset) with where the warp's
pose puts them: what remains of the rock's motion in the stabilised image.
F is their motion in the raw image of the open loop (the disturbance's
offset). nan when nothing was warped.

Also measured: the loop's estimate (pose_fused/frames with the IMU, else
pose_delta) against the truth at the frames' stamps, its mean (a systematic
error the loop settles on) and RMS (estimate_bias_*, estimate_error_*); the latency from exposure to command (stabilizer/error carries
the estimate's stamp and is published with the command), the commands and
holds, and the loop's sensitivity |S(f)|: the residual's spectrum over the
disturbance's (Welch averages), with the bandwidth where it first reaches
1/sqrt(2). Where the disturbance has little power the ratio is dominated by
the estimate's noise, so it is drawn only where the disturbance stands out.
A periodic disturbance (camera_driver/return_period > 0, e.g.
config/disturbance_probe.yaml) is measured exactly instead: the DFT of whole
periods after the first, at the disturbance's own frequencies; then also
|S| at 1 Hz and the peak.
"""
import math
import os
import threading

import numpy as np
import rospy
import yaml
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_srvs.srv import Trigger
from structured_light_stabilizer.evaluation import cloud_xyz, transform_matrix
from structured_light_stabilizer.msg import PoseDelta
from structured_light_stabilizer.roslaunch_end import end_launch

SEGMENT = 256  # samples per Welch segment (8.5 s at 30 Hz: 0.12 Hz resolution)
LOCK_WAIT_S = 15.0  # estimates flow but no truth from a lock this long: lock again
LOCKED = "reference locked on this frame"  # PoseDelta's status phrase


def offset_matrix(v):
    """4 x 4 of an offset (t, rotation vector) as the truth topics give it."""
    m = np.eye(4)
    w = np.asarray(v[3:], float)
    a = np.linalg.norm(w)
    if a > 0:
        k = w / a
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        m[:3, :3] = np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K
    m[:3, 3] = v[:3]
    return m


def project(m, points, f):
    """Pixel offsets from the axis (f x / z, f y / z) of the points moved by m."""
    q = points @ m[:3, :3].T + m[:3, 3]
    return np.stack([f[0] * q[:, 0] / q[:, 2], f[1] * q[:, 1] / q[:, 2]], axis=1)


def tone_sensitivity(open_rows, closed_rows, rate, period):
    """|S| at the tones of a periodic disturbance: the DFT over whole periods
    after the first (its transient), translation axes summed, at the bins
    where the disturbance has power. Frequencies and |S| (arrays)."""
    n = int(round(period * rate))
    o, c = np.asarray(open_rows, float), np.asarray(closed_rows, float)
    windows = (len(o) // n) - 1 if n > 0 else 0
    if windows < 1:
        return np.zeros(0), np.zeros(0)
    po = pc = 0.0
    for k in range(1, windows + 1):
        seg_o, seg_c = o[k * n:(k + 1) * n, :3], c[k * n:(k + 1) * n, :3]
        po = po + np.sum(np.abs(np.fft.rfft(seg_o - seg_o.mean(axis=0), axis=0)) ** 2, axis=1)
        pc = pc + np.sum(np.abs(np.fft.rfft(seg_c - seg_c.mean(axis=0), axis=0)) ** 2, axis=1)
    f = np.fft.rfftfreq(n, 1.0 / rate)
    tones = (po > 1e-3 * np.max(po[1:])) & (f > 0)
    return f[tones], np.sqrt(pc[tones] / po[tones])


def tone_figures(f, s):
    """|S| at 1 Hz (interpolated on log f), the bandwidth (first |S| >= 0.71) and the peak."""
    nan = float("nan")
    if len(f) < 2:
        return nan, nan, nan, nan
    s1 = float(np.interp(0.0, np.log(f), s)) if f[0] <= 1.0 <= f[-1] else nan
    bandwidth = nan
    for i in range(1, len(s)):
        if s[i] >= 1.0 / math.sqrt(2.0):
            u = (1.0 / math.sqrt(2.0) - s[i - 1]) / (s[i] - s[i - 1]) if s[i] != s[i - 1] else 0.0
            bandwidth = math.exp(math.log(f[i - 1]) + u * (math.log(f[i]) - math.log(f[i - 1])))
            break
    i = int(np.argmax(s))
    return s1, bandwidth, float(s[i]), float(f[i])


def vec6(msg):
    t, w = msg.twist.linear, msg.twist.angular
    return [t.x, t.y, t.z, w.x, w.y, w.z]


def rms(rows):
    """RMS of the translation norm (mm) and of the rotation angle (deg)."""
    a = np.asarray(rows, float).reshape(-1, 6)
    if len(a) == 0:
        return float("nan"), float("nan")
    return (1e3 * math.sqrt(np.mean(np.sum(a[:, :3] ** 2, axis=1))),
            math.degrees(math.sqrt(np.mean(np.sum(a[:, 3:] ** 2, axis=1)))))


def welch(x, rate):
    """One-sided power spectral density of each column of x (Hann, 50 % overlap)."""
    n = min(SEGMENT, len(x))
    window = np.hanning(n)
    scale = rate * np.sum(window ** 2)
    psd, count = 0.0, 0
    for start in range(0, len(x) - n + 1, max(1, n // 2)):
        seg = x[start:start + n] - np.mean(x[start:start + n], axis=0)
        psd = psd + np.abs(np.fft.rfft(seg * window[:, None], axis=0)) ** 2 / scale
        count += 1
    return np.fft.rfftfreq(n, 1.0 / rate), 2.0 * psd / max(1, count)


def sensitivity(open_rows, closed_rows, rate):
    """Frequencies, the disturbance's and the residual's PSD (translation
    axes summed, m^2/Hz), |S| where the disturbance stands out (else NaN), and
    the first frequency where |S| reaches 1/sqrt(2)."""
    o, c = np.asarray(open_rows, float), np.asarray(closed_rows, float)
    if len(o) < 64:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), float("nan")
    f, po = welch(o[:, :3], rate)
    _, pc = welch(c[:, :3], rate)
    po, pc = po.sum(axis=1), pc.sum(axis=1)
    # The disturbance stands out where it is well above the residual's floor
    # at high frequency (estimate noise, unrejected vibration).
    floor = np.median(pc[len(pc) // 2:]) if len(pc) > 4 else 0.0
    s = np.where(po > 10.0 * floor, np.sqrt(pc / np.maximum(po, 1e-30)), np.nan)
    s[0] = np.nan
    bandwidth = float("nan")
    for i in range(1, len(s)):
        if np.isfinite(s[i]) and s[i] >= 1.0 / math.sqrt(2.0):
            j = i - 1
            if np.isfinite(s[j]) and s[j] > 0:  # interpolate on log f
                u = (1.0 / math.sqrt(2.0) - s[j]) / (s[i] - s[j])
                bandwidth = math.exp(math.log(max(f[j], 1e-6)) + u * (math.log(f[i]) - math.log(max(f[j], 1e-6))))
            else:
                bandwidth = float(f[i])
            break
    return f, po, pc, s, bandwidth


class Monitor:
    def __init__(self):
        self.duration = float(rospy.get_param("~duration", 30.0))
        self.plot_path = rospy.get_param("~plot", "stabilization.png")
        self.stats_file = rospy.get_param("~stats_file", "")
        self.series_file = rospy.get_param("~series_file", "")
        self.exit = bool(rospy.get_param("~exit", True))
        self.controller = bool(rospy.get_param("~controller", True))
        self.imu = bool(rospy.get_param("~imu", False))
        self.image = bool(rospy.get_param("~image", False))
        # A periodic disturbance is measured at its own frequencies.
        self.period = float(rospy.get_param("camera_driver/return_period", 0.0))
        self.lock = threading.Lock()
        self.clouds = {}  # stamp -> true beam points (N, 3), recent frames
        self.dots = None  # the locked frame's true points (reference camera frame)
        self.lock_stamp = None
        self.focal = None  # (fx, fy) of the published image
        self.warps = {}  # stamp -> 4 x 4 pose the stabilised image was warped with
        self.estimated = {}  # stamp -> 4 x 4 of the loop's valid estimate at a frame's stamp
        self.truth = {}  # stamp -> [offset or None, disturbance or None]
        self.t0 = None
        self.latency = []  # s, exposure to command
        self.commands = 0
        self.zero_commands = 0
        self.estimates = 0
        self.valid = 0
        self.finished = False
        self.stats_pub = rospy.Publisher("~stats", DiagnosticStatus, queue_size=1, latch=True)
        rospy.Subscriber("sim/ground_truth/offset", TwistStamped, self.on_truth, 0, queue_size=50)
        rospy.Subscriber("sim/ground_truth/disturbance", TwistStamped, self.on_truth, 1, queue_size=50)
        rospy.Subscriber("stabilizer/cmd_twist", TwistStamped, self.on_command, queue_size=50)
        rospy.Subscriber("stabilizer/error", TwistStamped, self.on_error, queue_size=50)
        rospy.Subscriber("pose_delta", PoseDelta, self.on_pose, queue_size=50)
        # What the loop closes on, at the frames' stamps: with the IMU the fused estimate.
        rospy.Subscriber("pose_fused/frames" if self.imu else "pose_delta", PoseDelta, self.on_estimate, queue_size=50)
        if self.image:
            rospy.Subscriber("sim/ground_truth/points", PointCloud2, self.on_points, queue_size=20)
            rospy.Subscriber("camera/camera_info", CameraInfo, self.on_info, queue_size=2)
            rospy.Subscriber("stabilizer/image_stabilized/pose", PoseDelta, self.on_warp, queue_size=50)
        self.started = rospy.Time.now()
        self.relocked = False
        rospy.Timer(rospy.Duration(0.5), self.check_end)

    def on_truth(self, msg, which):
        with self.lock:
            stamp = msg.header.stamp.to_sec()
            self.truth.setdefault(stamp, [None, None])[which] = vec6(msg)
            if self.t0 is None:
                self.t0 = stamp
                # The lock's own pose_delta can go out before this monitor's
                # subscription connects: the truth offsets start at the lock.
                if self.lock_stamp is None:
                    self.lock_stamp = stamp
                rospy.loginfo("stabilize_monitor: truth from the locked pose flowing; %.0f s to go", self.duration)

    def on_command(self, msg):
        with self.lock:
            self.commands += 1
            self.zero_commands += int(not any(vec6(msg)))

    def on_error(self, msg):
        with self.lock:
            self.latency.append((rospy.Time.now() - msg.header.stamp).to_sec())

    def on_pose(self, msg):
        with self.lock:
            self.estimates += 1
            self.valid += int(msg.valid)
            if LOCKED in msg.status:
                self.lock_stamp = msg.header.stamp.to_sec()
                later = [k for k in sorted(self.clouds) if k >= self.lock_stamp]
                self.dots = self.clouds[later[0]] if later else None

    def on_points(self, msg):
        xyz = cloud_xyz(msg)
        stamp = msg.header.stamp.to_sec()
        with self.lock:
            self.clouds[stamp] = xyz[np.all(np.isfinite(xyz), axis=1)]
            for old in [k for k in self.clouds if k < stamp - 3.0]:
                del self.clouds[old]
            # The dots at the lock; when the monitor's subscription missed
            # that frame (the lock comes with the first frame, in real time
            # often before this subscriber connects), the first frame after
            # it: the dots only sample where the image motion is measured,
            # and they moved by the loop's residual (mm at 1.5 m) since.
            if self.lock_stamp == stamp or (self.dots is None and self.lock_stamp is not None
                                            and stamp > self.lock_stamp):
                self.dots = self.clouds[stamp]

    def on_info(self, msg):
        with self.lock:
            self.focal = (msg.K[0] / max(1, msg.binning_x), msg.K[4] / max(1, msg.binning_y))

    def on_estimate(self, msg):
        if msg.valid:
            with self.lock:
                self.estimated[msg.header.stamp.to_sec()] = transform_matrix(msg.transform)

    def estimate_figures(self, closed):
        """The loop's estimate against the truth at the same stamps: per-axis
        mean (a systematic error the loop settles on) and RMS, mm and deg (norms)."""
        with self.lock:
            estimated = dict(self.estimated)
        errors = []
        for stamp, c in zip(self.stamps, closed):
            e = estimated.get(stamp)
            if e is not None:
                d = np.linalg.inv(offset_matrix(c)) @ e
                errors.append(np.r_[d[:3, 3], 0.5 * np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]])])
        if not errors:
            return [float("nan")] * 4
        errors = np.array(errors)
        mean, square = errors.mean(axis=0), (errors ** 2).mean(axis=0)
        rospy.loginfo("stabilize_monitor: estimate minus truth, mean per axis: t %s mm, r %s deg (%d frames)",
                      " ".join("%+.3f" % v for v in 1e3 * mean[:3]),
                      " ".join("%+.4f" % v for v in np.degrees(mean[3:])), len(errors))
        return [1e3 * float(np.linalg.norm(mean[:3])), 1e3 * math.sqrt(float(square[:3].sum())),
                math.degrees(float(np.linalg.norm(mean[3:]))), math.degrees(math.sqrt(float(square[3:].sum())))]

    def on_warp(self, msg):
        with self.lock:
            self.warps[msg.header.stamp.to_sec()] = transform_matrix(msg.transform)

    def check_end(self, _event):
        with self.lock:
            waiting = self.t0 is None and self.estimates > 0
        if waiting and not self.relocked and (rospy.Time.now() - self.started).to_sec() > LOCK_WAIT_S:
            self.relock()
        with self.lock:
            if self.finished or self.t0 is None or not self.truth:
                return
            if max(self.truth) - self.t0 < self.duration:
                return
            self.finished = True
        self.finish()

    def relock(self):
        """The simulator learns the locked frame from the PoseDelta's status;
        if that message went by before it listened, lock again."""
        self.relocked = True
        rospy.logwarn("stabilize_monitor: no truth from a locked pose after %.0f s; asking pose_delta/lock", LOCK_WAIT_S)
        try:
            rospy.ServiceProxy("pose_delta/lock", Trigger)()
        except (rospy.ServiceException, rospy.ROSException) as e:
            rospy.logerr("stabilize_monitor: pose_delta/lock failed: %s", e)

    def series(self):
        with self.lock:
            rows = [(s, v[0], v[1]) for s, v in sorted(self.truth.items()) if v[0] is not None and v[1] is not None]
        rows = [r for r in rows if r[0] - self.t0 <= self.duration]
        self.stamps = [r[0] for r in rows]
        t = np.array([r[0] - self.t0 for r in rows])
        return t, np.array([r[1] for r in rows]).reshape(-1, 6), np.array([r[2] for r in rows]).reshape(-1, 6)

    def image_figures(self, closed, open_):
        """E (stabilised, frames warped) and F (raw, open loop): px RMS at the dots."""
        nan = float("nan")
        with self.lock:
            dots, focal, warps = self.dots, self.focal, dict(self.warps)
        if dots is None or focal is None or len(dots) == 0:
            return nan, nan, 0
        stab, raw = [], []
        for stamp, c, o in zip(self.stamps, closed, open_):
            base = project(np.eye(4), dots, focal)
            raw.append(np.sum((project(offset_matrix(o), dots, focal) - base) ** 2, axis=1))
            w = warps.get(stamp)
            if w is not None:
                stab.append(np.sum((project(offset_matrix(c), dots, focal) - project(w, dots, focal)) ** 2, axis=1))
        e = math.sqrt(np.mean(np.concatenate(stab))) if stab else nan
        f = math.sqrt(np.mean(np.concatenate(raw))) if raw else nan
        return e, f, len(stab)

    def figures(self):
        t, closed, open_ = self.series()
        rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 30.0
        a, b = rms(open_)
        c, d = rms(closed)
        f, po, pc, s, bandwidth = sensitivity(open_, closed, rate)
        tones_f, tones_s = tone_sensitivity(open_, closed, rate, self.period) if self.period > 0 else ([], [])
        s1, tone_bandwidth, peak, peak_f = tone_figures(np.asarray(tones_f), np.asarray(tones_s))
        if self.period > 0:
            bandwidth = tone_bandwidth
            rospy.loginfo("stabilize_monitor: |S(f)| at the disturbance's tones: %s",
                          ", ".join("%.2f Hz %.3f" % fs for fs in zip(tones_f, tones_s)))
        if not self.controller:
            s, bandwidth = np.full_like(s, np.nan), float("nan")  # no loop: |S| = 1 by construction
        image_e, image_f, image_frames = self.image_figures(closed, open_)
        bias_t, error_t, bias_r, error_r = self.estimate_figures(closed)
        # The largest residual of any frame after the first second (a step's
        # transient, the estimate's noise, the vibration).
        late = closed[t >= 1.0] if len(t) else closed
        max_t = 1e3 * float(np.max(np.linalg.norm(late[:, :3], axis=1))) if len(late) else float("nan")
        max_r = math.degrees(float(np.max(np.linalg.norm(late[:, 3:], axis=1)))) if len(late) else float("nan")
        with self.lock:
            lat = np.array(self.latency) if self.latency else np.array([float("nan")])
            figures = {
                "open_translation_mm": a, "open_rotation_deg": b, "closed_translation_mm": c, "closed_rotation_deg": d,
                "translation_ratio": c / a if a > 0 else float("nan"), "rotation_ratio": d / b if b > 0 else float("nan"),
                "frames": float(len(t)), "frame_rate_hz": rate, "seconds": float(t[-1]) if len(t) else 0.0,
                "latency_median_ms": 1e3 * float(np.median(lat)), "latency_p95_ms": 1e3 * float(np.percentile(lat, 95)),
                "commands": float(self.commands), "zero_commands": float(self.zero_commands),
                "estimates": float(self.estimates),
                "valid_fraction": self.valid / self.estimates if self.estimates else float("nan"),
                "closed_max_translation_mm": max_t, "closed_max_rotation_deg": max_r,
                "bandwidth_hz": bandwidth, "controller": float(self.controller), "imu": float(self.imu),
                "s_1hz": s1, "s_peak": peak, "s_peak_hz": peak_f,
                "image_residual_px": image_e, "image_open_px": image_f, "image_frames": float(image_frames),
                "estimate_bias_mm": bias_t, "estimate_error_mm": error_t, "estimate_bias_deg": bias_r,
                "estimate_error_deg": error_r}
        return figures, (t, closed, open_, f, po, pc, s, np.asarray(tones_f), np.asarray(tones_s))

    def finish(self):
        figures, data = self.figures()
        if self.plot_path:
            path = self.plot_path
            if not os.path.isabs(path):
                path = os.path.join(os.environ.get("ROS_HOME", os.path.expanduser("~/.ros")), path)
            try:
                draw(path, figures, *data)
                rospy.loginfo("stabilize_monitor: plot written to %s", path)
            except Exception as e:  # a plot that cannot be written must not lose the figures
                rospy.logerr("stabilize_monitor: cannot write the plot %s: %s", path, e)
        if self.series_file:
            t, closed, open_ = data[:3]
            np.savetxt(self.series_file, np.column_stack([t, closed, open_]), delimiter=",",
                       header="t_s,closed_tx,closed_ty,closed_tz,closed_rx,closed_ry,closed_rz,"
                              "open_tx,open_ty,open_tz,open_rx,open_ry,open_rz (m, rad)")
        if self.stats_file:
            with open(self.stats_file, "w") as out:
                yaml.safe_dump({k: float(v) for k, v in figures.items()}, out)
        lines = ("stabilization: open-loop %.2f mm %.3f deg RMS, closed-loop %.2f mm %.3f deg RMS" % (
            figures["open_translation_mm"], figures["open_rotation_deg"], figures["closed_translation_mm"],
            figures["closed_rotation_deg"]),
                 "image: residual motion %.3f px RMS at the dots, open loop %.2f px" % (
            figures["image_residual_px"], figures["image_open_px"]))
        # The message carries the two lines as printed (the rostests check their form).
        status = DiagnosticStatus(name="stabilize_monitor", level=DiagnosticStatus.OK, message="\n".join(lines))
        status.values = [KeyValue(k, repr(float(v))) for k, v in figures.items()]
        self.stats_pub.publish(status)
        # The summary, last.
        print(lines[0], flush=True)
        print(lines[1], flush=True)
        if self.exit:
            end_launch()
            rospy.signal_shutdown("duration reached")


def draw(path, figures, t, closed, open_, f, po, pc, s, tones_f, tones_s):
    from structured_light_stabilizer.plot import Figure
    fig = Figure(1500, 1120, "stabilization: open-loop %.2f mm %.3f deg RMS, closed-loop %.2f mm %.3f deg RMS "
                 "(%s; latency exposure to command %.0f ms median); image %.3f px at the dots" % (
                     figures["open_translation_mm"], figures["open_rotation_deg"], figures["closed_translation_mm"],
                     figures["closed_rotation_deg"], "with IMU" if figures["imu"] else "camera only",
                     figures["latency_median_ms"], figures["image_residual_px"]))
    names = ("tx", "ty", "tz", "rx", "ry", "rz")
    for a in range(6):
        scale, unit = (1e3, "mm") if a < 3 else (180.0 / math.pi, "deg")
        ax = fig.add((0 if a < 3 else 750, (a % 3) * 250, 750, 250),
                     "%s: offset from the locked pose" % names[a], "time since the lock (s)", unit)
        ax.plot(t, open_[:, a] * scale, "open loop (disturbance)")
        ax.plot(t, closed[:, a] * scale, "closed loop")
    spec = fig.add((0, 750, 750, 340), "translation PSD (tx+ty+tz)", "frequency (Hz)", "mm^2/Hz", xlog=True, ylog=True)
    ok = f > 0
    spec.plot(f[ok], po[ok] * 1e6, "disturbance")
    spec.plot(f[ok], pc[ok] * 1e6, "closed-loop residual")
    sens = fig.add((750, 750, 750, 340), "measured sensitivity |S| = residual / disturbance", "frequency (Hz)",
                   "|S|", xlog=True, ylog=True)
    label = "|S| measured, %s" % ("with IMU" if figures["imu"] else "camera only")
    if len(tones_f):
        sens.plot(tones_f, tones_s, label + " (at the disturbance's tones)")
    else:
        sens.plot(f[ok], s[ok], label)
    sens.hline(1.0 / math.sqrt(2.0), "0.71")
    bw = figures["bandwidth_hz"]
    if math.isfinite(bw):
        spec.vline(bw, "loop bandwidth %.2f Hz" % bw)
        sens.vline(bw, "bandwidth %.2f Hz" % bw)
    fig.save(path)


if __name__ == "__main__":
    rospy.init_node("stabilize_monitor")
    Monitor()
    rospy.spin()
