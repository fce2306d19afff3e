"""A URDF file read into plain data: links (inertia, meshes) and joints (origin, axis, limits).

Only what the arm entity and the robot description need is read; anything the reader does not
understand where it matters (a non-mesh geometry, a joint type other than revolute, continuous or
fixed) raises :class:`UrdfError` naming the file and the element. Units: metres, radians, kg.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np


class UrdfError(ValueError):
    """The URDF cannot be used; the message names the file and the element."""


@dataclasses.dataclass(frozen=True)
class Origin:
    """A pose relative to the parent frame: ``xyz`` (m) and roll-pitch-yaw (rad, fixed axes x-y-z,
    i.e. R = Rz(yaw) Ry(pitch) Rx(roll))."""

    xyz: np.ndarray
    rpy: np.ndarray

    @property
    def rotation(self) -> np.ndarray:
        return rpy_to_matrix(self.rpy)

    @property
    def quaternion(self) -> np.ndarray:
        """(w, x, y, z), unit, w >= 0."""
        return matrix_to_quaternion(self.rotation)


@dataclasses.dataclass(frozen=True)
class Inertial:
    mass: float  # kg
    origin: Origin  # centre of mass and principal frame, link frame
    inertia: np.ndarray  # 3 x 3 about the centre of mass, in the inertial frame, kg m^2


@dataclasses.dataclass(frozen=True)
class Mesh:
    uri: str  # as written in the URDF (package://...)
    origin: Origin
    rgba: tuple[float, float, float, float] | None  # the material's colour, if given inline or by name


@dataclasses.dataclass(frozen=True)
class Link:
    name: str
    inertial: Inertial | None
    visuals: tuple[Mesh, ...]
    collisions: tuple[Mesh, ...]


@dataclasses.dataclass(frozen=True)
class Joint:
    name: str
    type: str  # revolute | continuous | fixed
    parent: str
    child: str
    origin: Origin  # child link frame in the parent link frame
    axis: np.ndarray  # unit, child link frame
    lower: float  # rad; -inf for continuous joints
    upper: float  # rad; +inf for continuous joints
    velocity: float  # rad/s, |dq| <= velocity (0 for fixed joints)
    effort: float  # N m, |tau| <= effort (0 for fixed joints)


@dataclasses.dataclass(frozen=True)
class Urdf:
    path: Path
    name: str
    links: dict[str, Link]
    joints: dict[str, Joint]  # in file order

    def chain(self, root: str, tip: str) -> list[Joint]:
        """The joints from link ``root`` down to link ``tip``, root first."""
        by_child = {j.child: j for j in self.joints.values()}
        for link in (root, tip):
            if link not in self.links:
                raise UrdfError(f"{self.path}: no link {link!r}; links: {sorted(self.links)}")
        joints = []
        link = tip
        while link != root:
            if link not in by_child:
                raise UrdfError(f"{self.path}: link {tip!r} is not below link {root!r}")
            joints.append(by_child[link])
            link = by_child[link].parent
        return joints[::-1]


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), the URDF convention."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def matrix_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, dtype=float)
    trace = np.trace(m)
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2 * np.sqrt(1 + trace)
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2 * np.sqrt(1 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2 * np.sqrt(1 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2 * np.sqrt(1 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4]
    q = np.array(q) / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def _floats(text: str | None, count: int, where: str, default: list[float]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=float)
    try:
        values = np.array([float(v) for v in text.split()], dtype=float)
    except ValueError:
        raise UrdfError(f"{where}: expected {count} numbers, got {text!r}") from None
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise UrdfError(f"{where}: expected {count} finite numbers, got {text!r}")
    return values


def _origin(element: ET.Element | None, where: str) -> Origin:
    if element is None:
        return Origin(np.zeros(3), np.zeros(3))
    return Origin(_floats(element.get("xyz"), 3, f"{where} origin xyz", [0, 0, 0]),
                  _floats(element.get("rpy"), 3, f"{where} origin rpy", [0, 0, 0]))


def _meshes(link: ET.Element, tag: str, colours: dict[str, np.ndarray], where: str) -> tuple[Mesh, ...]:
    meshes = []
    for i, item in enumerate(link.findall(tag)):
        at = f"{where} <{tag}> {i}"
        geometry = item.find("geometry")
        mesh = None if geometry is None else geometry.find("mesh")
        if mesh is None or not mesh.get("filename"):
            raise UrdfError(f"{at}: only <mesh filename=...> geometry is supported")
        if mesh.get("scale") is not None and not np.allclose(_floats(mesh.get("scale"), 3, at, [1, 1, 1]), 1):
            raise UrdfError(f"{at}: scaled meshes are not supported")
        rgba = None
        material = item.find("material")
        if material is not None:
            colour = material.find("color")
            if colour is not None:
                rgba = _floats(colour.get("rgba"), 4, f"{at} material", [0, 0, 0, 1])
            elif material.get("name") in colours:
                rgba = colours[material.get("name")]
        meshes.append(Mesh(mesh.get("filename"), _origin(item.find("origin"), at),
                           None if rgba is None else tuple(float(v) for v in rgba)))
    return tuple(meshes)


def _inertial(link: ET.Element, where: str) -> Inertial | None:
    element = link.find("inertial")
    if element is None:
        return None
    mass_element, inertia_element = element.find("mass"), element.find("inertia")
    if mass_element is None or inertia_element is None:
        raise UrdfError(f"{where} <inertial>: needs <mass> and <inertia>")
    mass = float(_floats(mass_element.get("value"), 1, f"{where} mass", [0])[0])
    names = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    i = {n: float(_floats(inertia_element.get(n), 1, f"{where} inertia {n}", [0])[0]) for n in names}
    inertia = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]],
                        [i["ixz"], i["iyz"], i["izz"]]])
    return Inertial(mass, _origin(element.find("origin"), f"{where} <inertial>"), inertia)


def _joint(element: ET.Element, path: Path) -> Joint:
    name = element.get("name")
    kind = element.get("type")
    where = f"{path}: joint {name!r}"
    if kind not in ("revolute", "continuous", "fixed"):
        raise UrdfError(f"{where}: type {kind!r} is not supported (revolute, continuous, fixed)")
    parent, child = element.find("parent"), element.find("child")
    if parent is None or child is None:
        raise UrdfError(f"{where}: needs <parent> and <child>")
    axis = _floats(element.find("axis").get("xyz") if element.find("axis") is not None else None,
                   3, f"{where} axis", [1, 0, 0])
    lower, upper, velocity, effort = -np.inf, np.inf, 0.0, 0.0
    if kind != "fixed":
        if not np.linalg.norm(axis) > 0:
            raise UrdfError(f"{where}: the axis must not be zero")
        axis = axis / np.linalg.norm(axis)
        limit = element.find("limit")
        if limit is None:
            raise UrdfError(f"{where}: a {kind} joint needs <limit velocity= effort=>")
        velocity = float(_floats(limit.get("velocity"), 1, f"{where} velocity", [0])[0])
        effort = float(_floats(limit.get("effort"), 1, f"{where} effort", [0])[0])
        if not (velocity > 0 and effort > 0):
            raise UrdfError(f"{where}: velocity and effort limits must be > 0, got {velocity}, {effort}")
        if kind == "revolute":
            lower = float(_floats(limit.get("lower"), 1, f"{where} lower", [0])[0])
            upper = float(_floats(limit.get("upper"), 1, f"{where} upper", [0])[0])
            if not lower < upper:
                raise UrdfError(f"{where}: lower limit {lower} must be < upper limit {upper}")
    return Joint(name, kind, parent.get("link"), child.get("link"),
                 _origin(element.find("origin"), where), axis, lower, upper, velocity, effort)


def read_urdf(path: Path | str) -> Urdf:
    """Parse the URDF at ``path``."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as error:
        raise UrdfError(f"{path}: cannot read the URDF: {error}") from None
    colours = {}
    for material in root.findall("material"):
        colour = material.find("color")
        if colour is not None:
            colours[material.get("name")] = _floats(colour.get("rgba"), 4, f"{path}: material", [0, 0, 0, 1])
    links = {}
    for element in root.findall("link"):
        where = f"{path}: link {element.get('name')!r}"
        links[element.get("name")] = Link(element.get("name"), _inertial(element, where),
                                          _meshes(element, "visual", colours, where),
                                          _meshes(element, "collision", colours, where))
    joints = {j.name: j for j in (_joint(e, path) for e in root.findall("joint"))}
    return Urdf(path, root.get("name", ""), links, joints)
