#!/usr/bin/env python3
"""A recorded bag of strobed frames through pipeline.launch source:=none
strobe:=true (strobe_replay.test, the strobed acceptance):
1. the simulated camera, strobed at 20 Hz (strobe_bag_source.launch:
   projector-on and projector-off frames alternating, the rig moving, full
   sun, dots at ~30 % of the sunlit rock, 2 cm grain; the recommended rig's
   12-bit camera as bgr16), is recorded with its ground truth;
2. the bag is replayed through replay.launch strobe:=true at half speed and
   the outputs recorded.
Asserts against the bag's truth the issue's bounds: recall >= 99 % pooled
(dots within 3 px of their true pixel / visible dots, over the frames that
have their own projector-off frame on each side: see bracketed), centroid RMS <= 0.10
px, 0 wrong beams (a beam's point more than 2 cm from that beam's true hit
point), pose <= 1.0 mm / 0.05 deg RMS with >= 90 % valid (reference: the
first valid frame, as the replay locks it); and depth RMS <= 0.1 % of z,
every frame's recall >= 95 %. Measured (three runs at 20 Hz): recall 100 %
(worst frame 100 %), 0.0777-0.0783 px, depth 0.035-0.041 %, pose
0.175-0.195 mm / 0.006-0.007 deg, 57 of 58 projector-on frames scored
(docs/daylight.md)."""
import math
import os
import shutil
import tempfile
import time
import unittest

import numpy as np
import rosbag
import rospy
import rostest
from check_replay import accuracy, artifact_dir, read_truth, start, stop
from structured_light_stabilizer.evaluation import cloud_xyz

PKG = "structured_light_stabilizer"
INPUT_TOPICS = ["/camera/image_raw", "/camera/camera_info", "/camera/image_ambient", "/sim/ground_truth/points",
                "/sim/ground_truth/pose_delta", "/sim/ground_truth/spots"]
OUTPUT_TOPICS = ["/spots", "/points", "/pose_delta"]
RECORD_S = 6  # 20 Hz bgr16 frames: 6 MB each, about 720 MB of bag
WRONG_BEAM_M = 0.02  # neighbouring beams are ~5 cm apart at 1.5 m


def read_spots(path, topic):
    spots = {}
    with rosbag.Bag(path) as bag:
        for _, msg, _ in bag.read_messages(topics=[topic]):
            spots[msg.header.stamp.to_nsec()] = [(c.x, c.y) for c in msg.centroids]
    return spots


def bracketed(truth, path):
    """The true frames whose projector-on frame is in the bag with its own
    projector-off frames, one before and one after it, each within 0.6 of the
    median spacing of the projector-on frames (half of it apart in a strobe).
    `rosbag record --duration` cuts the sequence anywhere, and a recorder
    starved of CPU loses frames (the publisher queues five per subscriber):
    such an on-frame is compensated from one side only, or across a gap
    (recall 59 % measured on one, extrapolated, under CPU load). Those frames
    are left out of the spot scores, and counted."""
    with rosbag.Bag(path) as bag:
        off = sorted(m.header.stamp.to_nsec() for _, m, _ in bag.read_messages(topics=["/camera/image_ambient"]))
        images = set(m.header.stamp.to_nsec() for _, m, _ in bag.read_messages(topics=["/camera/image_raw"]))
    on = sorted(stamp for stamp in truth if stamp in images)
    if not off or len(on) < 2:
        return {}
    reach = 0.6 * float(np.median(np.diff(on)))
    off = np.array(off)
    kept = {}
    for stamp in on:
        i = int(np.searchsorted(off, stamp))
        if 0 < i < len(off) and stamp - off[i - 1] <= reach and off[i] - stamp <= reach:
            kept[stamp] = truth[stamp]
    return kept


def count_messages(path, topic):
    with rosbag.Bag(path) as bag:
        return bag.get_message_count(topic_filters=[topic])


def score_spots(found, truth):
    """Pooled recall, worst frame's recall, centroid RMS and the per-frame
    (stamp, recall, RMS) sorted worst RMS first: each true dot matched to the
    nearest spot within 3 px, closest pairs first."""
    matched, total, sq, frames = 0, 0, 0.0, []
    for stamp, gt in truth.items():
        spots = found.get(stamp, [])
        pairs = sorted((math.hypot(s[0] - g[0], s[1] - g[1]), i, j) for i, s in enumerate(spots)
                       for j, g in enumerate(gt))
        used_s, used_g, frame_sq = set(), set(), 0.0
        for d, i, j in pairs:
            if d > 3.0 or i in used_s or j in used_g:
                continue
            used_s.add(i)
            used_g.add(j)
            frame_sq += d * d
        matched += len(used_g)
        total += len(gt)
        sq += frame_sq
        if gt:
            frames.append((stamp, len(used_g) / len(gt), math.sqrt(frame_sq / max(len(used_g), 1))))
    frames.sort(key=lambda f: -f[2])
    worst = min((f[1] for f in frames), default=1.0)
    return matched / max(total, 1), worst, math.sqrt(sq / max(matched, 1)), frames


class StrobeReplay(unittest.TestCase):
    def setUp(self):
        rospy.init_node("check_strobe_replay", anonymous=True)
        self.dir = tempfile.mkdtemp(prefix="sls_strobe_replay_")
        self.log = open(os.path.join(self.dir, "processes.log"), "w")

    def tearDown(self):
        self.log.close()
        shutil.rmtree(self.dir, ignore_errors=True)

    def record(self, name, topics, duration=None):
        # A 2 GB buffer: 20 Hz bgr16 frames are 120 MB/s, more than the default 256 MB absorbs under CPU load.
        args = ["rosbag", "record", "--buffsize=2048", "-O", os.path.join(self.dir, name)]
        if duration:
            args.append("--duration=%d" % duration)
        return start(args + topics, self.log)

    def fail_with_log(self, what):
        self.log.flush()
        kept = os.path.join(artifact_dir(), "strobe_replay_processes.log")
        shutil.copy(self.log.name, kept)
        self.fail("%s (process log: %s)" % (what, kept))

    def test_strobed_bag(self):
        source = start(["roslaunch", PKG, "strobe_bag_source.launch"], self.log)
        try:
            from sensor_msgs.msg import Image
            rospy.wait_for_message("/camera/image_ambient", Image, timeout=90)
            rec = self.record("input.bag", INPUT_TOPICS, RECORD_S)
            rec.wait(timeout=90)
        finally:
            stop(source)
        bag_in = os.path.join(self.dir, "input.bag")
        if not os.path.exists(bag_in):
            self.fail_with_log("no input bag recorded")
        n_on, n_off = count_messages(bag_in, "/camera/image_raw"), count_messages(bag_in, "/camera/image_ambient")
        print("[ MEASURE ] recorded %d projector-on and %d ambient frames" % (n_on, n_off))
        self.assertGreaterEqual(n_on, 15)
        self.assertGreaterEqual(n_off, 15)

        time.sleep(2.0)
        if rospy.has_param("/use_sim_time"):
            rospy.delete_param("/use_sim_time")
        out = self.record("replay.bag", OUTPUT_TOPICS)
        time.sleep(3.0)  # the recorder subscribes before the replay starts
        launch = start(["roslaunch", PKG, "replay.launch", "bag:=" + bag_in, "rate:=0.5", "start_delay:=4",
                        "required:=true", "strobe:=true"], self.log)
        launch.wait(timeout=200)
        time.sleep(1.0)
        stop(out)
        bag_out = os.path.join(self.dir, "replay.bag")
        if not os.path.exists(bag_out):
            self.fail_with_log("the replay produced no output")

        truth_spots = read_spots(bag_in, "/sim/ground_truth/spots")
        scored = bracketed(truth_spots, bag_in)
        print("[ MEASURE ] spots scored on %d of %d projector-on frames (the others lack their projector-off frame "
              "on one side in the bag: the ends of the recording, frames the recorder lost)" %
              (len(scored), len(truth_spots)))
        self.assertGreaterEqual(len(scored), 15)
        recall, worst, rms, frames = score_spots(read_spots(bag_out, "/spots"), scored)
        print("[ MEASURE ] worst frames (stamp, recall, RMS px): %s" %
              ", ".join("%d %.2f %.3f" % f for f in frames[:3]))
        gt_points, _ = read_truth(bag_in)
        wrong, compared = 0, 0
        with rosbag.Bag(bag_out) as bag:
            for _, msg, _ in bag.read_messages(topics=["/points"]):
                gt = gt_points.get(msg.header.stamp.to_nsec())
                if gt is None:
                    continue
                est = cloud_xyz(msg)
                ok = np.isfinite(est).all(axis=1) & np.isfinite(gt).all(axis=1)
                err = np.linalg.norm(est[ok] - gt[ok], axis=1)
                wrong += int((err > WRONG_BEAM_M).sum())
                compared += int(ok.sum())
        outputs = ({}, {})
        with rosbag.Bag(bag_out) as bag:
            for topic, msg, _ in bag.read_messages(topics=["/points", "/pose_delta"]):
                outputs[0 if topic == "/points" else 1][msg.header.stamp.to_nsec()] = msg
        acc = accuracy(outputs, read_truth(bag_in))
        print("[ MEASURE ] strobed bag replay: recall %.4f (worst frame %.3f), centroid %.4f px, wrong beams %d of %d, "
              "%s" % (recall, worst, rms, wrong, compared, ", ".join("%s=%.4g" % kv for kv in sorted(acc.items()))))
        self.assertGreaterEqual(len(outputs[1]), n_on - 2, "pose deltas missing")
        self.assertGreaterEqual(recall, 0.99)
        self.assertGreaterEqual(worst, 0.95)
        self.assertLessEqual(rms, 0.10)
        self.assertEqual(wrong, 0)
        self.assertLessEqual(acc["depth_rms_percent"], 0.1)
        self.assertGreater(compared, 50 * n_on)
        self.assertLessEqual(acc["translation_rms_mm"], 1.0)
        self.assertLessEqual(acc["rotation_rms_deg"], 0.05)
        self.assertGreaterEqual(acc["valid_fraction"], 0.9)


if __name__ == "__main__":
    rostest.rosrun(PKG, "strobe_replay", StrobeReplay)
