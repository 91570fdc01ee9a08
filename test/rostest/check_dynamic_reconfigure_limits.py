#!/usr/bin/env python3
"""Checker for dynamic_reconfigure_limits.test (issue 9).

For each dynamic_reconfigure server of the pipeline (camera_driver,
spot_detector, triangulator, pose_delta), enumerated from the server's own
description: every numeric parameter is set to its min, its max, min - 1 and
max * 10 + 1, and the value read back must lie in [min, max]; every enum
string parameter gets an invalid string, which must be refused or coerced
with a WARN, keeping the previous valid value; inconsistent pairs (h_min >
h_max, min_depth > max_depth, ...) must come back consistent with a WARN.
The manager must stay alive throughout. Afterwards the initial configuration
is restored and the pipeline, driven by the simulator, must again produce
correct points (depth vs sim/ground_truth/points) and valid pose deltas:
the last good configuration is in force."""
import math
import os
import threading
import time
import unittest
import xmlrpc.client

import numpy as np
import rosgraph
import rosnode
import rospy
import rostest
from dynamic_reconfigure.client import Client
from nodelet.srv import NodeletList
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import PointCloud2

from structured_light_stabilizer.msg import PoseDelta
from structured_light_stabilizer.evaluation import cloud_xyz

PKG = "structured_light_stabilizer"
SERVERS = ("camera_driver", "spot_detector", "triangulator", "pose_delta")
# (server, {param: value}, [(lower, upper)] that must hold after, words one of which the WARN contains)
INCONSISTENT = [
    ("spot_detector", {"h_min": 120, "h_max": 40}, [("h_min", "h_max")], ("h_min", "swap")),
    ("spot_detector", {"s_min": 200, "s_max": 100}, [("s_min", "s_max")], ("s_min", "swap")),
    ("spot_detector", {"v_min": 220, "v_max": 60}, [("v_min", "v_max")], ("v_min", "swap")),
    ("spot_detector", {"min_area": 500, "max_area": 100}, [("min_area", "max_area")], ("area", "swap")),
    ("spot_detector", {"min_sigma_px": 9.0, "max_sigma_px": 2.0}, [("min_sigma_px", "max_sigma_px")],
     ("sigma", "swap")),
    ("spot_detector", {"blur_kernel": 4}, [], ("blur_kernel", "odd")),
    ("triangulator", {"min_depth": 3.0, "max_depth": 1.0}, [("min_depth", "max_depth")], ("min_depth", "swap")),
    ("triangulator", {"min_depth": 2.0, "max_depth": 2.0}, [("min_depth", "max_depth")], ("min_depth", "swap")),
    ("pose_delta", {"texture_min_features": 500, "texture_max_features": 100},
     [("texture_min_features", "texture_max_features")], ("texture_min_features",)),
    ("pose_delta", {"texture_window_px": 10}, [], ("texture_window_px", "odd")),
]


class DynamicReconfigureLimits(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_dynamic_reconfigure_limits")
        cls.lock = threading.Lock()
        cls.manager = rospy.get_param("~manager", "/stabilizer_manager")
        cls.logs = []
        cls.points, cls.gt_points, cls.poses = {}, {}, {}
        rospy.Subscriber("/rosout", Log, cls.on_log, queue_size=1000)
        rospy.Subscriber("points", PointCloud2, cls.keep(cls.points), queue_size=20)
        rospy.Subscriber("sim/ground_truth/points", PointCloud2, cls.keep(cls.gt_points), queue_size=20)
        rospy.Subscriber("pose_delta", PoseDelta, cls.keep(cls.poses), queue_size=20)
        cls.clients = {name: Client(name, timeout=60) for name in SERVERS}
        cls.initial = {name: c.get_configuration(timeout=10) for name, c in cls.clients.items()}
        rospy.ServiceProxy(cls.manager + "/list", NodeletList).wait_for_service(30)
        api = rosnode.get_api_uri(rosgraph.Master(rospy.get_name()), cls.manager, skip_cache=True)
        cls.manager_pid = xmlrpc.client.ServerProxy(api).getPid(rospy.get_name())[2]

    @classmethod
    def on_log(cls, msg):
        with cls.lock:
            cls.logs.append((msg.level, msg.name, msg.msg))

    @classmethod
    def keep(cls, store):
        def cb(msg):
            with cls.lock:
                store[msg.header.stamp] = msg
        return cb

    def manager_alive(self):
        os.kill(type(self).manager_pid, 0)  # raises if the process is gone
        names = rospy.ServiceProxy(self.manager + "/list", NodeletList)().nodelets
        self.assertEqual(len(names), 4, "nodelets in the manager: %s" % names)

    def wait_warn(self, mark, words, timeout=2.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                for level, name, text in self.logs[mark:]:
                    if level >= Log.WARN and name == self.manager and any(w in text for w in words):
                        return text
            time.sleep(0.02)
        return None

    def depth_check(self, label, seconds=4.0):
        """Depth error of the points published in the next `seconds` vs the
        ground truth of the same frames; returns (frames, beams, RMS %, valid)."""
        start = rospy.Time.now()
        time.sleep(seconds)
        with self.lock:
            stamps = [s for s in self.points if s > start and s in self.gt_points]
            pairs = [(self.points[s], self.gt_points[s]) for s in stamps]
            poses = [p for s, p in self.poses.items() if s > start]
        sq, n, beams_true = 0.0, 0, 0
        for est_msg, gt_msg in pairs:
            est, gt = cloud_xyz(est_msg), cloud_xyz(gt_msg)
            ok = np.isfinite(est).all(axis=1) & np.isfinite(gt).all(axis=1)
            beams_true += int(np.isfinite(gt).all(axis=1).sum())
            sq += float(np.sum(((est[ok, 2] - gt[ok, 2]) / gt[ok, 2]) ** 2))
            n += int(ok.sum())
        rms = 100.0 * math.sqrt(sq / n) if n else float("nan")
        valid = sum(p.valid for p in poses)
        print("[ MEASURE ] %s: %d frames, beams %d/%d, depth RMS %.4f %%, pose_delta %d/%d valid"
              % (label, len(pairs), n, beams_true, rms, valid, len(poses)))
        return len(pairs), n, beams_true, rms, valid, len(poses)

    def test_1_baseline_before(self):
        frames, n, beams_true, rms, valid, poses = self.depth_check("initial configuration")
        self.assertGreaterEqual(frames, 5)
        self.assertGreaterEqual(n, 0.85 * beams_true)
        self.assertLess(rms, 0.1)

    def test_2_numeric_limits(self):
        checked = 0
        for name, client in self.clients.items():
            for d in client.get_parameter_descriptions(timeout=10):
                if d["type"] not in ("int", "double"):
                    continue
                pname, lo, hi = d["name"], d["min"], d["max"]
                cast = int if d["type"] == "int" else float
                before = client.get_configuration(timeout=10)[pname]
                for value in (lo, hi, lo - 1, hi * 10 + 1):
                    got = client.update_configuration({pname: cast(value)})[pname]
                    self.assertTrue(lo <= got <= hi, "%s/%s set to %r read back %r outside [%r, %r]"
                                    % (name, pname, value, got, lo, hi))
                    checked += 1
                client.update_configuration({pname: before})
            self.manager_alive()
        print("[ MEASURE ] %d numeric settings at and beyond the limits, all read back inside [min, max]" % checked)
        self.assertGreater(checked, 4 * 40)

    def test_3_invalid_enum_strings(self):
        checked = 0
        for name, client in self.clients.items():
            for d in client.get_parameter_descriptions(timeout=10):
                if d["type"] != "str" or not d["edit_method"]:
                    continue
                pname = d["name"]
                values = [c["value"] for c in eval(d["edit_method"])["enum"]]  # description from the server
                # Start from a valid value other than the default, so that
                # "previous kept" cannot pass by falling back to the default.
                previous = [v for v in values if v != d["default"]][0]
                self.assertEqual(client.update_configuration({pname: previous})[pname], previous)
                for bad in ("bogus", "", "FAST ", "baseline; rm -rf /", "\u00e9\u00e8"):
                    mark = len(self.logs)
                    got = client.update_configuration({pname: bad})[pname]
                    self.assertEqual(got, previous, "%s/%s = %r: read back %r, not the previous %r"
                                     % (name, pname, bad, got, previous))
                    # The WARN names the value it refused (non-ASCII text
                    # reaches the server as '?'s, so only "unknown" there).
                    text = self.wait_warn(mark, ("'%s'" % bad,) if bad.isascii() else ("unknown",))
                    self.assertIsNotNone(text, "%s/%s = %r refused without a warning" % (name, pname, bad))
                    checked += 1
                print("[ MEASURE ] %s/%s: invalid strings refused, '%s' kept; e.g. \"%s\"" % (name, pname, previous,
                                                                                             text))
                client.update_configuration({pname: self.initial[name][pname]})
        self.manager_alive()
        self.assertGreaterEqual(checked, 3 * 5)

    def test_4_inconsistent_combinations(self):
        for name, changes, pairs, words in INCONSISTENT:
            client = self.clients[name]
            before = client.get_configuration(timeout=10)
            mark = len(self.logs)
            got = client.update_configuration(dict(changes))
            for lower, upper in pairs:
                self.assertLessEqual(got[lower], got[upper], "%s %s: %s %r > %s %r after validation"
                                     % (name, changes, lower, got[lower], upper, got[upper]))
                if lower == "min_depth":
                    self.assertLess(got[lower], got[upper])
            if "blur_kernel" in changes or "texture_window_px" in changes:
                key = list(changes)[0]
                self.assertEqual(got[key] % 2, 1, "%s %s: even kernel kept" % (name, changes))
            text = self.wait_warn(mark, words)
            self.assertIsNotNone(text, "%s %s: corrected without a warning naming it" % (name, changes))
            print("[ MEASURE ] %s %s -> %s; \"%s\"" % (name, changes, {k: got[k] for k in changes}, text))
            client.update_configuration({k: before[k] for k in changes})
        self.manager_alive()

    def test_5_restored_configuration_in_force(self):
        for name, client in self.clients.items():
            initial = {k: v for k, v in self.initial[name].items() if k != "groups"}
            got = client.update_configuration(initial)
            for k, v in initial.items():
                if isinstance(v, float):
                    self.assertAlmostEqual(got[k], v, places=9, msg="%s/%s not restored" % (name, k))
                else:
                    self.assertEqual(got[k], v, "%s/%s not restored" % (name, k))
        self.manager_alive()
        # The simulator's rate may have been at its minimum (0.1 Hz) for one
        # period: give the stream time to come back.
        deadline = time.time() + 15.0
        while time.time() < deadline:
            with self.lock:
                recent = [s for s in self.points if (rospy.Time.now() - s).to_sec() < 1.0]
            if recent:
                break
            time.sleep(0.2)
        frames, n, beams_true, rms, valid, poses = self.depth_check("restored configuration")
        self.assertGreaterEqual(frames, 5, "points no longer published after restoring the configuration")
        self.assertGreaterEqual(n, 0.85 * beams_true, "fewer than 85 % of the beams triangulated")
        self.assertLess(rms, 0.1, "depth RMS vs truth above 0.1 %")
        self.assertGreater(valid, 0.5 * poses, "pose_delta mostly invalid after restoring the configuration")


if __name__ == "__main__":
    rostest.rosrun(PKG, "dynamic_reconfigure_limits", DynamicReconfigureLimits)
