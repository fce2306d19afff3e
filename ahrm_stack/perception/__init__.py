"""Perception for the deploy loop: scene sources (obstacles from a measured layout file, the cube
from a pose source) and the AprilTag camera tracker, with its simulated camera.

``settings`` (configs/perception.yaml), ``geometry`` (pinhole intrinsics, extrinsics),
``tags`` (tag images from the detector's code tables), ``apriltag`` (tag pose → cube pose),
``tracker`` (constant-velocity Kalman filter, missed frames), ``scene_source`` (the
``SceneSource`` protocol, layout files), ``sim_camera`` (MuJoCo offscreen frames of the sim).
"""
