"""The proposal as a ready user effect: its name, its words, and its ``.py`` file for
``--plugin``, written from a template.
"""

from __future__ import annotations

from pathlib import Path
from string import Template


def effect_name(chosen: list) -> str:
    """The proposed effect's registry name, from its terms' slugs.

    Parameters
    ----------
    chosen : list of (Term, float)
        The terms and their coefficients.

    Returns
    -------
    str
        ``proposed_<slugs>`` (its parameters are ``c_<slug>``: unique names).
    """
    slugs = [t.slug for t, _ in chosen]
    return "proposed_" + "_".join(slugs)[:40]


#: the file of a proposed effect; each ``$name`` is filled in by :func:`plugin_source`
_FILE = Template('''"""A proposed effect: $description

Written by pmabayes' discrepancy step from the data's residual (an estimate,
not a law: check it with `pmabayes diagnose DATA --effects $name` after --plugin).
"""

import math

import numpy as np

import pmabayes as pb
$tables$state

def _physics($arguments):
    """Force opposing extension, and its derivatives in $derivatives."""
$body
    return $returns


class ProposedEffect(pb.Effect):
    """$description"""

    name = $name_repr
    stage = "force"
$attributes    parameters = (
$parameters    )
    description = $description_repr
    physics = staticmethod(_physics)


pb.register_effect(ProposedEffect)
''')

#: the tabulated shape's breakpoints and polynomial pieces
_TABLES = Template("""
_BREAKS = np.array($breaks)
_COEFS = np.array($coefs)

""")

#: the memory state: the low-passed velocity s' = (v - s) / tau, exact over a step of
#: constant v; tau is a parameter of the effect (the refit adjusts it)
_MEMORY = Template('''

def _advance(q, s, x0, x1, h):
    """The memory state over a step: exact for a constant velocity."""
    e = math.exp(-h / $tau)
    return s * e + (1.0 - e) * (x1 - x0) / h, (1.0 - e) / h
''')

#: the loop state: Dahl's h' = (sgn x' - h) |x'| / width, exact over a straight step; the
#: width is a parameter of the effect
_LOOP = Template('''

def _advance(q, s, x0, x1, h):
    """The loop state over a step: exact for a straight travel."""
    dx = x1 - x0
    target = 1.0 if dx >= 0.0 else -1.0
    e = math.exp(-abs(dx) / $width)
    return target + (s - target) * e, -(s - target) * e * target / $width
''')

#: the table evaluated inline: a compiled helper would be a second function the
#: simulator's cached kernel could not find again in a later process
_LOOKUP = Template("""    s = $symbol
    if s <= _BREAKS[0]:
        k = 0
        h = 0.0
        inside = 0.0
    elif s >= _BREAKS[-1]:
        k = _BREAKS.size - 2
        h = _BREAKS[-1] - _BREAKS[k]
        inside = 0.0
    else:
        k = np.searchsorted(_BREAKS, s) - 1
        h = s - _BREAKS[k]
        inside = 1.0
    shape = ((_COEFS[0, k] * h + _COEFS[1, k]) * h + _COEFS[2, k]) * h + _COEFS[3, k]
    slope = inside * ((3.0 * _COEFS[0, k] * h + 2.0 * _COEFS[1, k]) * h + _COEFS[2, k])""")

#: one parameter of the effect
_PARAMETER = Template(
    "        pb.Parameter($name, $unit, $default, $prior, "
    "bounds=($low, $high), null=$null,\n"
    "                     description=$description),\n")

_SYMBOL = {"position": "x", "velocity": "v", "pressure": "p"}


def plugin_source(name: str, chosen: list, description: str, tables=None) -> str:
    """The text of a ready user effect for ``--plugin``: a force-stage effect that
    registers itself when the file is loaded.

    Parameters
    ----------
    name : str
        The effect's registry name.
    chosen : list of (Term, float)
        The terms and their coefficients (the parameters' defaults).
    description : str
        The force in words.
    tables : tuple of numpy.ndarray, optional
        ``(breaks, coefs)`` of a tabulated shape (its one term's ``shape`` and
        ``slope``).

    Returns
    -------
    str
    """
    reads_z = any(t.reads_z for t, _ in chosen)
    tau = next((t.memory_tau_s for t, _ in chosen if t.memory_tau_s is not None), None)
    width = next((t.loop_width_m for t, _ in chosen if t.loop_width_m is not None), None)
    if tau is not None and width is not None:
        raise ValueError("an effect has one state: a memory term and a loop term cannot be "
                         "written in one effect")
    stateful = tau is not None or width is not None
    extended = reads_z or stateful  # the signature of effects that read z or s
    body = ["    f = 0.0", "    fx = 0.0", "    fv = 0.0"]
    body += ["    fz = 0.0", "    fs = 0.0"] if extended else []
    if tables is not None:
        body.append(_LOOKUP.substitute(symbol=_SYMBOL[chosen[0][0].state]))
    attributes = ["    reads_z = True"] if reads_z else []
    if stateful:
        attributes += [f'    state = "{"v_lp_m_s" if tau is not None else "h_loop"}"',
                       "    advance = staticmethod(_advance)"]
    extra = _extra_indices(chosen)[2]
    return _FILE.substitute(
        description=description, name=name, name_repr=repr(name),
        description_repr=repr(description),
        tables="" if tables is None else _tables(*tables),
        state=(_MEMORY.substitute(tau=extra) if tau is not None else
                _LOOP.substitute(width=extra) if width is not None else ""),
        arguments="q, x, v, p, z, s" if extended else "q, x, v, p",
        derivatives="x, v, z and s" if extended else "x and v",
        body="\n".join(body + _force_lines(chosen)),
        returns="f, fx, fv, fz, fs" if extended else "f, fx, fv",
        attributes="".join(a + "\n" for a in attributes),
        parameters=_parameters(chosen))


def _tables(breaks, coefs) -> str:
    return _TABLES.substitute(
        breaks=repr([float(f"{b:.10g}") for b in breaks]),
        coefs=repr([[float(f"{c:.10g}") for c in row] for row in coefs]))


def _extra_indices(chosen: list) -> tuple[str, str, str]:
    """The period's, the breakpoint's and the state's constant's (the memory's time
    constant or the loop's width) entries of ``q``, after the coefficients."""
    period = any(t.period_m is not None for t, _ in chosen)
    brk = any(t.breakpoint_m is not None for t, _ in chosen)
    n = len(chosen)
    return f"q[{n}]", f"q[{n + period}]", f"q[{n + period + brk}]"


def _force_lines(chosen: list) -> list[str]:
    """The force and its derivatives, a term at a time."""
    per, brk, _ = _extra_indices(chosen)

    def fill(expr: str) -> str:
        return expr.replace("{L}", per).replace("{B}", brk)

    lines = []
    for k, (t, _) in enumerate(chosen):
        lines.append(f"    f += q[{k}] * ({fill(t.force)})")
        for out, expr in (("fx", fill(t.dx)), ("fv", fill(t.dv)), ("fz", t.dz), ("fs", t.ds)):
            if expr != "0.0":
                lines.append(f"    {out} += q[{k}] * ({expr})")
    return lines


def _parameters(chosen: list) -> str:
    """The effect's parameters: a coefficient per term, then the period, the
    breakpoint and the state's scale (memory time constant or loop width) of the terms
    that have them."""
    out = []
    for t, coef in chosen:
        sd = max(2.0 * abs(coef), 1e-12)
        lo, hi = min(coef - 50.0 * sd, 0.0), max(coef + 50.0 * sd, 0.0)
        out.append(_parameter(f"c_{t.slug}", t.unit, coef, sd, lo, hi, 0.0,
                              f"coefficient of {t.name}: {t.words}"))
    period = next((t.period_m for t, _ in chosen if t.period_m is not None), None)
    if period is not None:
        out.append(_parameter("L_period", "m", period, 0.03 * period, 0.8 * period,
                              1.25 * period, period, "period in position of the force"))
    brk = next((t.breakpoint_m for t, _ in chosen if t.breakpoint_m is not None), None)
    if brk is not None:
        out.append(_parameter("x_break", "m", brk, 0.01, brk - 0.1, brk + 0.1, brk,
                              "position below which the spring acts"))
    tau = next((t.memory_tau_s for t, _ in chosen if t.memory_tau_s is not None), None)
    if tau is not None:
        # a scale within a factor 1000 either way: the prior's tails (6.9 sigma) inside
        out.append(_parameter("tau_memory", "s", tau, 1.0, 1e-3 * tau, 1e3 * tau, tau,
                              "time constant of the low-passed velocity", "LogNormal"))
    width = next((t.loop_width_m for t, _ in chosen if t.loop_width_m is not None), None)
    if width is not None:
        out.append(_parameter("w_loop", "m", width, 1.0, 1e-3 * width, 1e3 * width, width,
                              "travel over which the loop saturates", "LogNormal"))
    return "".join(out)


def _parameter(name: str, unit: str, default: float, sd: float, low: float, high: float,
               null: float, description: str, prior: str = "Normal") -> str:
    """One parameter's line: its prior ``Normal(default, sd)``, or ``LogNormal(default,
    sd)`` (``sd`` then of the logarithm) for a time constant."""
    return _PARAMETER.substitute(name=repr(name), unit=repr(unit), default=repr(default),
                                 prior=f"pb.{prior}({default!r}, {sd!r})", low=repr(low),
                                 high=repr(high), null=repr(null),
                                 description=repr(description))


#: slugs of the dictionary's terms odd in velocity (a force along -v when positive)
_ODD_IN_V = ("vabsv", "v3", "tanh")


def describe_terms(chosen: list, kind: str) -> tuple[str, str]:
    """The proposal as a formula with its coefficients and units, and in physical words."""
    if kind == "tabulated":
        t = chosen[0][0]
        return (f"{t.name}", f"a force with the estimated shape against {t.state}, "
                "tabulated with one amplitude (no closed form in the dictionary matches it)")
    parts, words = [], []
    for t, c in chosen:
        parts.append(f"{c:+.4g} {t.unit} * {t.name}")
        if t.state == "velocity" and t.slug.startswith(_ODD_IN_V):
            # odd in v: the sign says whether it opposes or aids the motion
            sense = "opposing motion" if c > 0 else "aiding motion"
        else:
            sense = "opposing extension" if c > 0 else "toward extension"
        words.append(f"a force of about {abs(c):.3g} {t.unit} times {t.name}, {sense}: "
                     f"{t.words}")
    return " ".join(parts).lstrip("+"), "; ".join(words)


def write_plugin(chosen: list, kind: str, tables, plugin_dir: str | Path) -> tuple[Path, bool]:
    """Write the effect's file in the folder ``plugin_dir``; never over another file. Its
    path, and whether this call created it."""
    _, description = describe_terms(chosen, kind)
    name = effect_name(chosen)
    body = plugin_source(name, chosen, description, tables)
    folder = Path(plugin_dir)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.py"
    k = 2
    while path.exists() and path.read_text() != body:
        path = folder / f"{name}_{k}.py"  # never overwrite another file silently
        k += 1
    created = not path.exists()
    path.write_text(body)
    return path, created
