"""AprilTag images, drawn from the code tables of the detector's own library.

``pupil-apriltags`` ships no tag images, but its C library holds every family's codes and bit
layout (``apriltag_family_t``: ``codes``, ``bit_x``, ``bit_y``, ``width_at_border``,
``total_width``, ``reversed_border``), which ``pupil_apriltags.Detector`` exposes. A tag is drawn
as the AprilTag library's ``apriltag_to_image`` draws it: a white frame, the black border, and bit
i of the code (most significant first) white at cell (``bit_x[i]``, ``bit_y[i]``) inside the
border. ``tests/test_perception.py`` checks the result against the published code of tag36h11 id 0
(``0xd7e00984b``, ``tag36h11.c``), against the library's ``apriltag_to_image``, and that the
detector decodes the drawn tag at its id.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ahrm_stack.perception.settings import PerceptionConfigError, TagSettings


@dataclasses.dataclass(frozen=True)
class TagFamily:
    """One family's code table: ``codes`` (one integer per id), the bit cells ``bit_x``/``bit_y``
    (relative to the black border's first cell), and the layout in cells."""

    name: str
    codes: tuple[int, ...]
    nbits: int
    bit_x: tuple[int, ...]
    bit_y: tuple[int, ...]
    width_at_border: int  # cells across the black border
    total_width: int  # cells across the whole image (with the white frame)
    reversed_border: bool


@functools.lru_cache(maxsize=None)
def tag_family(name: str) -> TagFamily:
    """The code table of family ``name``, read from the detector's C library."""
    from ahrm_stack.perception.detector import Detector

    detector = Detector(families=name)
    if name not in detector.tag_families:
        raise PerceptionConfigError(f"perception.tag.family: pupil-apriltags has no family {name!r}")
    fam = detector.tag_families[name].contents
    n = int(fam.nbits)

    def signed(value: int) -> int:  # bit cells outside the border are negative int32 in C
        return value - (1 << 32) if value >= 1 << 31 else value

    return TagFamily(name=name, codes=tuple(int(fam.codes[i]) for i in range(int(fam.ncodes))),
                     nbits=n, bit_x=tuple(signed(int(fam.bit_x[i])) for i in range(n)),
                     bit_y=tuple(signed(int(fam.bit_y[i])) for i in range(n)),
                     width_at_border=int(fam.width_at_border), total_width=int(fam.total_width),
                     reversed_border=bool(fam.reversed_border))


def tag_cells(family: TagFamily, tag_id: int) -> np.ndarray:
    """The tag as a (total_width, total_width) uint8 image, one pixel per cell: 0 black, 255
    white (``apriltag_to_image``'s drawing; pixels outside the white frame stay black there)."""
    if not 0 <= tag_id < len(family.codes):
        raise PerceptionConfigError(f"perception.tag.id {tag_id} is not in family {family.name} "
                                    f"(ids 0..{len(family.codes) - 1})")
    total, border = family.total_width, family.width_at_border
    image = np.zeros((total, total), dtype=np.uint8)
    white = border + (0 if family.reversed_border else 2)
    start, end = (total - white) // 2, (total - white) // 2 + white - 1
    image[start, start:end + 1] = image[end, start:end + 1] = 255  # the one-cell white ring
    image[start:end + 1, start] = image[start:end + 1, end] = 255
    first = (total - border) // 2
    code = family.codes[tag_id]
    for i in range(family.nbits):
        if code >> (family.nbits - 1 - i) & 1:
            image[family.bit_y[i] + first, family.bit_x[i] + first] = 255
    return image


def tag_face_image(tag: TagSettings, face_size: float) -> np.ndarray:
    """A square grey image of a box face ``face_size`` m wide with the tag centred on it, its
    black border ``tag.size`` m wide, ``tag.texture_cell_px`` pixels per cell, white around it.

    Row 0 is the image's top; how a renderer lays the image onto the face is the caller's
    business (:mod:`ahrm_stack.perception.sim_camera`)."""
    family = tag_family(tag.family)
    cells = tag_cells(family, tag.id)
    border = family.width_at_border
    needed = tag.size * family.total_width / border
    if face_size < needed - 1e-12:
        raise PerceptionConfigError(
            f"perception.tag.size {tag.size} m: a {family.name} tag with its white frame needs "
            f"{needed:.4g} m, more than the cube's face (task.cube.size {face_size} m)")
    px = tag.texture_cell_px
    tag_px = family.total_width * px
    face_px = int(round(face_size / tag.size * border * px))
    image = np.full((face_px, face_px), 255, dtype=np.uint8)
    start = (face_px - tag_px) // 2
    image[start:start + tag_px, start:start + tag_px] = np.kron(cells, np.ones((px, px), np.uint8))
    return image
