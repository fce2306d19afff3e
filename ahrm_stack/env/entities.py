"""Composer entities of the task: the cylindrical pusher and the box props (cube, obstacles)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from dm_control import composer, mjcf
from dm_control.composer.observation import observable


class _OneGeomEntity(composer.Entity):
    """An entity built as its own MJCF model around one geom: ``_build`` sets ``_mjcf_root`` and
    ``_geom``."""

    _mjcf_root: mjcf.RootElement
    _geom: mjcf.Element

    @property
    def mjcf_model(self) -> mjcf.RootElement:
        return self._mjcf_root

    @property
    def geom(self) -> mjcf.Element:
        return self._geom


class Pusher(_OneGeomEntity):
    """A solid cylinder that replaces the hand. Its axis is the local +z of the attachment site.

    Sites: ``center`` at the cylinder's centre and ``tip`` at the centre of its free end face,
    ``length`` metres from the attachment point.
    """

    def _build(self, radius: float, length: float, mass: float) -> None:
        self._mjcf_root = mjcf.RootElement(model="pusher")
        body = self._mjcf_root.worldbody.add("body", name="pusher")
        self._geom = body.add("geom", name="rod", type="cylinder", size=[radius, length / 2],
                              pos=[0, 0, length / 2], mass=mass, rgba=[0.85, 0.55, 0.1, 1])
        self._center_site = body.add("site", name="center", pos=[0, 0, length / 2], size=[1e-3])
        self._tip_site = body.add("site", name="tip", pos=[0, 0, length], size=[1e-3])
        self.radius = radius
        self.half_length = length / 2

    @property
    def center_site(self) -> mjcf.Element:
        return self._center_site

    @property
    def tip_site(self) -> mjcf.Element:
        return self._tip_site


class BoxProp(_OneGeomEntity):
    """A free box (the target cube or an obstacle). ``half_size`` in metres, ``mass`` in kg."""

    def _build(self, name: str, half_size: Sequence[float], mass: float,
               rgba: Sequence[float]) -> None:
        self._mjcf_root = mjcf.RootElement(model=name)
        self._geom = self._mjcf_root.worldbody.add("geom", name="box", type="box",
                                                   size=list(half_size), mass=mass, rgba=list(rgba))
        self.half_size = np.asarray(half_size, dtype=float)

    def set_face_images(self, faces: dict) -> None:
        """Texture the box with a cube map: ``faces`` maps MuJoCo's face names (``right`` +x,
        ``left`` -x, ``up`` +y, ``down`` -y, ``front`` +z, ``back`` -z of the box) to PNG bytes.
        Visual only (the perception runs texture a render-only copy of the task)."""
        files = {f"file{name}": mjcf.Asset(data, ".png") for name, data in faces.items()}
        texture = self._mjcf_root.asset.add("texture", name="faces", type="cube", **files)
        material = self._mjcf_root.asset.add("material", name="faces", texture=texture,
                                             rgba=[1, 1, 1, 1])
        self._geom.material = material
        self._geom.rgba = None

    def _build_observables(self) -> "BoxPropObservables":
        return BoxPropObservables(self)


class BoxPropObservables(composer.Observables):
    """World position (m) and linear velocity (m/s) of a free box."""

    @composer.observable
    def position(self) -> observable.Observable:
        return observable.MJCFFeature("xpos", self._entity.geom)

    @composer.observable
    def linear_velocity(self) -> observable.Observable:
        return observable.Generic(lambda physics: self._entity.get_velocity(physics)[0])
