"""A proposed effect: a force with the estimated shape against pressure, tabulated with one amplitude (no closed form in the dictionary matches it)

Written by pmabayes' discrepancy step from the data's residual (an estimate,
not a law: check it with `pmabayes diagnose DATA --effects proposed_shape_p` after --plugin).
"""

import math

import numpy as np

import pmabayes as pb

_BREAKS = np.array([-185280.0, -145456.6667, -105633.3333, -65810.0, -25986.66667, 13836.66667, 53660.0, 93483.33333, 133306.6667, 173130.0])
_COEFS = np.array([[-9.044094506e-11, -5.548231584e-10, 1.76131564e-09, -1.164868442e-09, -9.55071041e-11, 7.612644425e-10, -1.465262089e-09, 2.751716178e-09, -8.156976e-09], [-1.888627544e-05, -2.969125515e-05, -9.597597789e-05, 0.0001144484016, -2.47184311e-05, -3.612866483e-05, 5.481959812e-05, -0.0001202352637, 0.0002085122681], [0.1540580304, -1.780461163, -6.784949273, -6.049315785, -2.475969258, -4.899103442, -4.154768175, -6.75983803, -3.244353458], [744730.2611, 715201.7964, 562170.3325, 251000.1286, 118031.5587, -25802.51962, -230119.3028, -401177.4477, -687270.9094]])



def _physics(q, x, v, p):
    """Force opposing extension, and its derivatives in x and v."""
    f = 0.0
    fx = 0.0
    fv = 0.0
    s = p
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
    slope = inside * ((3.0 * _COEFS[0, k] * h + 2.0 * _COEFS[1, k]) * h + _COEFS[2, k])
    f += q[0] * (shape)
    return f, fx, fv


class ProposedEffect(pb.Effect):
    """a force with the estimated shape against pressure, tabulated with one amplitude (no closed form in the dictionary matches it)"""

    name = 'proposed_shape_p'
    stage = "force"
    parameters = (
        pb.Parameter('c_shape_p', '1', 1.0, pb.Normal(1.0, 2.0), bounds=(-99.0, 101.0), null=0.0,
                     description='coefficient of S_p(p): the estimated force shape in pressure, tabulated'),
    )
    description = 'a force with the estimated shape against pressure, tabulated with one amplitude (no closed form in the dictionary matches it)'
    physics = staticmethod(_physics)


pb.register_effect(ProposedEffect)
