"""Helpers to compare the pipeline's outputs with ground truth, shared by the
demo monitor and the rostests.

Conventions: clouds are the organised beam clouds of docs/interface.md (x y z
float32, NaN where a beam has no point), returned as (N, 3) float64 arrays in
beam order with the NaN rows kept, so that estimate and truth compare row by
row. Transforms are geometry_msgs/Transform, as 4 x 4 homogeneous matrices;
a PoseDelta maps reference points to current ones (p_cur = R p_ref + t)."""
import math

import numpy as np


def cloud_xyz(msg):
    """(N, 3) float64 of the x y z fields of a PointCloud2 of float32 fields,
    NaN rows kept (N = width * height)."""
    if msg.width * msg.height == 0:
        return np.zeros((0, 3))
    offsets = {f.name: f.offset for f in msg.fields}
    raw = np.frombuffer(bytes(msg.data), np.uint8)[:msg.row_step * msg.height].reshape(msg.height, msg.row_step)
    raw = raw[:, :msg.width * msg.point_step].reshape(-1, msg.point_step)
    columns = [raw[:, offsets[k]:offsets[k] + 4].copy().view(np.float32).reshape(-1) for k in ("x", "y", "z")]
    return np.stack(columns, axis=1).astype(np.float64)


def transform_matrix(tf):
    """4 x 4 matrix of a geometry_msgs/Transform (the quaternion is normalised)."""
    q = tf.rotation
    x, y, z, w = q.x, q.y, q.z, q.w
    n = math.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
    return m


def is_identity(tf, tolerance=1e-9):
    """True for the identity transform (what PoseDelta publishes for its reference frame)."""
    t, q = tf.translation, tf.rotation
    return max(abs(t.x), abs(t.y), abs(t.z), abs(q.x), abs(q.y), abs(q.z)) < tolerance


def rotation_angle_deg(rotation):
    """Angle (degrees) of a 3 x 3 rotation matrix."""
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(rotation) - 1.0) / 2.0))))


def pose_error(estimate, truth):
    """Translation (m) and rotation (deg) of estimate * truth^-1, both 4 x 4."""
    e = estimate @ np.linalg.inv(truth)
    return float(np.linalg.norm(e[:3, 3])), rotation_angle_deg(e[:3, :3])


def match_spots(found, truth, radius=3.0):
    """Number of true spots matched one to one by found spots within `radius`
    pixels: pairs are taken by increasing distance, each spot at most once
    (dots lie ~30 px apart, so this greedy matching is the optimal one).
    found, truth: sequences of (x, y). A found spot matches nothing it is
    not near, so spurious spots and merged dots do not count as recall."""
    f = np.asarray(found, dtype=np.float64).reshape(-1, 2)
    t = np.asarray(truth, dtype=np.float64).reshape(-1, 2)
    if len(f) == 0 or len(t) == 0:
        return 0
    d = np.linalg.norm(f[:, None, :] - t[None, :, :], axis=2)
    pairs = np.argwhere(d <= radius)
    order = np.argsort(d[pairs[:, 0], pairs[:, 1]], kind="stable")
    used_f, used_t = set(), set()
    for i, j in pairs[order]:
        if i not in used_f and j not in used_t:
            used_f.add(i)
            used_t.add(j)
    return len(used_t)
