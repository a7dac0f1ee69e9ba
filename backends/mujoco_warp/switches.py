"""Which constraints a world's substep used, as a number to compare across worlds: the switch detector
of the ``adaptive`` finite-difference scheme (:mod:`backends.mujoco_warp.adapter`).

Within one constraint set a MuJoCo step is smooth in its inputs: the same contacts (the same geom pair,
and which of the pair's contacts), the same joint limits, each constraint row in the same solver state
(satisfied, quadratic, on the friction cone). Where a perturbed world's set differs from the nominal
world's at some substep, a contact was made or broken, or friction started or stopped sliding, inside
the finite-difference stencil, and the quotient over the step is a jump, no derivative.

:class:`ConstraintSignature` reads a ``mujoco_warp.Data``'s constraint rows after a substep and gives
each world two 31-bit hashes of the multiset of its rows, each row named by (constraint type, object,
row within the object, solver state), the object being a contact's geom pair and collision index or
the joint or equality's id. A sum over rows makes the hash independent of the order in which the
collision pipeline wrote them (it differs between worlds); squaring inside the per-row hash keeps
different sets from summing alike. Two worlds with equal signatures have the same constraint set
except with probability about 2^-62 per comparison.
"""

from __future__ import annotations

import mujoco
import mujoco_warp as mjw
import torch
import warp as wp

#: two primes below 2^31: products of two residues stay inside int64
_PRIMES = (2_147_483_647, 2_147_483_629)
_MULTIPLIERS = ((48_271, 12_345), (69_621, 54_321))
_FIRST_CONTACT_TYPE = int(mujoco.mjtConstraint.mjCNSTR_CONTACT_FRICTIONLESS)  # contact types come last


class ConstraintSignature:
    """Torch views of one ``Data``'s constraint rows; calling it hashes every world's current set."""

    def __init__(self, data: mjw.Data, ngeom: int):
        self.ngeom = ngeom
        self.nefc = wp.to_torch(data.nefc)
        self.type = wp.to_torch(data.efc.type)
        self.id = wp.to_torch(data.efc.id)
        self.state = wp.to_torch(data.efc.state)
        self.geom = wp.to_torch(data.contact.geom)
        self.collision = wp.to_torch(data.contact.geomcollisionid)
        self.address = wp.to_torch(data.contact.efc_address)

    def row_keys(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(keys, valid), both (W, R) with R the largest ``nefc`` of the worlds: each row's name as one
        non-negative int64, and whether the row is in use (below the world's ``nefc``)."""
        nefc = self.nefc.long()
        rows = max(int(nefc.max()), 1) if nefc.numel() else 1  # the rows in use: most of njmax is spare
        index = torch.arange(rows, device=self.type.device)
        valid = index[None, :] < nefc[:, None]
        kind = self.type[:, :rows].long()
        ident = self.id[:, :rows].long()
        contact = valid & (kind >= _FIRST_CONTACT_TYPE)
        which = torch.where(contact, ident, torch.zeros_like(ident))  # a contact row's contact index
        pair = self.geom.long()[which]  # (W, rows, 2)
        ngeom = self.ngeom
        obj = pair[..., 0] * ngeom + pair[..., 1] + ngeom * ngeom * self.collision.long()[which]
        obj = torch.where(contact, obj, ident)
        offset = torch.where(contact, index[None, :] - self.address.long()[which, 0], torch.zeros_like(ident))
        state = self.state[:, :rows].long()
        keys = ((kind * 1_000_003 + obj) * 64 + offset) * 8 + state
        return keys, valid

    def __call__(self) -> torch.Tensor:
        """(W, 2) int64: each world's two hashes of its current constraint rows."""
        keys, valid = self.row_keys()
        hashes = []
        for prime, (a, b) in zip(_PRIMES, _MULTIPLIERS, strict=True):
            h = (keys % prime * a + 1) % prime
            h = h * h % prime
            h = (h * b + 7) % prime
            h = h * h % prime
            hashes.append(torch.where(valid, h, torch.zeros_like(h)).sum(dim=1) % prime)
        return torch.stack(hashes, dim=1)
