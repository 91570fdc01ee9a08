#!/usr/bin/env python3
"""PoseDelta's standard outputs (pose_delta_outputs.test).

Relays sim/ground_truth/points to relayed/points (PoseDelta's input), every
fourth cloud replaced by an all-NaN cloud of the same header ("sabotaged":
its estimate cannot be valid). Then:
  1. without any subscriber to pose_delta or pose_delta/pose, for 10 s: the
     tf camera_optical_frame -> camera_optical_frame_reference flows (at
     least half of the usable clouds), never for a sabotaged stamp, never
     twice with one stamp;
  2. `rostopic type pose_delta/pose` is geometry_msgs/PoseWithCovarianceStamped;
  3. subscribed to both pose topics for 10 s: pose_delta/pose and the tf come
     exactly for the valid pose_delta messages; the pose is the inverse of
     the PoseDelta transform (the current camera in the reference frame,
     frame camera_optical_frame_reference); its covariance is the PoseDelta
     covariance carried to that frame, C' = J C J^T, J = -diag(R^T, R^T)
     (recomputed here with numpy); the tf transform is the PoseDelta's.
"""
import math
import subprocess
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import PointCloud2
from structured_light_stabilizer.evaluation import transform_matrix
from structured_light_stabilizer.msg import PoseDelta
from tf2_msgs.msg import TFMessage

PKG = "structured_light_stabilizer"
FRAME = "camera_optical_frame"


def nan_cloud(msg):
    """The same cloud with every float32 field NaN (beam ids kept)."""
    out = PointCloud2(header=msg.header, height=msg.height, width=msg.width, fields=msg.fields,
                      is_bigendian=msg.is_bigendian, point_step=msg.point_step, row_step=msg.row_step,
                      is_dense=False)
    data = bytearray(msg.data)
    nan = np.array([np.nan], dtype=np.float32).tobytes()
    for f in msg.fields:
        if f.datatype == 7:  # FLOAT32
            for k in range(msg.width * msg.height):
                o = k * msg.point_step + f.offset
                data[o:o + 4] = nan
    out.data = bytes(data)
    return out


def pose_matrix(p):
    class T:
        pass
    t = T()
    t.translation, t.rotation = p.position, p.orientation
    return transform_matrix(t)


class PoseDeltaOutputs(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_pose_delta_outputs")
        cls.lock = threading.Lock()
        cls.count = 0
        cls.good, cls.sabotaged = set(), set()
        cls.tf = []  # (stamp, transform) of FRAME -> FRAME_reference, in arrival order
        cls.pub = rospy.Publisher("relayed/points", PointCloud2, queue_size=10)
        rospy.Subscriber("sim/ground_truth/points", PointCloud2, cls._relay, queue_size=10)
        rospy.Subscriber("/tf", TFMessage, cls._on_tf, queue_size=100)

    @classmethod
    def _relay(cls, msg):
        with cls.lock:
            cls.count += 1
            bad = cls.count % 4 == 0
            (cls.sabotaged if bad else cls.good).add(msg.header.stamp)
        cls.pub.publish(nan_cloud(msg) if bad else msg)

    @classmethod
    def _on_tf(cls, msg):
        with cls.lock:
            for t in msg.transforms:
                if t.header.frame_id == FRAME and t.child_frame_id == FRAME + "_reference":
                    cls.tf.append((t.header.stamp, t.transform))

    def tf_phase(self, seconds):
        with self.lock:
            start = len(self.tf)
        time.sleep(seconds)
        with self.lock:
            return self.tf[start:], set(self.good), set(self.sabotaged)

    def test_outputs(self):
        deadline = time.time() + 40.0
        while time.time() < deadline:
            with self.lock:
                if len(self.tf) >= 3:
                    break
            time.sleep(0.2)
        # 1. tf with no subscriber to a pose topic.
        tf, good, bad = self.tf_phase(10.0)
        stamps = [s for s, _ in tf]
        in_window = [s for s in good if stamps and stamps[0] <= s <= stamps[-1]]
        print("[ MEASURE ] no pose subscriber: %d tf in 10 s for %d usable clouds in that time; %d sabotaged "
              "clouds so far" % (len(tf), len(in_window), len(bad)))
        self.assertGreaterEqual(len(tf), 10, "the tf does not flow without a subscriber to a pose topic")
        self.assertGreaterEqual(len(tf), 0.5 * len(in_window))
        self.assertFalse(set(stamps) & bad, "tf sent for an unusable (invalid) cloud")
        self.assertEqual(len(stamps), len(set(stamps)), "tf sent twice with one stamp")

        # 2. rostopic type.
        kind = subprocess.check_output(["rostopic", "type", "pose_delta/pose"], timeout=30).decode().strip()
        self.assertEqual(kind, "geometry_msgs/PoseWithCovarianceStamped")

        # 3. both pose topics subscribed.
        deltas, poses = {}, {}
        s1 = rospy.Subscriber("pose_delta", PoseDelta, lambda m: deltas.__setitem__(m.header.stamp, m), queue_size=50)
        s2 = rospy.Subscriber("pose_delta/pose", PoseWithCovarianceStamped,
                              lambda m: poses.__setitem__(m.header.stamp, m), queue_size=50)
        tf, good, bad = self.tf_phase(10.0)
        s1.unregister()
        s2.unregister()
        time.sleep(0.5)
        tf_by_stamp = dict(tf)
        valid = {s for s, m in deltas.items() if m.valid}
        invalid = set(deltas) - valid
        print("[ MEASURE ] subscribed: %d pose_delta (%d valid, %d invalid, %d of them sabotaged), %d pose_delta/pose, "
              "%d tf" % (len(deltas), len(valid), len(invalid), len(invalid & bad), len(poses), len(tf)))
        self.assertGreaterEqual(len(valid), 10)
        self.assertTrue(invalid & bad, "no invalid estimate was seen: the test would prove nothing")
        self.assertFalse(valid & bad, "an all-NaN cloud gave a valid estimate")
        self.assertEqual(set(poses) & set(deltas), valid & set(poses))
        self.assertFalse(set(poses) & invalid, "pose_delta/pose published for an invalid estimate")
        self.assertFalse(set(tf_by_stamp) & invalid, "tf sent for an invalid estimate")
        # Every valid estimate but those at the edges of the window has its pose and tf.
        inner = sorted(valid)[2:-2]
        self.assertTrue(all(s in poses for s in inner), "a valid estimate without pose_delta/pose")
        self.assertTrue(all(s in tf_by_stamp for s in inner), "a valid estimate without tf")
        worst_pose = worst_cov = worst_tf = 0.0
        for s in inner:
            d, p = deltas[s], poses[s]
            self.assertEqual(p.header.frame_id, d.header.frame_id + "_reference")
            T = transform_matrix(d.transform)
            worst_pose = max(worst_pose, np.abs(pose_matrix(p.pose.pose) @ T - np.eye(4)).max())
            worst_tf = max(worst_tf, np.abs(transform_matrix(tf_by_stamp[s]) - T).max())
            C = np.array(d.covariance).reshape(6, 6)
            Rt = T[:3, :3].T
            J = -np.block([[Rt, np.zeros((3, 3))], [np.zeros((3, 3)), Rt]])
            expected = J @ C @ J.T
            got = np.array(p.pose.covariance).reshape(6, 6)
            scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected))) + 1e-30
            worst_cov = max(worst_cov, (np.abs(got - expected) / scale).max())
        print("[ MEASURE ] pose = PoseDelta^-1 within %.2g, covariance within %.2g (relative), tf = PoseDelta "
              "within %.2g" % (worst_pose, worst_cov, worst_tf))
        self.assertLess(worst_pose, 1e-6)
        self.assertLess(worst_cov, 1e-6)
        self.assertLess(worst_tf, 1e-6)


if __name__ == "__main__":
    rostest.rosrun(PKG, "pose_delta_outputs", PoseDeltaOutputs)
