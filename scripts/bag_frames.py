#!/usr/bin/env python3
"""Writes a bag's camera frames as a folder the CameraDriver's images source
plays (scripts/benchmark: the live configuration, frames coming from inside
the manager): frame_00000.png ... (lossless, in the bag's order) and
camera.yaml, the first camera_info in camera_info_manager's format (for
~camera_info_url file://<folder>/camera.yaml).

Usage: bag_frames.py BAG FOLDER [image topic (camera/image_raw)] [info topic (camera/camera_info)]
"""
import os
import sys

import cv2
import rosbag
import yaml
from cv_bridge import CvBridge


def camera_yaml(info):
    def matrix(rows, cols, data):
        return {"rows": rows, "cols": cols, "data": [float(v) for v in data]}

    return {"image_width": info.width, "image_height": info.height, "camera_name": "camera",
            "camera_matrix": matrix(3, 3, info.K), "distortion_model": info.distortion_model or "plumb_bob",
            "distortion_coefficients": matrix(1, len(info.D), info.D),
            "rectification_matrix": matrix(3, 3, info.R), "projection_matrix": matrix(3, 4, info.P)}


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    bag, folder = sys.argv[1], sys.argv[2]
    image_topic = sys.argv[3] if len(sys.argv) > 3 else "camera/image_raw"
    info_topic = sys.argv[4] if len(sys.argv) > 4 else "camera/camera_info"
    os.makedirs(folder, exist_ok=True)
    bridge = CvBridge()
    frames, info = 0, None
    with rosbag.Bag(bag) as b:
        topics = [image_topic, "/" + image_topic, info_topic, "/" + info_topic]
        for topic, msg, _ in b.read_messages(topics=topics):
            if topic.lstrip("/") == info_topic:
                info = info or msg
                continue
            image = bridge.imgmsg_to_cv2(msg)  # as stored; PNG keeps 8 and 16 bits
            if msg.encoding.startswith("rgb"):
                image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            if not cv2.imwrite(os.path.join(folder, "frame_%05d.png" % frames), image):
                sys.exit("cannot write %s" % folder)
            frames += 1
    if info is None or frames == 0:
        sys.exit("%s has no %s with %s" % (bag, image_topic, info_topic))
    with open(os.path.join(folder, "camera.yaml"), "w") as out:
        yaml.safe_dump(camera_yaml(info), out, default_flow_style=None)
    print("%d frames and camera.yaml written to %s" % (frames, folder))


if __name__ == "__main__":
    main()
