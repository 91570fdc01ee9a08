#!/usr/bin/env python3
"""Checker for bad_camera_info_files.test: loads one simulator CameraDriver
per malformed camera_info YAML (~camera_info_url) into the manager and
asserts for each: the load succeeds and the manager stays alive, an ERROR on
/rosout names the file, and the camera_info published is the simulator's own
(1024 x 1024, finite positive focal length): the bad file is refused and the
last good intrinsics stay in force."""
import math
import threading
import time
import unittest

import rospy
import rostest
from nodelet.srv import NodeletList, NodeletLoad
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo

PKG = "structured_light_stabilizer"
SIM_FOCAL_PX = 12.14e-3 / 12e-6  # the study's design camera, the simulator's default


class BadCameraInfoFiles(unittest.TestCase):
    def test_each_file_refused(self):
        rospy.init_node("check_bad_camera_info_files")
        cases = rospy.get_param("~cases").split()
        lock = threading.Lock()
        logs, infos = [], {}

        def on_log(msg):
            with lock:
                logs.append((msg.level, msg.name, msg.msg))
        rospy.Subscriber("/rosout", Log, on_log, queue_size=1000)
        subs = []
        for case in cases:
            def on_info(msg, case=case):
                with lock:
                    infos[case] = msg
            subs.append(rospy.Subscriber(case + "/camera/camera_info", CameraInfo, on_info, queue_size=1))
        rospy.wait_for_service("/manager/load_nodelet", 30)
        load = rospy.ServiceProxy("/manager/load_nodelet", NodeletLoad)
        listing = rospy.ServiceProxy("/manager/list", NodeletList)
        time.sleep(1.0)  # the /rosout subscription connects
        for case in cases:
            ok = load(name="/%s/camera_driver" % case, type="structured_light_stabilizer/CameraDriver",
                      remap_source_args=[], remap_target_args=[], my_argv=[], bond_id="").success
            self.assertTrue(ok, case + ": the CameraDriver did not load")
        deadline = time.time() + 30
        while time.time() < deadline:
            with lock:
                if len(infos) == len(cases):
                    break
            time.sleep(0.1)
        self.assertEqual(len(listing().nodelets), len(cases), "the manager lost nodelets")
        failures = []
        for case in cases:
            fname = "camera_info_%s.yaml" % case
            with lock:
                errors = [t for (lvl, name, t) in logs if lvl >= Log.ERROR and name == "/manager" and fname in t]
                info = infos.get(case)
            if not errors:
                failures.append("%s: no ERROR naming the file" % fname)
            else:
                print("[ MEASURE ] %s -> %s" % (fname, errors[0]))
            if info is None:
                failures.append("%s: no camera_info published (the driver stopped)" % fname)
                continue
            fx = info.K[0]
            print("[ MEASURE ] %s: camera_info published %dx%d, fx %.2f px" % (fname, info.width, info.height, fx))
            if (info.width, info.height) != (1024, 1024) or not math.isfinite(fx) or abs(fx - SIM_FOCAL_PX) > 1.0:
                failures.append("%s: camera_info %dx%d fx %r is not the simulator's own" % (fname, info.width,
                                                                                            info.height, fx))
        self.assertEqual(failures, [])


if __name__ == "__main__":
    rostest.rosrun(PKG, "bad_camera_info_files", BadCameraInfoFiles)
