#!/usr/bin/env python3
"""Checker for unload_shutdown.test (issue 9): nodelets unload cleanly while
data flows, and the manager shuts down in under 2 s.

The checker starts its own nodelet manager (a child process, so that its exit
can be timed exactly) and loads the four nodelets into it through the
manager's load_nodelet service, with the parameters the launch file set
(the CameraDriver on the simulator). Then, for each nodelet in turn, while
frames flow: unload it (the service must succeed, the manager stay alive and
~list no longer name it), load it again and check that spots, points and
pose_delta resume. Last, SIGINT to the manager: it must exit within 2 s,
with status 0 (the time is printed)."""
import os
import signal
import subprocess
import threading
import time
import unittest

import rospy
import rostest
from nodelet.srv import NodeletList, NodeletLoad, NodeletUnload
from sensor_msgs.msg import PointCloud2

from structured_light_stabilizer.msg import CentroidArray, PoseDelta

PKG = "structured_light_stabilizer"
MANAGER = "/unload_manager"
NODELETS = [("camera_driver", "structured_light_stabilizer/CameraDriver"),
            ("spot_detector", "structured_light_stabilizer/SpotDetector"),
            ("triangulator", "structured_light_stabilizer/Triangulator"),
            ("pose_delta", "structured_light_stabilizer/PoseDelta")]
SHUTDOWN_BOUND_S = 2.0


class UnloadShutdown(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_unload_shutdown")
        cls.lock = threading.Lock()
        cls.last = {}
        for topic, kind in (("spots", CentroidArray), ("points", PointCloud2), ("pose_delta", PoseDelta)):
            rospy.Subscriber(topic, kind, cls.stamp_of(topic), queue_size=5)
        cls.proc = subprocess.Popen(["rosrun", "nodelet", "nodelet", "manager", "__name:=" + MANAGER[1:],
                                     "_num_worker_threads:=4"])
        for srv in ("list", "load_nodelet", "unload_nodelet"):
            rospy.wait_for_service(MANAGER + "/" + srv, 30)
        cls.list = rospy.ServiceProxy(MANAGER + "/list", NodeletList)
        cls.load_srv = rospy.ServiceProxy(MANAGER + "/load_nodelet", NodeletLoad)
        cls.unload_srv = rospy.ServiceProxy(MANAGER + "/unload_nodelet", NodeletUnload)

    @classmethod
    def tearDownClass(cls):
        if cls.proc.poll() is None:
            cls.proc.kill()
            cls.proc.wait()

    @classmethod
    def stamp_of(cls, topic):
        def cb(msg):
            with cls.lock:
                cls.last[topic] = time.time()
        return cb

    def load(self, name, kind):
        t0 = time.time()
        ok = self.load_srv(name="/" + name, type=kind, remap_source_args=[], remap_target_args=[], my_argv=[],
                           bond_id="").success
        return ok, time.time() - t0

    def flowing(self, since, timeout=20.0):
        """True once spots, points and pose_delta have all arrived after `since`."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                if all(self.last.get(t, 0.0) > since for t in ("spots", "points", "pose_delta")):
                    return True
            time.sleep(0.05)
        return False

    def alive(self):
        self.assertIsNone(self.proc.poll(), "the manager died")
        return self.list().nodelets

    def test_unload_reload_then_sigint(self):
        for name, kind in NODELETS:
            ok, dt = self.load(name, kind)
            self.assertTrue(ok, "loading %s failed" % name)
        t0 = time.time()
        self.assertTrue(self.flowing(0.0, timeout=40.0), "the pipeline does not produce output")
        print("[ MEASURE ] output flowing %.1f s after loading" % (time.time() - t0))

        for name, kind in NODELETS:
            t0 = time.time()
            ok = self.unload_srv(name="/" + name).success
            unload_s = time.time() - t0
            self.assertTrue(ok, "unloading %s failed" % name)
            names = self.alive()
            self.assertNotIn("/" + name, names, "%s still listed after unloading" % name)
            time.sleep(0.5)  # the rest keeps running without it
            self.alive()
            ok, load_s = self.load(name, kind)
            self.assertTrue(ok, "reloading %s failed" % name)
            t1 = time.time()
            resumed = self.flowing(t1)
            print("[ MEASURE ] %s: unload %.3f s, reload %.3f s, output resumed %s after %.1f s"
                  % (name, unload_s, load_s, resumed, time.time() - t1))
            self.assertTrue(resumed, "output did not resume after reloading %s" % name)
        self.assertEqual(sorted(self.alive()), sorted("/" + n for n, _ in NODELETS))

        # All four at once, as roslaunch does on Ctrl-C: SIGINT to the manager.
        t0 = time.time()
        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            code = None
        took = time.time() - t0
        print("[ MEASURE ] manager exit after SIGINT: %.3f s (bound %.1f s), status %s" % (took, SHUTDOWN_BOUND_S, code))
        self.assertIsNotNone(code, "the manager hangs on SIGINT")
        self.assertEqual(code, 0, "the manager did not exit cleanly")
        self.assertLess(took, SHUTDOWN_BOUND_S, "the manager took too long to shut down")


if __name__ == "__main__":
    rostest.rosrun(PKG, "unload_shutdown", UnloadShutdown)
