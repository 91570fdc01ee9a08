"""Ending a launch from one of its nodes the way Ctrl-C does (a clean exit
with status 0), instead of a `required` node dying (roslaunch then reports
"REQUIRED process has died" in red). Used by nodes/stabilize_monitor.py."""
import os
import signal


def end_launch():
    """SIGINT to the roslaunch that started this node, if one did (not a
    rostest, not a shell): the launch then shuts down as on Ctrl-C. Returns
    whether it did."""
    parent = os.getppid()
    try:
        with open("/proc/%d/cmdline" % parent, "rb") as f:
            argv = [a.decode(errors="replace") for a in f.read().split(b"\0") if a]
    except OSError:
        return False
    if any(os.path.basename(a) == "roslaunch" for a in argv[:2]):
        os.kill(parent, signal.SIGINT)
        return True
    return False
