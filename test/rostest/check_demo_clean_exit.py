#!/usr/bin/env python3
"""demo.launch duration:=8 run by roslaunch in a subprocess (own master port,
own ROS_HOME): exit status 0 within 90 s, the monitor's "demo over" line with
its figures, no "REQUIRED process" message, and the figures sane (frames
published, recall > 0.9)."""
import os
import re
import shutil
import socket
import subprocess
import tempfile
import unittest

import rostest

PKG = "structured_light_stabilizer"


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DemoCleanExit(unittest.TestCase):
    def test_demo_ends_cleanly(self):
        port = free_port()
        home = tempfile.mkdtemp(prefix="sls_demo_exit_")
        env = dict(os.environ, ROS_MASTER_URI="http://localhost:%d" % port, ROS_HOME=home,
                   ROS_LOG_DIR=os.path.join(home, "log"))
        try:
            proc = subprocess.run(["roslaunch", "-p", str(port), PKG, "demo.launch", "duration:=8", "rate:=5"],
                                  env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=90)
        finally:
            shutil.rmtree(home, ignore_errors=True)
        out = proc.stdout.decode(errors="replace")
        tail = "\n".join(out.splitlines()[-15:])
        print("[ MEASURE ] roslaunch exit status %d; last lines:\n%s" % (proc.returncode, tail))
        self.assertEqual(proc.returncode, 0, tail)
        self.assertNotIn("REQUIRED process", out)
        m = re.search(r"demo over after .*frames_published=(\d+).*recall=([0-9.e+-]+)", out)
        self.assertIsNotNone(m, "no 'demo over' summary:\n" + tail)
        self.assertGreater(int(m.group(1)), 10)
        self.assertGreater(float(m.group(2)), 0.9)


if __name__ == "__main__":
    rostest.rosrun(PKG, "demo_clean_exit", DemoCleanExit)
