#!/usr/bin/env python3
"""Publishes camera_info at 20 Hz, each frame's spots 10 ms later and, for
all but every fifth frame, its points 25 ms and its pose_delta 40 ms later
(same stamp); the LatencyProbe must time the frames that have a pose_delta,
at 40 ms plus the scheduling of both processes (the median at least 38 ms
and at most 100 ms: Python's timers run late on a loaded machine, 49.5 ms
measured during a build; no frame below 32 ms, which is still above the
points' 25 ms: the probe stamps camera_info when its callback runs, and a
loaded manager can run it a few ms late, 36.7 ms measured once in CI), and
no others, and split them into the stages 10 / 15 / 15 ms (each median
within 8-50 ms)."""
import os
import threading
import time
import unittest

import rospy
import rostest
import yaml
from sensor_msgs.msg import CameraInfo, PointCloud2
from structured_light_stabilizer.msg import CentroidArray, PoseDelta

DELAY_S = 0.040
FRAMES = 60
WARMUP = 5  # latency_probe.test's ~warmup_frames


class LatencyProbeTest(unittest.TestCase):
    def test_times_the_frames_with_a_pose_delta(self):
        rospy.init_node("check_latency_probe")
        out_file = rospy.get_param("~out_file")
        if os.path.exists(out_file):
            os.remove(out_file)
        info_pub = rospy.Publisher("camera/camera_info", CameraInfo, queue_size=10)
        pose_pub = rospy.Publisher("pose_delta", PoseDelta, queue_size=10)
        spots_pub = rospy.Publisher("spots", CentroidArray, queue_size=10)
        points_pub = rospy.Publisher("points", PointCloud2, queue_size=10)
        deadline = time.time() + 20.0
        pubs = (info_pub, pose_pub, spots_pub, points_pub)
        while time.time() < deadline and any(p.get_num_connections() == 0 for p in pubs):
            time.sleep(0.1)
        self.assertGreater(info_pub.get_num_connections(), 0, "the probe never subscribed camera/camera_info")
        self.assertGreater(pose_pub.get_num_connections(), 0, "the probe never subscribed pose_delta")
        time.sleep(0.5)
        timers = []
        for k in range(FRAMES):
            stamp = rospy.Time(1000 + k)
            info = CameraInfo()
            info.header.stamp = stamp
            info_pub.publish(info)
            later = [(0.010, spots_pub, CentroidArray())]
            if k % 5 != 4:
                later += [(0.025, points_pub, PointCloud2()), (DELAY_S, pose_pub, PoseDelta())]
            for delay, pub, msg in later:
                msg.header.stamp = stamp
                t = threading.Timer(delay, pub.publish, args=(msg,))
                t.start()
                timers.append(t)
            time.sleep(0.05)
        for t in timers:
            t.join()
        expected = sum(1 for k in range(WARMUP, FRAMES) if k % 5 != 4)
        figures = {}
        deadline = time.time() + 10.0
        while time.time() < deadline:
            if os.path.exists(out_file):
                with open(out_file) as f:
                    figures = yaml.safe_load(f) or {}
                if figures.get("frames") == FRAMES and figures.get("timed") == expected:
                    break
            time.sleep(0.2)
        print("[ MEASURE ] latency probe: %s" % figures)
        self.assertEqual(figures.get("frames"), FRAMES)
        self.assertEqual(figures.get("timed"), expected, "frames without a pose_delta timed, or frames lost")
        self.assertGreaterEqual(figures["latency_min_ms"], 1e3 * DELAY_S - 8.0)
        self.assertGreaterEqual(figures["latency_median_ms"], 1e3 * DELAY_S - 2.0)
        self.assertGreaterEqual(figures["latency_median_ms"], figures["latency_min_ms"])
        self.assertLessEqual(figures["latency_median_ms"], 100.0)
        self.assertGreaterEqual(figures["latency_p99_ms"], figures["latency_median_ms"])
        self.assertGreaterEqual(figures["latency_max_ms"], figures["latency_p99_ms"])
        for stage in ("detector", "triangulator", "pose_delta"):
            self.assertGreaterEqual(figures["%s_median_ms" % stage], 8.0, stage)
            self.assertLessEqual(figures["%s_median_ms" % stage], 50.0, stage)
            self.assertGreaterEqual(figures["%s_p99_ms" % stage], figures["%s_median_ms" % stage], stage)
        self.assertAlmostEqual(figures["p99_over_median"],
                               figures["latency_p99_ms"] / figures["latency_median_ms"], places=3)


if __name__ == "__main__":
    rostest.rosrun("structured_light_stabilizer", "latency_probe", LatencyProbeTest)
