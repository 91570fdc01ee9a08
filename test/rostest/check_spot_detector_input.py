#!/usr/bin/env python3
"""Checker for spot_detector_input.test: drives the SpotDetector nodelet with
frames made here (truth known) and asserts what comes out on spots and
spots/debug_image, and what it says on /rosout for bad input."""
import math
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from dynamic_reconfigure.client import Client
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import Image

from structured_light_stabilizer.msg import CentroidArray

PKG = "structured_light_stabilizer"
W, H = 320, 240
ROWS, COLS = 4, 5


def dots_truth():
    pts = []
    for r in range(ROWS):
        for c in range(COLS):
            pts.append((60.0 + 50.0 * c + 0.37 * r, 45.0 + 50.0 * r + 0.21 * c))
    return pts


def render_bgr(sigma=2.0, seed=1):
    """Reddish rock (b, g, r) = (20, 35, 70) + noise, green Gaussian dots."""
    rng = np.random.default_rng(seed)
    img = np.empty((H, W, 3), np.float64)
    img[:] = (20.0, 35.0, 70.0)
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    for (x, y) in dots_truth():
        d = 180.0 * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * sigma * sigma))
        # The sensor's response to the 520 nm projector (b, g, r) = (0.22, 1, 0.08).
        img[:, :, 0] += 0.22 * d
        img[:, :, 1] += d
        img[:, :, 2] += 0.08 * d
    img += rng.normal(0.0, 1.0, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def bayer_rggb(bgr):
    """The RGGB mosaic of a bgr8 frame: each site keeps its own colour."""
    out = np.empty((H, W), np.uint8)
    out[0::2, 0::2] = bgr[0::2, 0::2, 2]
    out[0::2, 1::2] = bgr[0::2, 1::2, 1]
    out[1::2, 0::2] = bgr[1::2, 0::2, 1]
    out[1::2, 1::2] = bgr[1::2, 1::2, 0]
    return out


def uyvy(bgr):
    """yuv422 (UYVY) of a bgr8 frame, BT.601 video range, chroma of each pixel pair averaged."""
    f = bgr.astype(np.float64)
    b, g, r = f[:, :, 0], f[:, :, 1], f[:, :, 2]
    y = 16.0 + 0.256788 * r + 0.504129 * g + 0.097906 * b
    u = 128.0 - 0.148223 * r - 0.290993 * g + 0.439216 * b
    v = 128.0 + 0.439216 * r - 0.367788 * g - 0.071427 * b
    out = np.empty((H, W, 2), np.float64)
    out[:, 0::2, 0] = 0.5 * (u[:, 0::2] + u[:, 1::2])
    out[:, 1::2, 0] = 0.5 * (v[:, 0::2] + v[:, 1::2])
    out[:, :, 1] = y
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def render_red_bgr(seed=1):
    """Greenish-grey rock, red Gaussian dots (the sensor's response to a 650 nm projector)."""
    rng = np.random.default_rng(seed)
    img = np.empty((H, W, 3), np.float64)
    img[:] = (30.0, 40.0, 35.0)
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    for (x, y) in dots_truth():
        d = 180.0 * np.exp(-((xs - x) ** 2 + (ys - y) ** 2) / (2 * 2.0 * 2.0))
        img[:, :, 0] += 0.04 * d
        img[:, :, 1] += 0.10 * d
        img[:, :, 2] += d
    img += rng.normal(0.0, 1.0, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def image_msg(array, encoding, step=None, seq=0, bigendian=False):
    msg = Image()
    msg.header.stamp = rospy.Time.now()
    msg.header.frame_id = "camera_optical_frame"
    msg.header.seq = seq
    msg.height = array.shape[0] if array.ndim >= 1 else 0
    msg.width = array.shape[1] if array.ndim >= 2 else 0
    msg.encoding = encoding
    msg.is_bigendian = 1 if bigendian else 0
    if bigendian:
        array = array.astype(array.dtype.newbyteorder(">"))
    bpp = array.itemsize * (array.shape[2] if array.ndim == 3 else 1)
    msg.step = step if step is not None else msg.width * bpp
    if step is not None and step > msg.width * bpp:
        pad = np.zeros((msg.height, step), np.uint8)
        pad[:, : msg.width * bpp] = np.frombuffer(array.tobytes(), np.uint8).reshape(msg.height, msg.width * bpp)
        pad[:, msg.width * bpp:] = 0xAB
        msg.data = pad.tobytes()
    else:
        msg.data = array.tobytes()
    return msg


class SpotDetectorInput(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_spot_detector_input")
        cls.lock = threading.Lock()
        cls.spots = {}
        cls.debug = {}
        cls.logs = []
        cls.pub = rospy.Publisher("camera/image_raw", Image, queue_size=10)
        rospy.Subscriber("spots", CentroidArray, cls.on_spots, queue_size=50)
        rospy.Subscriber("spots/debug_image", Image, cls.on_debug, queue_size=5)
        rospy.Subscriber("/rosout", Log, cls.on_log, queue_size=200)
        rospy.Subscriber("/rosout_agg", Log, cls.on_log, queue_size=200)
        deadline = time.time() + 30
        while cls.pub.get_num_connections() == 0 and time.time() < deadline:
            time.sleep(0.1)
        cls.seq = 100
        cls.reconf = Client("spot_detector", timeout=30)

    # Frames are keyed by their stamp (rospy rewrites header.seq).
    @classmethod
    def on_spots(cls, msg):
        with cls.lock:
            cls.spots[msg.header.stamp] = msg

    @classmethod
    def on_debug(cls, msg):
        with cls.lock:
            cls.debug[msg.header.stamp] = msg

    @classmethod
    def on_log(cls, msg):
        with cls.lock:
            cls.logs.append(msg.msg)

    def send(self, msg, expect=True):
        """Publishes a frame; returns its spots message, or None if none came
        (within 5 s when one is expected, 1.5 s when not)."""
        cls = type(self)
        cls.seq += 1
        msg.header.stamp = rospy.Time(1000 + cls.seq)
        self.pub.publish(msg)
        deadline = time.time() + (5.0 if expect else 1.5)
        while time.time() < deadline:
            with cls.lock:
                if msg.header.stamp in cls.spots:
                    return cls.spots[msg.header.stamp]
            time.sleep(0.02)
        return None

    def wait_log(self, fragment, timeout=5.0):
        deadline = time.time() + timeout
        while time.time() < deadline:
            with type(self).lock:
                if any(fragment in m for m in type(self).logs):
                    return True
            time.sleep(0.05)
        return False

    def check_accuracy(self, out, bound, label):
        self.assertIsNotNone(out, label + ": no spots published")
        self.assertEqual((out.image_width, out.image_height), (W, H))
        self.assertEqual(out.header.frame_id, "camera_optical_frame")
        truth = dots_truth()
        self.assertEqual(len(out.centroids), len(truth), label)
        worst = 0.0
        for (x, y) in truth:
            d = min(math.hypot(c.x - x, c.y - y) for c in out.centroids)
            worst = max(worst, d)
        print("[ MEASURE ] %s: %d dots, worst centroid error %.4f px" % (label, len(out.centroids), worst))
        self.assertLess(worst, bound, label)

    def good(self, label):
        out = self.send(image_msg(render_bgr(seed=type(self).seq), "bgr8"))
        self.check_accuracy(out, 0.1, "fast, good frame after " + label)

    def test_1_fast_encodings_and_padding(self):
        bgr = render_bgr()
        self.check_accuracy(self.send(image_msg(bgr, "bgr8")), 0.1, "fast bgr8")
        self.check_accuracy(self.send(image_msg(bgr[:, :, ::-1].copy(), "rgb8")), 0.1, "fast rgb8")
        bgra = np.concatenate([bgr, np.full((H, W, 1), 255, np.uint8)], axis=2)
        self.check_accuracy(self.send(image_msg(bgra, "bgra8")), 0.1, "fast bgra8")
        rgba = np.concatenate([bgr[:, :, ::-1], np.full((H, W, 1), 255, np.uint8)], axis=2)
        self.check_accuracy(self.send(image_msg(rgba.copy(), "rgba8")), 0.1, "fast rgba8")
        self.check_accuracy(self.send(image_msg(bgr, "bgr8", step=W * 3 + 13)), 0.1, "fast bgr8, step = width*3 + 13")
        # mono8: intensity only, with a one-time warning.
        mono = np.ascontiguousarray(bgr[:, :, 1])
        mono_bright = np.clip(mono.astype(np.int32) + 60, 0, 255).astype(np.uint8)
        out = self.send(image_msg(mono_bright, "mono8"))
        self.check_accuracy(out, 0.1, "fast mono8")
        self.assertTrue(self.wait_log("mono8 input"), "no mono8 warning")

    def test_1b_raw_camera_encodings(self):
        # What a machine-vision driver sends: Bayer, yuv422, 16-bit mono
        # (both byte orders), each read in place.
        bgr = render_bgr(seed=21)
        self.check_accuracy(self.send(image_msg(bayer_rggb(bgr), "bayer_rggb8")), 0.1, "fast bayer_rggb8")
        self.check_accuracy(self.send(image_msg(uyvy(bgr), "yuv422")), 0.1, "fast yuv422 (UYVY)")
        yuyv = uyvy(bgr).reshape(H, W * 2)
        yuyv = yuyv.reshape(H, W // 2, 4)[:, :, [1, 0, 3, 2]].reshape(H, W, 2).copy()
        self.check_accuracy(self.send(image_msg(yuyv, "yuv422_yuy2")), 0.1, "fast yuv422_yuy2 (YUYV)")
        mono16 = (np.clip(bgr[:, :, 1].astype(np.int32) + 60, 0, 255) * 257).astype(np.uint16)
        self.check_accuracy(self.send(image_msg(mono16, "mono16")), 0.1, "fast mono16")
        self.check_accuracy(self.send(image_msg(mono16, "mono16", bigendian=True)), 0.1, "fast mono16 big-endian")
        self.check_accuracy(self.send(image_msg(mono16, "16UC1")), 0.1, "fast 16UC1")

    def test_1c_projector_color(self):
        cfg = self.reconf.update_configuration({"projector_color": "red"})
        self.assertEqual(cfg["projector_color"], "red")
        self.check_accuracy(self.send(image_msg(render_red_bgr(seed=31), "bgr8")), 0.1, "fast bgr8, red projector")
        # An unknown colour keeps the last good one, with a warning.
        cfg = self.reconf.update_configuration({"projector_color": "purple"})
        self.assertEqual(cfg["projector_color"], "red")
        self.assertTrue(self.wait_log("unknown projector_color"))
        self.reconf.update_configuration({"projector_color": "green"})
        self.check_accuracy(self.send(image_msg(render_bgr(seed=32), "bgr8")), 0.1, "fast bgr8, green again")

    def test_2_bad_input_survives(self):
        bad = [
            ("32FC1", image_msg(np.full((H, W), 0.5, np.float32), "32FC1"), "unsupported image encoding '32FC1'"),
            ("bayer16", image_msg(np.zeros((H, W), np.uint16), "bayer_rggb16"),
             "unsupported image encoding 'bayer_rggb16'"),
        ]
        odd = image_msg(np.zeros((H, W - 1, 2), np.uint8), "yuv422")
        bad.append(("yuv422 of odd width", odd, "odd width"))
        empty = Image()
        empty.encoding = "bgr8"
        bad.append(("empty", empty, "inconsistent image"))
        short = image_msg(render_bgr(), "bgr8")
        short.data = short.data[: len(short.data) // 2]
        bad.append(("truncated data", short, "inconsistent image"))
        small_step = image_msg(render_bgr(), "bgr8")
        small_step.step = W * 3 - 3
        bad.append(("step < width*3", small_step, "inconsistent image"))
        for label, msg, fragment in bad:
            out = self.send(msg, expect=False)
            self.assertIsNone(out, label + ": a refused frame must not produce spots")
            self.assertTrue(self.wait_log(fragment), label + ": no error naming the problem (" + fragment + ")")
            self.good(label)
        # Accepted but degenerate frames: no crash, no dot (an all-green frame
        # is one uniform region, no dot).
        degenerate = [
            ("1x1", image_msg(np.full((1, 1, 3), 255, np.uint8), "bgr8")),
            ("all black", image_msg(np.zeros((H, W, 3), np.uint8), "bgr8")),
            ("all green", image_msg(np.dstack([np.zeros((H, W)), np.full((H, W), 255), np.zeros((H, W))]).astype(np.uint8), "bgr8")),
            ("all saturated", image_msg(np.full((H, W, 3), 255, np.uint8), "bgr8")),
        ]
        for label, msg in degenerate:
            out = self.send(msg)
            self.assertIsNotNone(out, label + ": no spots message")
            self.assertEqual(len(out.centroids), 0, label)
            self.good(label)

    def test_3_baseline_and_reconfigure(self):
        cfg = self.reconf.update_configuration({"method": "baseline", "h_min": 95, "h_max": 25, "blur_kernel": 4})
        # min > max swapped, even kernel made odd, by the nodelet's validation.
        self.assertEqual((cfg["h_min"], cfg["h_max"], cfg["blur_kernel"]), (25, 95, 5))
        self.assertTrue(self.wait_log("swapped"))
        self.reconf.update_configuration({"blur_kernel": 1})
        out = self.send(image_msg(render_bgr(seed=7), "bgr8"))
        self.check_accuracy(out, 0.5, "baseline bgr8")
        # The study's row sort numbers the beams row-major.
        beams = [c.beam for c in out.centroids]
        self.assertEqual(beams, list(range(ROWS * COLS)))
        truth = dots_truth()
        for c in out.centroids:
            x, y = truth[c.beam]
            self.assertLess(math.hypot(c.x - x, c.y - y), 0.5)
        self.reconf.update_configuration({"method": "fast"})
        out = self.send(image_msg(render_bgr(seed=8), "bgr8"))
        self.check_accuracy(out, 0.1, "fast again")
        self.assertTrue(all(c.beam == -1 for c in out.centroids))

    def test_4_debug_image_on_demand(self):
        deadline = time.time() + 10
        got = None
        while time.time() < deadline and got is None:
            msg = image_msg(render_bgr(seed=9), "bgr8")
            self.send(msg)
            time.sleep(0.2)
            with type(self).lock:
                got = type(self).debug.get(msg.header.stamp)
        self.assertIsNotNone(got, "no spots/debug_image while subscribed")
        self.assertEqual((got.width, got.height, got.encoding), (W, H, "bgr8"))


if __name__ == "__main__":
    rostest.rosrun(PKG, "spot_detector_input", SpotDetectorInput)
