"""What the discrepancy step finds: the evidence per state, the proposal, and the whole."""

from __future__ import annotations

import math
from dataclasses import dataclass

from pmabayes.util import finite_or_none

__all__ = ["StateEvidence", "Proposal", "Discrepancy"]


@dataclass(frozen=True)
class StateEvidence:
    """The evidence that the missing force depends on one state.

    Parameters
    ----------
    state : str
        One of :data:`~pmabayes.criticism.discrepancy.problem.STATES`.
    unit : str
        Its unit.
    elpd_loss : float
        Leave-one-trial-out ELPD lost when the state's terms are dropped from the
        flexible force (positive: the state is needed).
    se : float
        Standard error of ``elpd_loss`` from the per-trial differences.
    amplitude_n : float
        RMS along the trajectory of the force's partial dependence on the state.
    needed : bool
        ``elpd_loss`` above two standard errors (and above 2).
    """

    state: str
    unit: str
    elpd_loss: float
    se: float
    amplitude_n: float
    needed: bool

    def to_dict(self) -> dict:
        """JSON-ready summary."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class Proposal:
    """A closed form for the missing force, ready as a user effect.

    Parameters
    ----------
    effect : str
        The proposed effect's registry name.
    expression : str
        The force as a formula, with the estimated coefficients and units.
    description : str
        The force in physical words.
    terms : list of dict
        ``{"term", "unit", "coefficient", "parameter", "words", "writable"}`` per term.
    kind : str
        ``"closed form"`` (a sparse sum of dictionary terms) or ``"tabulated"`` (the
        flexible shape in one state, with one amplitude).
    elpd_diff : float
        Leave-one-trial-out ELPD of the proposal minus the flexible estimate's.
    elpd_diff_se : float
        Its standard error.
    plugin : str or None
        Path of the written ``.py`` file; None when a term cannot be written as a
        force effect today (it needs ``z`` or memory), or nothing was written.
    verified : dict or None
        The nonlinear refit with the written effect: ``{"rms_m", "ratio", "energy",
        "ljung_box_p", "adequate", "values"}``.
    """

    effect: str
    expression: str
    description: str
    terms: list
    kind: str
    elpd_diff: float
    elpd_diff_se: float
    plugin: str | None
    verified: dict | None

    def to_dict(self) -> dict:
        """JSON-ready summary (``effect``, ``expression``, ``plugin`` and the details)."""
        return {"effect": self.effect, "expression": self.expression,
                "plugin": self.plugin, "description": self.description,
                "kind": self.kind, "terms": list(self.terms), "elpd_diff": self.elpd_diff,
                "elpd_diff_se": self.elpd_diff_se,
                # a record without repeats has no floor: its ratio is None
                "verified": None if self.verified is None else {
                    **self.verified, "ratio": finite_or_none(self.verified["ratio"])}}


@dataclass(frozen=True)
class Discrepancy:
    """The missing force estimated from the data, its states and a proposed closed form.

    Parameters
    ----------
    states : list of StateEvidence
        Every state, most evidence first.
    explained : float
        Share of the whitened residual's excess energy (above the noise) that the
        flexible force, with the parameters readjusted, removes (linearised).
    ratio_after : float
        RMS error over the floor with the flexible force (linearised); NaN for a record
        without repeats (no floor).
    elpd_gain : float
        Leave-one-trial-out ELPD of the flexible force minus that of the model with
        its parameters readjusted alone; for a record without repeats, leaving out one
        stretch of it at a time.
    elpd_gain_se : float
        Its standard error.
    memory_tau_s : float
        Time constant of the memory state (low-passed velocity), by the evidence.
    partial_dependence : dict
        State to ``{"grid", "force_n", "sd_n", "unit"}``: the flexible force's
        shape against that state (centred along the trajectory) and its posterior sd.
    proposal : Proposal or None
        The closed form (or tabulated shape), None when none could be formed.
    near_floor : bool
        Whether the flexible force brings the model near the floor (ratio within
        1.5x; without a floor, a whitened residual energy within the adequacy
        tolerance of pure noise).
    other_cause : str or None
        When the flexible force cannot: what is left and which non-force cause the
        residual's signature suggests.
    text : str
        The conclusion in words.
    explained_rms : float or None
        Share of the mean-square error above the floor that the flexible force
        removes (linearised; :func:`pmabayes.criticism.bands.excess_removed`), the
        share the words report; None without a floor.
    energy_after : float
        Mean square of the whitened residual with the flexible force (linearised; 1 for
        pure noise).
    loop_width_m : float
        Width of the loop state (the travel over which it saturates), by the evidence.
    not_a_force : bool
        Whether the verdict says the missing piece is not a force of the states tried:
        errors of the position reading predict the left-out data as well as the flexible
        force (then no force is proposed), or the flexible force leaves the model
        above the floor (:attr:`other_cause`).
    """

    states: list
    explained: float
    ratio_after: float
    elpd_gain: float
    elpd_gain_se: float
    memory_tau_s: float
    partial_dependence: dict
    proposal: Proposal | None
    near_floor: bool
    other_cause: str | None
    text: str
    explained_rms: float | None = None
    energy_after: float = math.nan
    loop_width_m: float = math.nan
    not_a_force: bool = False

    def to_dict(self) -> dict:
        """JSON-ready summary (the ``discrepancy`` key of ``pmabayes diagnose --json``)."""
        return {"states": [s.to_dict() for s in self.states], "explained": self.explained,
                "explained_rms": self.explained_rms,
                "ratio_after": finite_or_none(self.ratio_after),
                "energy_after": finite_or_none(self.energy_after),
                "elpd_gain": self.elpd_gain,
                "elpd_gain_se": self.elpd_gain_se, "memory_tau_s": self.memory_tau_s,
                "loop_width_m": finite_or_none(self.loop_width_m),
                "near_floor": self.near_floor, "other_cause": self.other_cause,
                "not_a_force": self.not_a_force,
                "proposal": None if self.proposal is None else self.proposal.to_dict(),
                "text": self.text}
