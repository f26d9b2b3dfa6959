"""The rig's schema: the keys of a sidecar's ``"rig"``, their types and values, and the
input column each kind of rig drives.

A data set's ``"rig"`` is checked against it when the data are read (every
:class:`~pmabayes.data.Dataset` is), so that a misspelt key or a value out of range is
an error naming the file and the fix there, not when a model is first built on the
file. :class:`pmabayes.model.Rig` has these keys as its fields and is built from a
checked dict by :meth:`pmabayes.model.Rig.from_dict`, the one conversion; it checks a
rig made in Python with the same :func:`rig_problem`. The schema lives here, below the
model, because the data layer reads the sidecar and must not import the model.

A ``"rig"`` that holds none of these keys (nor one close to them) is free-form notes
about the rig (``{"muscle": "DMSP-10"}`` or ``"bench-2"``): kept, and no rig is
declared (:func:`declared_rig`).
"""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Mapping

from pmabayes.data.keys import KeyDoc

__all__ = ["INPUT_OF_KIND", "DEFAULT_INPUT_KIND", "RIG_PRIOR_KEYS", "RIG_KEYS",
           "RIG_DICT_KEYS", "rig_problem", "declared_rig", "is_declared_rig"]

#: The input column each rig ``input_kind`` drives.
INPUT_OF_KIND: dict[str, str] = {"pressure": "pressure_pa", "force": "force_n"}
#: A rig that gives no ``input_kind`` is pressure-driven (a muscle).
DEFAULT_INPUT_KIND = "pressure"

#: Rig values that may be given as a prior's text (``"area_m2":
#: "LogNormal(1e-5, 1.5)"``): each is then identified with the physics as the model
#: parameter ``rig_KEY`` (unit, meaning).
RIG_PRIOR_KEYS: dict[str, tuple[str, str]] = {
    "moving_mass_kg": ("kg", "moving mass M + m"),
    "area_m2": ("m^2", "effective area A on which the pressure acts"),
}

#: The sidecar reference of each key of a ``"rig"``, in :class:`pmabayes.model.Rig`'s
#: field order; the defaults are the characterisation rig's, which a sidecar without a
#: rig gets (``tests/test_rig_schema.py`` checks them against the model's constants).
#:
#: :meta hide-value:
RIG_KEYS: dict[str, KeyDoc] = {
    "moving_mass_kg": KeyDoc(
        'number > 0, or a prior (`"LogNormal(0.07, 1.5)"`)', "kg",
        "0.067 (carriage + muscle)",
        "`M + m`: everything that moves with the muscle's free end (carriage, load, muscle).",
        "guide/rig_priors"),
    "gravity_sign": KeyDoc(
        "1, 0 or -1", "", "1", "`s_g`: +1 gravity pulls against extension (positive x, the "
        "direction the pressure drives: a muscle lifting a hanging load), -1 along it, 0 none "
        "(a horizontal rig).", "guide/rig_priors"),
    "area_m2": KeyDoc(
        'number > 0, or a prior (`"LogNormal(1e-4, 1.5)"`)', "m^2",
        "0.000218311 (derived from the paper's muscle)",
        "Effective area `A`, force per pressure; 1 for a force-driven oscillator.",
        "guide/rig_priors"),
    "input_kind": KeyDoc(
        '`"pressure"` or `"force"`', "", DEFAULT_INPUT_KIND, "What the input column holds: "
        "pressure in Pa (a muscle, with a dead zone) or force in N (an oscillator).",
        "guide/data"),
    "g_m_s2": KeyDoc("number > 0", "m/s^2", "9.81", "Gravitational acceleration.",
                     "guide/rig_priors"),
    "name": KeyDoc("string", "", "custom", "A label for reports; a fit of several "
                   "experiments matches held-out data to fitted ones by it.",
                   "guide/validation"),
}

#: The keys of a rig's dict (a sidecar's ``"rig"``, :meth:`pmabayes.model.Rig.to_dict`);
#: a value given as a prior is written under its own key.
RIG_DICT_KEYS: tuple[str, ...] = tuple(RIG_KEYS)

#: How close a key must be to a rig key to be taken for its misspelling (as for the
#: sidecar's own keys).
_CLOSE = 0.85


def _is_number(value: object) -> bool:
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(value))


def _value_problem(key: str, value: object) -> str | None:
    """What is wrong with one rig value, with the fix; None where it is right."""
    if key in ("input_kind", "name"):
        if key == "input_kind" and value not in INPUT_OF_KIND:
            return (f"input_kind must be {' or '.join(map(repr, INPUT_OF_KIND))}, got "
                    f"{value!r}; fix it")
        if key == "name" and not isinstance(value, str):
            return f"name must be a string (a label for reports), got {value!r}; fix it"
        return None
    if isinstance(value, str):
        if key in RIG_PRIOR_KEYS:  # a prior's text, parsed where priors are (the model)
            return None
        return (f"{key!r} is {value!r}; it must be a number (only "
                f"{', '.join(RIG_PRIOR_KEYS)} may be given as a prior)")
    if not _is_number(value):
        return f"{key!r} is {value!r}; it must be a finite number; fix it"
    if key == "moving_mass_kg" and not value > 0:
        return (f"rig mass must be > 0 kg (moving_mass_kg, everything that moves with the "
                f"muscle's free end), got {value}; fix it")
    if key == "gravity_sign" and value not in (-1, 0, 1):
        return (f"gravity_sign must be -1, 0 or +1 (+1 gravity opposes extension, -1 it "
                f"pulls toward extension, 0 none), got {value}; fix it")
    if key == "area_m2" and not value > 0:
        return (f"area_m2 must be > 0 (the effective area in m^2, force per pressure; 1 for "
                f"a force input), got {value}; fix it")
    if key == "g_m_s2" and not value > 0:
        return f"g_m_s2 must be > 0 (gravitational acceleration in m/s^2), got {value}; fix it"
    return None


def rig_problem(rig: object) -> str | None:
    """What is wrong with a rig's dict, said with its fix; None where it is right.

    The one check of a rig: :class:`~pmabayes.data.Dataset` raises it as a
    :class:`~pmabayes.data.DataError` naming the file, :class:`pmabayes.model.Rig` as a
    ``ModelError``. A value of :data:`RIG_PRIOR_KEYS` may be a string (a prior's text,
    which the model parses).

    Parameters
    ----------
    rig : object
        A rig's dict (:data:`RIG_DICT_KEYS`; ``moving_mass_kg`` required).

    Returns
    -------
    str or None
        The first problem, without the file's name.

    Examples
    --------
    >>> rig_problem({"moving_mass_kg": 0.1, "gravity_sign": 2})
    'gravity_sign must be -1, 0 or +1 (+1 gravity opposes extension, -1 it pulls toward extension, 0 none), got 2; fix it'
    >>> rig_problem({"moving_mass_kg": 0.1, "area_m2": "LogNormal(1e-4, 1.5)"}) is None
    True
    """  # noqa: E501
    if not isinstance(rig, Mapping):
        return (f"a rig is a JSON object of its constants (keys {', '.join(RIG_DICT_KEYS)}), "
                f"got {type(rig).__name__}; fix it")
    unknown = set(rig) - set(RIG_DICT_KEYS)
    if unknown:
        return (f"unknown rig keys {sorted(map(str, unknown))}; expected "
                f"{sorted(RIG_DICT_KEYS)}: rename or remove them")
    if "moving_mass_kg" not in rig:
        return ("no 'moving_mass_kg': a rig needs the mass that moves with the muscle's "
                "free end, in kg (or a prior); add it")
    for key, value in rig.items():
        problem = _value_problem(key, value)
        if problem:
            return problem
    return None


def is_declared_rig(rig: object) -> bool:
    """Whether a sidecar's ``"rig"`` declares a rig (a dict with a rig key, or a key close
    to one, taken for its misspelling) rather than free-form notes about it.

    Parameters
    ----------
    rig : object
        The sidecar's ``"rig"``.

    Returns
    -------
    bool
    """
    if not isinstance(rig, Mapping):
        return False
    return any(isinstance(key, str) and (key in RIG_DICT_KEYS or difflib.get_close_matches(
        key, RIG_DICT_KEYS, n=1, cutoff=_CLOSE)) for key in rig)


def declared_rig(metadata: Mapping | None) -> dict | None:
    """The rig a data set's metadata declares, as its dict; None where it declares none.

    A data set's ``"rig"`` has been checked when it was made (:func:`rig_problem`), so a
    declared rig's dict is valid; free-form notes about the rig declare none.

    Parameters
    ----------
    metadata : mapping or None
        A data set's metadata.

    Returns
    -------
    dict or None
    """
    rig = (metadata or {}).get("rig")
    return dict(rig) if is_declared_rig(rig) else None
