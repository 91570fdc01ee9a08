#!/usr/bin/env python3
"""Strobed operation end to end (strobe_sim.test, docs/daylight.md): the
recommended daylight rig under the study's brightest sun, one strobed stream
split by StrobeDemux. Asserts, once `frames` pose deltas were compared:
  - the demux: after its phase vote settled, every frame it published on
    camera/image_raw is one the simulator lit (the simulator publishes ground
    truth with exactly those stamps) and none on camera/image_ambient is;
  - the pipeline against the truth (acceptance for the recommended rig):
    recall >= 99.5 %, depth <= 0.1 %, pose <= 0.5 mm / 0.02 deg RMS, >= 95 %
    of the poses valid."""
import threading
import time
import unittest

import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import Image
from structured_light_stabilizer.msg import CentroidArray

SETTLE = 12  # frames the demux's phase vote may take at the start (9 votes)


class StrobeSim(unittest.TestCase):
    def test_strobed_pipeline(self):
        rospy.init_node("check_strobe_sim")
        frames = rospy.get_param("~frames", 80)
        latest, lock = {}, threading.Lock()
        stamps = {"on": [], "off": [], "lit": []}

        def on_stats(msg):
            with lock:
                latest.update({kv.key: float(kv.value) for kv in msg.values})

        def on_image(kind):
            return lambda msg: stamps[kind].append(msg.header.stamp.to_sec())

        rospy.Subscriber("demo_monitor/stats", DiagnosticStatus, on_stats)
        rospy.Subscriber("camera/image_raw", Image, on_image("on"), queue_size=20)
        rospy.Subscriber("camera/image_ambient", Image, on_image("off"), queue_size=20)
        rospy.Subscriber("sim/ground_truth/spots", CentroidArray, on_image("lit"), queue_size=100)
        deadline = time.time() + 200.0  # the monitor locks its own reference
        while time.time() < deadline:
            with lock:
                if latest.get("pose_compared", 0) >= frames:
                    break
            time.sleep(0.5)
        with lock:
            s = dict(latest)
        on, off = sorted(stamps["on"]), sorted(stamps["off"])
        print("[ MEASURE ] strobe_sim: %s" % ", ".join("%s=%.4g" % kv for kv in sorted(s.items())))
        self.assertGreaterEqual(s.get("pose_compared", 0), frames, "too few pose deltas compared: %s" % s)

        # The demux against the truth, once its vote settled (and the frames
        # still in flight at the end left out).
        lit = set(stamps["lit"])
        start, end = sorted(on + off)[SETTLE], max(stamps["lit"]) - 0.5
        on_late = [t for t in on if start <= t <= end]
        off_late = [t for t in off if start <= t <= end]
        misrouted = sum(t not in lit for t in on_late) + sum(t in lit for t in off_late)
        print("[ MEASURE ] demux: %d projector-on and %d ambient frames, %d misrouted after the first %d"
              % (len(on), len(off), misrouted, SETTLE))
        self.assertGreater(len(on_late), frames / 2)
        self.assertGreater(len(off_late), frames / 2)
        self.assertEqual(misrouted, 0, "frames routed to the wrong topic after the phase settled")

        self.assertGreaterEqual(s["recall"], 0.995)
        self.assertLessEqual(s["depth_rms_percent"], 0.1)
        self.assertGreaterEqual(s["pose_valid_fraction"], 0.95)
        self.assertLessEqual(s["translation_rms_mm"], 0.5)
        self.assertLessEqual(s["rotation_rms_deg"], 0.02)


if __name__ == "__main__":
    rostest.rosrun("structured_light_stabilizer", "strobe_sim", StrobeSim)
