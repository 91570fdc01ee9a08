#!/usr/bin/env python3
"""CameraDriver on real-file sources, good and bad.

Makes its own fixtures in a temporary folder (an MJPG .avi written with
OpenCV, PNG images, camera_info YAMLs, an unreadable "image"), starts one
standalone camera_driver_node per case in its own namespace, and checks:
- video and images: image + camera_info of matching size and identical
  stamps, at the requested rate, frame_id as configured, in the encoding the
  source gives (bgr8 for colour files and videos, mono16 for 16-bit grey
  PNGs, with their values); the camera_info is the calibration file's when
  it fits;
- the sensor window (~binning_x/y, ~roi_*): the image is the ROI binned
  (each pixel the mean of its block of the file), camera_info keeps the
  file's K and full size and states binning and ROI; a window that does not
  fit the frames is reported;
- bad inputs (missing video, empty folder, unreadable image, missing
  camera_info_url, camera_info_url of another size, missing V4L2 device):
  an ERROR on /rosout that names the problem, and the node still answers.
Each node's first error comes at once, the next ones after the throttle
period (10 s): the subscriber connects to each new node as it appears, so
the check waits long enough to see the repeated error too.
"""
import os
import shutil
import subprocess
import tempfile
import threading
import time
import unittest

import cv2
import numpy as np
import rosnode
import rospy
import rostest
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo, Image

PKG = "structured_light_stabilizer"
COLLECT_S = 4.0


def write_calibration(path, width, height, fx):
    with open(path, "w") as f:
        f.write(
            "image_width: %d\nimage_height: %d\ncamera_name: camera\n"
            "camera_matrix: {rows: 3, cols: 3, data: [%f, 0, %f, 0, %f, %f, 0, 0, 1]}\n"
            "distortion_model: plumb_bob\n"
            "distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.01, 0, 0, 0]}\n"
            "rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n"
            "projection_matrix: {rows: 3, cols: 4, data: [%f, 0, %f, 0, 0, %f, %f, 0, 0, 0, 1, 0]}\n"
            % (width, height, fx, (width - 1) / 2.0, fx, (height - 1) / 2.0, fx, (width - 1) / 2.0, fx,
               (height - 1) / 2.0))


class Recorder:
    """Images and camera_infos of one namespace."""

    def __init__(self, ns):
        self.lock = threading.Lock()
        self.images, self.infos = [], []
        rospy.Subscriber(ns + "/camera/image_raw", Image, self._on_image, queue_size=50)
        rospy.Subscriber(ns + "/camera/camera_info", CameraInfo, self._on_info, queue_size=50)

    def _on_image(self, msg):
        with self.lock:
            self.images.append(msg)

    def _on_info(self, msg):
        with self.lock:
            self.infos.append(msg)


class CameraDriverSources(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_camera_driver_sources")
        cls.errors = []
        cls.err_lock = threading.Lock()
        # /rosout itself, not /rosout_agg: every node publishes there, with or
        # without the aggregator running.
        log_sub = rospy.Subscriber("/rosout", Log, cls._on_log, queue_size=1000)
        cls.tmp = tempfile.mkdtemp(prefix="sls_camera_driver_")
        t = cls.tmp
        # Fixtures.
        cls.video = os.path.join(t, "clip.avi")
        writer = cv2.VideoWriter(cls.video, cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (320, 240))
        assert writer.isOpened(), "OpenCV cannot write MJPG .avi here"
        for i in range(20):
            frame = np.zeros((240, 320, 3), np.uint8)
            frame[:, :, 2] = 60 + 5 * i
            cv2.circle(frame, (40 + 10 * i, 120), 6, (40, 230, 60), -1)
            writer.write(frame)
        writer.release()
        cls.image_dir = os.path.join(t, "images")
        os.makedirs(cls.image_dir)
        for i in range(5):
            img = np.full((480, 640, 3), 30 * i, np.uint8)
            cv2.imwrite(os.path.join(cls.image_dir, "frame_%03d.png" % i), img)
        cls.calib_640 = os.path.join(t, "calib_640.yaml")
        write_calibration(cls.calib_640, 640, 480, 500.0)
        cls.calib_1024 = os.path.join(t, "calib_1024.yaml")
        write_calibration(cls.calib_1024, 1024, 1024, 1011.67)
        cls.empty_dir = os.path.join(t, "empty")
        os.makedirs(cls.empty_dir)
        cls.bad_dir = os.path.join(t, "bad")
        os.makedirs(cls.bad_dir)
        with open(os.path.join(cls.bad_dir, "a_broken.png"), "wb") as f:
            f.write(b"this is not a PNG file")
        cv2.imwrite(os.path.join(cls.bad_dir, "b_good.png"), np.full((240, 320, 3), 99, np.uint8))
        cls.mono16_dir = os.path.join(t, "mono16")
        os.makedirs(cls.mono16_dir)
        cls.mono16 = (np.arange(240 * 320, dtype=np.uint32).reshape(240, 320) * 7 % 65536).astype(np.uint16)
        for i in range(3):
            cv2.imwrite(os.path.join(cls.mono16_dir, "frame_%03d.png" % i), cls.mono16)
        cls.pattern_dir = os.path.join(t, "pattern")
        os.makedirs(cls.pattern_dir)
        yy, xx = np.mgrid[0:480, 0:640]
        cls.pattern = np.dstack([(xx + 2 * yy) % 256, (3 * xx) % 256, (5 * yy) % 256]).astype(np.uint8)
        for i in range(3):
            cv2.imwrite(os.path.join(cls.pattern_dir, "frame_%03d.png" % i), cls.pattern)

        exe = os.path.join(os.path.dirname(os.path.abspath(__file__)), "camera_driver_node")
        import roslib.packages
        found = roslib.packages.find_node(PKG, "camera_driver_node")
        if found:
            exe = found[0]
        cases = {
            "video_ok": ["_source:=video", "_video_file:=" + cls.video, "_rate:=15", "_frame_id:=test_frame"],
            "images_ok": ["_source:=images", "_image_dir:=" + cls.image_dir, "_rate:=10",
                          "_camera_info_url:=file://" + cls.calib_640],
            "video_missing": ["_source:=video", "_video_file:=" + os.path.join(t, "nope.avi")],
            "images_empty": ["_source:=images", "_image_dir:=" + cls.empty_dir],
            "images_unreadable": ["_source:=images", "_image_dir:=" + cls.bad_dir, "_rate:=10"],
            "info_missing": ["_source:=images", "_image_dir:=" + cls.image_dir, "_rate:=10",
                             "_camera_info_url:=file://" + os.path.join(t, "missing.yaml")],
            "info_wrong_size": ["_source:=images", "_image_dir:=" + cls.image_dir, "_rate:=10",
                                "_camera_info_url:=file://" + cls.calib_1024],
            "device_missing": ["_source:=device", "_device:=/dev/sls_no_such_camera"],
            "images_mono16": ["_source:=images", "_image_dir:=" + cls.mono16_dir, "_rate:=5"],
            "images_preload": ["_source:=images", "_image_dir:=" + cls.mono16_dir, "_rate:=5", "_preload:=true"],
            "images_window": ["_source:=images", "_image_dir:=" + cls.pattern_dir, "_rate:=5",
                              "_camera_info_url:=file://" + cls.calib_640, "_binning_x:=2", "_binning_y:=2",
                              "_roi_x_offset:=64", "_roi_y_offset:=32", "_roi_width:=320", "_roi_height:=240"],
            "window_too_big": ["_source:=images", "_image_dir:=" + cls.pattern_dir, "_rate:=5",
                               "_roi_x_offset:=400", "_roi_y_offset:=0", "_roi_width:=320", "_roi_height:=240"],
            # Simulator parameters of the wrong type: named, defaults kept, the simulator runs.
            "sim_bad_params": ["_source:=sim", "_rate:=5", "_rock_distance:=far", "_projector_rows:=2.5",
                               "_shot_noise:=3"],
        }
        cls.recorders = {name: Recorder("/" + name) for name in cases}
        time.sleep(0.5)
        cls.procs = []
        cls.stderr = {}
        for name, args in cases.items():
            cmd = [exe, "__name:=driver", "__ns:=/" + name] + args
            # stderr kept: start-up errors can go out before /rosout is connected.
            cls.stderr[name] = os.path.join(t, name + ".stderr")
            with open(cls.stderr[name], "w") as err:
                cls.procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err))
        # Wait until the good cases have streamed for COLLECT_S seconds.
        deadline = time.time() + 40.0
        while time.time() < deadline:
            if all(len(cls.recorders[n].images) > 0
                   for n in ("video_ok", "images_ok", "images_unreadable", "sim_bad_params", "images_mono16",
                             "images_window", "images_preload")):
                break
            time.sleep(0.2)
        time.sleep(COLLECT_S)
        # Bad-input errors repeat every 10 s (throttled); wait for them if the
        # first one went out before this node was connected to the publisher.
        bad = ["video_missing", "images_empty", "images_unreadable", "info_missing", "info_wrong_size",
               "device_missing", "window_too_big"]
        deadline = time.time() + 15.0
        while time.time() < deadline and not all(cls._errors_of(n) for n in bad):
            time.sleep(0.2)

    @classmethod
    def tearDownClass(cls):
        for p in cls.procs:
            p.terminate()
        for p in cls.procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    @classmethod
    def _on_log(cls, msg):
        if msg.level >= Log.ERROR:
            with cls.err_lock:
                cls.errors.append((msg.name, msg.msg))

    @classmethod
    def _errors_of(cls, ns):
        with cls.err_lock:
            return [m for n, m in cls.errors if n.startswith("/" + ns + "/")]

    def errors_of(self, ns):
        return self._errors_of(ns)

    def assert_alive(self, ns):
        self.assertTrue(rosnode.rosnode_ping("/%s/driver" % ns, max_count=1), "/%s/driver no longer answers" % ns)

    def check_stream(self, name, width, height, rate, frame_id="camera_optical_frame", encoding="bgr8", info_size=None):
        rec = self.recorders[name]
        with rec.lock:
            images, infos = list(rec.images), list(rec.infos)
        self.assertGreater(len(images), 5, "%s: only %d images" % (name, len(images)))
        for img in images:
            self.assertEqual((img.width, img.height), (width, height))
            self.assertEqual(img.encoding, encoding)
            self.assertEqual(img.header.frame_id, frame_id)
        info_by_stamp = {i.header.stamp: i for i in infos}
        self.assertTrue(info_by_stamp, "%s: no camera_info" % name)
        # Every image within the span of the infos received has the info of its
        # stamp. (Before the first info the two subscriptions may still be
        # connecting; after the last, infos may still be in flight: under CPU
        # load CI saw more than one such image.)
        first, last = min(info_by_stamp), max(info_by_stamp)
        inside = [img for img in images if first <= img.header.stamp <= last]
        self.assertGreater(len(inside), 5, "%s: only %d images within the camera_info stream" % (name, len(inside)))
        unmatched = [img.header.stamp.to_sec() for img in inside if img.header.stamp not in info_by_stamp]
        self.assertEqual(unmatched, [], "%s: image and camera_info stamps differ" % name)
        matched = [img for img in images if img.header.stamp in info_by_stamp]
        for img in matched:
            info = info_by_stamp[img.header.stamp]
            self.assertEqual((info.width, info.height), info_size or (img.width, img.height))
            self.assertEqual(info.header.frame_id, frame_id)
        stamps = sorted(img.header.stamp.to_sec() for img in images)
        measured = (len(stamps) - 1) / (stamps[-1] - stamps[0])
        print("[ MEASURE ] %s: %d frames, %.2f Hz (requested %.1f Hz)" % (name, len(images), measured, rate))
        self.assertLess(abs(measured - rate) / rate, 0.2, "%s: %.2f Hz instead of %.1f Hz" % (name, measured, rate))
        return images, [info_by_stamp[i.header.stamp] for i in matched]

    def test_video_publishes_at_the_requested_rate(self):
        images, _ = self.check_stream("video_ok", 320, 240, 15.0, frame_id="test_frame")
        # The content is the clip's: a red background with a green dot.
        first = np.frombuffer(images[0].data, np.uint8).reshape(240, 320, 3)
        self.assertGreater(int(first[:, :, 2].mean()), 40)
        self.assertGreater(int(first[:, :, 1].max()), 150)
        self.assert_alive("video_ok")

    def test_images_publish_with_their_calibration(self):
        _, infos = self.check_stream("images_ok", 640, 480, 10.0)
        self.assertAlmostEqual(infos[0].K[0], 500.0, places=3)
        self.assertEqual(infos[0].distortion_model, "plumb_bob")
        self.assertEqual(self.errors_of("images_ok"), [])

    def test_mono16_images_are_published_as_read(self):
        images, _ = self.check_stream("images_mono16", 320, 240, 5.0, encoding="mono16")
        img = images[0]
        data = np.frombuffer(img.data, np.dtype(np.uint16).newbyteorder(">" if img.is_bigendian else "<"))
        self.assertTrue(np.array_equal(data.reshape(240, 320), self.mono16), "mono16 values changed on the way")

    def test_preloaded_images_are_published_as_read(self):
        # ~preload: decoded once at start (scripts/benchmark's live runs), then from memory.
        images, _ = self.check_stream("images_preload", 320, 240, 5.0, encoding="mono16")
        for img in images[:3]:
            data = np.frombuffer(img.data, np.dtype(np.uint16).newbyteorder(">" if img.is_bigendian else "<"))
            self.assertTrue(np.array_equal(data.reshape(240, 320), self.mono16), "preloaded values changed")
        self.assertEqual(self.errors_of("images_preload"), [])

    def test_sensor_window_bins_the_roi(self):
        images, infos = self.check_stream("images_window", 160, 120, 5.0, info_size=(640, 480))
        info = infos[0]
        self.assertEqual((info.binning_x, info.binning_y), (2, 2))
        self.assertEqual((info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height), (64, 32, 320, 240))
        self.assertAlmostEqual(info.K[0], 500.0, places=3)  # the full sensor's K
        got = np.frombuffer(images[0].data, np.uint8).reshape(120, 160, 3).astype(float)
        cut = self.pattern[32:272, 64:384].astype(float)
        expected = cut.reshape(120, 2, 160, 2, 3).mean(axis=(1, 3))
        worst = np.abs(got - expected).max()
        print("[ MEASURE ] images_window: largest difference from the 2x2 block means %.2f DN" % worst)
        self.assertLessEqual(worst, 0.5 + 1e-9)
        self.assertEqual(self.errors_of("images_window"), [])

    def test_window_that_does_not_fit_is_reported(self):
        errs = self.errors_of("window_too_big")
        self.assertTrue(any("does not fit" in e for e in errs), errs)
        self.assertEqual(len(self.recorders["window_too_big"].images), 0)
        self.assert_alive("window_too_big")

    def test_missing_video_is_reported(self):
        errs = self.errors_of("video_missing")
        self.assertTrue(any("does not exist" in e for e in errs), errs)
        self.assertEqual(len(self.recorders["video_missing"].images), 0)
        self.assert_alive("video_missing")

    def test_empty_folder_is_reported(self):
        errs = self.errors_of("images_empty")
        self.assertTrue(any("contains no images" in e for e in errs), errs)
        self.assert_alive("images_empty")

    def test_unreadable_image_is_skipped(self):
        errs = self.errors_of("images_unreadable")
        self.assertTrue(any("a_broken.png" in e for e in errs), errs)
        self.check_stream("images_unreadable", 320, 240, 5.0)  # one good file of two at 10 Hz
        self.assert_alive("images_unreadable")

    def test_missing_camera_info_url_is_reported(self):
        errs = self.errors_of("info_missing")
        self.assertTrue(any("could not be loaded" in e for e in errs), errs)
        _, infos = self.check_stream("info_missing", 640, 480, 10.0)
        self.assertEqual(infos[0].K[0], 0.0)  # uncalibrated, but of the right size
        self.assert_alive("info_missing")

    def test_camera_info_of_another_size_is_refused(self):
        errs = self.errors_of("info_wrong_size")
        self.assertTrue(any("is for 1024x1024" in e and "640x480" in e for e in errs), errs)
        _, infos = self.check_stream("info_wrong_size", 640, 480, 10.0)
        self.assertEqual(infos[0].K[0], 0.0)
        self.assert_alive("info_wrong_size")

    def test_simulator_parameters_of_the_wrong_type_are_named(self):
        with open(self.stderr["sim_bad_params"]) as f:
            err = f.read()
        for expected in ("~rock_distance must be a number", "~projector_rows must be a non-negative integer",
                         "~shot_noise must be true or false"):
            self.assertIn(expected, err)
        self.check_stream("sim_bad_params", 1024, 1024, 5.0)
        self.assert_alive("sim_bad_params")

    def test_missing_device_is_reported(self):
        errs = self.errors_of("device_missing")
        self.assertTrue(any("cannot open V4L2 device" in e for e in errs), errs)
        self.assert_alive("device_missing")


if __name__ == "__main__":
    rostest.rosrun(PKG, "check_camera_driver_sources", CameraDriverSources)
