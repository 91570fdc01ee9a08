"""Messages the rostest checkers build by hand (shared by them; not a test)."""
from sensor_msgs.msg import CameraInfo


def camera_info(width, height, fx, fy=None, cx=None, cy=None):
    """A pinhole camera_info without distortion, the principal point at the centre by default."""
    info = CameraInfo()
    info.header.frame_id = "camera_optical_frame"
    info.width, info.height = width, height
    fy = fx if fy is None else fy
    cx = (width - 1) / 2.0 if cx is None else cx
    cy = (height - 1) / 2.0 if cy is None else cy
    info.distortion_model = "plumb_bob"
    info.D = [0.0] * 5
    info.K = [fx, 0, cx, 0, fy, cy, 0, 0, 1]
    info.R = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    info.P = [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0]
    return info
