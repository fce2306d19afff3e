"""The filter's kinematic snapshot (ahrm_stack/safety/constraints/base.py) on Pinocchio's sample
6-DoF manipulator, against finite differences of the forward kinematics and against its own
per-frame reads: the point rows of the distance constraints (n^T J of a point rigidly attached to a
frame), the batched position reads, an attached frame, a base that is not the identity."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ahrm_stack.safety.constraints.base import ArmSnapshot, Rows

MODEL = pin.buildSampleModelManipulator()
BASES = {"identity": pin.SE3.Identity(),
         "turned": pin.SE3(pin.utils.rotate("z", 0.7) @ pin.utils.rotate("x", -0.4), np.array([0.1, 0.5, 0.4]))}


def _frames() -> list[int]:
    return [i for i, f in enumerate(MODEL.frames) if f.type == pin.FrameType.BODY][1:]


def _world(base: pin.SE3, q: np.ndarray, frame: int) -> pin.SE3:
    """The frame's world placement straight from Pinocchio (the oracle)."""
    data = MODEL.createData()
    pin.framesForwardKinematics(MODEL, data, q)
    return base * data.oMf[frame]


@pytest.mark.parametrize("base", BASES, ids=list(BASES))
def test_point_rows_are_the_directional_velocity_of_the_attached_point(base):
    """n^T J for a world point rigidly attached to a frame equals the finite difference of that
    point's world position along n, for random q, points, directions and commands."""
    rng = np.random.default_rng(11)
    snapshot = ArmSnapshot(MODEL, BASES[base])
    frames = _frames()
    for _ in range(6):
        q = rng.uniform(-2.0, 2.0, MODEL.nq)
        snapshot.update(q)
        chosen = [int(f) for f in rng.choice(frames, 4)]
        points = np.array([snapshot.position(f) for f in chosen]) + rng.normal(size=(4, 3)) * 0.2
        directions = rng.normal(size=(4, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        rows = snapshot.point_rows(chosen, points, directions)
        origins = np.array([snapshot.position(f) for f in chosen])
        np.testing.assert_allclose(snapshot.point_rows(chosen, points, directions, origins), rows, atol=1e-12)
        u, eps = rng.normal(size=MODEL.nv), 1e-6
        for k, frame in enumerate(chosen):
            here = _world(BASES[base], q, frame)
            local = here.inverse().act(points[k])  # the point in the frame: fixed as q moves
            ahead, behind = (_world(BASES[base], q + s * eps * u, frame).act(local) for s in (1, -1))
            rate = (ahead - behind) / (2 * eps)
            assert rows[k] @ u == pytest.approx(directions[k] @ rate, abs=1e-6)


@pytest.mark.parametrize("base", BASES, ids=list(BASES))
def test_every_position_read_is_pinocchios_world_placement(base):
    rng = np.random.default_rng(4)
    snapshot = ArmSnapshot(MODEL, BASES[base])
    frames = _frames()
    q = rng.uniform(-2.0, 2.0, MODEL.nq)
    snapshot.update(q)
    want = np.array([_world(BASES[base], q, f).translation for f in frames])
    rotations = np.array([_world(BASES[base], q, f).rotation for f in frames])
    np.testing.assert_allclose(snapshot.positions(frames), want, atol=1e-12)
    into = np.empty((len(frames), 3))
    snapshot.positions_into(frames, into)
    np.testing.assert_allclose(into, want, atol=1e-12)
    placed_out = np.empty((len(frames), 3))
    placed = snapshot.place(frames, placed_out)
    np.testing.assert_allclose(placed_out, want, atol=1e-12)
    np.testing.assert_allclose(np.array([snapshot.world_rotation(p) for p in placed]), rotations, atol=1e-12)
    positions, rotated = snapshot.placements(frames)
    np.testing.assert_allclose(positions, want, atol=1e-12)
    np.testing.assert_allclose(rotated, rotations, atol=1e-12)
    for k, frame in enumerate(frames):
        position, rotation = snapshot.placement(frame)
        np.testing.assert_allclose(position, want[k], atol=1e-12)
        np.testing.assert_allclose(rotation, rotations[k], atol=1e-12)
        jacobian = snapshot.jacobian(frame)  # world-aligned: the linear rows move the origin
        u, eps = rng.normal(size=MODEL.nv), 1e-6
        rate = (_world(BASES[base], q + eps * u, frame).translation
                - _world(BASES[base], q - eps * u, frame).translation) / (2 * eps)
        np.testing.assert_allclose(jacobian[:3] @ u, rate, atol=1e-6)


def test_an_attached_frame_follows_its_parent_and_a_new_q_is_read_afresh():
    snapshot = ArmSnapshot(MODEL, BASES["turned"])
    frames = _frames()
    q0, q1 = np.full(MODEL.nq, 0.3), np.full(MODEL.nq, -0.5)
    snapshot.update(q0)
    parent = frames[-1]
    point = snapshot.position(parent) + np.array([0.05, -0.02, 0.1])
    new = snapshot.attach_frame("probe", parent, point, np.eye(3))
    np.testing.assert_allclose(snapshot.position(new), point, atol=1e-12)
    snapshot.update(q1)
    local = _world(BASES["turned"], q0, parent).inverse().act(point)
    np.testing.assert_allclose(snapshot.position(new), _world(BASES["turned"], q1, parent).act(local), atol=1e-12)
    first = snapshot.jacobian(parent).copy()
    snapshot.update(q0)  # the cached Jacobian of q1 is not served for q0
    assert not np.allclose(snapshot.jacobian(parent), first)


def test_empty_rows_have_no_row_and_the_arms_width():
    rows = Rows.empty(5)
    assert rows.matrix.shape == (0, 5) and rows.bound.shape == (0,) and rows.names == ()
