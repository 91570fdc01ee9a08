#!/usr/bin/env python3
"""Checker for hostile_inputs.test (issue 9).

Phases, in one test so that they run in order:
  1. good frames relayed from the simulator in ns "good" (locks PoseDelta's
     reference, proves the wiring);
  2. hostile frames on camera/image_raw + camera/camera_info, each with a
     unique stamp in [1000 s, 3000 s): every encoding of
     sensor_msgs/image_encodings, 0x0 and 1x1 images, a step smaller than a
     row, truncated data, camera_info with zeros / NaN / another size, random
     headers and bytes, a burst of 200 bad frames at 200 Hz;
  3. 5 s of silence;
  4. good frames again, compared with the simulator's ground truth.
Asserts: the manager process stays the same and alive and its ~list service
answers throughout; no spots / points / pose_delta carries a bad frame's
stamp; each bad input produced a WARN/ERROR on /rosout naming the problem,
and the burst did not flood /rosout; after the silence every stage is
correct again (spots vs true centroids, points vs true points, pose_delta
valid and close to the true motion since the reference)."""
import math
import os
import sys
import threading
import time
import unittest
import xmlrpc.client

import numpy as np
import rosgraph
import rosnode
import rospy
import rostest
from nodelet.srv import NodeletList
from diagnostic_msgs.msg import DiagnosticArray
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from structured_light_stabilizer.msg import CentroidArray, PoseDelta
from structured_light_stabilizer.evaluation import cloud_xyz, pose_error, transform_matrix

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from sample_msgs import camera_info  # noqa: E402

PKG = "structured_light_stabilizer"
BIG = 1 << 24  # rospy socket buffer for 3 MB images

# Every encoding of sensor_msgs/image_encodings.h (noetic): bytes per pixel
# (nv21: 1.5, stored as whole rows of width bytes over 1.5 x height rows).
ENCODINGS = {
    "rgb8": 3, "rgba8": 4, "rgb16": 6, "rgba16": 8, "bgr8": 3, "bgra8": 4, "bgr16": 6, "bgra16": 8,
    "mono8": 1, "mono16": 2,
    "bayer_rggb8": 1, "bayer_bggr8": 1, "bayer_gbrg8": 1, "bayer_grbg8": 1,
    "bayer_rggb16": 2, "bayer_bggr16": 2, "bayer_gbrg16": 2, "bayer_grbg16": 2,
    "yuv422": 2, "yuv422_yuy2": 2, "nv21": 1, "nv24": 3,
}
for _depth, _size in (("8U", 1), ("8S", 1), ("16U", 2), ("16S", 2), ("32S", 4), ("32F", 4), ("64F", 8)):
    for _ch in range(1, 5):
        ENCODINGS["%sC%d" % (_depth, _ch)] = _size * _ch
# SpotDetector's inputs (docs/interface.md; 8UC1 = mono8, 16UC1 = mono16).
ACCEPTED = ("bgr8", "rgb8", "bgra8", "rgba8", "bgr16", "rgb16", "mono8", "8UC1", "mono16", "16UC1", "bayer_rggb8",
            "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8", "yuv422", "yuv422_yuy2")


def image(width, height, encoding, step=None, data=None, fill=0):
    msg = Image()
    msg.header.frame_id = "camera_optical_frame"
    msg.width, msg.height, msg.encoding = width, height, encoding
    bpp = ENCODINGS.get(encoding, 1)
    msg.step = step if step is not None else width * bpp
    rows = height * 3 // 2 if encoding == "nv21" else height
    msg.data = data if data is not None else bytes([fill]) * (msg.step * rows)
    return msg


class HostileInputs(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("check_hostile_inputs")
        cls.lock = threading.Lock()
        cls.manager = rospy.get_param("~manager", "/stabilizer_manager")
        cls.out = {"spots": {}, "points": {}, "pose_delta": {}}
        cls.gt = {"points": {}, "pose": {}, "spots": {}}
        cls.logs = []  # (wall time, level, node, text)
        cls.good_images, cls.good_infos = {}, {}
        cls.relay = False
        cls.relayed = []  # stamps relayed, in order
        cls.carrier = None  # one good (image, info) kept to carry bad camera_infos
        cls.manager_failures = []
        cls.image_pub = rospy.Publisher("camera/image_raw", Image, queue_size=400)
        cls.info_pub = rospy.Publisher("camera/camera_info", CameraInfo, queue_size=400)
        rospy.Subscriber("/rosout", Log, cls.on_log, queue_size=1000)
        cls.diagnostics = {}  # status name -> latest "message; key=value ..." (printed when a check fails)
        rospy.Subscriber("/diagnostics", DiagnosticArray, cls.on_diagnostics, queue_size=50)
        rospy.Subscriber("spots", CentroidArray, cls.on_out("spots"), queue_size=400)
        rospy.Subscriber("points", PointCloud2, cls.on_out("points"), queue_size=400)
        rospy.Subscriber("pose_delta", PoseDelta, cls.on_out("pose_delta"), queue_size=400)
        rospy.Subscriber("good/sim/ground_truth/points", PointCloud2, cls.on_gt("points"), queue_size=20)
        rospy.Subscriber("good/sim/ground_truth/pose_delta", PoseDelta, cls.on_gt("pose"), queue_size=20)
        rospy.Subscriber("good/sim/ground_truth/spots", CentroidArray, cls.on_gt("spots"), queue_size=20)
        rospy.Subscriber("good/camera/image_raw", Image, cls.on_good_image, queue_size=4, buff_size=BIG)
        rospy.Subscriber("good/camera/camera_info", CameraInfo, cls.on_good_info, queue_size=4)
        # The whole chain is lazy: wait until the manager listens to the input
        # (one connection per process, however many nodelets subscribe).
        deadline = time.time() + 60
        while time.time() < deadline and (cls.image_pub.get_num_connections() < 1 or
                                          cls.info_pub.get_num_connections() < 1):
            time.sleep(0.1)
        time.sleep(1.0)
        cls.list_srv = rospy.ServiceProxy(cls.manager + "/list", NodeletList)
        cls.list_srv.wait_for_service(30)
        cls.manager_pid = cls.pid_of(cls.manager)
        print("[ MEASURE ] manager %s pid %d, nodelets %s" % (cls.manager, cls.manager_pid, cls.list_srv().nodelets))
        cls.watch_stop = threading.Event()
        cls.watch_calls = 0
        cls.watcher = threading.Thread(target=cls.watch_manager, daemon=True)
        cls.watcher.start()

    @classmethod
    def tearDownClass(cls):
        cls.watch_stop.set()

    # ------------------------------------------------------------------ I/O
    @staticmethod
    def pid_of(node):
        api = rosnode.get_api_uri(rosgraph.Master("/check_hostile_inputs"), node, skip_cache=True)
        code, _, pid = xmlrpc.client.ServerProxy(api).getPid("/check_hostile_inputs")
        assert code == 1, "getPid failed"
        return pid

    @classmethod
    def watch_manager(cls):
        """Once a second: the manager's pid is alive and its ~list answers."""
        while not cls.watch_stop.wait(1.0):
            try:
                os.kill(cls.manager_pid, 0)
                names = cls.list_srv().nodelets
                if len(names) < 4:
                    cls.manager_failures.append("~list answered only %s" % names)
                cls.watch_calls += 1
            except Exception as e:  # a dead process or an unanswered service
                cls.manager_failures.append("%.1f: %s" % (time.time(), e))

    @classmethod
    def on_diagnostics(cls, msg):
        with cls.lock:
            for st in msg.status:
                cls.diagnostics[st.name] = "%s; %s" % (st.message, ", ".join("%s=%s" % (kv.key, kv.value)
                                                                             for kv in st.values))

    @classmethod
    def on_log(cls, msg):
        with cls.lock:
            cls.logs.append((time.time(), msg.level, msg.name, msg.msg))

    @classmethod
    def on_out(cls, name):
        def cb(msg):
            with cls.lock:
                cls.out[name][msg.header.stamp] = msg
        return cb

    @classmethod
    def on_gt(cls, name):
        def cb(msg):
            with cls.lock:
                cls.gt[name][msg.header.stamp] = msg
        return cb

    @classmethod
    def on_good_image(cls, msg):
        with cls.lock:
            cls.good_images[msg.header.stamp] = msg
        cls.forward(msg.header.stamp)

    @classmethod
    def on_good_info(cls, msg):
        with cls.lock:
            cls.good_infos[msg.header.stamp] = msg
        cls.forward(msg.header.stamp)

    @classmethod
    def forward(cls, stamp):
        """Relays a good frame (camera_info first: the Triangulator uses the
        latest one) once both halves are in, stamps kept."""
        with cls.lock:
            img, info = cls.good_images.get(stamp), cls.good_infos.get(stamp)
            if img is None or info is None:
                return
            del cls.good_images[stamp], cls.good_infos[stamp]
            for d in (cls.good_images, cls.good_infos):
                for s in [s for s in d if s < stamp]:
                    del d[s]
            if cls.carrier is None:
                cls.carrier = (img, info)
            if not cls.relay:
                return
            cls.relayed.append(stamp)
        cls.info_pub.publish(info)
        cls.image_pub.publish(img)

    # ------------------------------------------------------------- helpers
    def log_mark(self):
        with self.lock:
            return len(self.logs)

    def wait_log(self, mark, fragments, timeout=3.0):
        """A WARN/ERROR of the manager after `mark` whose text contains every
        fragment (a tuple inside means one of them)."""
        def match(text):
            for f in fragments:
                alts = f if isinstance(f, tuple) else (f,)
                if not any(a in text for a in alts):
                    return False
            return True
        deadline = time.time() + timeout
        while time.time() < deadline:
            with self.lock:
                for (_, level, name, text) in self.logs[mark:]:
                    if level >= Log.WARN and name == self.manager and match(text):
                        return text
            time.sleep(0.02)
        return None

    def relay_good(self, seconds):
        type(self).relay = True
        time.sleep(seconds)
        type(self).relay = False
        with self.lock:
            return list(self.relayed)

    # --------------------------------------------------------------- checks
    def check_good(self, stamps, label):
        """Compares every stage's output on relayed frames with the truth."""
        time.sleep(2.0)  # the tail of the pipeline
        with self.lock:
            out = {k: dict(v) for k, v in self.out.items()}
            gt = {k: dict(v) for k, v in self.gt.items()}
        found = visible = 0
        centroid_sq, centroid_n = 0.0, 0
        depth_rel_sq, depth_n, beams_true, beams_est, clouds = 0.0, 0, 0, 0, 0
        for s in stamps:
            spots, truth = out["spots"].get(s), gt["spots"].get(s)
            if spots is not None and truth is not None and truth.centroids:
                visible += len(truth.centroids)
                t = np.array([[c.x, c.y] for c in truth.centroids])
                for c in spots.centroids:
                    d = np.hypot(t[:, 0] - c.x, t[:, 1] - c.y).min()
                    if d < 2.0:
                        found += 1
                        centroid_sq += d * d
                        centroid_n += 1
            cloud, truth = out["points"].get(s), gt["points"].get(s)
            if cloud is not None and truth is not None:
                est, tru = cloud_xyz(cloud), cloud_xyz(truth)
                self.assertEqual(est.shape, tru.shape, label + ": points layout differs from the truth")
                ok = np.isfinite(est).all(axis=1) & np.isfinite(tru).all(axis=1)
                beams_true += int(np.isfinite(tru).all(axis=1).sum())
                beams_est += int(ok.sum())
                rel = (est[ok, 2] - tru[ok, 2]) / tru[ok, 2]
                depth_rel_sq += float(np.sum(rel ** 2))
                depth_n += int(ok.sum())
                clouds += 1
        poses = [out["pose_delta"][s] for s in stamps if s in out["pose_delta"]]
        valid = [p for p in poses if p.valid]
        # auto_lock: the reference is the first frame with a valid pose delta
        # in the whole run, so the truth is relative to that frame's true pose.
        ref = min((s for s, p in out["pose_delta"].items() if p.valid and s in gt["pose"]), default=None)
        t_sq = r_sq = 0.0
        n_pose = 0
        for p in valid:
            truth_now = gt["pose"].get(p.header.stamp)
            if truth_now is None or ref is None:
                continue
            truth = transform_matrix(truth_now.transform) @ np.linalg.inv(transform_matrix(gt["pose"][ref].transform))
            t_err, r_err = pose_error(transform_matrix(p.transform), truth)
            t_sq += t_err ** 2
            r_sq += r_err ** 2
            n_pose += 1
        depth_rms = 100.0 * math.sqrt(depth_rel_sq / depth_n) if depth_n else float("nan")
        centroid_rms = math.sqrt(centroid_sq / centroid_n) if centroid_n else float("nan")
        t_rms = 1e3 * math.sqrt(t_sq / n_pose) if n_pose else float("nan")
        r_rms = math.sqrt(r_sq / n_pose) if n_pose else float("nan")
        print("[ MEASURE ] %s: %d frames relayed; spots %d/%d dots, centroid RMS %.3f px; %d clouds, beams %d/%d, "
              "depth RMS %.4f %%; pose_delta %d (%d valid), error RMS %.2f mm %.4f deg"
              % (label, len(stamps), found, visible, centroid_rms, clouds, beams_est, beams_true, depth_rms,
                 len(poses), len(valid), t_rms, r_rms))
        with self.lock:
            for name, text in sorted(self.diagnostics.items()):
                print("[ MEASURE ] %s: diagnostics %s: %s" % (label, name, text))
        try:
            api = rosnode.get_api_uri(rosgraph.Master("/check_hostile_inputs"), self.manager, skip_cache=True)
            _, _, bus = xmlrpc.client.ServerProxy(api).getBusInfo("/check_hostile_inputs")
            links = [b[1:5] for b in bus if "image_raw" in b[4] or "camera_info" in b[4]]
        except Exception as e:  # diagnostics only
            links = str(e)
        print("[ MEASURE ] %s: image publisher connections %d; manager's camera links %s"
              % (label, self.image_pub.get_num_connections(), links))
        have = lambda d: sum(1 for s in stamps if s in d)
        print("[ MEASURE ] %s: of %d stamps, spots %d (truth %d), points %d (truth %d), pose_delta %d (truth %d)"
              % (label, len(stamps), have(out["spots"]), have(gt["spots"]), have(out["points"]), have(gt["points"]),
                 have(out["pose_delta"]), have(gt["pose"])))
        self.assertGreaterEqual(len(stamps), 8, label + ": too few good frames relayed")
        self.assertGreater(visible, 0, label + ": no spots for the relayed frames")
        self.assertGreaterEqual(found, 0.9 * visible, label + ": SpotDetector recall below 90 %")
        self.assertLess(centroid_rms, 0.25, label + ": centroid RMS vs truth")
        self.assertGreaterEqual(clouds, 0.8 * len(stamps), label + ": points missing for relayed frames")
        self.assertGreaterEqual(beams_est, 0.85 * beams_true, label + ": fewer than 85 % of the beams triangulated")
        self.assertLess(depth_rms, 0.1, label + ": depth RMS vs truth above 0.1 %")
        self.assertGreaterEqual(len(poses), 0.8 * len(stamps), label + ": pose_delta missing for relayed frames")
        self.assertGreaterEqual(len(valid), 0.8 * len(poses), label + ": fewer than 80 % valid pose deltas")
        self.assertLess(t_rms, 2.0, label + ": pose_delta translation error RMS (mm)")
        self.assertLess(r_rms, 0.05, label + ": pose_delta rotation error RMS (deg)")

    # ----------------------------------------------------------------- test
    def test_hostile_inputs(self):
        cls = type(self)
        t0 = time.time()
        before = self.relay_good(4.0)
        self.check_good(before, "good frames before")
        self.assertIsNotNone(cls.carrier, "no good frame kept")
        good_img, good_info = cls.carrier
        W, H = good_img.width, good_img.height

        bad_stamps = {}        # stamp -> label: nothing may come out with it
        spots_allowed = set()  # well-formed images: spots fine, points not
        missing_logs = []
        seq = [0]

        def stamp():
            seq[0] += 1
            return rospy.Time(1000 + seq[0], 123)

        # A kind of problem is logged at once, then at most every 5 s (with
        # the count of frames suppressed), so a case may be covered by the
        # message of an earlier case of the same kind: logs are searched from
        # the start of the hostile phase.
        mark = self.log_mark()

        def send(label, img=None, info=None, fragments=None, points_only=False, own=True):
            """own: a new kind of problem, whose message must come after it."""
            s = stamp()
            case_mark = self.log_mark()
            if info is not None:
                info.header.stamp = s
                self.info_pub.publish(info)
                time.sleep(0.02)
            if img is not None:
                img.header.stamp = s
                self.image_pub.publish(img)
            bad_stamps[s] = label
            if points_only:
                spots_allowed.add(s)
            if fragments:
                text = self.wait_log(case_mark if own else mark, fragments)
                if text is None:
                    missing_logs.append("%s: no WARN/ERROR containing %s" % (label, fragments))
                else:
                    print("[ MEASURE ] %-28s -> %s" % (label, text))
            return s

        def carrier_image():
            m = Image()
            m.header.frame_id = good_img.header.frame_id
            m.width, m.height, m.encoding, m.step = good_img.width, good_img.height, good_img.encoding, good_img.step
            m.is_bigendian, m.data = good_img.is_bigendian, good_img.data
            return m

        good_info_copy = lambda: camera_info(W, H, good_info.K[0], good_info.K[4], good_info.K[2], good_info.K[5])

        # Every encoding ROS knows, well-formed 64x48 frames; the detector's
        # own (ACCEPTED) are not bad: some are sent separately below on a
        # real frame.
        for enc in sorted(ENCODINGS):
            if enc in ACCEPTED:
                continue
            send("encoding " + enc, image(64, 48, enc, fill=100), fragments=["'%s'" % enc])
        send("empty encoding", image(64, 48, "", step=64 * 3, fill=100), fragments=["encoding ''"])
        send("unknown encoding", image(64, 48, "hsv8", step=64 * 3, fill=100), fragments=["'hsv8'"])
        # Geometry of the buffer.
        send("0x0 image", image(0, 0, "bgr8", data=b""), fragments=["0x0", "empty"])
        send("0x0 image with data", image(0, 0, "rgb8", step=0, data=bytes(300)), fragments=["0x0", "empty"])
        send("width 0", image(0, 17, "bgr8", step=0, data=b""), fragments=["empty"], own=False)
        send("step < width*3", image(64, 48, "bgr8", step=100, fill=80), fragments=["step 100", "width * channels"])
        send("step < width*1 mono8", image(64, 48, "mono8", step=63, fill=80), fragments=["step 63", "width * channels"])
        send("truncated data", image(64, 48, "bgr8", data=bytes(64 * 3 * 47 + 5)), fragments=["truncated", "9029 data bytes"])
        trunc = carrier_image()
        trunc.data = trunc.data[: len(trunc.data) // 3]
        send("truncated real frame", trunc, fragments=["truncated"], own=False)
        send("huge size, no data", image(100000, 100000, "bgr8", data=bytes(16)), fragments=["truncated"], own=False)
        # 1x1: a well-formed frame, so spots may come (without dots), but the
        # latest camera_info is W x H: no points, and the Triangulator says why.
        send("1x1 image", image(1, 1, "bgr8", fill=200), info=good_info_copy(),
             fragments=["but the spots come from a 1x1 image"], points_only=True)
        # camera_info: zeros, NaN, another size, binning; carried by a good
        # image with the same stamp (spots are fine, points are not).
        zero = good_info_copy()
        zero.K = [0.0] * 9
        zero.P = [0.0] * 12
        send("camera_info zeros", carrier_image(), zero, fragments=["camera_info", ("zero", "focal")],
             points_only=True)
        nan = good_info_copy()
        nan.K = [float("nan")] * 9
        send("camera_info NaN", carrier_image(), nan, fragments=["NaN"], points_only=True)
        nan_d = good_info_copy()
        nan_d.D = [float("nan")] * 5
        send("camera_info NaN distortion", carrier_image(), nan_d, fragments=["NaN", "distortion"], points_only=True)
        send("camera_info other size", carrier_image(), camera_info(640, 480, 500.0),
             fragments=["camera_info is", "but the spots come from a"], points_only=True, own=False)
        binned = good_info_copy()
        binned.binning_x = binned.binning_y = 2
        send("camera_info binning", carrier_image(), binned, fragments=["binning 2x2"], points_only=True)
        odd = good_info_copy()
        odd.distortion_model = "kannala_brandt"  # rational_polynomial is supported 
        odd.D = [0.0] * 8
        send("camera_info unknown model", carrier_image(), odd, fragments=["kannala_brandt"], points_only=True)
        # Random headers and bytes: never consistent (data < one row of any
        # accepted encoding at width >= 100).
        rng = np.random.default_rng(9)
        names = sorted(ENCODINGS)
        for k in range(12):
            enc = names[rng.integers(len(names))]
            w, h = int(rng.integers(100, 5000)), int(rng.integers(1, 5000))
            msg = image(w, h, enc, step=int(rng.integers(0, 20000)),
                        data=rng.integers(0, 256, int(rng.integers(0, 90)), dtype=np.uint8).tobytes())
            send("random %s %dx%d" % (enc, w, h), msg, fragments=[enc], own=False)
        # Accepted encodings of the same real frame: not bad; spots must come.
        bgr = np.frombuffer(bytes(good_img.data), np.uint8).reshape(H, good_img.step)[:, : W * 3].reshape(H, W, 3)
        alpha = np.full((H, W, 1), 255, np.uint8)
        variants = {"rgb8": bgr[:, :, ::-1], "bgra8": np.concatenate([bgr, alpha], 2),
                    "rgba8": np.concatenate([bgr[:, :, ::-1], alpha], 2), "mono8": bgr[:, :, 1], "8UC1": bgr[:, :, 1]}
        accepted = {}
        for enc, arr in variants.items():
            m = image(W, H, enc, data=np.ascontiguousarray(arr).tobytes())
            info = good_info_copy()
            s = stamp()
            info.header.stamp = m.header.stamp = s
            self.info_pub.publish(info)
            time.sleep(0.02)
            self.image_pub.publish(m)
            accepted[s] = enc
            time.sleep(0.3)
        # Well-formed noise: survival only (nothing to assert on its output).
        noise = image(W, H, "bgr8", data=rng.integers(0, 256, W * H * 3, dtype=np.uint8).tobytes())
        noise_info = good_info_copy()
        noise_info.header.stamp = noise.header.stamp = stamp()
        self.info_pub.publish(noise_info)
        self.image_pub.publish(noise)
        time.sleep(1.0)

        # A burst of 200 bad frames at 200 Hz, three kinds in turn.
        mark = self.log_mark()
        burst_start = time.time()
        kinds = [lambda: image(0, 0, "bgr8", data=b""), lambda: image(32, 24, "32FC1", fill=7),
                 lambda: image(32, 24, "bgr8", data=bytes(100))]
        for k in range(200):
            msg = kinds[k % 3]()
            s = rospy.Time(2000 + k, 0)
            msg.header.stamp = s
            bad_stamps[s] = "burst frame %d" % k
            self.image_pub.publish(msg)
            time.sleep(max(0.0, burst_start + (k + 1) * 0.005 - time.time()))
        burst_s = time.time() - burst_start
        time.sleep(1.0)
        with self.lock:
            burst_logs = [l for l in self.logs[mark:] if l[2] == self.manager and l[1] >= Log.WARN]
        print("[ MEASURE ] burst: 200 bad frames in %.2f s (%.0f Hz), %d WARN/ERROR lines on /rosout"
              % (burst_s, 200 / burst_s, len(burst_logs)))

        # Silence, then good frames again.
        time.sleep(5.0)
        after = self.relay_good(5.0)
        self.check_good(after, "good frames after")

        # --- Assertions on the hostile phase.
        self.assertEqual(self.pid_of(self.manager), cls.manager_pid, "the manager was restarted")
        os.kill(cls.manager_pid, 0)
        print("[ MEASURE ] manager ~list answered %d times, %d failures" % (cls.watch_calls, len(cls.manager_failures)))
        self.assertEqual(cls.manager_failures, [], "the manager did not answer ~list")
        self.assertGreater(cls.watch_calls, 10)
        with self.lock:
            leaked = []
            for topic, msgs in self.out.items():
                for s in msgs:
                    if s in bad_stamps and not (topic == "spots" and s in spots_allowed):
                        leaked.append("%s from '%s'" % (topic, bad_stamps[s]))
            accepted_spots = {enc: len(self.out["spots"][s].centroids) if s in self.out["spots"] else None
                              for s, enc in accepted.items()}
            one = [m for s, m in self.out["spots"].items() if bad_stamps.get(s) == "1x1 image"]
        print("[ MEASURE ] accepted encodings of the real frame, dots found: %s" % accepted_spots)
        self.assertEqual(leaked, [], "output published from bad frames")
        for enc in ("rgb8", "bgra8", "rgba8", "mono8", "8UC1"):
            self.assertIsNotNone(accepted_spots[enc], "no spots for a well-formed %s frame" % enc)
        for enc in ("rgb8", "bgra8", "rgba8"):
            self.assertGreaterEqual(accepted_spots[enc], 80, "%s frame: too few dots" % enc)
        for m in one:
            self.assertEqual(len(m.centroids), 0, "dots found in a 1x1 image")
        self.assertEqual(missing_logs, [], "bad input without a message naming the problem")
        self.assertLessEqual(len(burst_logs), 20, "the 200 Hz burst flooded /rosout (not throttled)")
        print("[ MEASURE ] %d bad frames sent, none leaked; whole test %.1f s" % (len(bad_stamps), time.time() - t0))


if __name__ == "__main__":
    rostest.rosrun(PKG, "hostile_inputs", HostileInputs)
