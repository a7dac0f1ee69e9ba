"""Tetrahedral meshes generated in code: the soft jumper's table-like body.

The body is a voxel shape (a slab on four corner legs) cut into tetrahedra. Every voxel is split
into the six tetrahedra of the Freudenthal (Kuhn) subdivision: tetrahedron ``p`` of a voxel walks
from its low corner to its high corner along the three axes in the order of permutation ``p``. All
voxels share the same main diagonal, so neighbouring voxels cut their common face along the same
diagonal and the mesh is conforming (no hanging vertices). Vertices are shared between voxels, so a
particle belongs to every tetrahedron that touches it.

Conventions: z up, the body's footprint centred on the origin, its lowest vertices at z = 0.
Tetrahedra are ordered voxel by voxel, the six of a voxel consecutively, so "two tetrahedra per
action" pairs halves of one voxel. Vertex order within a tetrahedron gives positive signed volume
``det([x1 - x0, x2 - x0, x3 - x0]) / 6``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from simcore import TetMeshError, check_tet_mesh, signed_tet_volumes


@dataclass(frozen=True)
class TableShape:
    """A slab on four corner legs, in voxels. The defaults give a 2.5 x 2.5 x 1.8 body (x, y, z) of
    179 vertices and 480 tetrahedra: the size of the peer's jumper (docs/tasks.md, "SoftJumper")."""

    cells_x: int = 6  # slab voxels along x
    cells_y: int = 6  # slab voxels along y
    slab_layers: int = 2  # slab thickness in voxels
    leg_layers: int = 2  # leg height in voxels
    leg_cells: int = 1  # each leg is leg_cells x leg_cells voxels, under a corner of the slab
    size_x: float = 2.5
    size_y: float = 2.5
    height: float = 1.8

    def __post_init__(self) -> None:
        for name in ("cells_x", "cells_y", "slab_layers", "leg_layers", "leg_cells"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise TetMeshError(f"TableShape.{name} must be an integer >= 1, got {value!r}")
        if 2 * self.leg_cells > min(self.cells_x, self.cells_y):
            raise TetMeshError("TableShape: four legs of leg_cells voxels do not fit under the slab")
        for name in ("size_x", "size_y", "height"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise TetMeshError(f"TableShape.{name} must be a finite number > 0, got {value!r}")

    def voxels(self) -> list[tuple[int, int, int]]:
        """(i, j, k) of every occupied voxel, k = 0 at the floor: legs below, slab on top."""
        legs_x = set(range(self.leg_cells)) | set(range(self.cells_x - self.leg_cells, self.cells_x))
        legs_y = set(range(self.leg_cells)) | set(range(self.cells_y - self.leg_cells, self.cells_y))
        out = []
        for k in range(self.leg_layers + self.slab_layers):
            for i in range(self.cells_x):
                for j in range(self.cells_y):
                    if k >= self.leg_layers or (i in legs_x and j in legs_y):
                        out.append((i, j, k))
        return out


# the six paths from a voxel's low corner to its high corner (Freudenthal subdivision)
_AXIS_STEPS = np.eye(3, dtype=np.int64)
_KUHN_PATHS = tuple(itertools.permutations(range(3)))


def table_mesh(shape: TableShape | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (P, 3) float64 and tetrahedra (T, 4) int64 of the table-like body (module docstring)."""
    shape = shape or TableShape()
    layers = shape.leg_layers + shape.slab_layers
    spacing = np.array((shape.size_x / shape.cells_x, shape.size_y / shape.cells_y, shape.height / layers))
    index: dict[tuple[int, int, int], int] = {}  # grid corner -> vertex id, in order of first use
    tets = []
    for voxel in shape.voxels():
        low = np.array(voxel, dtype=np.int64)
        for path in _KUHN_PATHS:
            corners = [low]
            for axis in path:
                corners.append(corners[-1] + _AXIS_STEPS[axis])
            tets.append([index.setdefault(tuple(int(c) for c in corner), len(index)) for corner in corners])
    grid = np.array(sorted(index, key=index.get), dtype=np.float64)
    vertices = grid * spacing
    vertices[:, 0] -= 0.5 * shape.size_x
    vertices[:, 1] -= 0.5 * shape.size_y
    tets = np.array(tets, dtype=np.int64)
    # odd permutations of the axes give negatively oriented tets: swap two vertices to fix them
    flip = signed_tet_volumes(torch.from_numpy(vertices), torch.from_numpy(tets)).numpy() < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    check_tet_mesh(torch.from_numpy(vertices), torch.from_numpy(tets))
    return vertices, tets


__all__ = ["TableShape", "TetMeshError", "check_tet_mesh", "signed_tet_volumes", "table_mesh"]
