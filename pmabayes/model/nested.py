"""The linear models nested in the base physics.

With ``beta = gamma = 0`` the Bouc-Wen force is ``z = alpha x`` (from ``z = 0`` at
``x = 0``), a spring beside ``K_e``; above the dead zone the base model is then the
linear oscillator ``(M + m) x'' + d x' + (K_e + alpha) x = A (p - p_dz) - W`` (``W``
the gravity term), whose static limit is the straight line of position on input
``x = (A (p - p_dz) - W) / (K_e + alpha)``. Any record a static line describes is
therefore described at least as well by the base model at the values
:func:`static_line_values` gives, and a search that ends worse than that line has
failed (:func:`pmabayes.inference.search.find_map` starts from them as well).
"""

from __future__ import annotations

from pmabayes.model.model import Model

__all__ = ["static_line_values"]


def static_line_values(model: Model, slope: float, intercept_m: float, input_low: float, *,
                       area_m2: float, tau_s: float, alpha_share: float = 0.5,
                       relative: bool = False) -> dict[str, float]:
    """The base parameters under which the model is a first-order lag of a static line.

    Parameters
    ----------
    model : Model
        The model; its rig gives the gravity term and the input kind.
    slope : float
        The line's slope, metres per unit of input (Pa or N); must be positive (the
        model's position rises with its input).
    intercept_m : float
        The line's position at zero input.
    input_low : float
        The smallest input of the record: the dead zone is put at or below it.
    area_m2 : float
        The area the pressure acts on (1 for a force rig, whose input is the force).
    tau_s : float
        The lag's time constant ``d / (K_e + alpha)``.
    alpha_share : float
        The share of the line's stiffness ``A / slope`` given to ``alpha`` (the rest
        to ``K_e``), in (0, 1).
    relative : bool
        The record's positions are referred to its start, so the intercept is not the
        model's: the dead zone is then put at the smallest input. Otherwise it is
        where the line meets the model's intercept (the line then holds above it).

    Returns
    -------
    dict of str to float
        ``alpha``, ``beta``, ``gamma``, ``d``, ``K_e`` and, on a pressure rig,
        ``p_dz``.

    Raises
    ------
    ValueError
        If ``slope`` is not positive or ``alpha_share`` is outside (0, 1).

    Examples
    --------
    >>> from pmabayes import Model, Rig
    >>> rig = Rig(moving_mass_kg=1.0, gravity_sign=0.0, area_m2=1.0, input_kind="force")
    >>> v = static_line_values(Model(rig=rig), 1e-3, 0.0, -5.0, area_m2=1.0, tau_s=0.01)
    >>> v["K_e"] + v["alpha"], v["d"]
    (1000.0, 10.0)
    """
    if not slope > 0:
        raise ValueError(f"the static line's slope must be positive, got {slope!r}")
    if not 0.0 < alpha_share < 1.0:
        raise ValueError(f"alpha_share must be in (0, 1), got {alpha_share!r}")
    k_total = area_m2 / slope
    out = {"alpha": alpha_share * k_total, "beta": 0.0, "gamma": 0.0,
           "d": tau_s * k_total, "K_e": (1.0 - alpha_share) * k_total}
    if model.rig.input_kind == "pressure":
        # x = slope (p - p_dz) - W / k_total = intercept + slope p
        p_dz = -(intercept_m * k_total + model.rig.gravity_force_n) / area_m2
        out["p_dz"] = float(input_low if relative else p_dz)
    return out
