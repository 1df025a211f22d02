"""Per-phase assurance policy: the numbers a phase contract card gives the gates."""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from assurance.clock import ms_to_ns


class LinkLoss(StrEnum):
    """What a contact phase does when the policy link is lost (the fallback machine is
    DEGRADED): contact ends either way, the contact owner keeps motion."""

    RETRACT = "retract"
    """The contact owner's force-aware retreat: lift along the descent's axis to its start."""
    HOLD = "hold"
    """Stop pressing: hold compliantly where the tool is, at a reduced stiffness."""


@dataclass(frozen=True, slots=True)
class ForceBand:
    """Admissible range of the contact force residual (N)."""

    low: float
    high: float

    def contains(self, residual: float) -> bool:
        return self.low <= residual <= self.high


@dataclass(frozen=True, slots=True)
class PhasePolicy:
    """docs/contract.md §7 phase keys, in client units (ns, rad), with documented defaults."""

    max_observation_age_ns: int = ms_to_ns(100)
    max_action_age_ns: int = ms_to_ns(200)
    max_divergence: float = 0.05
    max_projection: float = 0.02
    trim: bool = False
    blend: bool = False
    force_band: ForceBand | None = None
    ood_threshold: float | None = None
    controller_mode: str | None = None
    """Controller mode active in this phase; ``None`` means the session's mode."""
    max_underrun_ns: int | None = None
    """How long a policy-owned phase may hold on an empty queue before SAFE_HOLD;
    ``None`` means ``max_action_age_ns``."""

    link_loss: LinkLoss = LinkLoss.RETRACT
    """Read in a phase whose executor is the contact owner (docs/contract.md)."""
    link_loss_hold_factor: float = 0.25
    """With ``link_loss = hold``: the stiffness the hold keeps, as a fraction (0, 1] of the
    contact law's (the damping scales with its square root, so the hold stays critically
    damped)."""

    @property
    def underrun_limit_ns(self) -> int:
        return self.max_underrun_ns if self.max_underrun_ns is not None else self.max_action_age_ns
