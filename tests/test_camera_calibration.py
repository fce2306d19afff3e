"""The calibration command against views synthesised by OpenCV with known intrinsics and lens
distortion (the board drawn by ``CharucoBoard.generateImage``, each view's pixels mapped through
``cv2.undistortPointsIter`` of the true camera onto the board's plane), the calibration file's
validation, and the extrinsics from a reference tag against the MuJoCo camera's true pose."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from ahrm_stack.perception.calibration import (CalibrationFile, Undistorter,  # noqa: E402
                                               apply_calibration, calibrate_intrinsics, camera_matrix,
                                               charuco_board, load_calibrated_settings, read_calibration,
                                               write_calibration)
from ahrm_stack.perception.settings import PerceptionConfigError, load_perception_settings  # noqa: E402

WIDTH, HEIGHT = 640, 480
TRUE_K = np.array([[610.0, 0.0, 322.0], [0.0, 605.0, 236.0], [0.0, 0.0, 1.0]])  # OpenCV's convention
TRUE_DIST = np.array([-0.28, 0.09, 0.0012, -0.0008, 0.0])  # k1 k2 p1 p2 k3: a wide webcam lens


def _rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    return cv2.Rodrigues(np.array([rx, ry, rz]))[0]


def board_image(board_settings, px_per_m: float) -> np.ndarray:
    """The printed board (grey, uint8; (0, 0) its top-left corner): OpenCV's ChArUco drawing, or
    a chessboard (black top-left square; the views put white around it)."""
    nx, ny = board_settings.squares
    size = (int(nx * board_settings.square_size * px_per_m), int(ny * board_settings.square_size * px_per_m))
    if board_settings.kind == "charuco":
        return charuco_board(board_settings).generateImage(size, marginSize=0)
    square = int(round(board_settings.square_size * px_per_m))
    cells = (np.indices((ny, nx)).sum(axis=0) % 2).astype(np.uint8) * 255
    return np.kron(cells, np.ones((square, square), dtype=np.uint8))


def synthesise_views(board_settings, count: int, seed: int = 0) -> tuple[list[np.ndarray], list]:
    """Grey views of the board seen by the true camera (TRUE_K, TRUE_DIST) at random poses; and
    the poses (R, t) board-to-camera."""
    nx, ny = board_settings.squares
    px_per_m = 2000.0
    image = board_image(board_settings, px_per_m)
    u, v = np.meshgrid(np.arange(WIDTH, dtype=np.float64), np.arange(HEIGHT, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)  # to convergence
    normal = cv2.undistortPointsIter(pixels, TRUE_K, TRUE_DIST, None, None, criteria).reshape(-1, 2)
    rays = np.hstack([normal, np.ones((len(normal), 1))])
    rng = np.random.default_rng(seed)
    centre = np.array([nx, ny]) * board_settings.square_size / 2
    views, poses = [], []
    for _ in range(count):
        R = _rotation(*rng.uniform(-0.45, 0.45, 2), rng.uniform(-0.3, 0.3))
        distance = rng.uniform(0.35, 0.5)
        t = np.array([*rng.uniform(-0.13, 0.13, 2) * [1.0, 0.75], distance]) - R @ np.array([*centre, 0.0])
        H = np.column_stack([R[:, 0], R[:, 1], t])  # board (X, Y, 1) -> ray (x, y, 1) * z
        board_xy = rays @ np.linalg.inv(H).T
        board_xy = board_xy[:, :2] / board_xy[:, 2:3] * px_per_m - 0.5  # pixel centres at i
        maps = board_xy.reshape(HEIGHT, WIDTH, 2).astype(np.float32)
        views.append(cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=255))
        poses.append((R, t))
    return views, poses


@pytest.fixture(scope="module")
def board():
    return load_perception_settings().calibration.board


@pytest.fixture(scope="module")
def views(board):
    return synthesise_views(board, 20)[0]


@pytest.fixture(scope="module")
def calibrated(views, board):
    return calibrate_intrinsics(views, board)


def test_charuco_calibration_recovers_the_known_camera(calibrated, board):
    fx, fy, cx, cy = calibrated.intrinsics
    assert calibrated.views >= board.min_views and calibrated.rms < 0.5  # px
    assert fx == pytest.approx(TRUE_K[0, 0], rel=5e-3) and fy == pytest.approx(TRUE_K[1, 1], rel=5e-3)
    assert cx == pytest.approx(TRUE_K[0, 2] + 0.5, abs=2.0) and cy == pytest.approx(TRUE_K[1, 2] + 0.5, abs=2.0)
    # the recovered camera projects known points where the true one does (OpenCV's projectPoints),
    # across the whole image, corners included where the distortion is largest
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-0.45, 0.45, (400, 2)), np.ones(400)]) * 0.6
    true_px = cv2.projectPoints(points, np.zeros(3), np.zeros(3), TRUE_K, TRUE_DIST)[0].reshape(-1, 2)
    inside = (true_px[:, 0] > 0) & (true_px[:, 0] < WIDTH) & (true_px[:, 1] > 0) & (true_px[:, 1] < HEIGHT)
    found_px = cv2.projectPoints(points, np.zeros(3), np.zeros(3), calibrated.matrix,
                                 calibrated.distortion)[0].reshape(-1, 2)
    error = np.linalg.norm(found_px - true_px, axis=1)[inside]
    # 20 views of a 28 x 20 cm board leave the principal point uncertain by ~1-2 px (40 views of
    # another seed: 0.5 px), which the distortion partly absorbs
    assert inside.sum() > 200 and np.percentile(error, 95) < 2.5, np.percentile(error, 95)


def test_undistorter_maps_a_distorted_point_to_the_pinhole():
    """A point's distorted pixel (OpenCV's projectPoints with the true camera) lands, after the
    undistorter, where the pinhole of the same intrinsics puts it."""
    intrinsics = (TRUE_K[0, 0], TRUE_K[1, 1], TRUE_K[0, 2] + 0.5, TRUE_K[1, 2] + 0.5)
    undistort = Undistorter(intrinsics, TRUE_DIST, WIDTH, HEIGHT)
    point = np.array([[0.21, -0.14, 0.5]])
    distorted = cv2.projectPoints(point, np.zeros(3), np.zeros(3), TRUE_K, TRUE_DIST)[0].reshape(2)
    image = np.zeros((HEIGHT, WIDTH), dtype=np.uint8)
    cv2.circle(image, tuple(int(round(c * 16)) for c in distorted), 3 * 16, 255, -1, cv2.LINE_AA, shift=4)
    out = undistort(image).astype(float)
    ys, xs = np.nonzero(out > 0)
    weights = out[ys, xs]
    centre = np.array([np.sum(xs * weights), np.sum(ys * weights)]) / weights.sum()  # OpenCV convention
    K = camera_matrix(intrinsics)
    pinhole = (K @ (point[0] / point[0, 2]))[:2]
    assert np.linalg.norm(centre - pinhole) < 0.5, (centre, pinhole)


def test_calibrate_command_writes_the_file_only_from_good_input(tmp_path, views, calibrated, capsys):
    from ahrm_stack.perception.calibrate import main

    paths = []
    for i, view in enumerate(views):
        paths.append(tmp_path / f"view{i:02d}.png")
        cv2.imwrite(str(paths[-1]), view)
    out = tmp_path / "camera.yaml"
    assert main(["intrinsics", "--out", str(out), *map(str, paths)]) == 0
    written = read_calibration(out)
    assert (written.width, written.height, written.views) == (WIDTH, HEIGHT, calibrated.views)
    np.testing.assert_allclose(written.intrinsics, calibrated.intrinsics, atol=1e-3)
    assert "RMS" in capsys.readouterr().out
    # bad input: one line, exit 2, nothing written
    other = tmp_path / "other.yaml"
    (tmp_path / "notes.png").write_text("not an image")
    for bad in ([str(tmp_path / "missing.png")], [str(tmp_path / "notes.png")]):
        assert main(["intrinsics", "--out", str(other), *map(str, paths[:3]), *bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and Path(bad[0]).name in err, err
    cv2.imwrite(str(tmp_path / "small.png"), views[0][:240, :320])
    assert main(["intrinsics", "--out", str(other), *map(str, paths), str(tmp_path / "small.png")]) == 1
    assert "320 x 240" in capsys.readouterr().err
    assert main(["intrinsics", "--out", str(other), *map(str, paths[:2])]) == 1  # board in 2 views
    assert "min_views" in capsys.readouterr().err
    assert not other.exists()


def test_chessboard_calibration_recovers_the_known_camera(board):
    chessboard = dataclasses.replace(board, kind="chessboard", squares=(9, 7), square_size=0.03)
    views, _ = synthesise_views(chessboard, 14, seed=1)
    found = calibrate_intrinsics(views, chessboard)
    fx, fy, cx, cy = found.intrinsics
    assert found.rms < 0.5 and found.views >= chessboard.min_views
    assert fx == pytest.approx(TRUE_K[0, 0], rel=5e-3) and fy == pytest.approx(TRUE_K[1, 1], rel=5e-3)
    assert cx == pytest.approx(TRUE_K[0, 2] + 0.5, abs=2.0) and cy == pytest.approx(TRUE_K[1, 2] + 0.5, abs=2.0)
    assert found.distortion[0] == pytest.approx(TRUE_DIST[0], abs=0.03)


def test_too_few_views_is_one_line(board):
    views, _ = synthesise_views(board, 2)
    with pytest.raises(ValueError, match=r"found in 2 of 2 views; perception.calibration.board.min_views is"):
        calibrate_intrinsics(views, board)


def test_calibration_file_round_trip_and_errors(tmp_path, calibrated):
    settings = load_perception_settings()
    entry = CalibrationFile(width=settings.camera.width, height=settings.camera.height,
                            intrinsics=calibrated.intrinsics,
                            distortion=tuple(float(x) for x in calibrated.distortion),  # type: ignore[arg-type]
                            rms_px=calibrated.rms, views=calibrated.views, extrinsics=None)
    path = write_calibration(tmp_path / "camera.yaml", entry)
    assert read_calibration(path) == entry
    applied = apply_calibration(settings, path)
    assert applied.camera.intrinsics == entry.intrinsics and applied.camera.distortion == entry.distortion
    import yaml

    from ahrm_stack.perception.settings import PERCEPTION_CONFIG

    data = yaml.safe_load(PERCEPTION_CONFIG.read_text())
    data["camera"]["calibration_file"] = str(path)  # what a run loads
    (tmp_path / "perception.yaml").write_text(yaml.safe_dump(data))
    loaded = load_calibrated_settings(tmp_path / "perception.yaml").camera
    assert loaded == dataclasses.replace(applied.camera, calibration_file=str(path))
    small = dataclasses.replace(entry, width=WIDTH, height=HEIGHT)
    wrong = write_calibration(tmp_path / "small.yaml", small)
    with pytest.raises(PerceptionConfigError, match=r"is for 640 x 480 px; perception.camera is"):
        apply_calibration(settings, wrong)
    broken = tmp_path / "broken.yaml"
    broken.write_text(path.read_text().replace("rms_px", "rms"))
    with pytest.raises(PerceptionConfigError) as error:
        read_calibration(broken)
    assert "\n" not in str(error.value) and "rms" in str(error.value) and "broken.yaml" in str(error.value)
    with pytest.raises(PerceptionConfigError, match="no such file"):
        read_calibration(tmp_path / "missing.yaml")
    assert not (tmp_path / "never.yaml").exists()
    with pytest.raises(PerceptionConfigError):  # invalid: nothing written
        write_calibration(tmp_path / "never.yaml", dataclasses.replace(entry, views=0))
    assert not (tmp_path / "never.yaml").exists()


@pytest.fixture(scope="module")
def rendered():
    """A MuJoCo frame of the sim's start scene from the configured camera: (task config,
    settings, grey frame, the cube's top-face tag as a reference tag at its true pose, the true
    camera position and rotation (optical) from MuJoCo's ``cam_xpos`` / ``cam_xmat``)."""
    pytest.importorskip("mujoco")
    from ahrm_stack.config import load_config
    from ahrm_stack.perception.geometry import OPTICAL_TO_MUJOCO, quaternion_to_matrix
    from ahrm_stack.perception.settings import ReferenceTagSettings
    from ahrm_stack.perception.sim_camera import SimCamera
    from ahrm_stack.hardware.protocol import FastClock
    from ahrm_stack.sim_arm import SimArm

    config = load_config()
    settings = load_perception_settings()
    arm = SimArm(config.task, seed=0, clock=FastClock())
    arm.connect()
    camera = SimCamera(config.task, settings)
    try:
        gray = camera.render_gray(arm.physics)
        truth = arm.perception()
        R = quaternion_to_matrix(truth.cube_quaternion)
        top = truth.cube_position + R @ np.array([0.0, 0.0, config.task.cube.size / 2])
        yaw = math.degrees(math.atan2(R[1, 0], R[0, 0]))
        tag = ReferenceTagSettings(family=settings.tag.family, id=settings.tag.id, size=settings.tag.size,
                                   position=tuple(float(v) for v in top), yaw_deg=yaw)  # type: ignore[arg-type]
        data = camera.physics.data
        position = data.cam_xpos[camera.camera_id].copy()
        rotation = data.cam_xmat[camera.camera_id].reshape(3, 3) @ OPTICAL_TO_MUJOCO
        return config.task, settings, gray, tag, position, rotation, truth
    finally:
        camera.close()
        arm.disconnect()


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1)))


def test_extrinsics_from_a_reference_tag_match_the_rendered_camera(rendered):
    """The cube's top-face tag in a MuJoCo frame is the reference tag at a surveyed pose (the
    simulator's); the camera pose measured from it matches MuJoCo's camera."""
    from ahrm_stack.perception.extrinsics import measure_extrinsics
    from ahrm_stack.perception.geometry import Intrinsics

    _, settings, gray, tag, true_position, true_rotation, _ = rendered
    intrinsics = Intrinsics.from_settings(settings.camera).params
    pose, spread, used = measure_extrinsics([gray], tag, intrinsics, None, 1)
    distance = np.linalg.norm(true_position - np.asarray(tag.position))
    # a 3 cm tag 1.0 m away, 36 px: its tilt is known to ~0.5 deg, which moves the camera
    # by distance * tilt, but hardly its distance from the tag
    assert used == 1 and spread == 0.0
    assert _angle_deg(pose.rotation, true_rotation) < 1.0
    assert np.linalg.norm(pose.position - true_position) < distance * math.radians(1.0), pose.position
    assert abs(np.linalg.norm(pose.position - np.asarray(tag.position)) - distance) < 0.005


def test_extrinsics_command_writes_the_pose_the_deploy_camera_then_uses(rendered, tmp_path, capsys):
    """``calibrate extrinsics`` on a rendered view (its reference tag the cube's, in a settings
    file of its own): the file's pose is MuJoCo's camera's, and the calibrated settings measure
    the cube within a centimetre of the simulator's."""
    import yaml

    from ahrm_stack.perception.apriltag import TagDetector
    from ahrm_stack.perception.calibrate import main
    from ahrm_stack.perception.geometry import Intrinsics
    from ahrm_stack.perception.settings import PERCEPTION_CONFIG

    task, settings, gray, tag, true_position, true_rotation, truth = rendered
    data = yaml.safe_load(PERCEPTION_CONFIG.read_text())
    data["calibration"]["reference_tag"] = dict(family=tag.family, id=tag.id, size=tag.size,
                                                position=list(tag.position), yaw_deg=tag.yaw_deg)
    data["calibration"]["frames"] = 1
    config = tmp_path / "perception.yaml"
    config.write_text(yaml.safe_dump(data))
    view = tmp_path / "view.png"
    cv2.imwrite(str(view), gray)
    calibration = tmp_path / "camera.yaml"
    camera = settings.camera
    write_calibration(calibration, CalibrationFile(
        width=camera.width, height=camera.height, intrinsics=Intrinsics.from_settings(camera).params,
        distortion=(0.0, 0.0, 0.0, 0.0, 0.0), rms_px=0.0, views=1, extrinsics=None))
    assert main(["--config", str(tmp_path / "missing.yaml"), "extrinsics", "--calibration",
                 str(calibration), str(view)]) == 2
    assert "missing.yaml" in capsys.readouterr().err and read_calibration(calibration).extrinsics is None
    assert main(["--config", str(config), "extrinsics", "--calibration", str(calibration), str(view)]) == 0
    written = read_calibration(calibration).extrinsics
    assert written is not None and written.frames == 1
    assert np.linalg.norm(np.array(written.position) - true_position) < 0.015
    calibrated = apply_calibration(settings, calibration)
    assert calibrated.camera.look_at is None and calibrated.camera.quaternion == written.quaternion
    from ahrm_stack.perception.geometry import CameraPose

    assert _angle_deg(CameraPose.from_settings(calibrated.camera).rotation, true_rotation) < 1.0
    detector = TagDetector(calibrated, task.cube.size)
    found = detector.measure(gray)
    detector.detector.close()
    assert found is not None and np.linalg.norm(found.position - truth.cube_position) < 0.01


@pytest.mark.parametrize("section, key, value, expected", [
    ("source", "kind", "webcam", "perception.source.kind"),
    ("source", "isolation", "fiber", "perception.source.isolation"),
    ("source", "fps", 0, "perception.source.fps"),
    ("source", "video_file", "", "perception.source.video_file: give the video file with kind video"),
    ("calibration", "frames", 0, "perception.calibration.frames"),
    ("camera", "distortion", [0.1, 0.0], "perception.camera.distortion"),
    ("camera", "calibration_file", "nowhere/camera.yaml", "calibration file nowhere/camera.yaml: no such file"),
])
def test_camera_keys_are_validated_in_one_line(tmp_path, section, key, value, expected):
    import yaml

    from ahrm_stack.perception.settings import PERCEPTION_CONFIG

    data = yaml.safe_load(PERCEPTION_CONFIG.read_text())
    data[section][key] = value
    if key == "video_file":
        data["source"]["kind"] = "video"
    path = tmp_path / "perception.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(PerceptionConfigError) as error:
        load_calibrated_settings(path)  # the settings, then the calibration file
    assert expected in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("key, value, expected", [
    ("squares", [2, 5], "perception.calibration.board.squares"),
    ("marker_size", 0.05, "marker_size 0.05 must be below square_size"),
    ("kind", "circles", "perception.calibration.board.kind"),
])
def test_board_keys_are_validated_in_one_line(tmp_path, key, value, expected):
    import yaml

    from ahrm_stack.perception.settings import PERCEPTION_CONFIG

    data = yaml.safe_load(PERCEPTION_CONFIG.read_text())
    data["calibration"]["board"][key] = value
    path = tmp_path / "perception.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(PerceptionConfigError) as error:
        load_perception_settings(path)
    assert expected in str(error.value) and "\n" not in str(error.value)


def test_an_unknown_aruco_dictionary_names_the_key(board):
    with pytest.raises(PerceptionConfigError, match=r"perception.calibration.board.dictionary 'DICT_9X9_1'"):
        charuco_board(dataclasses.replace(board, dictionary="DICT_9X9_1"))
