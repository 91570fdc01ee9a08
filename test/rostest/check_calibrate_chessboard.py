#!/usr/bin/env python3
"""Drives calibrate.launch in chessboard mode like an operator: a capture
every 2 s (plus the analysis) while the simulated rig drifts towards the tilted board, until
six views are taken; then checks the report (one centre of projection, every
view used) and the written YAML against the simulator's exact rays at
1.5 m (<= 0.5 mm RMS)."""
import math
import os
import time
import unittest

import rospy
import rostest
import yaml
from std_msgs.msg import String
from std_srvs.srv import Trigger


def point_at(beam, z):
    o, d = beam["origin"], beam["direction"]
    s = (z - o[2]) / d[2]
    return [o[i] + s * d[i] for i in range(3)]


class CalibrateChessboardTest(unittest.TestCase):
    def test_six_views(self):
        truth_path = rospy.get_param("~truth")
        output = rospy.get_param("~output")
        png = os.path.splitext(output)[0] + ".png"
        for f in (output, png):
            if os.path.exists(f):
                os.remove(f)
        reports = []
        rospy.Subscriber("/projector_calibrator/report", String, lambda m: reports.append(m.data))
        rospy.wait_for_service("/projector_calibrator/capture", timeout=30)
        capture = rospy.ServiceProxy("/projector_calibrator/capture", Trigger)
        taken = 0
        deadline = time.time() + 150
        # The rig drifts on in real time (1.6 m to about 1.25 m over 18 s,
        # config/sim_chessboard.yaml) and each capture's analysis takes 2-4 s
        # on a loaded machine: with 2 s between captures the sixth came at
        # about 28 s, with the board leaving the view (one CI run had only
        # four board views before it was gone). 0.5 s between captures.
        while taken < 6 and time.time() < deadline:
            time.sleep(0.5)
            res = capture()
            print("capture: %s %s" % (res.success, res.message))
            taken += 1 if res.success else 0
        self.assertEqual(taken, 6, "six views were not captured")
        deadline = time.time() + 30
        while not reports and time.time() < deadline:
            time.sleep(0.2)
        self.assertTrue(reports, "no report published")
        report = reports[-1]
        print(report)
        self.assertIn("model: central", report)
        self.assertIn("6 of 6 views used", report)
        self.assertTrue(os.path.exists(output), "calibration YAML not written")
        self.assertTrue(os.path.exists(png), "PNG report not written")
        with open(truth_path) as f:
            truth = yaml.safe_load(f)
        with open(output) as f:
            fitted = yaml.safe_load(f)
        self.assertEqual((fitted["rows"], fitted["cols"]), (truth["rows"], truth["cols"]))
        sum2, worst = 0.0, 0.0
        for t, g in zip(truth["beams"], fitted["beams"]):
            e = math.dist(point_at(t, 1.5), point_at(g, 1.5))
            sum2 += e * e
            worst = max(worst, e)
        rms = math.sqrt(sum2 / len(truth["beams"]))
        print("[ MEASURE ] calibrate.launch chessboard mode, 6 simulated views: rays at 1.5 m %.3f mm RMS, "
              "worst %.3f mm" % (rms * 1e3, worst * 1e3))
        self.assertLess(rms, 0.5e-3)


if __name__ == "__main__":
    rospy.init_node("check_calibrate_chessboard")
    rostest.rosrun("structured_light_stabilizer", "calibrate_chessboard", CalibrateChessboardTest)
