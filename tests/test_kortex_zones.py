"""Protection zones: the check against the task workspace compared with coal's exact distances
(spheres: the same answer; prisms and cylinders, either origin convention: never a miss), the
workspace in the arm's base frame against scipy's rotation, and the adapter reading, reporting and
refusing zones on connect over the fake arm."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fake_kortex_api.rig import make_for, options
from ahrm_stack.hardware.kortex import ProtectionZone, task_workspace, zone_report, zones_in_workspace
from ahrm_stack.hardware.protocol import HardwareError

coal = pytest.importorskip("coal")


def _zone(shape_type: int, origin, dimensions, envelope=0.0, enabled=True, name="z"):
    return ProtectionZone.from_values({"name": name, "enabled": enabled, "shape_type": shape_type,
                                       "origin": list(origin), "dimensions": list(dimensions),
                                       "envelope": envelope})


def _coal_distance(geometry, at, box: np.ndarray) -> float:
    """coal's distance (m, negative: penetration) between ``geometry`` translated to ``at`` and
    the axis-aligned ``box``."""
    half = (box[:, 1] - box[:, 0]) / 2
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    first = coal.Transform3s(np.eye(3), np.asarray(at, dtype=float))
    second = coal.Transform3s(np.eye(3), box.mean(axis=1))
    return coal.distance(geometry, first, coal.Box(*(2 * half)), second, request, result)


def _random_box(rng) -> np.ndarray:
    lo = rng.uniform(-0.5, 0.5, 3)
    return np.stack([lo, lo + rng.uniform(0.05, 0.6, 3)], axis=1)


def test_sphere_zones_match_coals_exact_answer():
    rng = np.random.default_rng(4)
    agree = 0
    for _ in range(300):
        box = _random_box(rng)
        radius, envelope = rng.uniform(0.01, 0.3), rng.uniform(0.0, 0.05)
        origin = rng.uniform(-1.0, 1.0, 3)
        ours = bool(zones_in_workspace([_zone(2, origin, [radius], envelope)], box))
        exact = _coal_distance(coal.Sphere(radius + envelope), origin, box) <= 1e-9
        agree += ours == exact
    assert agree == 300


@pytest.mark.parametrize("shape_type", [1, 3])
def test_prism_and_cylinder_zones_are_never_missed(shape_type):
    """Whichever point of the shape its origin is (centre, corner / base), a zone that coal finds
    reaching into the box is reported."""
    rng = np.random.default_rng(shape_type)
    hits = 0
    for _ in range(300):
        box = _random_box(rng)
        origin = rng.uniform(-1.0, 1.0, 3)
        if shape_type == 3:
            dims = rng.uniform(0.02, 0.4, 3)
            geometry, offsets = coal.Box(*dims), [np.zeros(3), dims / 2]
        else:
            dims = rng.uniform(0.02, 0.3, 2)
            geometry, offsets = coal.Cylinder(dims[0], dims[1]), [np.zeros(3), [0, 0, dims[1] / 2]]
        ours = bool(zones_in_workspace([_zone(shape_type, origin, dims)], box))
        for offset in offsets:
            if _coal_distance(geometry, origin + np.asarray(offset), box) <= 0.0:
                hits += 1
                assert ours, (origin, dims, box)
    assert hits > 5  # the draw did test overlapping cases


def test_the_bounding_sphere_is_the_tightest_for_either_origin_convention():
    """Its radius is the farthest point of the shape from the origin, over both conventions
    (prism: centred or cornered at the origin; cylinder: centred or standing on it), from the
    shapes' vertices / rims computed here; a zone it does not reach is not reported."""
    rng = np.random.default_rng(7)
    for _ in range(50):
        d, envelope = rng.uniform(0.01, 0.5, 3), rng.uniform(0.0, 0.05)
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        vertices = np.vstack([signs * d / 2, (signs + 1) / 2 * d])
        prism = _zone(3, [0, 0, 0], d, envelope)
        assert prism.bounding_radius == pytest.approx(
            np.linalg.norm(vertices, axis=1).max() + envelope)
        angles = np.linspace(0.0, 2 * np.pi, 64)
        rim = np.stack([d[0] * np.cos(angles), d[0] * np.sin(angles)], axis=1)
        heights = [-d[1] / 2, d[1] / 2, 0.0, d[1]]
        points = np.array([[x, y, h] for x, y in rim for h in heights])
        cylinder = _zone(1, [0, 0, 0], d[:2], envelope)
        assert cylinder.bounding_radius == pytest.approx(
            np.linalg.norm(points, axis=1).max() + envelope)
        sphere = _zone(2, [0, 0, 0], d[:1], envelope)
        assert sphere.bounding_radius == pytest.approx(d[0] + envelope)
    box = np.array([[1.0, 2.0], [0.0, 1.0], [0.0, 1.0]])
    for shape_type, dims in ((1, [0.3, 0.4]), (2, [0.5]), (3, [0.3, 0.3, 0.3])):
        zone = _zone(shape_type, [0.0, 0.5, 0.5], dims)
        reaches = _coal_distance(coal.Sphere(zone.bounding_radius), zone.origin, box) <= 0.0
        assert bool(zones_in_workspace([zone], box)) == reaches
    assert _zone(3, [0, 0, 0], [0.1, 0.2]).bounding_radius == np.inf  # too few dimensions


def test_disabled_and_unknown_zones():
    box = np.array([[0.0, 1.0], [0.0, 1.0], [0.0, 1.0]])
    inside = [0.5, 0.5, 0.5]
    assert not zones_in_workspace([_zone(2, inside, [0.1], enabled=False)], box)
    assert zones_in_workspace([_zone(0, [9.0, 9.0, 9.0], [])], box)  # unknown shape: refuse
    assert zone_report([]) == "protection zones: none"
    assert "'z' (enabled sphere, origin (0.500, 0.500, 0.500) m, dimensions [0.100] m" in \
        zone_report([_zone(2, inside, [0.1])])


@pytest.mark.parametrize("yaw_deg, base_x", [(0.0, 0.0), (90.0, 0.0), (30.0, 0.0), (90.0, 0.3),
                                             (-60.0, -0.2)])
def test_task_workspace_in_the_base_frame(task_config, yaw_deg, base_x):
    import dataclasses

    base = (base_x, *task_config.arm.base_position[1:])
    task = dataclasses.replace(task_config, arm=dataclasses.replace(
        task_config.arm, base_yaw_deg=yaw_deg, base_position=base))
    box = task_workspace(task, 0.3)
    hx, hy = task.table.half_extent
    top = task.table.height
    corners = np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (top, top + 0.3)])
    local = Rotation.from_euler("z", yaw_deg, degrees=True).inv().apply(
        corners - np.asarray(task.arm.base_position))
    np.testing.assert_allclose(box[:, 0], local.min(axis=0), atol=1e-12)
    np.testing.assert_allclose(box[:, 1], local.max(axis=0), atol=1e-12)
    if yaw_deg == 0.0 and base_x == 0.0:  # the task as configured: the table lies in front of the base (-y)
        np.testing.assert_allclose(box, [[-hx, hx], [-hy - 0.5, hy - 0.5], [0.0, 0.3]], atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Through the adapter, on the fake arm
# ---------------------------------------------------------------------------------------------

OVER_THE_TABLE = {"name": "lamp", "enabled": True, "shape_type": 2, "origin": [0.0, -0.5, 0.2],
                  "dimensions": [0.05], "envelope": 0.01}
BEHIND_THE_ARM = {"name": "cabinet", "enabled": True, "shape_type": 3, "origin": [0.0, 1.0, 0.5],
                  "dimensions": [0.2, 0.1, 0.2], "envelope": 0.0}


@pytest.fixture(scope="module")
def robot():
    from ahrm_stack.robot import describe, make_arm

    return describe("jaco", make_arm("jaco"))


def _adapter(robot, task_config, zones, **opts):
    adapter, arm = make_for(robot, opts=options(**opts), zones=zones)
    adapter._workspace = task_workspace(task_config, options().workspace_height)
    return adapter, arm


def test_zones_are_read_and_reported_on_connect(robot, task_config, caplog):
    adapter, arm = _adapter(robot, task_config, [BEHIND_THE_ARM])
    with caplog.at_level(logging.INFO):
        adapter.connect()
    try:
        assert [z.name for z in adapter.protection_zones] == ["cabinet"]
        assert "protection zones (1): 'cabinet' (enabled rectangular prism" in adapter.zone_summary
        assert any("'cabinet'" in r.getMessage() for r in caplog.records)
    finally:
        adapter.disconnect()


def test_a_zone_in_the_workspace_refuses_the_connection(robot, task_config):
    adapter, arm = _adapter(robot, task_config, [BEHIND_THE_ARM, OVER_THE_TABLE])
    with pytest.raises(HardwareError) as error:
        adapter.connect()
    text = str(error.value)
    assert "protection zone(s) 'lamp' reaching into the task workspace" in text
    assert "kortex.refuse_zones_in_workspace" in text and "\n" not in text
    assert not adapter.is_connected and arm.sessions == 0
    assert "SendJointSpeedsCommand" not in [c.name for c in arm.calls]


def test_refuse_false_reports_the_zone_only(robot, task_config, caplog):
    adapter, arm = _adapter(robot, task_config, [OVER_THE_TABLE], refuse_zones_in_workspace=False)
    with caplog.at_level(logging.WARNING):
        adapter.connect()
    try:
        assert adapter.is_connected
        assert any("'lamp' reaching into the task workspace" in r.getMessage()
                   for r in caplog.records)
    finally:
        adapter.disconnect()
