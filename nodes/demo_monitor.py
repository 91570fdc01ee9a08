#!/usr/bin/env python3
"""Demo monitor: once a second prints what the pipeline achieves against the
simulator's ground truth, and ends the demo after ~duration seconds.

Line printed each second:
  dots found / visible (a true dot counts as found when a detected spot lies
  within 3 px of it, one to one: spurious spots and merged dots do not make
  up for missed ones), depth error of `points` vs sim/ground_truth/points
  (RMS, by beam, same frame), pose error of `pose_delta` vs the true motion
  since the reference frame, share of valid pose deltas, and two latencies to
  pose_delta arrival: from image acquisition (the header stamp, which for the
  simulator includes its rendering) and from the image's publication (the
  pipeline's own latency; the ground truth, published by the driver right
  beside the image, marks the publication).

Outputs and ground truth are paired by header stamp in whichever order they
arrive: on a loaded machine this monitor's ground-truth callbacks can lag
behind the pipeline's outputs.

Dropped frames: a frame published by the driver whose pose_delta has not
arrived IN_FLIGHT_S after publication. Frames published before the first
pose_delta arrived (the lazy subscriptions are still connecting) are counted
as warm-up, not as dropped; frames still in flight at the end are not counted.

The cumulative figures are published on ~stats (diagnostic_msgs/DiagnosticStatus)
and written as YAML to ~stats_file at exit, for the demo rostest.

End: after ~duration seconds the monitor prints the summary ("demo over ...")
and, when roslaunch started it, ends the launch as Ctrl-C would (SIGINT to
roslaunch): a clean exit with status 0, not a "REQUIRED process has died".
"""
import collections
import math
import os
import signal
import threading

import numpy as np
import rospy
import yaml
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger
from structured_light_stabilizer.evaluation import (cloud_xyz, is_identity, match_spots, pose_error,
                                                    transform_matrix)
from structured_light_stabilizer.msg import CentroidArray, PoseDelta

HISTORY = 300  # frames kept while waiting for their partner stamp
MATCH_PX = 3.0  # a detected spot within this distance of a true dot finds it (one to one)
IN_FLIGHT_S = 1.0  # a frame without pose_delta this long after its publication is dropped


class StampPairs:
    """Pairs an output with the ground truth of the same header stamp,
    whichever comes first; on_pair(stamp, output, truth) runs when both are
    in. The caller serialises the calls."""

    def __init__(self, on_pair):
        self.on_pair = on_pair
        self.waiting = ({}, {})  # outputs, truths without a partner yet

    def _add(self, side, stamp, value):
        partner = self.waiting[1 - side].pop(stamp, None)
        if partner is None:
            self.waiting[side][stamp] = value
            while len(self.waiting[side]) > HISTORY:
                self.waiting[side].pop(next(iter(self.waiting[side])))
            return
        output, truth = (value, partner) if side == 0 else (partner, value)
        self.on_pair(stamp, output, truth)

    def output(self, stamp, value):
        self._add(0, stamp, value)

    def truth(self, stamp, value):
        self._add(1, stamp, value)


class Monitor:
    def __init__(self):
        self.duration = float(rospy.get_param("~duration", 0.0))
        self.stats_file = rospy.get_param("~stats_file", "")
        self.lock = threading.Lock()
        self.spots = StampPairs(self.pair_spots)
        self.points = StampPairs(self.pair_points)
        self.poses = StampPairs(self.pair_pose)
        self.published_at = collections.OrderedDict()  # stamp -> arrival of its ground truth
        self.delivered = collections.OrderedDict()  # stamps whose pose_delta has arrived
        self.pending = {}  # stamp -> publication time, until its pose_delta arrives
        self.first_pose_stamp = None
        self.truth_seen = False
        # The pose error needs the true pose of the reference frame: once the
        # ground truth and pose_delta both flow, lock a new reference; each
        # identity estimate stamped after the last estimate seen before the
        # lock request is a reference frame, the latest one counts.
        self.locked_after = None
        self.last_pose_stamp = None
        self.ref_truth = None
        self.window = self._empty()
        self.total = self._empty()
        self.stats_pub = rospy.Publisher("~stats", DiagnosticStatus, queue_size=1, latch=True)
        rospy.Subscriber("sim/ground_truth/points", PointCloud2, self.on_gt_points, queue_size=10)
        rospy.Subscriber("sim/ground_truth/pose_delta", PoseDelta, self.on_gt_pose, queue_size=10)
        rospy.Subscriber("sim/ground_truth/spots", CentroidArray, self.on_gt_spots, queue_size=10)
        rospy.Subscriber("spots", CentroidArray, self.on_spots, queue_size=10)
        rospy.Subscriber("points", PointCloud2, self.on_points, queue_size=10)
        rospy.Subscriber("pose_delta", PoseDelta, self.on_pose, queue_size=10)
        self.start = rospy.Time.now()
        self.finished = False
        threading.Thread(target=self.lock_reference, daemon=True).start()
        rospy.Timer(rospy.Duration(1.0), self.report)
        # Ctrl-C or roslaunch shutting down: keep the figures of the run.
        rospy.on_shutdown(lambda: None if self.finished else self.write_stats())

    def lock_reference(self):
        while not rospy.is_shutdown():
            with self.lock:
                flowing = self.truth_seen and self.last_pose_stamp is not None
                before = self.last_pose_stamp
            if flowing:
                try:
                    rospy.wait_for_service("pose_delta/lock", 5.0)
                    if rospy.ServiceProxy("pose_delta/lock", Trigger)().success:
                        rospy.loginfo("demo_monitor: reference locked for the accuracy figures")
                        with self.lock:
                            self.locked_after = before
                        return
                except (rospy.ServiceException, rospy.ROSException):
                    pass
            rospy.sleep(0.5)

    @staticmethod
    def _empty():
        return {"published": 0, "dropped": 0, "warmup": 0, "frames": 0, "dots_found": 0, "dots_visible": 0,
                "depth_sq": 0.0, "depth_rel_sq": 0.0, "depth_n": 0, "pose_n": 0, "pose_valid": 0, "pose_err_n": 0,
                "trans_sq": 0.0, "rot_sq": 0.0, "latency": [], "pipeline_latency": []}

    def _add(self, key, value=1):
        for acc in (self.window, self.total):
            acc[key] += value

    @staticmethod
    def _remember(d, key, value):
        d[key] = value
        while len(d) > HISTORY:
            d.popitem(last=False)

    # --- callbacks: ground truth ------------------------------------------
    def on_gt_points(self, msg):
        xyz = cloud_xyz(msg)
        with self.lock:
            self.points.truth(msg.header.stamp, xyz)

    def on_gt_pose(self, msg):
        now = rospy.Time.now()
        with self.lock:
            self.truth_seen = True
            self._add("published")
            stamp = msg.header.stamp
            self._remember(self.published_at, stamp, now)
            if stamp not in self.delivered:
                self.pending[stamp] = now
            self.poses.truth(stamp, transform_matrix(msg.transform))

    def on_gt_spots(self, msg):
        xy = [(c.x, c.y) for c in msg.centroids]
        with self.lock:
            self.spots.truth(msg.header.stamp, xy)

    # --- callbacks: pipeline outputs --------------------------------------
    def on_spots(self, msg):
        xy = [(c.x, c.y) for c in msg.centroids]
        with self.lock:
            self.spots.output(msg.header.stamp, xy)

    def on_points(self, msg):
        xyz = cloud_xyz(msg)
        with self.lock:
            self.points.output(msg.header.stamp, xyz)

    def on_pose(self, msg):
        now = rospy.Time.now()
        stamp = msg.header.stamp
        with self.lock:
            self._add("pose_n")
            self._add("latency", [(now - stamp).to_sec()])
            published = self.published_at.get(stamp)
            if published is not None:  # else this monitor's ground truth lags: no figure
                self._add("pipeline_latency", [(now - published).to_sec()])
            self.pending.pop(stamp, None)
            self._remember(self.delivered, stamp, True)
            if self.first_pose_stamp is None:
                self.first_pose_stamp = stamp
            if self.last_pose_stamp is None or stamp > self.last_pose_stamp:
                self.last_pose_stamp = stamp
            if msg.valid:
                self._add("pose_valid")
            self.poses.output(stamp, msg)

    # --- pairs (called under the lock) -------------------------------------
    def pair_spots(self, _stamp, found, visible):
        self._add("frames")
        self._add("dots_found", match_spots(found, visible, MATCH_PX))
        self._add("dots_visible", len(visible))

    def pair_points(self, _stamp, est, gt):
        if gt.shape != est.shape:
            return
        ok = np.isfinite(est).all(axis=1) & np.isfinite(gt).all(axis=1)
        if not ok.any():
            return
        err = np.linalg.norm(est[ok] - gt[ok], axis=1)
        rel = err / np.linalg.norm(gt[ok], axis=1)
        self._add("depth_sq", float(np.sum(err ** 2)))
        self._add("depth_rel_sq", float(np.sum(rel ** 2)))
        self._add("depth_n", int(ok.sum()))

    def pair_pose(self, stamp, msg, truth_now):
        if not msg.valid or self.locked_after is None:
            return
        if stamp <= self.locked_after:
            return  # processed before the lock request
        # PoseDelta publishes the exact identity for the frame it locks on,
        # and only then. Every identity after the request is a (re)lock and
        # becomes the reference: an auto-lock that lands between the request
        # and the lock it asked for is followed by a second identity, and the
        # estimates after that are relative to the second (strobe_sim.test
        # once scored them against the first: 1.05 mm from 0.2 s of motion).
        if is_identity(msg.transform):
            self.ref_truth = truth_now
        if self.ref_truth is None:
            return
        truth = truth_now @ np.linalg.inv(self.ref_truth)
        t_err, r_err = pose_error(transform_matrix(msg.transform), truth)
        self._add("pose_err_n")
        self._add("trans_sq", t_err ** 2)
        self._add("rot_sq", r_err ** 2)

    # --- figures ------------------------------------------------------------
    def count_dropped(self, now):
        """Moves the frames that are overdue from pending to the dropped or
        warm-up counts (caller holds the lock)."""
        for stamp in [s for s, t in self.pending.items() if (now - t).to_sec() > IN_FLIGHT_S]:
            del self.pending[stamp]
            if self.first_pose_stamp is None or stamp < self.first_pose_stamp:
                self._add("warmup")
            else:
                self._add("dropped")
                rospy.logwarn_throttle(5.0, "demo_monitor: no pose_delta for the frame stamped %.3f" % stamp.to_sec())

    @staticmethod
    def summary(acc):
        def rms(sq, n):
            return math.sqrt(sq / n) if n else float("nan")

        def pct(values, q):
            return 1e3 * float(np.percentile(values, q)) if values else float("nan")

        return {
            "frames_published": acc["published"],
            "frames": acc["frames"],
            "frames_dropped": acc["dropped"],
            "frames_warmup": acc["warmup"],
            "dots_found": acc["dots_found"],
            "dots_visible": acc["dots_visible"],
            "recall": acc["dots_found"] / acc["dots_visible"] if acc["dots_visible"] else float("nan"),
            "depth_rms_mm": 1e3 * rms(acc["depth_sq"], acc["depth_n"]),
            "depth_rms_percent": 100.0 * rms(acc["depth_rel_sq"], acc["depth_n"]),
            "pose_messages": acc["pose_n"],
            "pose_valid_fraction": acc["pose_valid"] / acc["pose_n"] if acc["pose_n"] else float("nan"),
            "pose_compared": acc["pose_err_n"],
            "translation_rms_mm": 1e3 * rms(acc["trans_sq"], acc["pose_err_n"]),
            "rotation_rms_deg": rms(acc["rot_sq"], acc["pose_err_n"]),
            "latency_median_ms": pct(acc["latency"], 50),
            "latency_p99_ms": pct(acc["latency"], 99),
            "pipeline_latency_median_ms": pct(acc["pipeline_latency"], 50),
            "pipeline_latency_p99_ms": pct(acc["pipeline_latency"], 99),
        }

    def report(self, _event):
        with self.lock:
            self.count_dropped(rospy.Time.now())
            w = self.summary(self.window)
            t = self.summary(self.total)
            self.window = self._empty()
        elapsed = (rospy.Time.now() - self.start).to_sec()
        rospy.loginfo("t=%4.0fs | frames %3d (dropped %d) | dots %d/%d | depth RMS %.2f mm (%.3f %%) | "
                      "pose err %.2f mm %.3f deg, valid %3.0f %% | latency %.1f ms from acquisition, %.1f ms from publication",
                      elapsed, w["frames_published"], w["frames_dropped"], w["dots_found"], w["dots_visible"], w["depth_rms_mm"],
                      w["depth_rms_percent"], w["translation_rms_mm"], w["rotation_rms_deg"],
                      100.0 * w["pose_valid_fraction"] if w["pose_messages"] else float("nan"),
                      w["latency_median_ms"], w["pipeline_latency_median_ms"])
        status = DiagnosticStatus(name="demo_monitor", level=DiagnosticStatus.OK,
                                  message="cumulative figures since start")
        status.values = [KeyValue(k, repr(v)) for k, v in t.items()]
        self.stats_pub.publish(status)
        if self.duration > 0 and elapsed >= self.duration:
            self.finish()

    def write_stats(self):
        with self.lock:
            self.count_dropped(rospy.Time.now())
            total = self.summary(self.total)
        if self.stats_file:
            with open(self.stats_file, "w") as f:
                yaml.safe_dump({k: float(v) for k, v in total.items()}, f)
        return total

    def finish(self):
        total = self.write_stats()
        rospy.loginfo("demo over after %.0f s: %s", self.duration,
                      ", ".join("%s=%.4g" % (k, v) for k, v in total.items()))
        self.finished = True
        end_launch()
        rospy.signal_shutdown("duration reached")


def end_launch():
    """SIGINT to the roslaunch that started this node, if one did (not a
    rostest, not a shell): the launch then shuts down as on Ctrl-C."""
    parent = os.getppid()
    try:
        with open("/proc/%d/cmdline" % parent, "rb") as f:
            argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
    except OSError:
        return
    if any(os.path.basename(a) == "roslaunch" for a in argv[:2]):
        os.kill(parent, signal.SIGINT)


if __name__ == "__main__":
    rospy.init_node("demo_monitor")
    Monitor()
    rospy.spin()
