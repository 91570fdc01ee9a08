#!/usr/bin/env python3
"""CameraDriver under use_sim_time with nothing publishing /clock
(camera_driver_sim_time.test): ROS time stands still, and the driver's
diagnostics, paced by wall time, must still arrive (diagnostic_updater's
Updater::update compares ROS time and would never publish)."""
import threading
import time
import unittest

import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticArray

PKG = "structured_light_stabilizer"


class CameraDriverSimTime(unittest.TestCase):
    def test_diagnostics_without_clock(self):
        rospy.init_node("check_camera_driver_sim_time")
        self.assertTrue(rospy.get_param("/use_sim_time"))
        lock = threading.Lock()
        names = []

        def cb(msg):
            with lock:
                names.extend(s.name for s in msg.status)

        rospy.Subscriber("/diagnostics", DiagnosticArray, cb, queue_size=20)
        deadline = time.time() + 30.0
        while time.time() < deadline:
            with lock:
                if len([n for n in names if n.startswith("camera_driver")]) >= 6:
                    break
            time.sleep(0.1)
        self.assertEqual(rospy.Time.now().to_sec(), 0.0, "something published /clock")
        with lock:
            ours = [n for n in names if n.startswith("camera_driver")]
        # Two or more publications (each with several statuses) within 30 s
        # of wall time, at 1 Hz.
        self.assertGreaterEqual(len(ours), 6, "diagnostics seen: %s" % sorted(set(names)))


if __name__ == "__main__":
    rostest.rosrun(PKG, "camera_driver_sim_time", CameraDriverSimTime)
