#!/usr/bin/env python3
"""Drives calibrate.launch like an operator: board at 1.0 m, capture, board
at 2.0 m, capture; then checks the report (no poor beam) and the written
YAML against the true rays (direction error, distance of the ray from the
true origin)."""
import math
import os
import time
import unittest

import rospy
import rostest
import yaml
from std_msgs.msg import String
from std_srvs.srv import Trigger


def unit(v):
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def line_distance(p, origin, direction):
    d = [p[i] - origin[i] for i in range(3)]
    t = sum(d[i] * direction[i] for i in range(3))
    return math.sqrt(sum((d[i] - t * direction[i]) ** 2 for i in range(3)))


class ProjectorCalibratorTest(unittest.TestCase):
    def test_two_boards(self):
        truth_path = rospy.get_param("~truth")
        output = rospy.get_param("~output")
        if os.path.exists(output):
            os.remove(output)
        reports = []
        rospy.Subscriber("/projector_calibrator/report", String, lambda m: reports.append(m.data))
        rospy.wait_for_service("/projector_calibrator/capture", timeout=30)
        capture = rospy.ServiceProxy("/projector_calibrator/capture", Trigger)
        for distance in (1.0, 2.0):
            rospy.set_param("/synthetic_spots/distance", distance)
            time.sleep(1.5)  # the board has moved: let the old frames pass
            res = capture()
            self.assertTrue(res.success, res.message)
            time.sleep(2.0)  # 5 frames at 10 Hz
        deadline = time.time() + 20
        while not reports and time.time() < deadline:
            time.sleep(0.1)
        self.assertTrue(reports, "no report published")
        print("[ MEASURE ] report: " + reports[-1].replace("\n", " | "))
        self.assertIn("0 poor beam", reports[-1])
        self.assertTrue(os.path.exists(output), "calibration YAML not written")
        with open(truth_path) as f:
            truth = yaml.safe_load(f)
        with open(output) as f:
            fitted = yaml.safe_load(f)
        self.assertEqual(fitted["rows"], truth["rows"])
        self.assertEqual(fitted["cols"], truth["cols"])
        worst_angle = 0.0
        worst_origin = 0.0
        for t, g in zip(truth["beams"], fitted["beams"]):
            dt, dg = unit(t["direction"]), unit(g["direction"])
            worst_angle = max(worst_angle, math.acos(min(1.0, sum(a * b for a, b in zip(dt, dg)))))
            worst_origin = max(worst_origin, line_distance(t["origin"], g["origin"], dg))
        print("[ MEASURE ] worst beam direction error %.1f urad, worst distance of a fitted ray from the true "
              "origin %.3f mm" % (worst_angle * 1e6, worst_origin * 1e3))
        # 0.05 px centroid noise over boards 1 m apart: ~1e-4 rad.
        self.assertLess(worst_angle, 1e-3)
        self.assertLess(worst_origin, 2e-3)


if __name__ == "__main__":
    rospy.init_node("check_projector_calibrator")
    rostest.rosrun("structured_light_stabilizer", "projector_calibrator", ProjectorCalibratorTest)
