"""The arena: floor, lights and the table."""

from __future__ import annotations

from dm_control import composer, mjcf

from ahrm_stack.config import TableConfig


class TableArena(composer.Arena):
    """A floor at z = 0 and a table whose top surface is at ``table.height``, centred at the origin.

    Only the table top collides; legs are visual.
    """

    def _build(self, table: TableConfig, name: str = "arena") -> None:
        super()._build(name=name)
        self.mjcf_model.visual.headlight.ambient = [0.4, 0.4, 0.4]
        self.mjcf_model.worldbody.add("light", pos=[0, 0, 3], dir=[0, 0, -1], diffuse=[0.6, 0.6, 0.6])
        self.mjcf_model.worldbody.add("geom", name="floor", type="plane", size=[3, 3, 0.1],
                                      rgba=[0.35, 0.4, 0.45, 1])
        hx, hy = table.half_extent
        half_t = table.thickness / 2
        self._top = self.mjcf_model.worldbody.add(
            "geom", name="table_top", type="box", size=[hx, hy, half_t],
            pos=[0, 0, table.height - half_t], rgba=[0.6, 0.45, 0.3, 1])
        leg_half = (table.height - table.thickness) / 2
        for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
            self.mjcf_model.worldbody.add(
                "geom", name=f"table_leg_{i}", type="box", size=[0.02, 0.02, leg_half],
                pos=[sx * (hx - 0.03), sy * (hy - 0.03), leg_half], contype=0, conaffinity=0,
                rgba=[0.5, 0.38, 0.25, 1])
        self.mjcf_model.worldbody.add("camera", name="overview", pos=[1.3, -1.3, 1.4],
                                      xyaxes=[0.707, 0.707, 0, -0.35, 0.35, 0.87])
        # Evaluation videos: the whole arm (base at y = 0.5 m, reaching up), the table top, the
        # cube and the obstacles; looks at (0, 0.12, 0.55) from the +x, -y corner.
        self.mjcf_model.worldbody.add("camera", name="video", pos=[1.2, -0.9, 1.3],
                                      xyaxes=[0.648, 0.762, 0, -0.328, 0.278, 0.903])

    @property
    def table_top(self) -> mjcf.Element:
        return self._top

    def add_fixed_camera(self, name: str, position, quaternion, fovy_deg: float) -> mjcf.Element:
        """A fixed camera at ``position`` (m) with MuJoCo's orientation ``quaternion`` (w, x, y, z;
        the camera looks along its -z, y up) and vertical field of view ``fovy_deg``. Cameras do
        not change the physics; the perception runs add one to a render-only copy of the task."""
        return self.mjcf_model.worldbody.add("camera", name=name, pos=list(map(float, position)),
                                             quat=list(map(float, quaternion)),
                                             fovy=float(fovy_deg))

    def add_pedestal(self, position, height: float) -> None:
        """A visual column under the arm base from the floor up to ``height``."""
        self.mjcf_model.worldbody.add(
            "geom", name="pedestal", type="cylinder", size=[0.06, height / 2],
            pos=[position[0], position[1], height / 2], contype=0, conaffinity=0,
            rgba=[0.25, 0.25, 0.25, 1])
