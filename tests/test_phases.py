"""Tests for ahrm_stack.kinematics.phases (spec §2: phases and the boundary distance x).

Expected values are computed by hand in the comments. Most hand cases use dyadic numbers
(multiples of 1/64 m) so float arithmetic is exact and "touching" really gives 0.
Tilted pushers take the general (non-closed-form) path, the stand-in for python-fcl's signed
distance; they are compared with tolerance FCL_TOL = 5e-4 m (the accuracy asked of the
FCL path), and also with 1e-9 m, which is what it achieves. python-fcl itself is called only
on generic poses clear of touching: near touching it can abort the whole process (uncaught
C++ exception), see the module notes.

Hand scene (world frame, z up, metres), RegionParams(1/8, 1/8, 1/16, 1/4), table top z = 0.5:
  target centre (0, 0, *)                    -> B_target    x,y in [-0.125, 0.125],     z in [0.5, 0.625]
  obstacle A: centre (-0.25, 0.125), half (1/16, 1/16) -> x [-0.3125, -0.1875], y [0.0625, 0.1875]
  obstacle B: centre (0.25, -0.1875), half (1/16, 1/32) -> x [0.1875, 0.3125],   y [-0.21875, -0.15625]
  AABB x [-0.3125, 0.3125], y [-0.21875, 0.1875]; grown by 1/16 ->
                                                B_obstacles x [-0.375, 0.375], y [-0.28125, 0.25], z [0.5, 0.75]
Pusher: radius r = 1/32 = 0.03125, half length h = 1/16 = 0.0625.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ahrm_stack.kinematics.phases import (
    PHASE_NAMES,
    UPRIGHT_TOL,
    Box,
    Cylinder,
    PhaseScene,
    RegionParams,
    cylinder_box_distance,
    obstacle_region,
    phase_and_x,
    phase_from_distances,
    phase_geometry,
    region_distances,
    target_region,
    upright_cylinder_box_distance,
)
from fcl_reference import fcl_signed_distance as _fcl_signed_distance
from ahrm_stack.kinematics.phases import _general_cylinder_box_distance as general_distance

FCL_TOL = 5e-4  # accuracy required of the non-upright (FCL-replacement) path (m)
EXACT = 1e-12  # closed-form cases (m)
R_P = 1 / 32  # pusher radius
H_P = 1 / 16  # pusher half length
S2 = math.sqrt(2.0)


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# Upright poses: axis +z, axis -z (flipped), and yawed variants; all must give identical results.
UPRIGHT = {
    "up": np.eye(3),
    "down": rot_x(math.pi),
    "yaw": rot_z(0.7),
    "yaw-down": rot_z(-2.0) @ rot_x(math.pi),
}
AXIS_ALONG_Y = rot_x(math.pi / 2)  # local z -> world -y: lying horizontal
AXIS_ALONG_X = rot_y(math.pi / 2)  # local z -> world +x: lying horizontal
TILT_45 = rot_y(math.pi / 4)  # local z -> (sin45, 0, cos45)

HAND_PARAMS = RegionParams(target_half_width=1 / 8, target_height=1 / 8, obstacle_margin=1 / 16, obstacle_height=1 / 4)


def hand_scene() -> PhaseScene:
    return PhaseScene(
        table_height=0.5,
        target_center=np.array([0.0, 0.0, 0.5625]),
        obstacle_centers=np.array([[-0.25, 0.125, 0.5625], [0.25, -0.1875, 0.53125]]),
        obstacle_half_sizes=np.array([[0.0625, 0.0625, 0.0625], [0.0625, 0.03125, 0.03125]]),
        params=HAND_PARAMS,
    )


def pusher(center, rotation=np.eye(3), radius=R_P, half_length=H_P) -> Cylinder:
    return Cylinder(np.asarray(center, dtype=float), rotation, radius, half_length)


# --------------------------------------------------------------------------- regions


def test_phase_from_distances_counts_a_distance_of_zero_as_inside():
    assert phase_from_distances(0.5, 0.0) == (3, 0.0)  # touching B_target: phase 3
    assert phase_from_distances(0.0, 0.25) == (2, 0.25)  # touching B_obstacles: phase 2, x to B_target
    assert phase_from_distances(0.125, 0.25) == (1, 0.125)


def test_clipped_distances_saturate_deep_inside_and_far_outside():
    """The pusher centred in B_target (itself inside B_obstacles), 1/16 m from its nearest face:
    both distances are below -clip and read -clip; far above the table both read +clip."""
    phase, x, clipped = phase_geometry(hand_scene(), pusher((0.0, 0.0, 0.5625)), 0.01)
    assert phase == 3 and x < -0.01
    assert clipped.tolist() == [-0.01, -0.01]
    phase, x, clipped = phase_geometry(hand_scene(), pusher((0.0, 0.0, 2.0)), 0.01)
    assert phase == 1 and x > 0.01 and clipped.tolist() == [0.01, 0.01]


@pytest.mark.parametrize("rotation", [np.eye(3), TILT_45], ids=["upright", "tilted"])
@pytest.mark.parametrize("center,phase", [((0.0, 0.0, 0.9), 1), ((0.3, 0.2, 0.6), 2)], ids=["phase1", "phase2"])
def test_phase_geometry_runs_one_exact_query_away_from_the_other_boundary(monkeypatch, rotation, center, phase):
    """phase_geometry's promise: with the pusher's bounding ball clear of one region (here B_target,
    0.12-0.28 m away) the bounds decide that region, so only x's own exact query runs. Phase 1:
    centre 0.9 m, B_obstacles' top 0.75, B_target's 0.625; phase 2: centre (0.3, 0.2, 0.6), 0.05 m
    inside B_obstacles, 0.19 m from B_target."""
    from ahrm_stack.kinematics import phases as module

    calls = []
    for name in ("_upright_distance", "_general_distance"):
        real = getattr(module, name)

        def counted(*args, _real=real):
            calls.append(args)
            return _real(*args)

        monkeypatch.setattr(module, name, counted)
    result = phase_geometry(hand_scene(), pusher(center, rotation), 0.01)
    assert result[0] == phase and len(calls) == 1
    assert result[2].tolist() == ([0.01, 0.01] if phase == 1 else [-0.01, 0.01])


def test_a_scene_holds_float_copies_of_what_it_was_given_and_cannot_be_changed():
    import dataclasses

    target = [0, 0, 1]
    centers = np.array([[-0.25, 0.125, 0.5625]])
    scene = PhaseScene(table_height=1, target_center=target, obstacle_centers=centers,
                       obstacle_half_sizes=[[0.0625, 0.0625, 0.0625]], params=HAND_PARAMS)
    assert type(scene.table_height) is float
    for name in ("target_center", "obstacle_centers", "obstacle_half_sizes"):
        value = getattr(scene, name)
        assert isinstance(value, np.ndarray) and value.dtype == np.float64, name
    centers[0, 0] = 9.0  # the caller's array: not the scene's
    assert scene.obstacle_centers[0, 0] == -0.25
    with pytest.raises(dataclasses.FrozenInstanceError):
        scene.table_height = 0.0  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        HAND_PARAMS.target_height = 1.0  # type: ignore[misc]
    # compared and hashed by identity (its arrays have no single truth value)
    assert scene == scene and scene != hand_scene() and {scene: 1}[scene] == 1


def test_hand_scene_regions():
    scene = hand_scene()
    t, o = target_region(scene), obstacle_region(scene)
    assert t.bounds() == (-0.125, -0.125, 0.5, 0.125, 0.125, 0.625)
    assert o.bounds() == (-0.375, -0.28125, 0.5, 0.375, 0.25, 0.75)
    np.testing.assert_array_equal(t.center, [0.0, 0.0, 0.5625])
    np.testing.assert_array_equal(t.half_size, [0.125, 0.125, 0.0625])


def test_regions_with_spec_defaults():
    # Spec defaults: target half width 0.08, target height 0.15, margin 0.05, obstacle height 0.25.
    params = RegionParams(0.08, 0.15, 0.05, 0.25)
    scene = PhaseScene(
        table_height=0.7,
        target_center=np.array([0.5, -0.1, 0.74]),  # z of the target centre is ignored
        obstacle_centers=np.array([[0.4, 0.15, 0.75], [0.6, -0.3, 0.76]]),
        obstacle_half_sizes=np.array([[0.03, 0.04, 0.05], [0.02, 0.05, 0.06]]),
        params=params,
    )
    t = target_region(scene)
    # x: 0.5 +- 0.08; y: -0.1 +- 0.08; z: 0.7 .. 0.7 + 0.15
    np.testing.assert_allclose(t.bounds(), (0.42, -0.18, 0.7, 0.58, -0.02, 0.85), atol=EXACT)
    o = obstacle_region(scene)
    # AABB x: min(0.37, 0.58) = 0.37, max(0.43, 0.62) = 0.62; y: min(0.11, -0.35) = -0.35, max(0.19, -0.25) = 0.19
    # grown by 0.05 -> x [0.32, 0.67], y [-0.40, 0.24]; z 0.7 .. 0.95 (obstacle z extents ignored)
    np.testing.assert_allclose(o.bounds(), (0.32, -0.40, 0.7, 0.67, 0.24, 0.95), atol=EXACT)


def test_zero_margin_allowed_and_single_obstacle():
    params = RegionParams(0.125, 0.125, 0.0, 0.25)
    scene = PhaseScene(0.0, np.zeros(3), np.array([[1.0, 2.0, 0.5]]), np.array([[0.25, 0.5, 0.5]]), params)
    assert obstacle_region(scene).bounds() == (0.75, 1.5, 0.0, 1.25, 2.5, 0.25)


# --------------------------------------------------------------------------- hand cases, upright

# (description, pusher centre, expected phase, expected x)
UPRIGHT_CASES = [
    # --- B_target (phase 3 inside/touching, else phase 2 since these are all inside B_obstacles)
    # Centre 0.09375 in x: nearest target edge 0.125 - 0.09375 = 0.03125 away, horizontal overlap
    # r + 0.03125 = 0.0625; z [0.5, 0.625] vs [0.5, 0.625]: vertical overlap 0.125 -> x = -0.0625.
    ("inside target, horizontal overlap smaller", (0.09375, 0.0, 0.5625), 3, -0.0625),
    # Centre on the axis, bottom at 0.671875 - 0.0625 = 0.609375: vertical overlap 0.625 - 0.609375
    # = 0.015625 < horizontal overlap r + 0.125 -> x = -0.015625.
    ("inside target, vertical overlap smaller", (0.0, 0.0, 0.671875), 3, -0.015625),
    # Side surface at 0.15625 - r = 0.125 = target face: touching -> x = 0, counts as in B_target.
    ("touching target +x face", (0.15625, 0.0, 0.5625), 3, 0.0),
    # Bottom at 0.6875 - 0.0625 = 0.625 = target top: touching.
    ("touching target top", (0.0, 0.0, 0.6875), 3, 0.0),
    # Disc at 45 deg from the vertical edge (0.125, 0.125), centre at edge + (r/sqrt2 -+ 1e-9)(1, 1):
    # planar distance r -+ sqrt2 * 1e-9 (r/sqrt2 itself is inexact, so step just inside / outside).
    ("just inside target vertical edge", (0.125 + R_P / S2 - 1e-9, 0.125 + R_P / S2 - 1e-9, 0.5625), 3, -S2 * 1e-9),
    ("just outside target vertical edge", (0.125 + R_P / S2 + 1e-9, 0.125 + R_P / S2 + 1e-9, 0.5625), 2, S2 * 1e-9),
    # Planar gap to x = 0.125: 0.1875 - 0.125 - r = 0.03125.
    ("outside target +x face", (0.1875, 0.0, 0.5625), 2, 0.03125),
    # Beyond the -y face: -0.125 - (-0.21875) - r = 0.0625.
    ("outside target -y face", (0.0, -0.21875, 0.5625), 2, 0.0625),
    # Beyond the vertical edge (0.125, 0.125): offset (3/64, 4/64) -> planar 5/64, minus r = 3/64.
    ("outside target vertical edge", (0.171875, 0.1875, 0.5625), 2, 0.046875),
    # Above the top: bottom 0.734375 - 0.0625 = 0.671875, gap 0.046875 (z overlaps B_obstacles).
    ("above target top", (0.0, 0.0, 0.734375), 2, 0.046875),
    # Above the top edge x = 0.125: s_xy = 0.203125 - 0.125 - r = 3/64, s_z = 0.6875 - 0.625 = 4/64 -> 5/64.
    ("above target top edge", (0.203125, 0.0, 0.75), 2, 0.078125),
    # Above the top corner: planar offset (3/64, 4/64) -> 5/64 - r = 3/64; s_z = 4/64 -> 5/64.
    ("above target top corner", (0.171875, 0.1875, 0.75), 2, 0.078125),
    # In B_obstacles near obstacle A: planar gap to x = -0.125: 0.125 - r = 0.09375.
    ("inside obstacles, beside target", (-0.25, 0.0, 0.5625), 2, 0.09375),
    # High in B_obstacles (bottom 0.71875 < 0.75): s_xy = 0.09375, s_z = 0.71875 - 0.625 = 0.09375.
    ("inside obstacles, diagonal to target", (-0.25, 0.0, 0.78125), 2, 0.09375 * S2),
    # --- B_obstacles (phase 2 when in it, else 1)
    # Side at 0.40625 - r = 0.375 = face: touching -> in B_obstacles, x = gap to target 0.40625-0.125-r = 0.25.
    ("touching obstacles +x face", (0.40625, 0.0, 0.5625), 2, 0.25),
    # Planar gap 0.75 - 0.375 - r = 0.34375.
    ("far outside obstacles", (0.75, 0.0, 0.5625), 1, 0.34375),
    # Beyond the -y face: -0.28125 - (-0.34375) - r = 0.03125.
    ("outside obstacles -y face", (0.0, -0.34375, 0.5625), 1, 0.03125),
    # Beyond the vertical edge (0.375, 0.25): offset (3/64, 4/64) -> 5/64 - r = 3/64.
    ("outside obstacles vertical edge", (0.421875, 0.3125, 0.5625), 1, 0.046875),
    # Above the top: bottom 0.84375 - 0.0625 = 0.78125, gap to 0.75 = 0.03125.
    ("above obstacles top", (0.25, 0.0, 0.84375), 1, 0.03125),
    # Touching the top from above: bottom at 0.75 -> in B_obstacles, x = gap to target top
    # 0.75 - 0.625 = 0.125 (centre x 0.25: s_xy = 0.25 - 0.125 - r = 0.09375) -> hypot = 0.15625.
    ("touching obstacles top", (0.25, 0.0, 0.8125), 2, 0.15625),
    # Above the top edge x = 0.375: s_xy = 3/64, s_z = 0.875 - 0.0625 - 0.75 = 4/64 -> 5/64.
    ("above obstacles top edge", (0.375 + R_P + 0.046875, 0.0, 0.875), 1, 0.078125),
    # Above the top corner (0.375, 0.25): planar 5/64 - r = 3/64, s_z = 4/64 -> 5/64.
    ("above obstacles top corner", (0.421875, 0.3125, 0.875), 1, 0.078125),
    # Below the table (e.g. a bad FK): z gap 0.5 - (0.375 + 0.0625) = 0.0625.
    ("below obstacles bottom", (0.0, 0.0, 0.375), 1, 0.0625),
]


@pytest.mark.parametrize("rot_name", list(UPRIGHT))
@pytest.mark.parametrize("name,center,phase,x", UPRIGHT_CASES, ids=[c[0] for c in UPRIGHT_CASES])
def test_upright_hand_cases(name, center, phase, x, rot_name):
    k, xx = phase_and_x(hand_scene(), pusher(center, UPRIGHT[rot_name]))
    assert (k, PHASE_NAMES[k - 1]) == (phase, PHASE_NAMES[phase - 1])
    assert xx == pytest.approx(x, abs=EXACT)


def test_touching_is_exactly_zero_not_negative_zero():
    d = upright_cylinder_box_distance(pusher((0.15625, 0.0, 0.5625)), target_region(hand_scene()))
    assert d == 0.0 and math.copysign(1.0, d) == 1.0


def test_upright_closed_form_disc_centre_outside_rectangle_overlap():
    # Centre outside the rectangle but the disc overlaps it: horizontal overlap = r - planar distance.
    # Box x,y in [-1, 1], z in [-1, 1]; cylinder r = 0.5, h = 0.5 at (1.25, 0, 0):
    # planar distance 0.25 -> horizontal overlap 0.25; vertical overlap min(0.5+1, 1+0.5) = 1.5 -> -0.25.
    box = Box(np.zeros(3), np.ones(3))
    assert upright_cylinder_box_distance(pusher((1.25, 0.0, 0.0), radius=0.5, half_length=0.5), box) == -0.25
    # Diagonal: centre at (1.3, 1.4, 0) -> planar distance hypot(0.3, 0.4) = 0.5 = r: touching.
    assert upright_cylinder_box_distance(pusher((1.3, 1.4, 0.0), radius=0.5, half_length=0.5), box) == pytest.approx(
        0.0, abs=EXACT
    )
    # Centre at (1.15, 1.2, 0): planar hypot(0.15, 0.2) = 0.25 -> overlap r - 0.25 = 0.25.
    assert upright_cylinder_box_distance(pusher((1.15, 1.2, 0.0), radius=0.5, half_length=0.5), box) == pytest.approx(
        -0.25, abs=EXACT
    )


def test_upright_cylinder_box_distance_rejects_tilt():
    with pytest.raises(ValueError, match="parallel to z"):
        upright_cylinder_box_distance(pusher((0, 0, 1), rot_y(1e-3)), target_region(hand_scene()))
    # Within the tolerance it is accepted (error <= h * 1e-7).
    d = upright_cylinder_box_distance(pusher((0.0, 0.0, 0.734375), rot_y(1e-7)), target_region(hand_scene()))
    assert d == pytest.approx(0.046875, abs=1e-9)


# --------------------------------------------------------------------------- hand cases, tilted (general path)

C45 = (H_P + R_P) / S2  # 45 deg tilt about y: lowest point is cz - (h + r)/sqrt2, leftmost is cx - (h + r)/sqrt2
TILTED_CASES = [
    # Lying along y above the target top: lowest line z = cz - r; cz = 0.625 + r + 0.046875 -> gap 0.046875.
    # Its y extent +-h lies inside the target's +-0.125, so the top face is the nearest feature.
    ("90deg along y, above target top", (0.0, 0.0, 0.625 + R_P + 0.046875), AXIS_ALONG_Y, 2, 0.046875),
    # Same, dipping 0.01 into the top: shortest separating move is up by 0.01 -> x = -0.01.
    ("90deg along y, into target top", (0.0, 0.0, 0.625 + R_P - 0.01), AXIS_ALONG_Y, 3, -0.01),
    # Lying along y beside the +x face: nearest side line x = cx - r; gap = 0.2031.. - r - 0.125 = 0.046875.
    ("90deg along y, beside target +x face", (0.203125, 0.0, 0.5625), AXIS_ALONG_Y, 2, 0.046875),
    # Lying along x, flat end cap facing the +x face: cap at cx - h; gap = 0.21875 - 0.0625 - 0.125 = 0.03125.
    ("90deg along x, cap facing target face", (0.21875, 0.0, 0.5625), AXIS_ALONG_X, 2, 0.03125),
    # Lying along y, parallel to the top edge (x = 0.125, z = 0.625): axis offset (0.0375, 0.05) in (x, z)
    # -> hypot = 0.0625, minus r = 0.03125.
    ("90deg along y, parallel to target top edge", (0.1625, 0.0, 0.675), AXIS_ALONG_Y, 2, 0.03125),
    # Lying along y, beyond the obstacles' +x face at 0.375: gap = cx - r - 0.375 = 0.05.
    ("90deg along y, outside obstacles +x face", (0.375 + R_P + 0.05, 0.0, 0.6), AXIS_ALONG_Y, 1, 0.05),
    # Lying along x beyond the obstacles' top edge (x = 0.375, z = 0.75): nearest point is the cap rim
    # corner (cx - h, cz - r); offset (0.03, 0.04) from the edge -> 0.05.
    ("90deg along x, rim corner over obstacles top edge", (0.375 + H_P + 0.03, 0.0, 0.75 + R_P + 0.04), AXIS_ALONG_X, 1, 0.05),
    # 45 deg about y above the target top: lowest rim point z = cz - (h + r)/sqrt2, at x = cx - (h - r)/sqrt2
    # = -0.022 (inside the face) -> gap 0.02.
    ("45deg above target top", (0.0, 0.0, 0.625 + 0.02 + C45), TILT_45, 2, 0.02),
    # 45 deg dipping 0.01 into the target top: depth 0.01 (the body is deep inside horizontally).
    ("45deg into target top", (0.0, 0.0, 0.625 - 0.01 + C45), TILT_45, 3, -0.01),
    # 45 deg beside the +x face: leftmost rim point x = cx - (h + r)/sqrt2 at z = cz - (h - r)/sqrt2 = 0.540
    # (within the face's z range [0.5, 0.625]) -> gap 0.03.
    ("45deg beside target +x face", (0.125 + 0.03 + C45, 0.0, 0.5625), TILT_45, 2, 0.03),
    # 45 deg above the obstacles' top (0.75), lowest point at x = 0.25 - 0.022 (inside) -> gap 0.04.
    ("45deg above obstacles top", (0.25, 0.0, 0.75 + 0.04 + C45), TILT_45, 1, 0.04),
]


@pytest.mark.parametrize("name,center,rot,phase,x", TILTED_CASES, ids=[c[0] for c in TILTED_CASES])
def test_tilted_hand_cases(name, center, rot, phase, x):
    k, xx = phase_and_x(hand_scene(), pusher(center, rot))
    assert k == phase
    assert xx == pytest.approx(x, abs=FCL_TOL)
    assert xx == pytest.approx(x, abs=1e-9)  # what is actually achieved
    # Spinning the pusher about its own axis changes nothing.
    k2, xx2 = phase_and_x(hand_scene(), pusher(center, rot @ rot_z(1.1)))
    assert k2 == phase and xx2 == pytest.approx(x, abs=FCL_TOL)


def test_small_tilt_is_continuous_with_closed_form():
    # Tilting by 1e-4 rad moves surface points by at most h*1e-4 + r*5e-9 ~ 6.3e-6 m.
    box = target_region(hand_scene())
    for center in [(0.0, 0.0, 0.734375), (0.171875, 0.1875, 0.75), (0.09375, 0.0, 0.5625), (0.1875, 0.0, 0.5625)]:
        exact = upright_cylinder_box_distance(pusher(center), box)
        tilted = cylinder_box_distance(pusher(center, rot_y(1e-4) @ rot_x(-1e-4)), box)
        assert tilted == pytest.approx(exact, abs=FCL_TOL + 2e-5)


def test_case_where_fcl_gjk_overestimates():
    # Found by random search: python-fcl 0.7 (GJK) reports 0.13369 m here; the truth is 0.06645 m.
    # Box x [0.096, 0.322], y [-0.063, 0.279], z [0.026, 0.090]; upright cylinder r 0.009, h 0.084 at
    # (0.365, -0.125, 0.058): z overlaps, planar offset (0.365 - 0.322, -0.063 + 0.125) = (0.043, 0.062)
    # -> hypot = sqrt(0.005693) = 0.0754520, minus r -> 0.0664520.
    cyl = pusher((0.365, -0.125, 0.058), radius=0.009, half_length=0.084)
    box = Box(np.array([0.209, 0.108, 0.058]), np.array([0.113, 0.171, 0.032]))
    expected = math.sqrt(0.043**2 + 0.062**2) - 0.009
    assert upright_cylinder_box_distance(cyl, box) == pytest.approx(expected, abs=EXACT)
    assert general_distance(cyl, box) == pytest.approx(expected, abs=1e-9)


def test_case_where_fcl_epa_returns_zero_for_an_overlap():
    # python-fcl 0.7 (EPA) reports ~2e-18 here; the disc overlaps the box's vertical edge by 1e-4.
    # Box x [-0.296875, -0.265625], y [-0.265625, 0.203125], z [-0.09375, 0.0625]; centre offset
    # from the edge (-0.265625, -0.265625) along the diagonal so that the planar distance is r - 1e-4.
    r, h = 0.046875, 0.078125
    off = (r - 1e-4) / S2
    cyl = pusher((-0.265625 + off, -0.265625 - off, 0.0625), radius=r, half_length=h)
    box = Box(np.array([-0.28125, -0.03125, -0.015625]), np.array([0.015625, 0.234375, 0.078125]))
    assert upright_cylinder_box_distance(cyl, box) == pytest.approx(-1e-4, abs=1e-12)
    assert general_distance(cyl, box) == pytest.approx(-1e-4, abs=1e-9)


@pytest.mark.parametrize(
    "center,rot",
    [
        ((0.15625, 0.0, 0.5625), np.eye(3)),  # side on the +x face
        ((0.0, 0.0, 0.6875), rot_x(math.pi)),  # cap on the top face
        ((0.15625, 0.0, 0.6875), np.eye(3)),  # rim on the top +x edge
        ((0.0, 0.0, 0.625 + R_P), AXIS_ALONG_Y),  # lying on the top face (line contact)
        ((0.125 + H_P, 0.0, 0.5625), AXIS_ALONG_X),  # flat end on the +x face
        ((0.125 + H_P, 0.125 + R_P, 0.5625), AXIS_ALONG_X),  # end rim on the vertical edge
    ],
)
def test_exact_touching_gives_zero(center, rot):
    # Exactly touching configurations (dyadic, exact arithmetic); python-fcl aborts or returns
    # garbage on such inputs. The last one: axis along x, end cap in the plane x = 0.125 of the
    # +x face, side tangent to the plane y = 0.125 of the +y face: they meet on the vertical edge.
    cyl, box = pusher(center, rot), target_region(hand_scene())
    assert cylinder_box_distance(cyl, box) == pytest.approx(0.0, abs=1e-12)
    assert general_distance(cyl, box) == pytest.approx(0.0, abs=1e-12)
    assert phase_and_x(hand_scene(), cyl)[0] == 3
    assert phase_geometry(hand_scene(), cyl, 0.05)[0] == 3  # touching is inside, on the fast path too


def _rot_xyz(ax: float, ay: float, az: float) -> np.ndarray:
    return rot_z(az) @ rot_y(ay) @ rot_x(ax)


@pytest.mark.parametrize(
    "center,angles",
    [
        ((0.61, 0.03, 0.83), (0.3, 0.2, 0.1)),
        ((0.47, -0.05, 0.95), (0.5, -0.4, 1.0)),
        ((0.52, 0.02, 0.80), (0.2, 0.7, 0.3)),
        ((0.35, 0.12, 0.74), (1.2, 0.3, -0.5)),
        ((0.55, -0.07, 0.86), (0.9, -0.2, 0.4)),
        ((0.66, 0.11, 0.90), (0.1, 1.1, 0.7)),
    ],
)
def test_same_quantity_as_python_fcl_on_generic_poses(center, angles):
    # Same sign convention and value as python-fcl's signed distance (spec §2) on generic tilted
    # poses, clear of touching (python-fcl can abort there) and of the degenerate alignments
    # where it is wrong. Spec-default B_target around (0.5, 0, 0.7 .. 0.85); r 0.02, h 0.06.
    box = Box(np.array([0.5, 0.0, 0.775]), np.array([0.08, 0.08, 0.075]))
    cyl = pusher(center, _rot_xyz(*angles), radius=0.02, half_length=0.06)
    d = cylinder_box_distance(cyl, box)
    assert abs(d) > 1e-3
    assert _fcl_signed_distance(cyl, box.bounds()) == pytest.approx(d, abs=FCL_TOL)


# --------------------------------------------------------------------------- walking through boundaries


def test_walk_out_of_target_along_x_changes_sign_at_boundary():
    # Step 1/256 m in x from the target centre outward at z = 0.5625 (exact dyadic arithmetic).
    # The pusher's z range [0.5, 0.625] equals the target's: vertical overlap 0.125. Horizontal
    # overlap r + 0.125 - cx (centre inside: r + distance to the edge x = 0.125; centre outside:
    # r - planar distance, the same expression). So x = -min(0.15625 - cx, 0.125) until the side
    # reaches the face at cx = 0.15625 (x = 0), then x = cx - 0.125 - r.
    scene = hand_scene()
    prev = -math.inf
    for i in range(0, 81):
        cx = i / 256
        k, x = phase_and_x(scene, pusher((cx, 0.0, 0.5625)))
        expected = cx - 0.125 - R_P if cx > 0.125 + R_P else -min(R_P + 0.125 - cx, 0.125)
        assert x == pytest.approx(expected, abs=EXACT)
        assert x >= prev  # monotone
        prev = x
        if cx < 0.125 + R_P:  # 0.15625 = 40/256
            assert (k, x < 0) == (3, True)
        elif cx == 0.125 + R_P:
            assert (k, x) == (3, 0.0)
        else:
            assert k == 2 and x > 0


def test_walk_into_obstacles_from_outside():
    # Walk from x = 0.5 down to x = 0.3 (step 1/256) at y = 0, z = 0.5625. Boundary where cx - r = 0.375.
    scene = hand_scene()
    for i in range(0, 52):
        cx = 0.5 - i / 256
        k, x = phase_and_x(scene, pusher((cx, 0.0, 0.5625)))
        d_obst = cx - 0.375 - R_P  # > 0 outside
        if d_obst > 0:
            assert k == 1 and x == pytest.approx(d_obst, abs=EXACT)
        else:  # inside or touching: x jumps to the distance to B_target
            assert k == 2 and x == pytest.approx(cx - 0.125 - R_P, abs=EXACT)


@pytest.mark.parametrize(
    "rot,drop,tol",
    [(np.eye(3), H_P, EXACT), (AXIS_ALONG_Y, R_P, FCL_TOL), (TILT_45, C45, FCL_TOL)],
    ids=["upright", "90deg", "45deg"],
)
def test_walk_down_onto_target_top_sign_change(rot, drop, tol):
    # Lower the pusher onto the target top (z = 0.625) in 2 mm steps. Its lowest surface point is
    # z_low = cz - drop with drop = h (upright), r (lying), (h + r)/sqrt2 (45 deg), so expected
    # x = z_low - 0.625: positive above (phase 2, we are inside B_obstacles), 0 touching, and
    # -(0.625 - z_low) below (phase 3; the vertical overlap is the shortest way out).
    scene = hand_scene()
    signs = []
    for i in range(-10, 11):
        expected = 0.002 * i
        k, x = phase_and_x(scene, pusher((0.0, 0.0, 0.625 + drop + expected), rot))
        assert x == pytest.approx(expected, abs=tol)
        if abs(expected) > tol:
            assert k == (3 if expected < 0 else 2)
            signs.append(math.copysign(1.0, x))
    assert signs == [-1.0] * 10 + [1.0] * 10


# --------------------------------------------------------------------------- property tests

finite = dict(allow_nan=False, allow_infinity=False)
coord = st.floats(-0.5, 0.5, **finite)
half = st.floats(0.01, 0.3, **finite)
unit_offset = st.floats(-1.5, 1.5, **finite)
angle = st.floats(0.0, 2 * math.pi, **finite)


@st.composite
def upright_placements(draw):
    """A random AABB and an upright pusher (random yaw, either axis sign) placed around it."""
    bc = np.array([draw(coord) for _ in range(3)])
    bh = np.array([draw(half) for _ in range(3)])
    r = draw(st.floats(0.005, 0.08, **finite))
    h = draw(st.floats(0.01, 0.2, **finite))
    u = np.array([draw(unit_offset) for _ in range(3)])
    # Offsets in units of the touching distance per axis: |u| < 1 overlaps that slab, > 1 is apart.
    c = bc + u * (bh + np.array([r, r, h]))
    rot = rot_z(draw(angle)) @ (rot_x(math.pi) if draw(st.booleans()) else np.eye(3))
    return Cylinder(c, rot, r, h), Box(bc, bh)


@st.composite
def random_rotations(draw):
    q = np.array([draw(st.floats(-1.0, 1.0, **finite)) for _ in range(4)])
    n = np.linalg.norm(q)
    if n < 1e-3:
        return np.eye(3)
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@settings(max_examples=3000, deadline=None)
@given(upright_placements())
def test_general_signed_distance_agrees_with_closed_form(placement):
    # The non-upright path (FCL stand-in) on upright pushers against the exact closed form.
    cyl, box = placement
    exact = upright_cylinder_box_distance(cyl, box)
    d = general_distance(cyl, box)
    assert d == pytest.approx(exact, abs=FCL_TOL)
    assert d == pytest.approx(exact, abs=1e-9)  # what is actually achieved
    assert cylinder_box_distance(cyl, box) == exact  # the public function takes the closed form


def closed_form_axis_aligned(cyl: Cylinder, box: Box, axis: int) -> float:
    """Exact distance for a cylinder whose axis is world axis ``axis``: relabel axes so it is z."""
    perm = [(axis + 1) % 3, (axis + 2) % 3, axis]
    return upright_cylinder_box_distance(
        Cylinder(cyl.center[perm], np.eye(3), cyl.radius, cyl.half_length), Box(box.center[perm], box.half_size[perm])
    )


dyadic = st.integers(-24, 24).map(lambda i: i / 64)
dyadic_size = st.integers(1, 16).map(lambda i: i / 64)


@st.composite
def snapped_placements(draw):
    """Dyadic boxes and cylinders lying along x or y, placed at touching / overlapping / apart offsets."""
    bc = np.array([draw(dyadic) for _ in range(3)])
    bh = np.array([draw(dyadic_size) for _ in range(3)])
    r, h = draw(dyadic_size), draw(dyadic_size)
    axis = draw(st.sampled_from([0, 1]))
    ext = np.array([r, r, r])
    ext[axis] = h
    u = np.array([draw(st.sampled_from([-1.5, -1.0, -0.75, 0.0, 0.5, 1.0, 1.25])) for _ in range(3)])
    rot = {0: AXIS_ALONG_X, 1: AXIS_ALONG_Y}[axis] @ rot_z(draw(st.sampled_from([0.0, math.pi / 2, 1.0])))
    return Cylinder(bc + u * (bh + ext), rot, r, h), Box(bc, bh), axis


@settings(max_examples=600, deadline=None)
@given(snapped_placements())
def test_lying_cylinder_agrees_with_relabelled_closed_form(placement):
    # A cylinder lying along x or y is an "upright" cylinder after relabelling the axes, so the
    # closed form gives the exact answer; these snapped placements hit exact touching often.
    cyl, box, axis = placement
    assert cylinder_box_distance(cyl, box) == pytest.approx(closed_form_axis_aligned(cyl, box, axis), abs=1e-9)


def _fibonacci_sphere(m: int) -> np.ndarray:
    """m near-uniform unit vectors."""
    i = np.arange(m) + 0.5
    z = 1.0 - 2.0 * i / m
    phi = np.pi * (1.0 + 5**0.5) * i
    rho = np.sqrt(1.0 - z * z)
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)


_FIB_DIRS = _fibonacci_sphere(20000)


def _gaps(n: np.ndarray, cyl: Cylinder, box: Box) -> np.ndarray:
    a = cyl.rotation[:, 2]
    lo, hi = box.center - box.half_size, box.center + box.half_size
    box_min = (n * np.where(n > 0, lo, hi)).sum(axis=1)
    na = n @ a
    cyl_max = n @ cyl.center + cyl.half_length * np.abs(na) + cyl.radius * np.linalg.norm(n - na[:, None] * a, axis=1)
    return box_min - cyl_max


def dense_support_gap(cyl: Cylinder, box: Box) -> float:
    """Independent estimate of the signed distance: for convex bodies it is the max over unit n
    of min_box n.x - max_cyl n.x. Maximised by a 20000-direction grid, then a derivative-free
    random search around the best direction with a shrinking step (the gap has kinks)."""
    g = _gaps(_FIB_DIRS, cyl, box)
    rng = np.random.default_rng(0)
    best = float(g.max())
    for start in _FIB_DIRS[np.argsort(g)[-4:]]:  # the 4 best grid directions
        n, val, sigma = start, float(_gaps(start[None, :], cyl, box)[0]), 0.03
        for _ in range(40):
            trial = n + sigma * rng.standard_normal((100, 3))
            trial /= np.linalg.norm(trial, axis=1)[:, None]
            tg = _gaps(trial, cyl, box)
            if tg.max() > val:
                n, val = trial[tg.argmax()], float(tg.max())
            else:
                sigma *= 0.6
        best = max(best, val)
    return best


def sampled_surface_distance(cyl: Cylinder, box: Box) -> float:
    """Independent upper bound on max(signed distance, 0): the least distance from the box to
    20000 points on the cylinder's surface (side and caps), refined by a shrinking random search."""
    rng = np.random.default_rng(1)
    r, h = cyl.radius, cyl.half_length
    m = 20000

    def surface(u: np.ndarray) -> np.ndarray:  # u in [0, 1)^3 -> local surface points
        phi, w, k = 2 * math.pi * u[:, 0], (2 * u[:, 1] - 1) * h, u[:, 2]
        rho = np.where(k < 0.5, r, r * np.sqrt(u[:, 1]))  # side, or a cap disc
        z = np.where(k < 0.5, w, np.where(k < 0.75, h, -h))
        return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1) @ cyl.rotation.T + cyl.center

    def dist(p: np.ndarray) -> np.ndarray:
        lo, hi = box.center - box.half_size, box.center + box.half_size
        return np.linalg.norm(p - np.clip(p, lo, hi), axis=1)

    u = rng.random((m, 3))
    d = dist(surface(u))
    best_u, best = u[d.argmin()], float(d.min())
    sigma = 0.02
    for _ in range(40):
        trial = best_u + sigma * rng.standard_normal((100, 3))
        trial[:, 0] %= 1.0
        trial[:, 1] = np.clip(trial[:, 1], 0.0, 1.0)
        trial[:, 2] = best_u[2]  # stay on the same surface patch
        dt = dist(surface(trial))
        if dt.min() < best:
            best_u, best = trial[dt.argmin()], float(dt.min())
        else:
            sigma *= 0.6
    return best


@settings(max_examples=200, deadline=None)
@given(upright_placements(), random_rotations())
def test_tilted_distance_against_independent_bounds(placement, rot):
    # Sandwich the general path between two independent numeric searches:
    #   dual:   max over directions n of (min_box n.x - max_cyl n.x) <= signed distance;
    #   primal: distance from the box to sampled cylinder surface points >= max(signed distance, 0).
    cyl0, box = placement
    cyl = Cylinder(cyl0.center, rot, cyl0.radius, cyl0.half_length)
    d = cylinder_box_distance(cyl, box)
    # Nearly upright poses take the closed form, which ignores a tilt of up to UPRIGHT_TOL.
    tol = 1e-9 + (cyl.radius + cyl.half_length) * UPRIGHT_TOL
    assert dense_support_gap(cyl, box) <= d + tol
    upper = sampled_surface_distance(cyl, box)
    assert d <= upper + tol
    if d > 0.0:  # when apart, the sampled surface finds the nearest point to within the tolerance
        assert upper - d <= FCL_TOL


@settings(max_examples=300, deadline=None)
@given(upright_placements(), st.sampled_from([-1.0, 1.0]), st.sampled_from([-1.0, 1.0]), coord, coord, coord)
def test_closed_form_symmetries(placement, sx, sy, tx, ty, tz):
    cyl, box = placement
    d = upright_cylinder_box_distance(cyl, box)
    tol = 1e-12
    # Mirror x and/or y (both bodies): the AABB stays axis-aligned, the cylinder stays upright.
    m = np.array([sx, sy, 1.0])
    mirrored = upright_cylinder_box_distance(Cylinder(cyl.center * m, np.eye(3), cyl.radius, cyl.half_length), Box(box.center * m, box.half_size))
    assert mirrored == pytest.approx(d, abs=tol)
    # Swap x and y (mirror in the plane x = y).
    p = [1, 0, 2]
    swapped = upright_cylinder_box_distance(
        Cylinder(cyl.center[p], np.eye(3), cyl.radius, cyl.half_length), Box(box.center[p], box.half_size[p])
    )
    assert swapped == pytest.approx(d, abs=tol)
    # Translate both.
    t = np.array([tx, ty, tz])
    moved = upright_cylinder_box_distance(Cylinder(cyl.center + t, cyl.rotation, cyl.radius, cyl.half_length), Box(box.center + t, box.half_size))
    assert moved == pytest.approx(d, abs=tol)
    # Flip the axis / spin about it: same solid.
    flipped = Cylinder(cyl.center, cyl.rotation @ rot_x(math.pi) @ rot_z(1.0), cyl.radius, cyl.half_length)
    assert upright_cylinder_box_distance(flipped, box) == d
    # Swelling the pusher never increases the distance (monotone in r and h).
    fat = Cylinder(cyl.center, cyl.rotation, cyl.radius + 0.01, cyl.half_length + 0.01)
    assert upright_cylinder_box_distance(fat, box) <= d


@settings(max_examples=200, deadline=None)
@given(upright_placements(), random_rotations(), st.sampled_from([-1.0, 1.0]), coord, coord)
def test_tilted_symmetries(placement, rot, sx, tx, ty):
    cyl, box = placement
    tilted = Cylinder(cyl.center, rot, cyl.radius, cyl.half_length)
    d = cylinder_box_distance(tilted, box)
    # Flipping the axis and spinning about it describe the same solid.
    same = Cylinder(cyl.center, rot @ rot_x(math.pi) @ rot_z(0.9), cyl.radius, cyl.half_length)
    assert cylinder_box_distance(same, box) == pytest.approx(d, abs=FCL_TOL)
    # Mirror in x (M R M keeps det +1 and mirrors the axis) and translate horizontally.
    mm = np.diag([sx, 1.0, 1.0])
    t = np.array([tx, ty, 0.0])
    mirrored = Cylinder(mm @ cyl.center + t, mm @ rot @ mm, cyl.radius, cyl.half_length)
    assert cylinder_box_distance(mirrored, Box(mm @ box.center + t, box.half_size)) == pytest.approx(d, abs=FCL_TOL)
    # Sandwich: the pusher contains its centre point and is contained in its bounding sphere
    # (radius hypot(r, h)), and signed distance only decreases as a body grows.
    R = math.hypot(cyl.radius, cyl.half_length)
    p_sd = point_box_signed_distance(cyl.center, box)
    assert p_sd - R - FCL_TOL <= d <= p_sd + FCL_TOL


def point_box_signed_distance(p: np.ndarray, box: Box) -> float:
    """Distance from p to the box if outside, minus the distance to the nearest face if inside."""
    excess = np.abs(p - box.center) - box.half_size  # per-axis, > 0 beyond that slab
    if (excess > 0).any():
        return float(np.linalg.norm(np.maximum(excess, 0.0)))
    return float(excess.max())


@st.composite
def scenes(draw):
    z0 = draw(st.floats(-1.0, 1.0, **finite))
    n = draw(st.integers(1, 4))
    centers = np.array([[draw(coord), draw(coord), z0 + 0.05] for _ in range(n)])
    halves = np.array([[draw(st.floats(0.01, 0.1, **finite)) for _ in range(3)] for _ in range(n)])
    params = RegionParams(
        target_half_width=draw(st.floats(0.02, 0.2, **finite)),
        target_height=draw(st.floats(0.02, 0.3, **finite)),
        obstacle_margin=draw(st.floats(0.0, 0.1, **finite)),
        obstacle_height=draw(st.floats(0.05, 0.4, **finite)),
    )
    return PhaseScene(z0, np.array([draw(coord), draw(coord), z0 + 0.05]), centers, halves, params)


def pushers(z0_from_scene: PhaseScene, rotations):
    return st.builds(
        lambda x, y, dz, rot, r, h: Cylinder(np.array([x, y, z0_from_scene.table_height + dz]), rot, r, h),
        st.floats(-0.8, 0.8, **finite),
        st.floats(-0.8, 0.8, **finite),
        st.floats(-0.1, 0.6, **finite),
        rotations,
        st.floats(0.005, 0.05, **finite),
        st.floats(0.01, 0.1, **finite),
    )


def check_phase_invariants(scene: PhaseScene, cyl: Cylinder, tol: float) -> None:
    k, x = phase_and_x(scene, cyl)
    d_target = cylinder_box_distance(cyl, target_region(scene))
    d_obst = cylinder_box_distance(cyl, obstacle_region(scene))
    assert k in (1, 2, 3)
    if k == 3:  # in B_target: x is its own (non-positive) signed distance
        assert x <= 0.0 and x == pytest.approx(d_target, abs=tol)
    elif k == 2:  # in B_obstacles, not in B_target: x = distance to B_target
        assert x > 0.0 and x == pytest.approx(d_target, abs=tol) and d_obst <= tol
    else:  # approach: x = distance to B_obstacles, outside both
        assert x > 0.0 and x == pytest.approx(d_obst, abs=tol) and d_target > -tol
    # The two-step route (both distances, then the phase) agrees.
    k2, x2 = phase_from_distances(*region_distances(scene, cyl))
    assert k2 == k and x2 == pytest.approx(x, abs=tol)


@settings(max_examples=400, deadline=None)
@given(st.data())
def test_phase_invariants_upright(data):
    scene = data.draw(scenes())
    rots = st.builds(lambda a, f: rot_z(a) @ (rot_x(math.pi) if f else np.eye(3)), angle, st.booleans())
    check_phase_invariants(scene, data.draw(pushers(scene, rots)), 1e-12)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_phase_invariants_tilted(data):
    scene = data.draw(scenes())
    check_phase_invariants(scene, data.draw(pushers(scene, random_rotations())), 1e-8)


# --------------------------------------------------------------------------- bad input

GOOD_SCENE_ARGS = dict(
    table_height=0.5,
    target_center=np.array([0.0, 0.0, 0.5625]),
    obstacle_centers=np.array([[-0.25, 0.125, 0.5625], [0.25, -0.1875, 0.53125], [0.0, 0.2, 0.55]]),
    obstacle_half_sizes=np.array([[0.0625, 0.0625, 0.0625], [0.0625, 0.03125, 0.03125], [0.03, 0.03, 0.03]]),
    params=HAND_PARAMS,
)


def _scene_with(**changes):
    args = dict(GOOD_SCENE_ARGS)
    args.update(changes)
    return PhaseScene(**args)


_bad_halves = GOOD_SCENE_ARGS["obstacle_half_sizes"].copy()
_bad_halves[2, 1] = -0.03
_nan_centers = GOOD_SCENE_ARGS["obstacle_centers"].copy()
_nan_centers[1, 2] = np.nan

BAD_INPUTS = [
    (lambda: Box(np.zeros(3), np.array([0.1, -0.1, 0.1])), r"half_size\[1\] must be > 0, got -0\.1"),
    (lambda: Box(np.zeros(3), np.array([0.1, 0.1, 0.0])), r"half_size\[2\] must be > 0, got 0\.0"),
    (lambda: Box(np.array([0.0, 0.0, np.nan]), np.ones(3)), r"center\[2\] must be finite, got nan"),
    (lambda: Box(np.zeros(2), np.ones(3)), r"center must have shape \(3,\), got \(2,\)"),
    (lambda: Box(np.zeros(3), "big"), r"half_size must be an array of numbers"),
    (lambda: Cylinder(np.zeros(3), np.eye(3), 0.0, 0.1), r"radius must be > 0, got 0\.0"),
    (lambda: Cylinder(np.zeros(3), np.eye(3), -0.02, 0.1), r"radius must be > 0, got -0\.02"),
    (lambda: Cylinder(np.zeros(3), np.eye(3), 0.02, float("nan")), r"half_length must be finite, got nan"),
    (lambda: Cylinder(np.zeros(3), np.eye(3), None, 0.1), r"radius must be a number"),
    (lambda: Cylinder(np.zeros(3), 2 * np.eye(3), 0.02, 0.1), r"rotation must be a rotation matrix"),
    (lambda: Cylinder(np.zeros(3), np.diag([1.0, 1.0, -1.0]), 0.02, 0.1), r"rotation must be a rotation matrix.*det = -1"),
    (lambda: Cylinder(np.zeros(3), np.eye(4), 0.02, 0.1), r"rotation must have shape \(3, 3\), got \(4, 4\)"),
    (lambda: Cylinder(np.array([0.0, np.inf, 0.0]), np.eye(3), 0.02, 0.1), r"center\[1\] must be finite, got inf"),
    (lambda: RegionParams(-0.08, 0.15, 0.05, 0.25), r"target_half_width must be > 0, got -0\.08"),
    (lambda: RegionParams(0.08, 0.0, 0.05, 0.25), r"target_height must be > 0, got 0\.0"),
    (lambda: RegionParams(0.08, 0.15, -0.01, 0.25), r"obstacle_margin must be >= 0, got -0\.01"),
    (lambda: RegionParams(0.08, 0.15, 0.05, float("inf")), r"obstacle_height must be finite, got inf"),
    (lambda: _scene_with(obstacle_half_sizes=_bad_halves), r"obstacle_half_sizes\[2\]\[1\] must be > 0, got -0\.03"),
    (lambda: _scene_with(obstacle_centers=_nan_centers), r"obstacle_centers\[1\]\[2\] must be finite, got nan"),
    (lambda: _scene_with(obstacle_centers=np.zeros((3, 2))), r"obstacle_centers must have shape \(n, 3\), got \(3, 2\)"),
    (lambda: _scene_with(obstacle_half_sizes=np.ones((2, 3))), r"same shape as obstacle_centers \(3, 3\), got \(2, 3\)"),
    (lambda: _scene_with(obstacle_centers=np.zeros((0, 3)), obstacle_half_sizes=np.zeros((0, 3))), r"at least one obstacle"),
    (lambda: _scene_with(table_height=float("nan")), r"table_height must be finite, got nan"),
    (lambda: _scene_with(target_center=np.zeros(4)), r"target_center must have shape \(3,\), got \(4,\)"),
    (lambda: _scene_with(params=(0.08, 0.15, 0.05, 0.25)), r"params must be a RegionParams, got tuple"),
]


@pytest.mark.parametrize("make,message", BAD_INPUTS, ids=[m for _, m in BAD_INPUTS])
def test_bad_input_raises_value_error(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2), st.integers(0, 2), st.floats(-1.0, 0.0, **finite))
def test_any_nonpositive_obstacle_size_is_named(i, j, bad):
    halves = GOOD_SCENE_ARGS["obstacle_half_sizes"].copy()
    halves[i, j] = bad
    with pytest.raises(ValueError, match=rf"obstacle_half_sizes\[{i}\]\[{j}\] must be > 0, got {re_float(bad)}"):
        _scene_with(obstacle_half_sizes=halves)


def re_float(v: float) -> str:
    import re

    return re.escape(str(v))


def test_inputs_are_copied_and_read_only():
    c = np.array([0.0, 0.0, 0.7])
    cyl = Cylinder(c, np.eye(3), R_P, H_P)
    c[0] = 5.0  # the caller's array is not aliased
    assert cyl.center[0] == 0.0
    with pytest.raises(ValueError):
        cyl.center[0] = 1.0  # read-only
    # Lists are accepted and converted.
    assert Box([0, 0, 0], [1, 1, 1]).bounds() == (-1.0, -1.0, -1.0, 1.0, 1.0, 1.0)


# --------------------------------------------------------------------------- phase_geometry
from hypothesis import given as _given, settings as _settings, strategies as _st  # noqa: E402

from ahrm_stack.kinematics.phases import phase_geometry as _phase_geometry  # noqa: E402
from ahrm_stack.kinematics.phases import region_distances as _region_distances  # noqa: E402


def _rotation_from(axis_angle: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(axis_angle))
    if angle < 1e-12:
        return np.eye(3)
    k = axis_angle / angle
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


@_settings(max_examples=400, deadline=None)
@_given(_st.lists(_st.floats(-0.35, 0.35), min_size=3, max_size=3),
        _st.floats(0.4, 0.9), _st.lists(_st.floats(-1.5, 1.5), min_size=3, max_size=3),
        _st.booleans())
def test_phase_geometry_matches_phase_and_x_and_clipped_distances(xy_z, z, tilt, upright):
    scene = PhaseScene(0.4, np.array([0.0, 0.0, 0.425]),
                       np.array([[0.16, 0.05, 0.45], [-0.15, 0.16, 0.45]]),
                       np.full((2, 3), [0.03, 0.03, 0.05]),
                       RegionParams(0.08, 0.15, 0.05, 0.25))
    rotation = np.eye(3) if upright else _rotation_from(np.asarray(tilt))
    pusher = Cylinder(np.array([xy_z[0], xy_z[1], z - 0.3 + xy_z[2]]), rotation, 0.02, 0.075)
    phase, x, clipped = _phase_geometry(scene, pusher, clip=0.1)
    assert (phase, x) == phase_and_x(scene, pusher)
    exact = _region_distances(scene, pusher)
    np.testing.assert_allclose(clipped, np.clip(exact, -0.1, 0.1), atol=1e-9)


# --------------------------------------------------------------------------- fast path (certified shortcuts)
# The fast path (coal's directions, exact bounds) must agree with the reference routine whenever
# it answers, and answer the task's usual poses; coal's own values are never trusted.
import ahrm_stack.kinematics.cylinder_box as _phases  # noqa: E402


def _pusher_like(draw, box: Box) -> Cylinder:
    """The task's pusher (r 0.02, h 0.075) tilted up to ~0.5 rad, around and inside ``box``."""
    tilt = _rotation_from(np.array([draw(_st.floats(-0.5, 0.5)), draw(_st.floats(-0.5, 0.5)), 0.0]))
    yaw = rot_z(draw(angle))
    u = np.array([draw(_st.floats(-1.3, 1.3)) for _ in range(3)])
    return Cylinder(box.center + u * (box.half_size + np.array([0.02, 0.02, 0.075])), yaw @ tilt, 0.02, 0.075)


@_settings(max_examples=300, deadline=None)
@_given(upright_placements(), random_rotations())
def test_fast_path_agrees_with_reference_on_random_poses(placement, rot):
    cyl0, box = placement
    cd = _phases._cyl_data(Cylinder(cyl0.center, rot, cyl0.radius, cyl0.half_length))
    fast = _phases._fast_distance(cd, box.bounds())
    if fast is not None:
        # The fast value is bracketed to POLISH_TOL (1e-9 m) by its own bounds. The reference's
        # arc search is that good except on nearly axis-aligned poses (tilts ~1e-5 rad), where it
        # falls short by up to ~3e-8 m; there the fast value is the higher lower bound, i.e. closer.
        ref = _phases._reference_distance(cd, box.bounds())
        assert ref - 2e-9 <= fast <= ref + 1e-7


@_settings(max_examples=300, deadline=None)
@_given(_st.data())
def test_fast_path_agrees_with_reference_on_pusher_poses(data):
    box = Box(np.array([0.0, 0.0, 0.475]), np.array([0.08, 0.08, 0.075]))  # a B_target
    cd = _phases._cyl_data(_pusher_like(data.draw, box))
    fast = _phases._fast_distance(cd, box.bounds())
    if fast is not None:  # both certified to POLISH_TOL (1e-9 m): they may differ by twice that
        assert fast == pytest.approx(_phases._reference_distance(cd, box.bounds()), abs=2e-9)


def test_fast_path_answers_most_pusher_poses():
    # Task-like poses from a fixed seed: the pusher's tip (its lower end) in and around a B_target,
    # tilted up to 0.4 rad. The certified shortcut answers nearly all of them (it is what makes
    # the step fast; measured 385/400 before the fan and the search of the curved optima, 398/400
    # with them); the rest take the reference.
    rng = np.random.default_rng(0)
    box = Box(np.array([0.0, 0.0, 0.475]), np.array([0.08, 0.08, 0.075]))
    answered = overlapping = 0
    for _ in range(400):
        rot = rot_z(rng.uniform(0.0, 2 * math.pi)) @ _rotation_from(np.array([*rng.uniform(-0.4, 0.4, 2), 0.0]))
        tip = np.array([*rng.uniform(-0.11, 0.11, 2), rng.uniform(0.405, 0.6)])
        cd = _phases._cyl_data(Cylinder(tip + 0.075 * rot[:, 2], rot, 0.02, 0.075))
        fast = _phases._fast_distance(cd, box.bounds())
        answered += fast is not None
        overlapping += fast is not None and fast < 0.0
    assert answered >= 0.98 * 400 and overlapping >= 200


# Overlaps whose optimum is curved (found among the fallbacks of benchmarks/bench_phases.py's random
# tilted poses, a B_target of the task): (cylinder centre, rotation, bounds, the reference's value).
_B_TARGET = (-0.07902372992145351, -0.07569621267255161, 0.4, 0.08097627007854649, 0.08430378732744839, 0.55)
_CURVED = {
    "box edge vs cap rim": (
        (-0.08704982137131415, -0.0031403039786791556, 0.6244815478954429),
        [[0.9681102404567284, -0.23706618059206183, -0.08100733511421969],
         [-0.22883845118911544, -0.968399357528452, 0.09917483348031489],
         [-0.10195845026373436, -0.07747457878538797, -0.9917671924710175]], -0.002447518117297663),
    "box vertex vs side": (
        (-0.08867691612334137, -0.0672287004287259, 0.5833453282606281),
        [[0.9878428646866987, 0.10169779955897029, -0.1175756448097999],
         [0.039147828410363204, -0.8946941250023058, -0.4449605265831016],
         [-0.15044574509878797, 0.43494825008410115, -0.8877984554674831]], -0.004585998779602973),
    "coal's EPA fails (-DBL_MAX)": (
        (0.10759976352076107, 0.11752217349507639, 0.568736424056343),
        [[-0.0034738432978827422, -0.9312215413630187, -0.36443706358468186],
         [-0.9196666794765772, 0.14608560176878305, -0.36451638593673563],
         [0.39268451850470043, 0.3338943513408638, -0.8569209012910092]], -0.012392688121440992),
}


@pytest.mark.parametrize("name", list(_CURVED))
def test_fast_path_certifies_curved_optima(name):
    # Before the geometric fan of prism vertices (cylinder_box._fan) and the search of the curved
    # optima (_searched_gap) these went to the reference routine (~0.3-0.8 ms).
    center, rot, want = _CURVED[name]
    cd = _phases._cyl_data(Cylinder(np.array(center), np.array(rot), 0.02, 0.075))
    assert _phases._reference_distance(cd, _B_TARGET) == pytest.approx(want, abs=1e-12)
    fast = _phases._fast_distance(cd, _B_TARGET)
    assert fast is not None and fast == pytest.approx(want, abs=2e-9)


def test_coal_failure_on_a_curved_overlap_is_searched(monkeypatch):
    # coal answers nothing usable: the search of the curved optima still certifies the overlap.
    center, rot, want = _CURVED["box edge vs cap rim"]
    cd = _phases._cyl_data(Cylinder(np.array(center), np.array(rot), 0.02, 0.075))
    monkeypatch.setattr(_phases, "_coal_query", lambda cd, b: (math.nan, np.zeros(3), np.zeros(3)))
    fast = _phases._fast_distance(cd, _B_TARGET)
    assert fast is not None and fast == pytest.approx(want, abs=2e-9)


def test_coal_epa_wrong_face_is_not_trusted():
    # Found by hypothesis: coal's EPA reports -0.046875 (a face) for this lying pusher; the truth
    # (the relabelled closed form of test_lying_cylinder_agrees_with_relabelled_closed_form) is
    # -0.0096224657881. The fast path must not return coal's value.
    cyl = pusher((-0.140625, -0.140625, -0.17578125), rot_y(math.pi / 2), radius=10 / 64, half_length=11 / 64)
    box = Box(np.zeros(3), np.array([0.015625, 0.03125, 0.078125]))
    assert general_distance(cyl, box) == pytest.approx(-0.009622465788097972, abs=1e-9)


def test_coal_failure_falls_back_to_reference(monkeypatch):
    # coal's EPA failure value (-DBL_MAX) or a garbage direction: the reference routine answers.
    cyl = pusher((0.02, 0.01, 0.6), TILT_45)
    box = target_region(hand_scene())
    want = _phases._reference_distance(_phases._cyl_data(cyl), box.bounds())
    bad = [(-1.7976931348623157e308, np.array([1.0, 0.0, 0.0]), np.zeros(3)),
           (0.3, np.array([0.0, 0.0, 0.0]), np.zeros(3)), (0.3, np.array([0.6, 0.8, 0.0]), np.zeros(3))]
    for reply in bad:
        monkeypatch.setattr(_phases, "_coal_query", lambda cd, b, reply=reply: reply)
        assert general_distance(cyl, box) == pytest.approx(want, abs=1e-9)


def test_unchecked_constructors_match_checked_ones():
    # The per-step constructors (inputs from the simulator) give the same scene and pusher.
    args = dict(GOOD_SCENE_ARGS)
    fast = PhaseScene.unchecked(args["table_height"], args["target_center"], args["obstacle_centers"],
                                args["obstacle_half_sizes"], args["params"])
    slow = PhaseScene(**args)
    assert fast._target_bounds == slow._target_bounds and fast._obstacle_bounds == slow._obstacle_bounds
    rot = _rot_xyz(0.3, -0.2, 1.0)
    centre = np.array([0.1, 0.0, 0.6])
    a, b = Cylinder(centre, rot, R_P, H_P), Cylinder.unchecked(centre, rot, R_P, H_P)
    assert _phase_geometry(slow, a, 0.1)[:2] == _phase_geometry(fast, b, 0.1)[:2]
    with pytest.raises(ValueError, match="pusher pose must be finite"):
        Cylinder.unchecked(np.array([0.0, np.nan, 0.0]), rot, R_P, H_P)
    with pytest.raises(ValueError, match="must be finite"):
        PhaseScene.unchecked(0.5, np.array([np.inf, 0.0, 0.0]), args["obstacle_centers"], args["obstacle_half_sizes"],
                             args["params"])
