#!/usr/bin/env python3
"""Publishes camera_info at 20 Hz and, for all but every fifth frame, its
pose_delta 40 ms later (same stamp); the LatencyProbe must time the frames
that have a pose_delta, at 40 ms plus this process's scheduling (bounded:
the median within 38-60 ms, no frame below 38 ms), and no others."""
import os
import threading
import time
import unittest

import rospy
import rostest
import yaml
from sensor_msgs.msg import CameraInfo
from structured_light_stabilizer.msg import PoseDelta

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
        deadline = time.time() + 20.0
        while time.time() < deadline and (info_pub.get_num_connections() == 0 or
                                          pose_pub.get_num_connections() == 0):
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
            if k % 5 != 4:
                pose = PoseDelta()
                pose.header.stamp = stamp
                t = threading.Timer(DELAY_S, pose_pub.publish, args=(pose,))
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
        self.assertGreaterEqual(figures["latency_min_ms"], 1e3 * DELAY_S - 2.0)
        self.assertGreaterEqual(figures["latency_median_ms"], figures["latency_min_ms"])
        self.assertLessEqual(figures["latency_median_ms"], 60.0)
        self.assertGreaterEqual(figures["latency_p99_ms"], figures["latency_median_ms"])
        self.assertGreaterEqual(figures["latency_max_ms"], figures["latency_p99_ms"])
        self.assertAlmostEqual(figures["p99_over_median"],
                               figures["latency_p99_ms"] / figures["latency_median_ms"], places=3)


if __name__ == "__main__":
    rostest.rosrun("structured_light_stabilizer", "latency_probe", LatencyProbeTest)
