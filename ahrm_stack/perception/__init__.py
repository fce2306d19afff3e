"""Perception for the deploy loop: scene sources (obstacles from a measured layout file, the cube
from a pose source) and the AprilTag camera tracker, with its simulated camera.

``settings`` (configs/perception.yaml), ``geometry`` (pinhole intrinsics, extrinsics),
``tags`` (tag images from the detector's code tables), ``apriltag`` (tag pose → cube pose),
``tracker`` (constant-velocity Kalman filter, missed frames), ``scene_source`` (the
``SceneSource`` protocol, layout files), ``sim_camera`` (MuJoCo offscreen frames of the sim).
A real camera (docs/camera.md): ``frames`` (video file, UVC, RealSense frame sources),
``detection_thread`` / ``detection_process`` (capture and detection beside the control loop; the
tick reads the newest pose), ``camera_scene`` (the camera scene for any backend), ``calibration``
(intrinsics and distortion from a ChArUco board, the calibration file, undistortion),
``extrinsics`` (the camera's pose from a reference tag), and the commands ``calibrate``,
``camera_check`` (bring-up) and ``detection_range`` (range on rendered frames).
"""
