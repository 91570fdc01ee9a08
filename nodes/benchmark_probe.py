#!/usr/bin/env python3
"""Benchmark probe (scripts/benchmark): the CPU of a nodelet manager and of
each of its nodelets while the benchmark runs; not a part of the pipeline.

Every nodelet of the package reports a "callback CPU" diagnostic status: the
thread CPU time its frame callbacks took (the core's work, conversions and
publication included; receiving and deserialising messages, which happen on
roscpp's threads, not). This node keeps the newest of those per nodelet and
samples the manager process's user + system CPU (/proc/<pid>/stat; the
manager's pid is asked from the node ~manager through its master), and
times each frame from its
publication (the arrival of camera/camera_info, published with the image by
the CameraDriver and by rosbag play) to the arrival of its pose_delta (wall
clock, so also on a replayed bag's clock). At shutdown it writes to ~out_file:

  manager_cpu_s: user + system seconds of the manager while this node ran
  published: camera_info messages seen (all frames while this node ran)
  frames: camera_info messages after the first pose_delta (earlier ones are
          the warm-up: the lazy subscriptions connecting)
  pose_deltas: frames with their pose_delta; latency_samples: those timed
  dropped: frames with no pose_delta within 1 s (those of the
          last second not counted); dropped_at_s: when they were published
          (s after the first pose_delta; the first 50)
  latency_median_ms, latency_p99_ms: publication -> pose_delta
  nodelets: {<diagnostic name>: {callbacks: N, cpu_s: seconds, ms_per_callback}}

  With ~rate (the source's frame rate): ticks, the frames the source should
  have published from the first pose_delta to the end, and not_published,
  those it did not (a late driver skips ticks).

Parameters: ~manager (default stabilizer_manager), ~out_file (YAML path),
~rate (Hz, 0: no ticks), ~duration (s after the first pose_delta, or with
~pose_delta false after the first frame; then the node writes and exits,
which ends a launch where it is required; 0: at shutdown only).
"""
import math
import os
import threading
import time

import xmlrpc.client

import numpy as np
import rosgraph
import rospy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo
from structured_light_stabilizer.msg import PoseDelta

IN_FLIGHT_S = 1.0
START_TIMEOUT_S = 60.0  # with ~duration: the longest wait for the first frame or pose_delta


def find_pid(name):
    """Pid of the node `name` as its own master knows it (the node's getPid),
    so that a manager of the same name under another master is never taken."""
    try:
        uri = rosgraph.Master(rospy.get_name()).lookupNode(name)
        code, _, pid = xmlrpc.client.ServerProxy(uri).getPid(rospy.get_name())
        return int(pid) if code == 1 else None
    except (OSError, xmlrpc.client.Error, rosgraph.MasterError):
        return None


def stat_cpu_seconds(path):
    """User + system CPU seconds from a /proc stat file (None once it is gone)."""
    try:
        with open(path) as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / float(os.sysconf("SC_CLK_TCK"))


def cpu_seconds(pid):
    """User + system CPU seconds of a process (None once it is gone)."""
    return stat_cpu_seconds("/proc/%d/stat" % pid)


def thread_cpu_seconds(pid):
    """{thread id: user + system CPU seconds} of a process's threads ({} once it is gone)."""
    try:
        tids = os.listdir("/proc/%d/task" % pid)
    except OSError:
        return {}
    cpu = {int(tid): stat_cpu_seconds("/proc/%d/task/%s/stat" % (pid, tid)) for tid in tids}
    return {tid: s for tid, s in cpu.items() if s is not None}


class Probe:
    def __init__(self):
        self.manager = rospy.resolve_name(rospy.get_param("~manager", "stabilizer_manager"))
        self.out_file = rospy.get_param("~out_file", "")
        self.rate = float(rospy.get_param("~rate", 0.0))
        self.duration = float(rospy.get_param("~duration", 0.0))
        self.published_since_first = 0
        # Without PoseDelta (a detector alone) the run counts from the first frame.
        self.poses_expected = bool(rospy.get_param("~pose_delta", True))
        self.first_info = None
        self.started = time.time()
        self.nodelets = {}
        self.pid = None
        self.cpu_start = None
        self.cpu_last = None
        self.infos_at_cpu_start = 0
        self.threads_start = {}
        self.threads_last = {}
        self.infos_at_cpu_last = 0
        self.lock = threading.Lock()
        self.published = {}  # stamp -> wall time of the camera_info
        self.poses = {}  # stamp -> wall time of the pose_delta
        self.first_pose = None
        self.infos = 0
        rospy.Subscriber("/diagnostics", DiagnosticArray, self.diagnostics_cb, queue_size=50)
        rospy.Subscriber("camera/camera_info", CameraInfo, self.info_cb, queue_size=100)
        rospy.Subscriber("pose_delta", PoseDelta, self.pose_cb, queue_size=100)
        self.timer = rospy.Timer(rospy.Duration(0.2), self.sample)

    def sample(self, _event):
        if self.pid is None:
            self.pid = find_pid(self.manager)
            if self.pid is None:
                return
        start = self.first_pose if self.poses_expected else self.first_info
        if self.duration > 0 and start is not None and time.time() - start > self.duration:
            rospy.signal_shutdown("benchmark_probe: %.0f s measured" % self.duration)
            return
        if self.duration > 0 and start is None and time.time() - self.started > self.duration + START_TIMEOUT_S:
            rospy.logerr("benchmark_probe: no %s in %.0f s; ending the run without figures",
                         "pose_delta" if self.poses_expected else "camera_info", self.duration + START_TIMEOUT_S)
            rospy.signal_shutdown("benchmark_probe: nothing to measure")
            return
        # The manager's CPU is measured from the first result on (mode pipeline:
        # the first pose_delta; else the first frame): the start-up before it
        # (loading, a preloaded folder's decoding, the lock) is not a frame's cost.
        if start is None:
            return
        cpu = cpu_seconds(self.pid)
        if cpu is None:
            return
        threads = thread_cpu_seconds(self.pid)
        with self.lock:
            if self.cpu_start is None:
                self.cpu_start = cpu
                self.infos_at_cpu_start = self.infos
                self.threads_start = threads
            self.cpu_last = cpu
            self.infos_at_cpu_last = self.infos
            self.threads_last = threads

    def info_cb(self, msg):
        with self.lock:
            self.published[msg.header.stamp.to_nsec()] = time.time()
            self.infos += 1
            if self.first_info is None:
                self.first_info = time.time()
            self.published_since_first += int(self.first_pose is not None)

    def pose_cb(self, msg):
        now = time.time()
        with self.lock:
            if self.first_pose is None:
                self.first_pose = now
            self.poses[msg.header.stamp.to_nsec()] = now

    def frame_figures(self):
        """Pairs frames and pose_deltas by stamp, whichever callback ran
        first (rospy runs each subscription on its own thread): a frame
        without a pose_delta is dropped; the latency is taken where the
        camera_info's callback ran first (else its time is not the
        publication's)."""
        with self.lock:
            end = time.time()
            first = self.first_pose if self.first_pose is not None else end
            lat, dropped_at, delivered = [], [], 0
            for stamp, t in self.published.items():
                if t < first:
                    continue  # warm-up
                arrived = self.poses.get(stamp)
                if arrived is None:
                    if t < end - IN_FLIGHT_S:
                        dropped_at.append(t - first)
                    continue
                delivered += 1
                if arrived >= t:
                    lat.append(1e3 * (arrived - t))
            lat = np.array(lat)
            dropped_at.sort()
        ticks = {}
        if self.rate > 0 and self.first_pose is not None:
            # The ticks due after the first pose_delta and before the end (floor:
            # the tick after the end is not yet due; within one frame of the truth).
            n = int(math.floor(self.rate * (end - first)))
            ticks = {"ticks": n, "not_published": max(0, n - self.published_since_first)}
        return dict(ticks, **{
            "published": self.infos,
            "frames": delivered + len(dropped_at),
            "pose_deltas": delivered,
            "latency_samples": int(len(lat)),
            "dropped": len(dropped_at),
            "dropped_at_s": [round(t, 3) for t in dropped_at[:50]],
            "latency_median_ms": float(np.median(lat)) if len(lat) else None,
            "latency_p99_ms": float(np.percentile(lat, 99)) if len(lat) else None,
        })

    def diagnostics_cb(self, msg):
        for status in msg.status:
            if not status.name.endswith(": callback CPU"):
                continue
            values = {kv.key: kv.value for kv in status.values}
            if "callbacks" not in values:
                continue  # the updater's first status ("Node starting up") has no values
            try:
                self.nodelets[status.name[: -len(": callback CPU")]] = {
                    "callbacks": int(values["callbacks"]),
                    "cpu_s": float(values["thread CPU total (s)"]),
                    "ms_per_callback": float(values["thread CPU per callback (ms)"]),
                }
            except (KeyError, ValueError):
                rospy.logwarn_throttle(10.0, "benchmark_probe: malformed callback CPU status from %s", status.name)

    def write(self):
        self.sample(None)
        result = {
            "manager": self.manager,
            "manager_pid": self.pid,
            "manager_cpu_s": (self.cpu_last - self.cpu_start) if self.cpu_start is not None else None,
            # frames published between the two CPU samples (the manager's CPU per frame divides by this)
            "published_in_cpu_window": (self.infos_at_cpu_last - self.infos_at_cpu_start)
            if self.cpu_start is not None else None,
            # The manager's busiest threads over the same window, CPU seconds (work a callback hands to
            # other threads, e.g. OpenCV's parallel_for pool, shows here and not in its callback CPU).
            "busiest_threads_cpu_s": sorted(
                (round(t - self.threads_start[tid], 3) for tid, t in self.threads_last.items()
                 if tid in self.threads_start), reverse=True)[:6],
            "nodelets": self.nodelets,
        }
        result.update(self.frame_figures())
        if self.out_file:
            with open(self.out_file, "w") as f:
                yaml.safe_dump(result, f, default_flow_style=False)
        rospy.loginfo("benchmark_probe: %s", result)


def main():
    rospy.init_node("benchmark_probe")
    probe = Probe()
    rospy.on_shutdown(probe.write)
    rospy.spin()


if __name__ == "__main__":
    main()
