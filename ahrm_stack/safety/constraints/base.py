"""What every constraint family returns, and the kinematic snapshot the Cartesian families read.

The filter's decision variable is the joint-velocity command ``u`` (rad/s, one entry per arm
joint, in the robot description's joint order). A family contributes either

* :class:`JointBounds` — a box ``lower <= u <= upper`` (the hard bounds: position, velocity,
  acceleration), or
* :class:`Rows` — coupled rows ``matrix @ u <= bound`` in metres: each row is a clearance
  (table, workspace face, obstacle distance) predicted over the filter's horizon, so
  ``bound - matrix @ u`` is the clearance left at the end of the horizon, in m.

These run every control step, so they are plain named tuples and the per-step methods are short.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np
import pinocchio as pin


class ConstraintDefinitionError(ValueError):
    """A constraint was built with an invalid value; the message names which and where it came
    from."""


class JointBounds(NamedTuple):
    """``lower <= u <= upper`` per joint, rad/s. Entries may be -inf / +inf."""

    lower: np.ndarray
    upper: np.ndarray


class Rows(NamedTuple):
    """Coupled rows ``matrix @ u <= bound``: ``matrix`` (m x nv) in m per rad/s, ``bound`` (m,)
    in m; ``names[i]`` names row i in reports (e.g. ``"table:tip"``)."""

    matrix: np.ndarray
    bound: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def empty(cls, nv: int) -> "Rows":
        return cls(np.zeros((0, nv)), np.zeros(0), ())


class ControlPoints(NamedTuple):
    """Named points of the arm (the pusher tip, the wrist) at the current configuration, stacked
    by coordinate: ``positions[3 k + a]`` is coordinate a (x, y, z) of point k (m, world frame) and
    ``jacobians[3 k + a]`` its row of the linear Jacobian (m per rad/s)."""

    names: tuple[str, ...]
    positions: np.ndarray  # (3 k,)
    jacobians: np.ndarray  # (3 k, nv)


_AXES = "xyz"
# (r x n)_i = r_{i+1} n_{i+2} - r_{i+2} n_{i+1}, indices mod 3: the factors of both products
_R_CROSS = np.array([1, 2, 0, 2, 0, 1])
_N_CROSS = np.array([2, 0, 1, 1, 2, 0])


class CoordinateRows:
    """Rows that bound one world coordinate of a control point, over the horizon ``T``:

        sign * (p_a + T J_a u) >= sign * limit     stored as   -sign T J_a u <= sign p_a - sign limit

    (sign +1: a floor, sign -1: a ceiling). The selection matrices are built once here, so the
    per-step :meth:`rows` is two small products.

    Args:
        points: the control points' names, in the order of :class:`ControlPoints`.
        bounds: one ``(point, axis, sign, limit, name)`` per row; axis in "xyz", limit in m.
        horizon: s over which the command is linearised.
    """

    def __init__(self, points: Sequence[str], bounds: Sequence[tuple[str, str, int, float, str]],
                 horizon: float) -> None:
        if not (np.isfinite(horizon) and horizon > 0):
            raise ConstraintDefinitionError(f"horizon must be finite and > 0 s, got {horizon!r}")
        self.points = tuple(points)
        self.horizon = float(horizon)
        select = np.zeros((len(bounds), 3 * len(self.points)))
        offset = np.zeros(len(bounds))
        for row, (point, axis, sign, limit, _) in enumerate(bounds):
            if point not in self.points or axis not in _AXES or sign not in (1, -1):
                raise ConstraintDefinitionError(f"bad coordinate row {(point, axis, sign, limit)}")
            if not np.isfinite(limit):
                raise ConstraintDefinitionError(f"limit of row {(point, axis, sign)} must be finite, "
                                                f"got {limit!r}")
            select[row, 3 * self.points.index(point) + _AXES.index(axis)] = sign
            offset[row] = -sign * limit
        self._select = select  # sign, at the row's coordinate
        self._select_jacobian = -self.horizon * select
        self._offset = offset
        self.names = tuple(b[4] for b in bounds)

    @classmethod
    def stacked(cls, families: Sequence["CoordinateRows"]) -> "CoordinateRows":
        """One set of rows doing the work of ``families`` (same points and horizon) in one product
        per step; its rows are theirs, in order."""
        first = families[0]
        if any(f.points != first.points or f.horizon != first.horizon for f in families):
            raise ConstraintDefinitionError("stacked coordinate rows need the same points and horizon")
        merged = cls.__new__(cls)
        merged.points, merged.horizon = first.points, first.horizon
        merged._select = np.concatenate([f._select for f in families])
        merged._select_jacobian = np.concatenate([f._select_jacobian for f in families])
        merged._offset = np.concatenate([f._offset for f in families])
        merged.names = sum((f.names for f in families), ())
        return merged

    def rows(self, points: ControlPoints) -> Rows:
        if points.names != self.points:
            raise ValueError(f"rows expect control points {self.points}, got {points.names}")
        return Rows(self._select_jacobian @ points.jacobians, self._select @ points.positions + self._offset,
                    self.names)

    def write(self, jacobians: np.ndarray, positions: np.ndarray, matrix: np.ndarray, bound: np.ndarray) -> None:
        """:meth:`rows` into preallocated arrays (the same products, the same numbers):
        ``jacobians`` (3 k x nv) and ``positions`` (3 k,) stacked as in :class:`ControlPoints`,
        ``matrix`` (len(names) x nv) and ``bound`` (len(names),) overwritten."""
        np.matmul(self._select_jacobian, jacobians, out=matrix)
        np.matmul(self._select, positions, out=bound)
        np.add(bound, self._offset, out=bound)


class ArmSnapshot:
    """Forward kinematics and Jacobians of the arm at one configuration, on a private copy of the
    Pinocchio model and its own ``Data`` (so the filter never disturbs the caller's kinematics).

    Positions are world-frame (m); Jacobians are world-aligned, 6 x nv, linear rows first (m per
    rad/s, then rad/s per rad/s). Call :meth:`update` first.
    """

    def __init__(self, model: pin.Model, base: pin.SE3,
                 configuration: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        """``configuration`` maps the joint angles (rad) to Pinocchio's configuration vector
        (:meth:`ArmKinematics.configuration`; default: the identity, for models with nq = nv)."""
        self.model = pin.Model(model)  # a private copy: frames may be attached to it
        self._configuration = configuration
        self.data = self.model.createData()
        self.base_rotation = np.array(base.rotation)
        self.base_translation = np.array(base.translation)
        self._identity_base = bool(np.array_equal(self.base_rotation, np.eye(3)))
        self._jacobians: dict[int, np.ndarray] = {}
        self._q = np.zeros(self.model.nv)  # joint angles, rad

    def update(self, q: np.ndarray) -> None:
        """Joint placements and joint Jacobians at ``q`` (rad)."""
        configuration = q if self._configuration is None else self._configuration(q)
        pin.computeJointJacobians(self.model, self.data, configuration)
        self._jacobians.clear()
        self._q = q

    def jacobian(self, frame: int) -> np.ndarray:
        """6 x nv world-aligned Jacobian of frame ``frame``'s origin, linear rows first."""
        jac = self._jacobians.get(frame)
        if jac is None:
            jac = pin.getFrameJacobian(self.model, self.data, frame, pin.LOCAL_WORLD_ALIGNED)
            if not self._identity_base:
                jac = np.vstack([self.base_rotation @ jac[:3], self.base_rotation @ jac[3:]])
            self._jacobians[frame] = jac
        return jac

    def placement(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """World position (m) and rotation matrix of frame ``frame``."""
        local = pin.updateFramePlacement(self.model, self.data, frame)
        if self._identity_base:
            return local.translation + self.base_translation, local.rotation
        return (self.base_rotation @ local.translation + self.base_translation,
                self.base_rotation @ local.rotation)

    def position(self, frame: int) -> np.ndarray:
        """World position of frame ``frame``, m."""
        return self.placement(frame)[0]

    def positions(self, frames: Sequence[int]) -> np.ndarray:
        """World positions (len(frames) x 3, m) of several frames."""
        model, data = self.model, self.data
        local = np.array([pin.updateFramePlacement(model, data, f).translation for f in frames])
        if self._identity_base:
            return local + self.base_translation
        return local @ self.base_rotation.T + self.base_translation

    def positions_into(self, frames: Sequence[int], out: np.ndarray) -> None:
        """:meth:`positions` written into ``out`` (len(frames) x 3, m): the same numbers."""
        model, data = self.model, self.data
        for k, f in enumerate(frames):
            out[k] = pin.updateFramePlacement(model, data, f).translation
        if self._identity_base:
            np.add(out, self.base_translation, out=out)
        else:
            out[...] = out @ self.base_rotation.T + self.base_translation

    def place(self, frames: Sequence[int], out: np.ndarray) -> list[pin.SE3]:
        """World positions of several frames written into ``out`` (len(frames) x 3, m; the numbers
        of :meth:`placements`), and their placements in the model's frame, for
        :meth:`world_rotation` to turn into world rotations where needed."""
        model, data = self.model, self.data
        placed = [pin.updateFramePlacement(model, data, f) for f in frames]
        for k, local in enumerate(placed):
            out[k] = local.translation
        if self._identity_base:
            np.add(out, self.base_translation, out=out)
        else:
            out[...] = out @ self.base_rotation.T + self.base_translation
        return placed

    def world_rotation(self, local: pin.SE3) -> np.ndarray:
        """The world rotation matrix of a placement from :meth:`place` (that of :meth:`placements`)."""
        if self._identity_base:
            return local.rotation
        return np.einsum("ij,kjl->kil", self.base_rotation, local.rotation[None])[0]

    def placements(self, frames: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """World positions (k x 3, m) and rotation matrices (k x 3 x 3) of several frames."""
        model, data = self.model, self.data
        homogeneous = np.array([pin.updateFramePlacement(model, data, f).homogeneous for f in frames])
        local, rotations = homogeneous[:, :3, 3], homogeneous[:, :3, :3]
        if self._identity_base:
            return local + self.base_translation, rotations
        return (local @ self.base_rotation.T + self.base_translation,
                np.einsum("ij,kjl->kil", self.base_rotation, rotations))

    def attach_frame(self, name: str, frame: int, position: np.ndarray, rotation: np.ndarray) -> int:
        """Add a frame rigidly attached to ``frame`` at world ``position`` (m) and ``rotation``, as
        they are at the configuration of the last :meth:`update`; returns its id."""
        frame_position, frame_rotation = self.placement(frame)
        local = pin.SE3(frame_rotation.T @ rotation, frame_rotation.T @ (position - frame_position))
        parent = self.model.frames[frame]
        new = self.model.addFrame(pin.Frame(name, parent.parentJoint, frame, parent.placement * local,
                                            pin.FrameType.OP_FRAME))
        self.data = self.model.createData()
        self.update(self._q)
        return new

    def point_rows(self, frames: Sequence[int], points: np.ndarray, directions: np.ndarray,
                   origins: np.ndarray | None = None) -> np.ndarray:
        """``directions[k]^T J_k`` (k x nv, m per rad/s along the unit ``directions[k]``) with J_k
        the linear Jacobian of the world point ``points[k]`` (m) rigidly attached to
        ``frames[k]``: ``J_v - [r]_x J_w``, r the point relative to the frame's origin, so
        ``n^T J_k = n^T J_v + (r x n)^T J_w``. ``origins`` (k x 3, m): the frames' world positions
        when the caller has them (:meth:`placements`), else they are looked up here."""
        if origins is None:
            placed = {f: self.position(f) for f in set(frames)}
            origins = np.array([placed[f] for f in frames])
        jacobian = self.jacobian
        jacobians = np.array([jacobian(f) for f in frames])  # k x 6 x nv
        # r x n: (r_{i+1} n_{i+2}) - (r_{i+2} n_{i+1}), indices mod 3, both products in one
        products = (points - origins)[:, _R_CROSS] * directions[:, _N_CROSS]
        moments = products[:, :3] - products[:, 3:]
        return np.einsum("ki,kij->kj", np.concatenate((directions, moments), axis=1), jacobians)
