"""What the homing step sends, against Kinova's own binary's debug information (DWARF, read with
binutils' ``readelf``): ``MoveHome`` takes no argument and returns int; ``POSITION_TYPE``'s
``ANGULAR_POSITION`` and ``ANGULAR_VELOCITY`` have the values ahrm_stack/hardware/kinova_gen2/ sends; the
``Limitation``, ``UserPosition`` and ``TrajectoryPoint`` structs have the size and member offsets of
the ctypes layouts (``speedParameter1``/``2``, ``LimitationsActive``: the homing move's speed
limits)."""

from __future__ import annotations

import ctypes
import re
import shutil
import subprocess
import typing

import pytest

from ahrm_stack.hardware import kinova_gen2
from ahrm_stack.hardware.kinova_gen2 import sdk
from ahrm_stack.hardware.kinova_gen2.loader import VENDOR_LIBRARY
from ahrm_stack.hardware.kinova_gen2.settings import ROBOT_TYPES, RobotType

pytestmark = pytest.mark.skipif(shutil.which("readelf") is None or not VENDOR_LIBRARY.is_file(),
                                reason="binutils' readelf and the vendored Gen2 SDK are needed")
HEADER = re.compile(r"^ <(\d+)><([0-9a-f]+)>: Abbrev Number: \d+ \((DW_TAG_\w+)\)")
ATTRIBUTE = re.compile(r"^\s+<[0-9a-f]+>\s+(DW_AT_\w+)\s*:\s*(.*)$")


@pytest.fixture(scope="module")
def dies() -> list[dict]:
    """Every debugging information entry: depth, tag, attributes (name -> text), in file order."""
    text = subprocess.run(["readelf", "--debug-dump=info", str(VENDOR_LIBRARY)], capture_output=True,
                          text=True, check=True).stdout
    out: list[dict] = []
    for line in text.splitlines():
        header = HEADER.match(line)
        if header:
            out.append({"depth": int(header.group(1)), "tag": header.group(3), "at": {}})
            continue
        attribute = ATTRIBUTE.match(line)
        if attribute and out:
            value = attribute.group(2).strip()
            out[-1]["at"][attribute.group(1)] = value.split(": ")[-1] if "indirect string" in value else value
    return out


def _children(dies: list[dict], index: int) -> list[dict]:
    depth, out = dies[index]["depth"], []
    for die in dies[index + 1:]:
        if die["depth"] <= depth:
            break
        if die["depth"] == depth + 1:
            out.append(die)
    return out


def _find(dies, tag: str, name: str) -> int:
    return next(i for i, d in enumerate(dies) if d["tag"] == tag and d["at"].get("DW_AT_name") == name
                and d["at"].get("DW_AT_declaration") is None)


def test_move_home_takes_no_argument(dies):
    index = _find(dies, "DW_TAG_subprogram", "MoveHome")
    assert dies[index]["at"].get("DW_AT_external") == "1"
    assert not [c for c in _children(dies, index) if c["tag"] == "DW_TAG_formal_parameter"]
    assert "MoveHome" in kinova_gen2.SIGNATURES and kinova_gen2.SIGNATURES["MoveHome"] == ()
    send = _find(dies, "DW_TAG_subprogram", "SendAdvanceTrajectory")
    parameters = [c for c in _children(dies, send) if c["tag"] == "DW_TAG_formal_parameter"]
    assert [p["at"]["DW_AT_name"] for p in parameters] == ["trajectory"]


def test_position_types_have_the_values_sent(dies):
    values = {d["at"]["DW_AT_name"]: int(d["at"]["DW_AT_const_value"]) for d in dies
              if d["tag"] == "DW_TAG_enumerator" and d["at"].get("DW_AT_name") in
              ("ANGULAR_POSITION", "ANGULAR_VELOCITY")}
    assert values == {"ANGULAR_POSITION": kinova_gen2.ANGULAR_POSITION,
                      "ANGULAR_VELOCITY": kinova_gen2.ANGULAR_VELOCITY}


@pytest.mark.parametrize("struct", [kinova_gen2.Limitation, kinova_gen2.UserPosition,
                                    kinova_gen2.TrajectoryPoint, sdk.QuickStatus])
def test_structs_match_the_ctypes_layouts(dies, struct):
    index = _find(dies, "DW_TAG_structure_type", struct.__name__)
    assert int(dies[index]["at"]["DW_AT_byte_size"]) == ctypes.sizeof(struct)
    members = {c["at"]["DW_AT_name"]: int(c["at"]["DW_AT_data_member_location"])
               for c in _children(dies, index) if c["tag"] == "DW_TAG_member"
               and "DW_AT_data_member_location" in c["at"]}
    ours = {name: getattr(struct, name).offset for name, _ in struct._fields_}
    assert members == ours


def test_robot_types_are_the_binarys_and_quick_status_takes_one_pointer(dies):
    """The arm check (connect refuses another arm) reads QuickStatus.RobotType: ROBOT_TYPE's values
    as the binary has them, and every name deploy.yaml may give is one of them."""
    index = _find(dies, "DW_TAG_enumeration_type", "ROBOT_TYPE")
    values = {int(c["at"]["DW_AT_const_value"]): c["at"]["DW_AT_name"] for c in _children(dies, index)
              if c["tag"] == "DW_TAG_enumerator"}
    assert values == ROBOT_TYPES
    assert set(typing.get_args(RobotType)) <= set(values.values())
    query = _find(dies, "DW_TAG_subprogram", "GetQuickStatus")
    parameters = [c for c in _children(dies, query) if c["tag"] == "DW_TAG_formal_parameter"]
    assert len(parameters) == 1 and len(sdk.SIGNATURES["GetQuickStatus"]) == 1
