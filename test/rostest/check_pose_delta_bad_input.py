#!/usr/bin/env python3
"""PoseDelta bad input (pose_delta_bad_input.test): every bad cloud gives a
pose_delta with valid = false and a status naming the problem, the lock
service refuses while no map has arrived, and the node keeps working. With
the texture on, images that cannot be read (truncated data, an odd step for
16 bits, an encoding cv_bridge does not know, a truncated frame of an
encoding to convert) are refused with an ERROR that
says why, and each cloud still gets its pose_delta from the geometry. With
the texture on and no image ever, the lock waits 2 s of stamps for one, then
takes the geometry alone."""
import math
import os
import sys
import threading
import time
import unittest

import rospy
import rostest
from sensor_msgs import point_cloud2
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from structured_light_stabilizer.msg import PoseDelta

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from sample_msgs import camera_info  # noqa: E402

PKG = "structured_light_stabilizer"
FIELDS = [PointField("x", 0, PointField.FLOAT32, 1), PointField("y", 4, PointField.FLOAT32, 1),
          PointField("z", 8, PointField.FLOAT32, 1), PointField("intensity", 12, PointField.FLOAT32, 1),
          PointField("beam", 16, PointField.UINT32, 1)]


def rock_points(rows=10, cols=10):
    """An organised grid of points on a rough analytic surface 1.5 m away."""
    pts = []
    for r in range(rows):
        for c in range(cols):
            x, y = (c - 4.5) * 0.055, (r - 4.5) * 0.055
            z = 1.5 + 0.04 * math.sin(6 * x) + 0.03 * math.cos(5 * y) + 0.02 * math.sin(9 * (x + y))
            pts.append([x, y, z])
    return pts


def cloud(points, rows, cols, fields=FIELDS, stamp=None):
    header = Header(frame_id="camera_optical_frame", stamp=stamp or rospy.Time.now())
    data = [p + [1.0, i] for i, p in enumerate(points)] if len(fields) == 5 else points
    msg = point_cloud2.create_cloud(header, fields, data)
    msg.height, msg.width = rows, cols
    msg.row_step = msg.point_step * cols
    msg.is_dense = False
    return msg


def image(stamp, width, height, encoding, step, data):
    msg = Image()
    msg.header.frame_id, msg.header.stamp = "camera_optical_frame", stamp
    msg.width, msg.height, msg.encoding, msg.step, msg.data = width, height, encoding, step, data
    return msg


class PoseDeltaBadInput(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_pose_delta_bad_input")
        cls.lock = threading.Lock()
        cls.received = {}
        rospy.Subscriber("pose_delta", PoseDelta, cls._on_pose, queue_size=20)
        cls.pub = rospy.Publisher("points", PointCloud2, queue_size=5)
        rospy.wait_for_service("pose_delta/lock", 20.0)
        cls.lock_srv = rospy.ServiceProxy("pose_delta/lock", Trigger)
        deadline = time.time() + 20.0
        while cls.pub.get_num_connections() == 0 and time.time() < deadline:
            time.sleep(0.1)

    @classmethod
    def _on_pose(cls, msg):
        with cls.lock:
            cls.received[msg.header.stamp] = msg

    def send(self, msg):
        self.pub.publish(msg)
        deadline = time.time() + 5.0
        while time.time() < deadline:
            with self.lock:
                if msg.header.stamp in self.received:
                    return self.received[msg.header.stamp]
            time.sleep(0.05)
        self.fail("no pose_delta for the cloud stamped %.3f" % msg.header.stamp.to_sec())

    def test_sequence(self):
        good = rock_points()
        nan = [float("nan")] * 3
        # No map yet: the lock request is refused with the reason.
        res = self.lock_srv()
        self.assertFalse(res.success)
        self.assertIn("no map has arrived", res.message)
        print("lock before any map: %s" % res.message)

        # A good map, but no lock requested (~auto_lock false).
        out = self.send(cloud(good, 10, 10))
        self.assertFalse(out.valid)
        self.assertIn("no reference locked", out.status)

        res = self.lock_srv()
        self.assertTrue(res.success, res.message)
        out = self.send(cloud(good, 10, 10))
        self.assertTrue(out.valid, out.status)
        self.assertIn("reference locked", out.status)

        cases = [
            ("all NaN", cloud([nan] * 100, 10, 10), "all NaN"),
            ("too few", cloud(good[:5] + [nan] * 95, 10, 10), "too few points"),
            ("other layout", cloud(good, 5, 20), "differs from the reference"),
            ("empty", cloud([], 0, 0), "bad points cloud"),
            ("no xyz", cloud([[1.0, 2.0]] * 100, 10, 10,
                             [PointField("a", 0, PointField.FLOAT32, 1), PointField("b", 4, PointField.FLOAT32, 1)]),
             "lacks float32 x, y, z"),
            ("another rock", cloud([[p[0], p[1], 1.0 + 0.5 * p[0]] for p in good], 10, 10), "residual"),
        ]
        for name, msg, expected in cases:
            out = self.send(msg)
            print("%s: valid=%s status=%s" % (name, out.valid, out.status))
            self.assertFalse(out.valid, name)
            self.assertIn(expected, out.status, name)

        # Still alive and still locked on the same reference.
        out = self.send(cloud(good, 10, 10))
        self.assertTrue(out.valid, out.status)
        self.assertLess(abs(out.transform.translation.x) + abs(out.transform.translation.y) +
                        abs(out.transform.translation.z), 1e-6)

    def test_unreadable_images_with_the_texture_on(self):
        errors, poses, lock = [], {}, threading.Lock()

        def on_log(msg):
            if msg.level >= Log.ERROR and "PoseDelta" in msg.msg:
                with lock:
                    errors.append(msg.msg)

        def on_pose(msg):
            with lock:
                poses[msg.header.stamp] = msg

        log_sub = rospy.Subscriber("/rosout", Log, on_log, queue_size=50)
        rospy.Subscriber("textured/pose_delta", PoseDelta, on_pose, queue_size=20)
        pub_cloud = rospy.Publisher("textured/points", PointCloud2, queue_size=5)
        pub_image = rospy.Publisher("textured/camera/image_raw", Image, queue_size=5)
        pub_info = rospy.Publisher("textured/camera/camera_info", CameraInfo, queue_size=5)
        deadline = time.time() + 20.0
        while time.time() < deadline and not (pub_cloud.get_num_connections() and pub_image.get_num_connections()
                                              and pub_info.get_num_connections() and log_sub.get_num_connections()):
            time.sleep(0.1)
        self.assertTrue(pub_image.get_num_connections(), "the textured PoseDelta did not subscribe to its images")
        w, h = 64, 48
        cases = [
            ("truncated bgr16", "bgr16", w * 6, bytes(w * 6 * (h - 1)), "truncated"),
            ("odd step bgr16", "bgr16", w * 6 + 1, bytes((w * 6 + 1) * h), "odd step"),
            ("short step bgr8", "bgr8", w * 3 - 1, bytes(w * 3 * h), "step"),
            ("unknown encoding", "no_such_encoding", w, bytes(w * h), "texture"),
            # cv_bridge refuses it: "height * step != size".
            ("truncated bayer_rggb8 (converted)", "bayer_rggb8", w, bytes(w * (h - 2)), "size"),
        ]
        good = rock_points()
        for name, encoding, step, data, fragment in cases:
            stamp = rospy.Time.now()
            with lock:
                del errors[:]
            info = camera_info(w, h, 0.8 * w)
            info.header.stamp = stamp
            pub_info.publish(info)
            pub_image.publish(image(stamp, w, h, encoding, step, data))
            time.sleep(0.2)
            pub_cloud.publish(cloud(good, 10, 10, stamp=stamp))
            deadline = time.time() + 5.0
            while time.time() < deadline:
                with lock:
                    if stamp in poses and any(fragment in e for e in errors):
                        break
                time.sleep(0.05)
            with lock:
                got, said = poses.get(stamp), list(errors)
            print("%s: pose_delta %s, errors %s" % (name, "received" if got else "missing", said))
            self.assertIsNotNone(got, "%s: no pose_delta for its cloud" % name)
            self.assertTrue(any(fragment in e for e in said), "%s: no ERROR naming '%s': %s" % (name, fragment, said))

    def test_the_lock_waits_two_seconds_of_stamps_for_an_image(self):
        # Clouds 50 ms apart (stamps), no image ever: the first 40 (10 frames or
        # 2 s, whichever is longer) wait for one; then the lock takes the
        # geometry alone. The last ~image_queue_size (5) clouds stay queued
        # for their images.
        poses, lock = [], threading.Lock()

        def on_pose(msg):
            with lock:
                poses.append(msg)

        rospy.Subscriber("waiting/pose_delta", PoseDelta, on_pose, queue_size=100)
        pub_cloud = rospy.Publisher("waiting/points", PointCloud2, queue_size=100)
        deadline = time.time() + 20.0
        while time.time() < deadline and not pub_cloud.get_num_connections():
            time.sleep(0.1)
        time.sleep(0.5)  # the pose_delta subscription
        good, t0 = rock_points(), rospy.Time.now()
        for k in range(60):
            pub_cloud.publish(cloud(good, 10, 10, stamp=t0 + rospy.Duration(0.05 * k)))
            time.sleep(0.03)
        deadline = time.time() + 10.0
        while time.time() < deadline:
            with lock:
                if len(poses) >= 55:
                    break
            time.sleep(0.05)
        with lock:
            got = sorted(poses, key=lambda m: m.header.stamp)
        waiting = [m for m in got if "lock waits for a frame with its image" in m.status]
        print("the lock waited %d of %d frames" % (len(waiting), len(got)))
        self.assertGreaterEqual(len(got), 50)
        self.assertEqual(len(waiting), 40, [m.status for m in got[38:42]])
        self.assertEqual(got[39].header.stamp, t0 + rospy.Duration(0.05 * 39))
        self.assertTrue(all("lock waits" not in m.status for m in got[40:]), [m.status for m in got[40:43]])


if __name__ == "__main__":
    rostest.rosrun(PKG, "pose_delta_bad_input", PoseDeltaBadInput)
