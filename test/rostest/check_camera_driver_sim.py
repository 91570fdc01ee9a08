#!/usr/bin/env python3
"""CameraDriver with source:=sim in a nodelet manager.

Checks image + camera_info (size, encoding, frame_id, K of the study's camera,
identical stamps, the requested rate), that the ground-truth topics carry the
stamps of the frames, that the ground truth is self-consistent (spot pixels
are the projections of the cloud's points, the PoseDelta is valid and counts
the visible dots, the rendered image has a green dot at each true spot), that
the projector calibration file was written, and that a dynamic_reconfigure
change of the sun level shows in the frames.
"""
import math
import threading
import time
import unittest

import dynamic_reconfigure.client
import numpy as np
import rospy
import rostest
import yaml
from sensor_msgs import point_cloud2
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from structured_light_stabilizer.msg import CentroidArray, PoseDelta

PKG = "structured_light_stabilizer"


class CameraDriverSim(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_camera_driver_sim")
        cls.rate = rospy.get_param("~rate")
        cls.calibration = rospy.get_param("~calibration_file")
        cls.lock = threading.Lock()
        cls.msgs = {"image": [], "info": [], "points": [], "pose": [], "spots": []}
        for key, topic, typ in (("image", "camera/image_raw", Image), ("info", "camera/camera_info", CameraInfo),
                                ("points", "sim/ground_truth/points", PointCloud2),
                                ("pose", "sim/ground_truth/pose_delta", PoseDelta),
                                ("spots", "sim/ground_truth/spots", CentroidArray)):
            rospy.Subscriber(topic, typ, cls._make_cb(key), queue_size=20)
        deadline = time.time() + 40.0
        while time.time() < deadline and len(cls.msgs["image"]) < 2:
            time.sleep(0.1)
        time.sleep(4.0)
        with cls.lock:
            cls.snapshot = {k: list(v) for k, v in cls.msgs.items()}

    @classmethod
    def _make_cb(cls, key):
        def cb(msg):
            with cls.lock:
                cls.msgs[key].append(msg)
        return cb

    def test_image_and_camera_info(self):
        images, infos = self.snapshot["image"], self.snapshot["info"]
        self.assertGreater(len(images), 5)
        info_stamps = {i.header.stamp: i for i in infos}
        for img in images[:-1]:
            self.assertEqual((img.width, img.height, img.encoding), (1024, 1024, "bgr8"))
            self.assertEqual(img.header.frame_id, "camera_optical_frame")
            self.assertIn(img.header.stamp, info_stamps)
            info = info_stamps[img.header.stamp]
            self.assertEqual((info.width, info.height), (1024, 1024))
            self.assertAlmostEqual(info.K[0], 12.14e-3 / 12e-6, places=6)
            self.assertAlmostEqual(info.K[2], 511.5, places=6)
        stamps = sorted(i.header.stamp.to_sec() for i in images)
        measured = (len(stamps) - 1) / (stamps[-1] - stamps[0])
        print("[ MEASURE ] sim: %d frames, %.2f Hz (requested %.1f Hz)" % (len(images), measured, self.rate))
        self.assertLess(abs(measured - self.rate) / self.rate, 0.2)

    def test_ground_truth_shares_the_frame_stamps(self):
        image_stamps = {i.header.stamp for i in self.snapshot["image"]}
        for key in ("points", "pose", "spots"):
            msgs = self.snapshot[key]
            self.assertGreater(len(msgs), 5, key)
            common = [m for m in msgs if m.header.stamp in image_stamps]
            self.assertGreaterEqual(len(common), len(msgs) - 1, "%s stamps differ from the frames'" % key)

    def test_ground_truth_is_consistent(self):
        info = self.snapshot["info"][0]
        fx, cx, fy, cy = info.K[0], info.K[2], info.K[4], info.K[5]
        images = {i.header.stamp: i for i in self.snapshot["image"]}
        poses = {p.header.stamp: p for p in self.snapshot["pose"]}
        spots_by_stamp = {s.header.stamp: s for s in self.snapshot["spots"]}
        checked = 0
        worst = 0.0
        for cloud in self.snapshot["points"]:
            stamp = cloud.header.stamp
            if stamp not in spots_by_stamp or stamp not in poses or stamp not in images:
                continue
            self.assertEqual((cloud.height, cloud.width), (10, 10))
            pts = list(point_cloud2.read_points(cloud, field_names=("x", "y", "z", "beam"), skip_nans=False))
            spots = spots_by_stamp[stamp]
            self.assertEqual(poses[stamp].points_used, len(spots.centroids))
            self.assertTrue(poses[stamp].valid)
            img = np.frombuffer(images[stamp].data, np.uint8).reshape(1024, 1024, 3)
            green_dots = 0
            for c in spots.centroids:
                x, y, z, beam = pts[c.beam]
                self.assertEqual(beam, c.beam)
                self.assertFalse(math.isnan(z))
                worst = max(worst, math.hypot(fx * x / z + cx - c.x, fy * y / z + cy - c.y))
                u, v = int(round(c.x)), int(round(c.y))
                patch = img[max(v - 12, 0):v + 13, max(u - 12, 0):u + 13, 1].astype(float)
                green_dots += img[v, u, 1] > np.median(patch) + 10
            self.assertGreater(green_dots, 0.9 * len(spots.centroids))
            nan_beams = sum(1 for p in pts if math.isnan(p[2]))
            self.assertEqual(nan_beams, 100 - len(spots.centroids))
            checked += 1
        print("[ MEASURE ] %d ground-truth frames checked, spot vs projected point max %.2e px" % (checked, worst))
        self.assertGreater(checked, 3)
        self.assertLess(worst, 1e-3)
        # The rig moves (jitter configured in the launch file).
        first, last = self.snapshot["pose"][0].transform.translation, self.snapshot["pose"][-1].transform.translation
        self.assertGreater(abs(first.x - last.x) + abs(first.y - last.y) + abs(first.z - last.z), 1e-5)

    def test_projector_calibration_written(self):
        with open(self.calibration) as f:
            cal = yaml.safe_load(f)
        self.assertEqual((cal["rows"], cal["cols"]), (10, 10))
        self.assertEqual(len(cal["beams"]), 100)
        self.assertAlmostEqual(cal["beams"][0]["origin"][0], 0.25, places=6)

    def test_sun_level_is_live(self):
        client = dynamic_reconfigure.client.Client("camera_driver", timeout=20)

        def mean_red(after):
            deadline = time.time() + 15.0
            while time.time() < deadline:
                with self.lock:
                    imgs = [i for i in self.msgs["image"] if i.header.stamp.to_sec() > after]
                if len(imgs) >= 2:
                    return float(np.frombuffer(imgs[-1].data, np.uint8).reshape(1024, 1024, 3)[:, :, 2].mean())
                time.sleep(0.1)
            self.fail("no frame after the reconfiguration")

        client.update_configuration({"sun_level": 0.0})
        night = mean_red(rospy.Time.now().to_sec())
        client.update_configuration({"sun_level": 1.0})
        day = mean_red(rospy.Time.now().to_sec())
        print("[ MEASURE ] mean red: %.1f DN at sun_level 0, %.1f DN at sun_level 1" % (night, day))
        self.assertLess(night, 3.0)
        # 37 DN with the default corrected radiometry (the recommended rig's exposure), 79 with `study`.
        self.assertGreater(day, 20.0)


if __name__ == "__main__":
    rostest.rosrun(PKG, "check_camera_driver_sim", CameraDriverSim)
