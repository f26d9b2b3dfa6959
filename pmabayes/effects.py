"""The old import path of :mod:`pmabayes.model.effects`, kept so that plugins written
against it still load.

``from pmabayes.effects import Effect, register_effect`` gives the very objects of
:mod:`pmabayes.model.effects` (the registry is the same one, so an effect registered
through either path is known to both), and ``pmabayes.effects.base`` (or any other
module of that package) is the new module itself. The names the old module held
beside its own (:class:`~pmabayes.model.parameters.Parameter` and the priors
``Normal``, ``LogNormal`` and ``HalfNormal``) are there too. Importing this module
warns once, with a ``FutureWarning`` naming the new path; this alias will be
removed in a later release.
"""

from __future__ import annotations

import importlib
import os
import sys
import warnings

import pmabayes.model.effects as _new
import pmabayes.model.parameters as _parameters

#: the path to import from instead
NEW_PATH = _new.__name__

__all__ = list(_new.__all__)
globals().update({name: getattr(_new, name) for name in __all__})
# the old module imported these beside its own names, and plugins took them from it
globals().update({name: getattr(_parameters, name)
                  for name in ("Parameter", "Normal", "LogNormal", "HalfNormal")})


def _alias_modules() -> None:
    """Make each module of the new package importable under the old path too."""
    # the package's __init__ has imported every one of its modules, so each is in
    # sys.modules, and the import system returns an entry found there without
    # needing this module to be a package
    for name, module in list(sys.modules.items()):
        if name.startswith(NEW_PATH + "."):
            old = __name__ + name[len(NEW_PATH):]
            sys.modules[old] = module
            if "." not in name[len(NEW_PATH) + 1:]:
                globals()[name.rpartition(".")[2]] = module  # pmabayes.effects.base


_alias_modules()

# the module body runs once per process, so this warns once; the warning points at
# the importing line, past the import machinery's frames
warnings.warn(
    f"pmabayes.effects is the old path of {NEW_PATH} and will be removed in a later "
    f"release; import from {NEW_PATH} instead (the same objects)",
    FutureWarning,
    skip_file_prefixes=("<frozen importlib", os.path.dirname(importlib.__file__)),
)
