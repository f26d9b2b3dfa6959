"""A quadratic drag, hidden in synthetic data to stand in for physics no library holds.

Loaded with ``pmabayes --plugin docs/plugins/hidden_drag.py ...`` (see the docs'
Model criticism page, "Beyond the library"): the data are simulated with it, and
``diagnose`` is run without it, to see whether it finds the missing force.
"""

import pmabayes as pb


def drag(q, x, v, p):
    """Force ``c v |v|`` opposing the motion, and its derivatives in ``x`` and ``v``."""
    c = q[0]
    return c * v * abs(v), 0.0, 2.0 * c * abs(v)


class HiddenDrag(pb.Effect):
    """Drag growing with the square of the velocity (synthetic, hidden)."""

    name = "hidden_drag"
    stage = "force"
    parameters = (
        pb.Parameter("c_hidden", "N s^2/m^2", 50.0, pb.HalfNormal(200.0), bounds=(0.0, 1e5),
                     null=0.0, description="drag force per squared velocity"),
    )
    description = "Drag growing with the square of the velocity."
    physics = staticmethod(drag)


pb.register_effect(HiddenDrag)
