#!/usr/bin/env python3
"""rviz under Xvfb with rviz/stabilizer.rviz: takes a screenshot with the
depth cloud's topic remapped to nothing (control), then one with the real
cloud, and asserts that the cloud's colours appear in the 3D view only in the
second. Both screenshots are saved as PNG beside the test results.

The screenshot is Xvfb's own frame buffer, which it keeps as an X window dump
file in -fbdir: no screenshot tool (xwd, package x11-apps) is needed."""
import os
import shutil
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np
import rospkg
import rospy
import rostest
from sensor_msgs.msg import PointCloud2

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import xwd_image  # noqa: E402

PKG = "structured_light_stabilizer"
BACKGROUND = (48, 48, 48)  # Global Options / Background Color of the config


def artifact_dir():
    for arg in sys.argv:
        if arg.startswith("--gtest_output=xml:"):
            return os.path.dirname(arg.split(":", 1)[1])
    return tempfile.gettempdir()


def free_display():
    for n in range(90, 200):
        if not os.path.exists("/tmp/.X%d-lock" % n):
            return ":%d" % n
    raise RuntimeError("no free X display")


def cloud_pixels(rgb):
    """Saturated pixels in the centre of the 3D view. The view is the
    bounding box of the background colour; the cloud lies around the focal
    point, i.e. the view's centre, while the TF axes are drawn at the camera
    origin, away from it."""
    bg = np.all(rgb == BACKGROUND, axis=2)
    ys, xs = np.nonzero(bg)
    if len(xs) < 1000:
        return 0, None
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    cx, cy, w, h = (x0 + x1) // 2, (y0 + y1) // 2, (x1 - x0) // 4, (y1 - y0) // 4
    centre = rgb[cy - h:cy + h, cx - w:cx + w].astype(int)
    saturated = (centre.max(axis=2) - centre.min(axis=2)) > 80
    return int(saturated.sum()), (x0, y0, x1, y1)


class RvizScreenshot(unittest.TestCase):
    def screenshot(self, display, fb_file, name, extra_args):
        rviz_cfg = os.path.join(rospkg.RosPack().get_path(PKG), "rviz", "stabilizer.rviz")
        env = dict(os.environ, DISPLAY=display, LIBGL_ALWAYS_SOFTWARE="1")
        log = open(os.path.join(self.out, name + "_rviz.log"), "w")
        rviz = subprocess.Popen(["rosrun", "rviz", "rviz", "-d", rviz_cfg, "__name:=rviz_" + name] + extra_args,
                                env=env, stdout=log, stderr=subprocess.STDOUT)
        try:
            best, box = 0, None
            deadline = time.time() + 40.0
            path = os.path.join(self.out, name + ".xwd")
            while time.time() < deadline:
                time.sleep(3.0)
                shutil.copyfile(fb_file, path)
                rgb = xwd_image.read_xwd(path)
                best, box = cloud_pixels(rgb)
                if best > 2000 or (name == "control" and box is not None and time.time() > deadline - 25):
                    break
            png = os.path.join(self.out, "rviz_%s.png" % name)
            xwd_image.write_png(png, rgb)
            os.remove(path)
            print("[ MEASURE ] %s: %d cloud-coloured pixels in the 3D view %s; screenshot %s" % (name, best, box, png))
            return best, box
        finally:
            rviz.terminate()
            try:
                rviz.wait(10)
            except subprocess.TimeoutExpired:
                rviz.kill()
            log.close()

    def test_cloud_visible(self):
        rospy.init_node("check_rviz_screenshot")
        self.out = artifact_dir()
        rospy.wait_for_message("points", PointCloud2, timeout=60.0)
        display = free_display()
        fb_dir = tempfile.mkdtemp(prefix="sls_xvfb_")
        xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", "1280x900x24", "-nolisten", "tcp", "-fbdir", fb_dir],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        fb_file = os.path.join(fb_dir, "Xvfb_screen0")
        try:
            time.sleep(2.0)
            control, control_box = self.screenshot(display, fb_file, "control", ["points:=/no_cloud_here"])
            shown, box = self.screenshot(display, fb_file, "cloud", [])
        finally:
            xvfb.terminate()
            xvfb.wait(10)
            shutil.rmtree(fb_dir, ignore_errors=True)
        self.assertIsNotNone(control_box, "rviz did not draw its 3D view")
        self.assertIsNotNone(box, "rviz did not draw its 3D view")
        self.assertGreater(shown, 300, "the depth cloud is not visible")
        self.assertLess(control, shown / 10.0, "coloured pixels without the cloud: the check would not see a missing cloud")


if __name__ == "__main__":
    rostest.rosrun(PKG, "rviz_screenshot", RvizScreenshot)
