#!/usr/bin/env python3
"""End to end on the simulator: image -> spots -> points -> pose, against the
simulator's ground truth, for one kind of camera input (end_to_end.launch;
one .test file per kind sets the camera and the bounds).

Per frame (paired by header stamp):
  spots/assigned vs sim/ground_truth/spots: one-to-one matching within
    ~match_radius_px (greedy by distance), recall = matched / visible true
    dots, centroid error of each matched dot (pixels of the published image),
    wrong beams = assigned spots whose beam is not the matched true dot's (or
    that match no true dot);
  points vs sim/ground_truth/points: 3D error of each beam present in both,
    relative to its distance;
  pose_delta vs sim/ground_truth/pose_delta: after a lock requested by this
    checker, the estimate against gt_k * gt_lock^-1 (the
    check_pose_delta_sim.py scheme).
Asserts, pooled over ~frames frames: recall >= ~min_recall, centroid RMS <=
~max_centroid_px, wrong beams = 0 (also per frame), depth RMS <=
~max_depth_percent of z, pose RMS <= ~max_translation_mm / ~max_rotation_deg,
valid share >= ~min_valid; per frame: recall >= ~min_frame_recall. Also: the
image has ~expect_encoding (when set) and the size camera_info's binning and
ROI say (REP 104).
"""
import math
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import Trigger
from structured_light_stabilizer.evaluation import cloud_xyz, is_identity, rotation_angle_deg, transform_matrix
from structured_light_stabilizer.msg import CentroidArray, PoseDelta

PKG = "structured_light_stabilizer"


def match_spots(found, truth, radius):
    """One-to-one greedy matching by distance: list of (found index, truth index, distance)."""
    if not found or not truth:
        return []
    f = np.array([(c.x, c.y) for c in found])
    t = np.array([(c.x, c.y) for c in truth])
    d = np.linalg.norm(f[:, None, :] - t[None, :, :], axis=2)
    pairs, used_f, used_t = [], set(), set()
    for k in np.argsort(d, axis=None):
        i, j = np.unravel_index(k, d.shape)
        if d[i, j] > radius:
            break
        if i in used_f or j in used_t:
            continue
        used_f.add(i)
        used_t.add(j)
        pairs.append((int(i), int(j), float(d[i, j])))
    return pairs


class EndToEnd(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_end_to_end")
        cls.p = {k: rospy.get_param("~" + k, v) for k, v in (
            ("label", "end to end"), ("frames", 40), ("match_radius_px", 3.0), ("min_recall", 0.99),
            ("min_frame_recall", 0.95), ("max_centroid_px", 0.10), ("max_depth_percent", 0.1),
            ("max_translation_mm", 1.0), ("max_rotation_deg", 0.05), ("min_valid", 0.95),
            ("expect_encoding", ""))}
        cls.lock = threading.Lock()
        cls.topics = {"spots": {}, "gt_spots": {}, "points": {}, "gt_points": {}, "pose": {}, "gt_pose": {}}
        cls.pose_order = []
        subs = [rospy.Subscriber(topic, typ, cls._store(key), queue_size=30) for key, topic, typ in (
            ("spots", "spots/assigned", CentroidArray), ("gt_spots", "sim/ground_truth/spots", CentroidArray),
            ("points", "points", PointCloud2), ("gt_points", "sim/ground_truth/points", PointCloud2),
            ("pose", "pose_delta", PoseDelta), ("gt_pose", "sim/ground_truth/pose_delta", PoseDelta))]
        deadline = time.time() + 60.0
        while time.time() < deadline and any(s.get_num_connections() == 0 for s in subs):
            time.sleep(0.2)
        rospy.wait_for_service("pose_delta/lock", 30.0)
        lock = rospy.ServiceProxy("pose_delta/lock", Trigger)
        with cls.lock:
            cls.mark = len(cls.pose_order)
        while time.time() < deadline and not lock().success:
            time.sleep(0.2)
        deadline = time.time() + 20.0 + 4.0 * cls.p["frames"]
        while time.time() < deadline:
            with cls.lock:
                if len(cls.pose_order) - cls.mark >= cls.p["frames"] + 2:
                    break
            time.sleep(0.2)
        time.sleep(1.0)
        with cls.lock:
            cls.data = {k: dict(v) for k, v in cls.topics.items()}
            cls.after_lock = cls.pose_order[cls.mark:]

    @classmethod
    def _store(cls, key):
        def cb(msg):
            with cls.lock:
                cls.topics[key][msg.header.stamp] = msg
                if key == "pose":
                    cls.pose_order.append(msg.header.stamp)
        return cb

    def measure(self, name, value):
        print("[ MEASURE ] %s: %s %s" % (self.p["label"], name, value))

    def test_image_matches_camera_info(self):
        image = rospy.wait_for_message("camera/image_raw", Image, 30.0)
        info = rospy.wait_for_message("camera/camera_info", CameraInfo, 30.0)
        bx, by = max(1, info.binning_x), max(1, info.binning_y)
        roi_w = info.roi.width or info.width
        roi_h = info.roi.height or info.height
        self.measure("image", "%s %dx%d; camera_info %dx%d %s, binning %dx%d, ROI %dx%d+%d+%d" % (
            image.encoding, image.width, image.height, info.width, info.height, info.distortion_model, bx, by,
            roi_w, roi_h, info.roi.x_offset, info.roi.y_offset))
        self.assertEqual((image.width, image.height), (roi_w // bx, roi_h // by))
        if self.p["expect_encoding"]:
            self.assertEqual(image.encoding, self.p["expect_encoding"])

    def test_spots_recall_centroids_and_beams(self):
        d = self.data
        stamps = sorted(s for s in d["spots"] if s in d["gt_spots"])
        self.assertGreaterEqual(len(stamps), self.p["frames"], "too few frames with both spots and their truth")
        visible = found = wrong = 0
        errors, worst_frame = [], 1.0
        for s in stamps:
            truth, spots = d["gt_spots"][s].centroids, d["spots"][s].centroids
            pairs = match_spots(spots, truth, self.p["match_radius_px"])
            matched_of = {i: j for i, j, _ in pairs}
            frame_wrong = sum(1 for i, c in enumerate(spots)
                              if c.beam >= 0 and (i not in matched_of or truth[matched_of[i]].beam != c.beam))
            visible += len(truth)
            found += len(pairs)
            wrong += frame_wrong
            errors += [e for _, _, e in pairs]
            if truth:
                worst_frame = min(worst_frame, len(pairs) / float(len(truth)))
            self.assertEqual(frame_wrong, 0, "wrong beams in the frame stamped %.3f" % s.to_sec())
        recall = found / float(visible)
        rms = math.sqrt(np.mean(np.square(errors)))
        self.measure("spots", "%d frames, recall %.4f (worst frame %.4f), centroid RMS %.4f px (p95 %.4f), "
                     "wrong beams %d" % (len(stamps), recall, worst_frame, rms, np.percentile(errors, 95), wrong))
        self.assertGreaterEqual(recall, self.p["min_recall"])
        self.assertGreaterEqual(worst_frame, self.p["min_frame_recall"])
        self.assertLessEqual(rms, self.p["max_centroid_px"])

    def test_depth(self):
        d = self.data
        stamps = sorted(s for s in d["points"] if s in d["gt_points"])
        self.assertGreaterEqual(len(stamps), self.p["frames"])
        rel, worst = [], 0.0
        for s in stamps:
            est, gt = cloud_xyz(d["points"][s]), cloud_xyz(d["gt_points"][s])
            self.assertEqual(est.shape, gt.shape)
            ok = np.isfinite(est).all(axis=1) & np.isfinite(gt).all(axis=1)
            frame = np.linalg.norm(est[ok] - gt[ok], axis=1) / np.linalg.norm(gt[ok], axis=1)
            rel += list(frame)
            if len(frame):
                worst = max(worst, math.sqrt(np.mean(frame ** 2)))
        pooled = 100.0 * math.sqrt(np.mean(np.square(rel)))
        self.measure("depth", "RMS %.4f %% of z (worst frame %.4f %%) over %d points" % (pooled, 100 * worst, len(rel)))
        self.assertLessEqual(pooled, self.p["max_depth_percent"])

    def test_pose(self):
        d = self.data
        after = [d["pose"][s] for s in self.after_lock if s in d["pose"]]
        locks = [i for i, e in enumerate(after) if is_identity(e.transform)]
        self.assertTrue(locks, "no locked frame (identity estimate) after the lock request")
        after = after[locks[-1]:]
        pairs = [(e, d["gt_pose"][e.header.stamp]) for e in after if e.header.stamp in d["gt_pose"]]
        self.assertGreaterEqual(len(pairs), self.p["frames"] // 2, "too few pose estimates matched the truth")
        gt_lock_inv = np.linalg.inv(transform_matrix(pairs[0][1].transform))
        t_err, r_err, valid, moved = [], [], 0, 0.0
        for est, gt in pairs[1:]:
            truth = transform_matrix(gt.transform) @ gt_lock_inv
            moved = max(moved, np.linalg.norm(truth[:3, 3]) * 1e3)
            valid += 1 if est.valid else 0
            if est.valid:
                E = transform_matrix(est.transform) @ np.linalg.inv(truth)
                t_err.append(np.linalg.norm(E[:3, 3]) * 1e3)
                r_err.append(rotation_angle_deg(E[:3, :3]))
        share = valid / float(len(pairs) - 1)
        t_rms = math.sqrt(np.mean(np.square(t_err))) if t_err else float("nan")
        r_rms = math.sqrt(np.mean(np.square(r_err))) if r_err else float("nan")
        self.measure("pose", "%.3f mm / %.4f deg RMS, %.1f %% of %d valid (largest true motion %.1f mm)" % (
            t_rms, r_rms, 100 * share, len(pairs) - 1, moved))
        self.assertGreater(moved, 1.0, "the rig did not move: the pose test would prove nothing")
        self.assertGreaterEqual(share, self.p["min_valid"])
        self.assertLessEqual(t_rms, self.p["max_translation_mm"])
        self.assertLessEqual(r_rms, self.p["max_rotation_deg"])


if __name__ == "__main__":
    rostest.rosrun(PKG, "end_to_end", EndToEnd)
