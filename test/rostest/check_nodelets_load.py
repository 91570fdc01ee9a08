#!/usr/bin/env python3
"""Checks that the manager loaded all eight nodelets (the four of the pipeline,
the StabilizationController, the StrobeDemux, the ProjectorCalibrator and the
benchmark's LatencyProbe) without an error, that its
services answer, that each standalone node is up, and that rosmsg knows the
package's three messages with exactly the fields of docs/interface.md."""
import subprocess
import time
import unittest

import rosgraph
import rosnode
import rospy
import rostest
from nodelet.srv import NodeletList
from rosgraph_msgs.msg import Log

PKG = "structured_light_stabilizer"
NODELETS = ["/camera_driver", "/spot_detector", "/triangulator", "/pose_delta", "/stabilization_controller",
            "/strobe_demux", "/projector_calibrator", "/latency_probe"]
STANDALONE = ["/standalone/" + n.strip("/") for n in NODELETS]

EXPECTED_FIELDS = {
    "Centroid": ["float64 x", "float64 y", "float32 area", "float32 intensity", "int32 beam"],
    "CentroidArray": ["std_msgs/Header header", "uint32 image_width", "uint32 image_height",
                      "Centroid[] centroids"],
    "PoseDelta": ["std_msgs/Header header", "geometry_msgs/Transform transform", "float64[36] covariance",
                  "float64 rms_residual", "uint32 points_used", "bool valid", "string status"],
}


class NodeletsLoad(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_nodelets_load")
        cls.errors = []
        rospy.Subscriber("/rosout_agg", Log, cls._on_log, queue_size=100)

    @classmethod
    def _on_log(cls, msg):
        if msg.level >= Log.ERROR:
            cls.errors.append("%s: %s" % (msg.name, msg.msg))

    def test_manager_loads_all_eight(self):
        rospy.wait_for_service("/manager/list", timeout=30.0)
        listing = rospy.ServiceProxy("/manager/list", NodeletList)
        deadline = time.time() + 30.0
        loaded = []
        while time.time() < deadline:
            loaded = listing().nodelets
            if all(n in loaded for n in NODELETS):
                break
            time.sleep(0.5)
        self.assertEqual(sorted(loaded), sorted(NODELETS))
        time.sleep(2.0)  # let start-up messages reach rosout_agg
        self.assertEqual(self.errors, [], "errors logged while loading: %s" % self.errors)

    def test_standalone_nodes_run(self):
        deadline = time.time() + 30.0
        alive = []
        while time.time() < deadline:
            alive = [n for n in STANDALONE if n in rosnode.get_node_names()]
            if len(alive) == len(STANDALONE):
                break
            time.sleep(0.5)
        self.assertEqual(sorted(alive), sorted(STANDALONE))
        master = rosgraph.Master("/check_nodelets_load")
        for node in STANDALONE:
            self.assertTrue(rosnode.rosnode_ping(node, max_count=1), "%s does not answer" % node)
            # Every node answers its logger services, proof its callbacks spin.
            self.assertTrue(master.lookupService(node + "/get_loggers"))

    def test_rosmsg_shows_messages(self):
        for name, fields in EXPECTED_FIELDS.items():
            out = subprocess.run(["rosmsg", "show", "-r", "%s/%s" % (PKG, name)],
                                 capture_output=True, text=True, timeout=30)
            self.assertEqual(out.returncode, 0, out.stderr)
            lines = [l.split("#")[0].strip() for l in out.stdout.splitlines()]
            lines = [" ".join(l.split()) for l in lines if l]
            self.assertEqual(lines, fields, "rosmsg show %s" % name)


if __name__ == "__main__":
    rostest.rosrun(PKG, "nodelets_load", NodeletsLoad)
