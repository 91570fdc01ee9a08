#!/usr/bin/env python3
"""Reads the stabilisation monitor's final figures (stabilize_monitor/stats)
and asserts them (stabilize.test, stabilize_open_loop.test).

Closed loop (acceptance): closed-loop RMS <= 10 % of the open-loop
RMS in translation and in rotation (the open loop: the disturbance's own
offset from the locked pose in the same run, seed and lock); per frame after
the first second: <= 1.5 mm and 0.08 deg (the open loop drifts to several mm
and 0.1-0.2 deg in 30 s); frames at a usable rate, the estimates valid, the
controller commanding; the PNG written.

Lockstep with the IMU (stabilize_lockstep_imu.test) sets ~max_ratio,
~max_frame_mm / ~max_frame_deg, ~min_open_mm, ~max_image_px and ~min_rate
to its own bounds. Always: the two lines of the monitor (the stats' message)
in exactly their printed form, with the figures of the stats.

Open loop (~open_loop): no command at all, and the closed-loop figures equal
the open-loop ones (the arm still: the true offset is the disturbance's)."""
import math
import re
import os
import time
import unittest

import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TwistStamped


class Stabilize(unittest.TestCase):
    def test_stabilization(self):
        rospy.init_node("check_stabilize")
        open_loop = rospy.get_param("~open_loop", False)
        plot = rospy.get_param("~plot", "")
        latest = {}
        offsets = {}

        message = [""]

        def on_stats(msg):
            message[0] = msg.message
            latest.update({kv.key: float(kv.value) for kv in msg.values})

        def on_truth(msg, which):
            offsets.setdefault(msg.header.stamp, [None, None])[which] = msg

        rospy.Subscriber("stabilize_monitor/stats", DiagnosticStatus, on_stats)
        rospy.Subscriber("sim/ground_truth/offset", TwistStamped, on_truth, 0)
        rospy.Subscriber("sim/ground_truth/disturbance", TwistStamped, on_truth, 1)
        deadline = time.time() + 140.0
        while time.time() < deadline and not latest and not rospy.is_shutdown():
            time.sleep(0.5)
        s = dict(latest)
        print("[ MEASURE ] stabilize%s: %s" % (" (open loop)" if open_loop else "",
                                               ", ".join("%s=%.4g" % kv for kv in sorted(s.items()))))
        self.assertTrue(s, "no figures from stabilize_monitor")
        self.assertGreaterEqual(s["frames"], rospy.get_param("~min_rate", 15.0) * s["seconds"],
                                "frames came too slowly: %s" % s)
        self.check_lines(s, message[0])
        if open_loop:
            self.assertEqual(s["commands"], 0.0)
            self.assertAlmostEqual(s["closed_translation_mm"], s["open_translation_mm"], places=9)
            self.assertAlmostEqual(s["closed_rotation_deg"], s["open_rotation_deg"], places=9)
            pairs = [p for p in offsets.values() if p[0] is not None and p[1] is not None]
            self.assertGreater(len(pairs), 50)
            for a, b in pairs:
                self.assertEqual((a.twist.linear, a.twist.angular), (b.twist.linear, b.twist.angular))
            return
        self.assertGreaterEqual(s["valid_fraction"], 0.95)
        self.assertGreater(s["commands"], 0.9 * s["estimates"])
        self.assertGreater(s["open_translation_mm"], rospy.get_param("~min_open_mm", 1.0),
                           "the disturbance did not move the camera: %s" % s)
        max_ratio = rospy.get_param("~max_ratio", 0.10)
        self.assertLessEqual(s["translation_ratio"], max_ratio)
        self.assertLessEqual(s["rotation_ratio"], max_ratio)
        self.assertLessEqual(s["closed_max_translation_mm"], rospy.get_param("~max_frame_mm", 1.5))
        self.assertLessEqual(s["closed_max_rotation_deg"], rospy.get_param("~max_frame_deg", 0.08))
        max_image = rospy.get_param("~max_image_px", 0.0)
        if max_image > 0:
            self.assertGreater(s["image_frames"], 0.9 * s["frames"], "frames not warped: %s" % s)
            self.assertGreater(s["image_open_px"], 5.0 * max_image, "the rock hardly moved in the image: %s" % s)
            self.assertLessEqual(s["image_residual_px"], max_image)
        self.assertTrue(math.isfinite(s["latency_median_ms"]))
        if plot:
            path = plot if os.path.isabs(plot) else os.path.join(
                os.environ.get("ROS_HOME", os.path.expanduser("~/.ros")), plot)
            with open(path, "rb") as f:
                self.assertEqual(f.read(8), b"\x89PNG\r\n\x1a\n", "%s is not a PNG" % path)

    def check_lines(self, s, message):
        """The monitor's last two lines, exactly in their form, with the stats' figures."""
        number = r"([0-9]+\.[0-9]+|nan)"
        lines = message.split("\n")
        self.assertEqual(len(lines), 2, repr(message))
        m = re.fullmatch(r"stabilization: open-loop %s mm %s deg RMS, closed-loop %s mm %s deg RMS"
                         % (number, number, number, number), lines[0])
        self.assertTrue(m, "first line not in its form: %r" % lines[0])
        for value, key, places in zip(m.groups(), ("open_translation_mm", "open_rotation_deg",
                                                   "closed_translation_mm", "closed_rotation_deg"), (2, 3, 2, 3)):
            self.assertAlmostEqual(float(value), s[key], delta=0.51 * 10 ** -places)
        m = re.fullmatch(r"image: residual motion %s px RMS at the dots, open loop %s px" % (number, number), lines[1])
        self.assertTrue(m, "second line not in its form: %r" % lines[1])
        if math.isfinite(s["image_residual_px"]):
            self.assertAlmostEqual(float(m.group(1)), s["image_residual_px"], delta=0.00051)
            self.assertAlmostEqual(float(m.group(2)), s["image_open_px"], delta=0.0051)


if __name__ == "__main__":
    rostest.rosrun("structured_light_stabilizer", "stabilize", Stabilize)
