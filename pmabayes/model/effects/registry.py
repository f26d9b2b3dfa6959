"""Effects by name: registration, lookup, and the one loader of user plugins."""

from __future__ import annotations

import difflib
import importlib
import importlib.util
import os
import sys
from collections.abc import Iterable
from pathlib import Path
from types import ModuleType

from pmabayes.model.effects.base import Effect, EffectError

__all__ = ["register_effect", "registered_effects", "get_effect", "resolve_effects", "load_plugin"]


_REGISTRY: dict[str, type[Effect]] = {}
#: while set, register_effect checks an effect but leaves the registry as it is
_UNREGISTERED: list[bool] = [False]


def register_effect(effect: type[Effect], *, replace: bool = False) -> type[Effect]:
    """Add an effect class to the registry so it can be named in the API and CLI.

    Parameters
    ----------
    effect : type
        A subclass of :class:`Effect`.
    replace : bool
        Allow replacing a different class already registered under the same name.
        A class with the same module and qualified name (the same definition
        imported again) always replaces the old one.

    Returns
    -------
    type
        ``effect`` itself, so this can be used as a class decorator.

    Raises
    ------
    EffectError
        If ``effect`` is not an Effect subclass, or its name is taken by another class.
    """
    if not (isinstance(effect, type) and issubclass(effect, Effect) and effect.name):
        raise EffectError(f"register_effect needs an Effect subclass with a name, got {effect!r}")
    old = _REGISTRY.get(effect.name)
    # the same definition imported again (a reloaded plugin, a re-run notebook cell)
    redefined = old is not None and (old.__module__, old.__qualname__) == (
        effect.__module__, effect.__qualname__)
    if _UNREGISTERED[0]:  # only tried (a proposal checked), so no name is taken
        return effect
    if old is not None and old is not effect and not (replace or redefined):
        raise EffectError(
            f"an effect named {effect.name!r} is already registered ({old.__module__}."
            f"{old.__qualname__}); choose another name or pass replace=True"
        )
    _REGISTRY[effect.name] = effect
    return effect


def registered_effects() -> dict[str, type[Effect]]:
    """All registered effects by name.

    Returns
    -------
    dict
        Name to effect class, built-in and user-registered.
    """
    return dict(_REGISTRY)


def get_effect(name: str) -> type[Effect]:
    """Look up a registered effect by name.

    Parameters
    ----------
    name : str
        Registry name, e.g. ``"regulator_lag"``.

    Returns
    -------
    type
        The effect class.

    Raises
    ------
    EffectError
        If no effect of that name is registered; the message lists the known ones.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        known = ", ".join(sorted(_REGISTRY))
        near = difflib.get_close_matches(str(name), list(_REGISTRY), n=1)
        hint = f"did you mean {near[0]!r}? " if near else ""
        raise EffectError(f"unknown effect {name!r}; {hint}known effects: {known}") from None


def resolve_effects(effects: Iterable[str | type[Effect] | Effect] | str | None) -> tuple:
    """Turn names, classes or instances (or a comma-separated string) into effect classes.

    Parameters
    ----------
    effects : iterable, str or None
        Names, Effect subclasses or instances; or one comma-separated string.

    Returns
    -------
    tuple of type
        The effect classes in the given order.

    Raises
    ------
    EffectError
        On an unknown name, a non-effect, or the same effect listed twice.
    """
    if effects is None:
        return ()
    if isinstance(effects, str):
        effects = [e.strip() for e in effects.split(",") if e.strip()]
    out: list[type[Effect]] = []
    for e in effects:
        if isinstance(e, str):
            cls = get_effect(e)
        elif isinstance(e, Effect):
            cls = type(e)
        elif isinstance(e, type) and issubclass(e, Effect) and e.name:
            cls = e
        else:
            raise EffectError(f"not an effect: {e!r}")
        if cls in out:
            raise EffectError(f"effect {cls.name!r} is listed twice")
        out.append(cls)
    return tuple(out)


def load_plugin(spec: str | os.PathLike, *, register: bool = True) -> ModuleType:
    """Import a ``.py`` file or an importable module of user effects.

    The file's effects register themselves (``register_effect``) as it is imported,
    as for ``pmabayes --plugin FILE``.

    Parameters
    ----------
    spec : str or path-like
        A path to a Python file, or an importable module name.
    register : bool
        With False, the file is imported and its effects are checked, but the
        registry is left as it was (a proposed effect tried before it is adopted).

    Returns
    -------
    module
        The imported module.

    Raises
    ------
    EffectError
        For a missing file, a module that cannot be found, or a file that does not
        compile or run (the message names the file and the line).

    Examples
    --------
    The plugin of the docs' criticism page (``docs/plugins/`` of a checkout), a drag
    the library does not hold:

    >>> import pmabayes
    >>> from pmabayes.model.effects import load_plugin
    >>> module = load_plugin("docs/plugins/hidden_drag.py")
    >>> "hidden_drag" in pmabayes.registered_effects()
    True
    >>> pmabayes.Model(["hidden_drag"]).parameter_names[-1]
    'c_hidden'
    """
    text = os.fspath(spec)
    _UNREGISTERED[0] = not register
    try:
        if not text.endswith(".py"):
            try:
                return importlib.import_module(text)
            except ModuleNotFoundError as err:
                raise EffectError(f"plugin {text}: no module named {err.name!r}; give a "
                                  "path to a .py file or an importable module") from None
        return _load_file(Path(text), register)
    finally:
        _UNREGISTERED[0] = False


def _load_file(path: Path, register: bool) -> ModuleType:
    if not path.is_file():
        raise EffectError(f"plugin {path}: no such file; check the path")
    name = f"pmabayes_plugin_{path.stem}" if register else f"pmabayes_unregistered_{path.stem}"
    module_spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(module_spec)
    sys.modules[name] = module  # dataclasses and numba look their module up there
    try:
        module_spec.loader.exec_module(module)
    except SyntaxError as err:
        sys.modules.pop(name, None)
        raise EffectError(f"{path}: line {err.lineno}: {err.msg}; fix the plugin's "
                          "Python") from None
    except EffectError as err:
        sys.modules.pop(name, None)
        raise EffectError(f"{path}: {err}") from None
    except Exception as err:
        sys.modules.pop(name, None)
        line = _traceback_line(err, path)
        raise EffectError(f"{path}: line {line}: {type(err).__name__}: {err}; fix the "
                          "plugin") from None
    return module


def _traceback_line(err: BaseException, path: Path) -> int | str:
    """The last line of ``path`` in ``err``'s traceback ("?" where none is)."""
    line: int | str = "?"
    tb = err.__traceback__
    while tb is not None:
        if Path(tb.tb_frame.f_code.co_filename) == path:
            line = tb.tb_lineno
        tb = tb.tb_next
    return line
