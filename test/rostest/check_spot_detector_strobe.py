#!/usr/bin/env python3
"""Checker for spot_detector_strobe.test: a strobed camera's pairs (projector
off, then on) of a finely textured rock in daylight. The dot's light is
reflected by the albedo under each pixel, so its raw centroid leans towards
the bright grains; with the projector-off frame the detector divides the
albedo out. Truth: the dots' centres (the beams' hit points)."""
import math
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import Image

from structured_light_stabilizer.msg import CentroidArray

PKG = "structured_light_stabilizer"
W, H = 320, 240
ROWS, COLS = 4, 5


def dots_truth():
    return [(60.0 + 50.0 * c + 0.37 * r, 45.0 + 50.0 * r + 0.21 * c) for r in range(ROWS) for c in range(COLS)]


def albedo():
    """Relative albedo: +-25 % texture of 9-13 px (1-2 cm at 1.5 m)."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    return 1.0 + 0.25 * np.sin(2 * math.pi * xs / 11.0 + 0.7) * np.sin(2 * math.pi * ys / 13.0 + 0.3)


def render(seed, dots):
    """bgr8 of the sunlit rock (b, g, r) = (25, 45, 80) x albedo, plus, with
    dots, Gaussian dots (the sensor's 520 nm response) x albedo."""
    rng = np.random.default_rng(seed)
    a = albedo()
    img = np.empty((H, W, 3), np.float64)
    for k, level in enumerate((25.0, 45.0, 80.0)):
        img[:, :, k] = level * a
    if dots:
        ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
        for (x, y) in dots_truth():
            d = 120.0 * a * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 2.2 * 2.2))
            img[:, :, 0] += 0.22 * d
            img[:, :, 1] += d
            img[:, :, 2] += 0.08 * d
    img += rng.normal(0.0, 0.7, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def image_msg(array, stamp):
    msg = Image()
    msg.header.stamp = stamp
    msg.header.frame_id = "camera_optical_frame"
    msg.height, msg.width = array.shape[0], array.shape[1]
    msg.encoding = "bgr8"
    msg.step = msg.width * 3
    msg.data = array.tobytes()
    return msg


class SpotDetectorStrobe(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_spot_detector_strobe")
        cls.lock = threading.Lock()
        cls.spots = {}
        cls.logs = []
        cls.pub = rospy.Publisher("camera/image_raw", Image, queue_size=10)
        cls.pub_ambient = rospy.Publisher("camera/image_ambient", Image, queue_size=10)
        rospy.Subscriber("spots", CentroidArray, cls.on_spots, queue_size=50)
        rospy.Subscriber("/rosout", Log, cls.on_log, queue_size=200)
        rospy.Subscriber("/rosout_agg", Log, cls.on_log, queue_size=200)
        deadline = time.time() + 30
        while (cls.pub.get_num_connections() == 0 or cls.pub_ambient.get_num_connections() == 0) and \
                time.time() < deadline:
            time.sleep(0.1)

    @classmethod
    def on_spots(cls, msg):
        with cls.lock:
            cls.spots[msg.header.stamp] = msg

    @classmethod
    def on_log(cls, msg):
        with cls.lock:
            cls.logs.append(msg.msg)

    def pair(self, t, ambient_gap_s, seed):
        """Publishes an ambient frame ambient_gap_s before the frame at t
        (none when None) and returns the frame's spots message."""
        if ambient_gap_s is not None:
            self.pub_ambient.publish(image_msg(render(seed + 1, False), rospy.Time(t - ambient_gap_s)))
            time.sleep(0.3)  # the cache has it before the frame arrives
        stamp = rospy.Time(t)
        self.pub.publish(image_msg(render(seed, True), stamp))
        deadline = time.time() + 5.0
        while time.time() < deadline:
            with self.lock:
                if stamp in self.spots:
                    return self.spots[stamp]
            time.sleep(0.02)
        return None

    def errors(self, out):
        self.assertIsNotNone(out, "no spots published")
        self.assertEqual(len(out.centroids), ROWS * COLS)
        return [min(math.hypot(c.x - x, c.y - y) for c in out.centroids) for (x, y) in dots_truth()]

    def test_1_ambient_frame_removes_the_texture_pull(self):
        errs = []
        for k in range(3):
            errs += self.errors(self.pair(2000.0 + k, 0.02, 10 * k))
        rms = math.sqrt(sum(e * e for e in errs) / len(errs))
        print("[ MEASURE ] strobed pairs, +-25 %% texture: centroid RMS %.4f px, worst %.4f px" % (rms, max(errs)))
        self.assertLess(rms, 0.05)
        self.assertLess(max(errs), 0.12)

    def test_2_without_a_fitting_ambient_frame(self):
        # The only ambient frame is 1 s old: the frame is detected without
        # it (the texture's pull stays), and the node says why.
        errs = self.errors(self.pair(3000.0, 1.0, 50))
        rms = math.sqrt(sum(e * e for e in errs) / len(errs))
        print("[ MEASURE ] no fitting ambient frame: centroid RMS %.4f px" % rms)
        self.assertLess(max(errs), 1.0)
        deadline = time.time() + 5
        found = False
        while time.time() < deadline and not found:
            with self.lock:
                found = any("no camera/image_ambient frame within" in m for m in self.logs)
            time.sleep(0.05)
        self.assertTrue(found, "no warning about the missing ambient frame")


if __name__ == "__main__":
    rostest.rosrun(PKG, "spot_detector_strobe", SpotDetectorStrobe)
