"""A dm_control composer arm built from a URDF: one MJCF body per link of the chain from the root
link to the flange link, named like the URDF links, posed by the URDF joint origins; hinge joints
with the URDF's axes and (for revolute joints) limits; velocity actuators whose control range is the
URDF velocity limit and whose force range is the URDF effort; inertials from the URDF.

Meshes: every collision mesh becomes a colliding, visible mesh geom; visual meshes that are not
also collision meshes (e.g. the joint rings) are visible only. The hand's meshes are left out: the
pusher replaces the hand at ``wrist_site``, on the flange link's origin, with its +z axis pointing
from the flange toward the URDF's end-effector frame (the hand's approach direction), or along that
frame's z where it sits on the flange (a tool frame). The flange link may be a fixed child of the
last moving link (the Gen3's tool flange, ``end_effector_link``): it is then a body without joint.
"""

from __future__ import annotations

import numpy as np
from dm_control import mjcf
from dm_control.composer import define
from dm_control.composer.observation import observable
from dm_control.entities.manipulators import base

from ahrm_stack.arms.assets import resolve_uri
from ahrm_stack.arms.meshes import load_mesh, stl_bytes
from ahrm_stack.arms.urdf import Joint, Link, Urdf, matrix_to_quaternion
from ahrm_stack.config import UrdfArmConfig

WRIST_SITE = "wrist_site"


def mount_rotation(urdf: Urdf, flange: str, end_effector: str) -> np.ndarray:
    """Rotation (flange frame) of the pusher's mount: +z from the flange origin toward the
    end-effector origin, +x the end-effector frame's z axis made orthogonal to it. An end-effector
    frame on the flange's origin (a tool frame, e.g. the Gen3's) gives its own axes: +z its approach
    axis z, +x its x."""
    rotation, position = np.eye(3), np.zeros(3)
    for joint in urdf.chain(flange, end_effector):
        if joint.type != "fixed":
            raise ValueError(f"{urdf.path}: joint {joint.name!r} between {flange!r} and "
                             f"{end_effector!r} must be fixed")
        position = position + rotation @ joint.origin.xyz
        rotation = rotation @ joint.origin.rotation
    if not np.linalg.norm(position) > 0:
        return rotation.copy()
    z = position / np.linalg.norm(position)
    x = rotation[:, 2] - (rotation[:, 2] @ z) * z
    if not np.linalg.norm(x) > 1e-9:
        x = rotation[:, 0] - (rotation[:, 0] @ z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


class UrdfArm(base.RobotArm):
    """The arm of ``urdf`` from ``settings.root_link`` to ``settings.flange_link``."""

    def _build(self, urdf: Urdf, settings: UrdfArmConfig, name: str) -> None:
        self.urdf = urdf
        self._mjcf_root = mjcf.RootElement(model=name)
        self._mjcf_root.compiler.angle = "radian"  # URDF units (MJCF's default is degrees)
        chain = urdf.chain(settings.root_link, settings.flange_link)
        actuated = [j for j in chain if j.type != "fixed"]
        if len(actuated) != len(settings.armature):
            raise ValueError(f"robots/{name}.urdf: armature and frictionloss give {len(settings.armature)} "
                             f"values, but {urdf.path} has {len(actuated)} joints from "
                             f"{settings.root_link!r} to {settings.flange_link!r}")
        self._meshes: dict[str, mjcf.Element] = {}
        body = self._mjcf_root.worldbody.add("body", name=settings.root_link)
        self._add_link(body, urdf.links[settings.root_link], settings)
        self._joints: list = []
        self._actuators: list = []
        for joint in chain:
            parent = body
            body = parent.add("body", name=joint.child, pos=joint.origin.xyz,
                              quat=joint.origin.quaternion)
            self._add_link(body, urdf.links[joint.child], settings)
            self._mjcf_root.contact.add("exclude", body1=parent, body2=body)
            if joint.type != "fixed":
                self._add_joint(body, joint, settings, len(self._joints))
        self._wrist_site = body.add(
            "site", name=WRIST_SITE, quat=matrix_to_quaternion(
                mount_rotation(urdf, settings.flange_link, settings.end_effector_link)))

    def _add_link(self, body: mjcf.Element, link: Link, settings: UrdfArmConfig) -> None:
        inertial = link.inertial
        if inertial is not None and inertial.mass > 0:
            eigenvalues, axes = np.linalg.eigh(inertial.origin.rotation @ inertial.inertia
                                               @ inertial.origin.rotation.T)
            if np.linalg.det(axes) < 0:
                axes[:, 0] = -axes[:, 0]
            body.add("inertial", pos=inertial.origin.xyz, mass=inertial.mass,
                     diaginertia=eigenvalues, quat=matrix_to_quaternion(axes))
        collision = {m.uri for m in link.collisions}
        colours = {m.uri: m.rgba for m in link.visuals if m.rgba is not None}
        seen = set()
        for mesh in (*link.collisions, *link.visuals):
            file_name = mesh.uri.rsplit("/", 1)[-1]
            if file_name in settings.hand_meshes or (mesh.uri, mesh.origin.xyz.tobytes()) in seen:
                continue
            seen.add((mesh.uri, mesh.origin.xyz.tobytes()))
            extra = {} if mesh.uri in collision else {"contype": 0, "conaffinity": 0}
            rgba = colours.get(mesh.uri)
            body.add("geom", type="mesh", mesh=self._mesh(mesh.uri), pos=mesh.origin.xyz,
                     quat=mesh.origin.quaternion, **extra, **({"rgba": rgba} if rgba else {}))

    def _mesh(self, uri: str) -> mjcf.Element:
        """The MJCF mesh asset of a URDF mesh reference (converted once per arm)."""
        if uri not in self._meshes:
            vertices, faces = load_mesh(resolve_uri(uri))
            name = uri.rsplit("/", 1)[-1].rsplit(".", 1)[0]
            self._meshes[uri] = self._mjcf_root.asset.add(
                "mesh", name=name, file=mjcf.Asset(stl_bytes(vertices, faces), ".stl"))
        return self._meshes[uri]

    def _add_joint(self, body: mjcf.Element, joint: Joint, settings: UrdfArmConfig, index: int) -> None:
        limits = {"range": [joint.lower, joint.upper], "limited": True} if joint.type == "revolute" \
            else {"limited": False}
        element = body.add("joint", name=joint.name, type="hinge", axis=joint.axis,
                           damping=settings.joint_damping, armature=settings.armature[index],
                           frictionloss=settings.frictionloss[index], **limits)
        self._joints.append(element)
        self._actuators.append(self._mjcf_root.actuator.add(
            "velocity", name=joint.name, joint=element, kv=settings.velocity_gain,
            ctrllimited=True, ctrlrange=[-joint.velocity, joint.velocity],
            forcelimited=True, forcerange=[-joint.effort, joint.effort]))

    def _build_observables(self) -> "UrdfArmObservables":
        return UrdfArmObservables(self)

    @property
    def joints(self) -> list[mjcf.Element]:
        return list(self._joints)

    @property
    def actuators(self) -> list[mjcf.Element]:
        return list(self._actuators)

    @property
    def wrist_site(self) -> mjcf.Element:
        """The pusher's mount on the flange link (where the hand would be)."""
        return self._wrist_site

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root


class UrdfArmObservables(base.JointsObservables):
    """Joint angles as (sin, cos) pairs (bounded, like dm_control's JACO) and velocities (rad/s)."""

    @define.observable
    def joints_pos(self) -> observable.Observable:
        def sin_cos(physics: mjcf.Physics) -> np.ndarray:
            q = physics.bind(self._entity.joints).qpos
            return np.vstack([np.sin(q), np.cos(q)]).T
        return observable.Generic(sin_cos)
