#!/usr/bin/env python3
"""Demo monitor: once a second prints what the pipeline achieves against the
simulator's ground truth, and ends the demo after ~duration seconds.

Line printed each second:
  dots found / visible, depth error of `points` vs sim/ground_truth/points
  (RMS, by beam, same frame), pose error of `pose_delta` vs the true motion
  since the reference frame, share of valid pose deltas, and two latencies to
  pose_delta arrival: from image acquisition (the header stamp, which for the
  simulator includes its rendering) and from the image's publication (the
  pipeline's own latency).

The cumulative figures are published on ~stats (diagnostic_msgs/DiagnosticStatus)
and written as YAML to ~stats_file at exit, for the demo rostest.
"""
import math
import threading

import numpy as np
import rospy
import yaml
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger
from sensor_msgs import point_cloud2
from structured_light_stabilizer.msg import CentroidArray, PoseDelta

HISTORY = 300  # frames of ground truth kept for matching by stamp


def cloud_xyz(msg):
    pts = np.array(list(point_cloud2.read_points(msg, field_names=("x", "y", "z"), skip_nans=False)),
                   dtype=np.float64)
    return pts.reshape(-1, 3) if pts.size else np.zeros((0, 3))


def transform_matrix(tf):
    q = tf.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return m


def is_identity(tf):
    t, q = tf.translation, tf.rotation
    return max(abs(t.x), abs(t.y), abs(t.z), abs(q.x), abs(q.y), abs(q.z)) < 1e-9


def pose_error(est, truth):
    """Translation (m) and rotation (deg) of est * truth^-1."""
    e = est @ np.linalg.inv(truth)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(e[:3, :3]) - 1.0) / 2.0))))
    return float(np.linalg.norm(e[:3, 3])), angle


class Monitor:
    def __init__(self):
        self.duration = float(rospy.get_param("~duration", 0.0))
        self.stats_file = rospy.get_param("~stats_file", "")
        self.lock = threading.Lock()
        self.gt_points, self.gt_pose, self.gt_visible, self.published_at = {}, {}, {}, {}
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
        # The pose error needs the true pose of the reference frame: once the
        # ground truth and pose_delta both flow, lock a new reference; the
        # first identity estimate after that is the reference frame.
        self.locked = False
        threading.Thread(target=self.lock_reference, daemon=True).start()
        rospy.Timer(rospy.Duration(1.0), self.report)
        # Ctrl-C or roslaunch shutting down: keep the figures of the run.
        rospy.on_shutdown(lambda: None if self.finished else self.write_stats())

    def lock_reference(self):
        while not rospy.is_shutdown():
            with self.lock:
                flowing = bool(self.gt_pose) and self.total["pose_n"] > 0
            if flowing:
                try:
                    rospy.wait_for_service("pose_delta/lock", 5.0)
                    if rospy.ServiceProxy("pose_delta/lock", Trigger)().success:
                        rospy.loginfo("demo_monitor: reference locked for the accuracy figures")
                        with self.lock:
                            self.locked = True
                        return
                except (rospy.ServiceException, rospy.ROSException):
                    pass
            rospy.sleep(0.5)

    @staticmethod
    def _empty():
        return {"published": 0, "frames": 0, "dots_found": 0, "dots_visible": 0, "depth_sq": 0.0, "depth_rel_sq": 0.0,
                "depth_n": 0, "pose_n": 0, "pose_valid": 0, "pose_err_n": 0, "trans_sq": 0.0, "rot_sq": 0.0,
                "latency": [], "pipeline_latency": []}

    @staticmethod
    def _trim(d):
        while len(d) > HISTORY:
            d.pop(next(iter(d)))

    def on_gt_points(self, msg):
        with self.lock:
            self.gt_points[msg.header.stamp] = cloud_xyz(msg)
            self._trim(self.gt_points)

    def on_gt_pose(self, msg):
        with self.lock:
            self.gt_pose[msg.header.stamp] = transform_matrix(msg.transform)
            self._trim(self.gt_pose)
            # The driver publishes the ground truth right beside the image, so
            # its arrival time is the image's publication time.
            self.published_at[msg.header.stamp] = rospy.Time.now()
            self._trim(self.published_at)
            for acc in (self.window, self.total):
                acc["published"] += 1

    def on_gt_spots(self, msg):
        with self.lock:
            self.gt_visible[msg.header.stamp] = len(msg.centroids)
            self._trim(self.gt_visible)

    def on_spots(self, msg):
        with self.lock:
            visible = self.gt_visible.get(msg.header.stamp)
            if visible is None:
                return
            for acc in (self.window, self.total):
                acc["frames"] += 1
                acc["dots_found"] += min(len(msg.centroids), visible)
                acc["dots_visible"] += visible

    def on_points(self, msg):
        est = cloud_xyz(msg)
        with self.lock:
            gt = self.gt_points.get(msg.header.stamp)
        if gt is None or gt.shape != est.shape:
            return
        ok = np.isfinite(est).all(axis=1) & np.isfinite(gt).all(axis=1)
        if not ok.any():
            return
        err = np.linalg.norm(est[ok] - gt[ok], axis=1)
        rel = err / np.linalg.norm(gt[ok], axis=1)
        with self.lock:
            for acc in (self.window, self.total):
                acc["depth_sq"] += float(np.sum(err ** 2))
                acc["depth_rel_sq"] += float(np.sum(rel ** 2))
                acc["depth_n"] += int(ok.sum())

    def on_pose(self, msg):
        now = rospy.Time.now()
        latency = (now - msg.header.stamp).to_sec()
        with self.lock:
            published = self.published_at.get(msg.header.stamp)
            for acc in (self.window, self.total):
                acc["pose_n"] += 1
                acc["latency"].append(latency)
                if published is not None:
                    acc["pipeline_latency"].append((now - published).to_sec())
            if not msg.valid:
                return
            for acc in (self.window, self.total):
                acc["pose_valid"] += 1
            truth_now = self.gt_pose.get(msg.header.stamp)
            if truth_now is None or not self.locked:
                return
            if self.ref_truth is None:
                if not is_identity(msg.transform):
                    return  # a frame processed before the lock took effect
                # auto_lock: the first valid map is the reference, so the
                # estimate is relative to that frame's true pose (kept here:
                # the history of ground truth is only HISTORY frames long).
                self.ref_truth = truth_now
            truth = truth_now @ np.linalg.inv(self.ref_truth)
            t_err, r_err = pose_error(transform_matrix(msg.transform), truth)
            for acc in (self.window, self.total):
                acc["pose_err_n"] += 1
                acc["trans_sq"] += t_err ** 2
                acc["rot_sq"] += r_err ** 2

    @staticmethod
    def summary(acc):
        def rms(sq, n):
            return math.sqrt(sq / n) if n else float("nan")
        lat = np.array(acc["latency"]) if acc["latency"] else np.array([float("nan")])
        pipe = np.array(acc["pipeline_latency"]) if acc["pipeline_latency"] else np.array([float("nan")])
        return {
            "frames_published": acc["published"],
            "frames": acc["frames"],
            "frames_dropped": max(0, acc["published"] - acc["pose_n"]),
            "dots_found": acc["dots_found"],
            "dots_visible": acc["dots_visible"],
            "recall": acc["dots_found"] / acc["dots_visible"] if acc["dots_visible"] else float("nan"),
            "depth_rms_mm": 1e3 * rms(acc["depth_sq"], acc["depth_n"]),
            "depth_rms_percent": 100.0 * rms(acc["depth_rel_sq"], acc["depth_n"]),
            "pose_messages": acc["pose_n"],
            "pose_valid_fraction": acc["pose_valid"] / acc["pose_n"] if acc["pose_n"] else float("nan"),
            "translation_rms_mm": 1e3 * rms(acc["trans_sq"], acc["pose_err_n"]),
            "rotation_rms_deg": rms(acc["rot_sq"], acc["pose_err_n"]),
            "latency_median_ms": 1e3 * float(np.median(lat)),
            "latency_p99_ms": 1e3 * float(np.percentile(lat, 99)),
            "pipeline_latency_median_ms": 1e3 * float(np.median(pipe)),
            "pipeline_latency_p99_ms": 1e3 * float(np.percentile(pipe, 99)),
        }

    def report(self, _event):
        with self.lock:
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
            self.finish(t)

    def write_stats(self):
        with self.lock:
            total = self.summary(self.total)
        if self.stats_file:
            with open(self.stats_file, "w") as f:
                yaml.safe_dump({k: float(v) for k, v in total.items()}, f)
        return total

    def finish(self, _total):
        total = self.write_stats()
        rospy.loginfo("demo over after %.0f s: %s", self.duration,
                      ", ".join("%s=%.4g" % (k, v) for k, v in total.items()))
        self.finished = True
        rospy.signal_shutdown("duration reached")


if __name__ == "__main__":
    rospy.init_node("demo_monitor")
    Monitor()
    rospy.spin()
