#!/usr/bin/env python3
"""rosbag round trip (the pipeline issue):
1. live: demo.launch (simulator + pipeline); rosbag records the camera topics
   and ground truth (bag A) and the live outputs (bag L);
2. replay A twice through replay.launch (source:=none, --clock, use_sim_time)
   recording the outputs (R1, R2), and once with split:=true, PoseDelta as a
   standalone node in its own process (R3).
Asserts: R1 and R2 are identical (same stamps, same points bytes, same
pose_delta); R3 equals R1 (crossing a process boundary changes nothing); the
live run and the replays meet the stage bounds against the ground truth."""
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np
import rosbag
import rosgraph
import yaml
import rospy
import rostest
from structured_light_stabilizer.evaluation import cloud_xyz, pose_error, transform_matrix

PKG = "structured_light_stabilizer"
INPUT_TOPICS = ["/camera/image_raw", "/camera/camera_info", "/sim/ground_truth/points",
                "/sim/ground_truth/pose_delta", "/sim/ground_truth/spots"]
OUTPUT_TOPICS = ["/points", "/pose_delta"]
RECORD_S = 6


def artifact_dir():
    """The test results folder (rostest passes --gtest_output=xml:<file>)."""
    for arg in sys.argv:
        if arg.startswith("--gtest_output=xml:"):
            return os.path.dirname(arg.split(":", 1)[1])
    return tempfile.gettempdir()


def start(args, log):
    return subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def group_alive(pgid):
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def stop(proc, timeout=20.0):
    """SIGINT to the process group, then wait until every process of the
    group has exited. Waiting for `proc` alone is not enough: the `rosbag
    record` wrapper exits on SIGINT at once, while its `record` child is still
    closing the bag (until then the file is <name>.active)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
    deadline = time.time() + timeout
    while time.time() < deadline:
        proc.poll()  # reap the leader: a zombie still counts as a member of the group
        if not group_alive(proc.pid):
            break
        time.sleep(0.1)
    if group_alive(proc.pid):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def read_outputs(path):
    points, poses = {}, {}
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages(topics=OUTPUT_TOPICS):
            if topic == "/points":
                points[msg.header.stamp.to_nsec()] = msg
            else:
                poses[msg.header.stamp.to_nsec()] = msg
    return points, poses


def complete_frames(path):
    """Stamps (ns) of the frames whose image and camera_info are both in the
    bag: the recorder subscribes to each topic on its own, so the first frame
    may be recorded in part (e.g. its ground truth without its image)."""
    stamps = {"/camera/image_raw": set(), "/camera/camera_info": set()}
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages(topics=list(stamps)):
            stamps[topic].add(msg.header.stamp.to_nsec())
    return stamps["/camera/image_raw"] & stamps["/camera/camera_info"]


def read_truth(path):
    points, poses = {}, {}
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages(topics=["/sim/ground_truth/points", "/sim/ground_truth/pose_delta"]):
            if topic.endswith("points"):
                points[msg.header.stamp.to_nsec()] = cloud_xyz(msg)
            else:
                poses[msg.header.stamp.to_nsec()] = transform_matrix(msg.transform)
    return points, poses


def accuracy(outputs, truth):
    """Depth RMS (% of distance), pose translation RMS (mm), rotation RMS (deg),
    valid fraction; the pose is compared with the true motion since the first
    valid frame (the auto-lock reference)."""
    points, poses = outputs
    gt_points, gt_poses = truth
    rel = []
    for stamp, msg in points.items():
        if stamp in gt_points:
            est, gt = cloud_xyz(msg), gt_points[stamp]
            ok = np.isfinite(est).all(axis=1) & np.isfinite(gt).all(axis=1)
            rel.extend(np.linalg.norm(est[ok] - gt[ok], axis=1) / np.linalg.norm(gt[ok], axis=1))
    t_sq, r_sq, valid, ref = [], [], 0, None
    for stamp in sorted(poses):
        msg = poses[stamp]
        if not msg.valid or stamp not in gt_poses:
            continue
        valid += 1
        if ref is None:
            ref = gt_poses[stamp]
        truth_rel = gt_poses[stamp] @ np.linalg.inv(ref)
        t_err, r_err = pose_error(transform_matrix(msg.transform), truth_rel)
        t_sq.append(t_err ** 2)
        r_sq.append(r_err ** 2)
    rms = lambda v: math.sqrt(np.mean(v)) if len(v) else float("nan")
    return {"depth_rms_percent": 100 * rms(np.square(rel)), "translation_rms_mm": 1e3 * rms(t_sq),
            "rotation_rms_deg": rms(r_sq), "valid_fraction": valid / max(1, len(poses)),
            "frames": len(points)}


class ReplayRoundTrip(unittest.TestCase):
    def setUp(self):
        rospy.init_node("check_replay", anonymous=True)
        self.dir = tempfile.mkdtemp(prefix="sls_replay_")
        self.log = open(os.path.join(self.dir, "processes.log"), "w")

    def tearDown(self):
        self.log.close()
        shutil.rmtree(self.dir, ignore_errors=True)

    def record(self, name, topics, duration=None):
        """Starts rosbag record and returns once the master lists it as a
        subscriber of every topic: a recorder started just before the
        pipeline can otherwise connect after the first messages are out
        (python start-up of `rosbag record` takes seconds on a loaded
        machine), and the bag misses them."""
        node = "/recorder_" + os.path.splitext(name)[0]
        args = ["rosbag", "record", "-O", os.path.join(self.dir, name), "__name:=" + node[1:]]
        if duration:
            args.append("--duration=%d" % duration)
        proc = start(args + topics, self.log)
        master = rosgraph.Master(rospy.get_name())
        deadline = time.time() + 60.0
        while time.time() < deadline and proc.poll() is None:
            subscribers = dict(master.getSystemState()[1])
            if all(node in subscribers.get(t, []) for t in topics):
                return proc
            time.sleep(0.1)
        self.fail("rosbag record for %s did not subscribe to %s within 60 s (exit %s)" % (name, topics, proc.poll()))

    def replay(self, name, split):
        time.sleep(2.0)  # let the previous launch's names leave the master
        # The previous replay left /use_sim_time set: the recorder would wait
        # for /clock; it records on wall time (the outputs are compared by
        # header stamp), replay.launch sets sim time again for the pipeline.
        if rospy.has_param("/use_sim_time"):
            rospy.delete_param("/use_sim_time")
        outputs = self.record(name, OUTPUT_TOPICS)
        launch = start(["roslaunch", PKG, "replay.launch", "bag:=" + os.path.join(self.dir, "input.bag"),
                        "rate:=0.5", "start_delay:=3", "required:=true", "split:=%s" % str(split).lower()],
                       self.log)
        launch.wait(timeout=120)
        time.sleep(1.0)
        stop(outputs)
        path = os.path.join(self.dir, name)
        if not os.path.exists(path):
            kept = self.keep_log()
            with open(self.log.name) as f:
                tail = f.read()[-3000:]
            self.fail("the %s replay produced no output (launch exit %s, recorder exit %s, files %s; whole log in %s); "
                      "process log tail:\n%s" % (name, launch.returncode, outputs.returncode,
                                                  sorted(os.listdir(self.dir)), kept, tail))
        return read_outputs(path)

    def test_round_trip(self):
        try:
            self.round_trip()
        except Exception:
            self.keep_log()
            raise

    def keep_log(self):
        """Copies the processes' output (PoseDelta names why a frame is not
        valid) beside the results; returns where."""
        self.log.flush()
        kept = os.path.join(artifact_dir(), "replay_processes.log")
        shutil.copy(self.log.name, kept)
        return kept

    def round_trip(self):
        live_stats = os.path.join(self.dir, "live_stats.yaml")
        live = start(["roslaunch", PKG, "demo.launch", "rate:=10", "stats_file:=" + live_stats], self.log)
        try:
            from sensor_msgs.msg import PointCloud2
            rospy.wait_for_message("/points", PointCloud2, timeout=60)
            rec_in = self.record("input.bag", INPUT_TOPICS, RECORD_S)
            rec_out = self.record("live.bag", OUTPUT_TOPICS, RECORD_S)
            rec_in.wait(timeout=60)
            rec_out.wait(timeout=60)
        finally:
            stop(live)
        truth = read_truth(os.path.join(self.dir, "input.bag"))
        live_out = read_outputs(os.path.join(self.dir, "live.bag"))
        with open(live_stats) as f:
            live_acc = yaml.safe_load(f)
        invalid = [(s, m.status) for s, m in sorted(live_out[1].items()) if not m.valid]
        print("[ MEASURE ] live: %d of %d recorded pose deltas invalid%s" % (
            len(invalid), len(live_out[1]), "".join("; %d: %s" % (s, st) for s, st in invalid[:10])))
        r1 = self.replay("replay1.bag", split=False)
        r2 = self.replay("replay2.bag", split=False)
        r3 = self.replay("split.bag", split=True)

        # Frames whose image and camera_info are both in the bag: one cloud and
        # one pose_delta each in every replay.
        complete = sorted(complete_frames(os.path.join(self.dir, "input.bag")))
        n_input = len(complete)
        print("[ MEASURE ] recorded %d frames; replays produced %d / %d / %d clouds and %d / %d / %d pose deltas"
              % (n_input, len(r1[0]), len(r2[0]), len(r3[0]), len(r1[1]), len(r2[1]), len(r3[1])))
        self.assertGreaterEqual(n_input, 3 * RECORD_S, "too few frames recorded")
        # Every recorded frame goes through the replay (nothing dropped at half speed).
        missing = [i for i, s in enumerate(complete) if s not in r1[0]]
        self.assertEqual(missing, [], "frames (by index among %d) without a cloud in the first replay; process log: "
                         "replay_processes.log beside the results" % n_input)
        self.assertEqual(sorted(r1[0]), complete)
        self.assertEqual(sorted(r1[1]), complete)

        for name, other in (("second replay", r2), ("split replay", r3)):
            self.assertEqual(sorted(other[0]), sorted(r1[0]), "%s: other cloud stamps" % name)
            self.assertEqual(sorted(other[1]), sorted(r1[1]), "%s: other pose_delta stamps" % name)
            for stamp, msg in r1[0].items():
                self.assertEqual(bytes(other[0][stamp].data), bytes(msg.data), "%s: points differ" % name)
            for stamp, msg in r1[1].items():
                o = other[1][stamp]
                self.assertEqual((o.valid, o.status, o.points_used), (msg.valid, msg.status, msg.points_used),
                                 "%s: pose_delta of frame %d of %d (stamp %d) differs from the first replay's"
                                 % (name, sorted(r1[1]).index(stamp), len(r1[1]), stamp))
                self.assertTrue(np.array_equal(transform_matrix(o.transform), transform_matrix(msg.transform)), "%s: pose differs" % name)
                self.assertEqual(tuple(o.covariance), tuple(msg.covariance))

        # The live run locked its reference before recording began, so its
        # pose figures come from the demo monitor, which saw the whole run.
        live_acc["valid_fraction"] = live_acc["pose_valid_fraction"]
        # The replays start from the bag's first frame: their reference is the
        # first valid frame of the bag.
        replay_acc = accuracy(r1, truth)
        # Live and replay see the same frames: their clouds agree closely.
        common = [s for s in r1[0] if s in live_out[0]]
        live_vs_replay = max(np.nanmax(np.abs(cloud_xyz(live_out[0][s]) - cloud_xyz(r1[0][s]))) for s in common)
        print("[ MEASURE ] live vs replay on %d common frames: max |points difference| = %.3g m"
              % (len(common), live_vs_replay))
        self.assertGreater(len(common), 0)
        self.assertLess(live_vs_replay, 1e-3)
        # The valid fraction: the replays process every frame with its image
        # at half speed, 0.9; the live run shares two cores with the
        # simulator and two recorders writing 30 MB/s, and one CI run on a
        # slower VM had 14 of 85 live pose deltas not valid (0.835, 2026-12-02;
        # the demo monitor's per-second figure dipped to 77-91 % in four of
        # eight seconds): 0.75 there, the statuses printed above and the
        # processes' log kept on failure.
        for name, acc, min_valid in (("live", live_acc, 0.75), ("replay", replay_acc, 0.9)):
            print("[ MEASURE ] %s: %s" % (name, ", ".join("%s=%.4g" % kv for kv in sorted(acc.items()))))
            self.assertLessEqual(acc["depth_rms_percent"], 0.1, name)
            self.assertLessEqual(acc["translation_rms_mm"], 1.0, name)
            self.assertLessEqual(acc["rotation_rms_deg"], 0.05, name)
            self.assertGreaterEqual(acc["valid_fraction"], min_valid, name)


if __name__ == "__main__":
    rostest.rosrun(PKG, "replay_round_trip", ReplayRoundTrip)
