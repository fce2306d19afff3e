"""Triangle meshes of URDF links, for MuJoCo, which cannot read COLLADA (``.dae``).

The meshes are read with the assimp loader that Pinocchio's collision library (coal) already ships,
so no extra dependency is needed, and handed to MuJoCo in memory as binary STL. Vertices are in
the mesh file's own frame, metres (assimp applies the file's unit).
"""

from __future__ import annotations

import functools
import struct
from pathlib import Path

import coal
import numpy as np


class MeshError(ValueError):
    """A mesh file cannot be used; the message names the file."""


@functools.lru_cache(maxsize=32)
def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, faces)`` of the mesh at ``path``: n x 3 float (m) and m x 3 int indices."""
    try:
        bvh = coal.MeshLoader().load(str(path), np.ones(3))
    except Exception as error:  # coal raises plain RuntimeErrors from assimp
        raise MeshError(f"{path}: cannot load the mesh: {error}") from None
    vertices = np.array(bvh.vertices(), dtype=float).reshape(-1, 3)
    faces = np.array([[bvh.tri_indices(i)[k] for k in range(3)] for i in range(bvh.num_tris)],
                     dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0 or not np.all(np.isfinite(vertices)):
        raise MeshError(f"{path}: the mesh has no triangles or non-finite vertices")
    vertices.setflags(write=False)
    faces.setflags(write=False)
    return vertices, faces


def stl_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """A binary STL of the triangles ``faces`` (indices into ``vertices``, m)."""
    triangles = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]  # m x 3 x 3
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
    record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.zeros(len(triangles), dtype=record)
    data["normal"] = normals
    data["vertices"] = triangles
    return b"\0" * 80 + struct.pack("<I", len(triangles)) + data.tobytes()
