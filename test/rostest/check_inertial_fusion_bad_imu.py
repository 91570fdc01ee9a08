#!/usr/bin/env python3
"""Checker for inertial_fusion_bad_imu.test: bad Imu messages through the
InertialFusion nodelet.

Good input: a still IMU in imu_link (zero rate, a constant specific force)
every 5 ms of stamp time, and every 8th sample a PoseDelta at that stamp
(identity, 0.1 mm / 0.1 mrad sigma; the first after 1.2 s carries the lock
phrase). Stamps are the checker's own timeline, sent faster than real time
with small pauses (the fusion works on stamps).

Bad input, between good samples, each with a stamp no good sample has:
NaN angular velocity, infinite linear acceleration, frame_id camera_link,
a stamp 0.1 s older than the last good one, and a burst of 30 NaN samples.

Asserted: no pose_fused carries a bad message's stamp (dropped); /rosout has
an ERROR naming each problem (NaN, the frame_id and ~imu_frame, the stamp
order), the burst said at most twice (throttled); the manager is the same
process, alive and answering ~list with the nodelet; every good sample after
the bad ones is answered, valid (fused)."""
import math
import threading
import time
import unittest
import xmlrpc.client

import rosgraph
import rosnode
import rospy
import rostest
from geometry_msgs.msg import Vector3
from nodelet.srv import NodeletList
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import Imu

from structured_light_stabilizer.msg import PoseDelta

DT = 0.005
CAMERA_EVERY = 8
LOCK_AFTER = 240  # samples: 1.2 s of gravity before the lock
LOCKED_PHRASE = "reference locked on this frame"


def imu_msg(stamp, frame="imu_link", w=(0.0, 0.0, 0.0), a=(0.0, 0.0, 3.711)):
    m = Imu()
    m.header.stamp = stamp
    m.header.frame_id = frame
    m.orientation_covariance[0] = -1.0
    m.angular_velocity = Vector3(*w)
    m.linear_acceleration = Vector3(*a)
    return m


def pose_msg(stamp, locked):
    m = PoseDelta()
    m.header.stamp = stamp
    m.header.frame_id = "camera_optical_frame"
    m.transform.rotation.w = 1.0
    m.covariance = [0.0] * 36
    for i in range(6):
        m.covariance[7 * i] = 1e-8
    m.valid = True
    m.points_used = 100
    m.status = "ok: 100 points" + ("; " + LOCKED_PHRASE if locked else "")
    return m


def manager_pid(name):
    api = rosnode.get_api_uri(rosgraph.Master("/check"), name)
    return xmlrpc.client.ServerProxy(api).getPid("/check")[2]


class BadImu(unittest.TestCase):
    def test_bad_imu_messages_are_dropped(self):
        rospy.init_node("check_inertial_fusion_bad_imu")
        manager = rospy.get_param("~manager")
        fused, errors = {}, []
        lock = threading.Lock()

        def on_fused(msg):
            with lock:
                fused[msg.header.stamp.to_nsec()] = msg

        def on_log(msg):
            if msg.level >= Log.ERROR and "InertialFusion" in msg.msg:
                with lock:
                    errors.append(msg.msg)

        rospy.Subscriber("pose_fused", PoseDelta, on_fused, queue_size=2000)
        rospy.Subscriber("/rosout", Log, on_log, queue_size=200)
        imu_pub = rospy.Publisher("imu/data", Imu, queue_size=1000)
        pose_pub = rospy.Publisher("pose_delta", PoseDelta, queue_size=100)
        deadline = time.time() + 20.0
        while time.time() < deadline and (imu_pub.get_num_connections() == 0 or pose_pub.get_num_connections() == 0):
            time.sleep(0.1)
        self.assertGreater(imu_pub.get_num_connections(), 0, "InertialFusion did not subscribe imu/data")
        pid = manager_pid(manager)
        t0 = rospy.Time(1000.0)
        k = [0]

        def good(n):
            stamps = []
            for _ in range(n):
                stamp = t0 + rospy.Duration(k[0] * DT)
                imu_pub.publish(imu_msg(stamp))
                if k[0] >= LOCK_AFTER and (k[0] - LOCK_AFTER) % CAMERA_EVERY == 0:
                    pose_pub.publish(pose_msg(stamp, k[0] == LOCK_AFTER))
                stamps.append(stamp)
                k[0] += 1
                time.sleep(0.002)
            return stamps

        def between(fraction):  # a stamp between the last good sample and the next
            return t0 + rospy.Duration((k[0] - 1 + fraction) * DT)

        good(LOCK_AFTER + 160)
        time.sleep(0.5)
        last = fused[max(fused)]
        self.assertTrue(last.valid, "no valid fused output before the bad messages: %s" % last.status)

        bad = []
        for frac, msg in ((0.2, dict(w=(float("nan"), 0.0, 0.0))), (0.4, dict(a=(0.0, float("inf"), 3.7))),
                          (0.6, dict(frame="camera_link"))):
            bad.append(imu_msg(between(frac), **msg))
        bad.append(imu_msg(t0 + rospy.Duration((k[0] - 1) * DT - 0.1 - 0.0013)))  # out of order
        for m in bad:
            imu_pub.publish(m)
            time.sleep(0.01)
        good(20)
        burst = [imu_msg(between(0.01 * (i + 1)), w=(0.0, float("nan"), 0.0)) for i in range(30)]
        for m in burst:
            imu_pub.publish(m)
        time.sleep(0.3)
        after = good(200)
        time.sleep(1.0)

        with lock:
            fused_stamps = set(fused)
            said = list(errors)
        for line in said:
            print("[ MEASURE ] error said: %s" % line)
        for m in bad + burst:
            self.assertNotIn(m.header.stamp.to_nsec(), fused_stamps,
                             "a bad Imu message (%s) was fused" % m.header.frame_id)
        for needle in ("NaN or infinite angular velocity", "NaN or infinite linear acceleration",
                       "frame_id 'camera_link' is not ~imu_frame 'imu_link'", "is not after the last sample's"):
            self.assertTrue(any(needle in e for e in said), "no ERROR saying %r in %s" % (needle, said))
        nan_said = sum("angular velocity" in e for e in said)
        self.assertLessEqual(nan_said, 2, "the burst of 30 NaN samples was not throttled: %s" % said)
        answered = [fused.get(s.to_nsec()) for s in after]
        missing = sum(a is None for a in answered)
        invalid = [a.status for a in answered if a is not None and not a.valid]
        print("[ MEASURE ] good samples after the bad ones: %d, answered %d, valid %d" % (
            len(after), len(after) - missing, len(after) - missing - len(invalid)))
        self.assertEqual(missing, 0, "good samples after the bad ones were not fused")
        self.assertEqual(invalid, [], "fused output invalid after the bad ones")
        self.assertTrue(all(math.isfinite(a.transform.translation.x) for a in answered))
        self.assertEqual(manager_pid(manager), pid, "the manager was restarted")
        rospy.wait_for_service(manager + "/list", timeout=5.0)
        self.assertIn("/inertial_fusion", rospy.ServiceProxy(manager + "/list", NodeletList)().nodelets)


if __name__ == "__main__":
    rostest.rosrun("structured_light_stabilizer", "inertial_fusion_bad_imu", BadImu)
