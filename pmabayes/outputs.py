"""The rules of pmabayes' outputs: never over a file pmabayes did not make.

Every output path is checked before the first computation: it must be writable, a
folder where a folder is meant and a file where a file is meant, not one of the
inputs, and either new or pmabayes' own output of the same kind. pmabayes' outputs
carry a mark of what made them (:func:`stamp`: ``{"kind": KIND, "version": ...}``):

* a fit file, the root attribute ``pmabayes`` (:func:`pmabayes.inference.fitfile.is_fit_file`);
* a JSON output, the key ``"pmabayes"``;
* a folder, the file ``.pmabayes`` (:data:`MARK`, the same JSON);
* a data set, the generator ``pmabayes.synthetic...`` (``pmabayes simulate``) or the
  key ``"written_by"`` (``pmabayes read --out``) in its metadata.

An empty folder is new. Pages are written to a temporary folder beside the output and
moved in whole, the HTML last (:func:`staged`).

The command line (:mod:`pmabayes.cli`) and the Python API obey the same rules from
here: :func:`pmabayes.diagnose` writes its proposed effect only into the folder
``plugin_dir`` names, checked first by :func:`check_folder_for_new_files`.

This module imports only the standard library at its top (the command line's
``--help`` stays quick); it reads fit files and data sets, where it must, through their
layers' own readers.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

from pmabayes import __version__
from pmabayes.util import Progress

__all__ = ["MARK", "OutputError", "stamp", "json_kind", "folder_kind", "is_own_data",
           "check_writable", "check_file", "check_folder", "check_folder_for_new_files",
           "check_chains", "check_fits_folder", "refuse_foreign", "mark_folder", "created",
           "staged", "write_json"]

#: the file that marks a folder as pmabayes' own
MARK = ".pmabayes"


class OutputError(ValueError):
    """An output path is refused: the message names the path, why, and the fix."""


def stamp(kind: str) -> dict:
    """The mark of pmabayes' outputs: what made them, and its version.

    Parameters
    ----------
    kind : str
        The command (or output) that made it, e.g. ``"diagnose"``.

    Returns
    -------
    dict
        ``{"kind": kind, "version": pmabayes.__version__}``.
    """
    return {"kind": kind, "version": __version__}


def _read_json(path: Path) -> object:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def json_kind(path: str | Path) -> str | None:
    """The kind of the JSON output at ``path`` (its ``"pmabayes"`` key), or None.

    Parameters
    ----------
    path : str or Path
        Any path (a JSON file there is read).

    Returns
    -------
    str or None
        None for a missing, unreadable or foreign file.
    """
    obj = _read_json(Path(path))
    mark = obj.get("pmabayes") if isinstance(obj, dict) else None
    return mark.get("kind") if isinstance(mark, dict) else None


def folder_kind(path: str | Path) -> str | None:
    """The kind of output a folder is (its ``.pmabayes`` file), or None.

    Parameters
    ----------
    path : str or Path
        A folder.

    Returns
    -------
    str or None
        None where the folder carries no mark.
    """
    obj = _read_json(Path(path) / MARK)
    return obj.get("kind") if isinstance(obj, dict) else None


def is_own_data(path: str | Path) -> bool:
    """Whether ``path`` is a data set that pmabayes wrote: generated (``pmabayes
    simulate``) or read from a lab's file and written again (``pmabayes read --out``).

    Parameters
    ----------
    path : str or Path
        Any path; only a data file that loads can be one.

    Returns
    -------
    bool
        False for a missing or unreadable data set, or a lab's own file.
    """
    from pmabayes.data import DataError, load

    try:
        meta = load(path).metadata
    except (DataError, OSError, ValueError):
        return False
    generator = meta.get("generator")
    return (isinstance(generator, dict) and str(generator.get("function", "")).startswith(
        "pmabayes.")) or isinstance(meta.get("written_by"), str)


def _is_fit(path: Path) -> bool:
    # the fit file's own test, at the layer that writes fits (numerics load only here)
    from pmabayes.inference.fitfile import is_fit_file

    return is_fit_file(path)


def check_writable(path: str | Path, option: str, shown: str | Path | None = None) -> None:
    """Refuse a path where nothing can be written, by trying (before any work).

    Parameters
    ----------
    path : str or Path
        A folder to write in (it may not exist yet: its nearest existing parent is tried).
    option : str
        The option or argument that named it, for the message (``--out``, ``plugin_dir``).
    shown : str or Path, optional
        The path as the user gave it (``path`` by default).

    Raises
    ------
    OutputError
        If a parent is a file, or the folder cannot be written in.
    """
    path = Path(path)
    shown = path if shown is None else shown
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{option} {shown}: {probe} is a file, so nothing can be written "
                          "under it; give another path")
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as err:
        raise OutputError(f"{option} {shown}: cannot write in {probe} ({err.strerror}); give "
                          "a place you can write to") from None


def _not_an_input(path: Path, option: str, inputs: Sequence[str | Path]) -> None:
    for item in inputs:
        if Path(item).exists() and path.exists() and os.path.samefile(item, path):
            raise OutputError(f"{option} {path} is one of the command's inputs; give a new "
                              "name for the output")


def refuse_foreign(path: str | Path, option: str, what: str) -> None:
    """Refuse to write over ``path``, which pmabayes did not make (or not of this kind).

    Parameters
    ----------
    path : str or Path
        The output refused.
    option : str
        The option that named it.
    what : str
        What is there, e.g. ``"this file exists and is not a pmabayes fit"``.

    Raises
    ------
    OutputError
        Always.
    """
    raise OutputError(f"{option} {path}: {what}; pmabayes writes only over its own outputs "
                      "of the same kind. Give a new name, or move that away first")


def check_file(path: str | Path, kind: str, option: str,
               inputs: Sequence[str | Path] = ()) -> Path:
    """An output file's path, checked before any work.

    It must be writable, not a folder, not one of ``inputs``, and new or pmabayes' own
    output of ``kind``.

    Parameters
    ----------
    path : str or Path
        The file to write.
    kind : str
        ``"fit"`` (a fit file), ``"data"`` (a data set of ``simulate`` or ``read``, with
        its JSON sidecar beside a CSV), or the command of a JSON output.
    option : str
        The option that named it, for the messages.
    inputs : sequence of str or Path
        The inputs of the work, never written over.

    Returns
    -------
    Path
        ``path``, checked.

    Raises
    ------
    OutputError
        Naming the path, why it is refused, and the fix.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{option} {path}: this is a folder; give the name of the file to "
                          "write")
    _not_an_input(path, option, inputs)
    if path.exists():
        Progress().say(f"{path} exists: checking that it is pmabayes' own {kind} output")
        if kind == "fit":
            if not _is_fit(path):
                refuse_foreign(path, option, "this file exists and is not a pmabayes fit")
        elif kind == "data":
            if not is_own_data(path):
                refuse_foreign(path, option, "this file exists and is not a data set that "
                               "pmabayes wrote (`pmabayes simulate` or `pmabayes read --out`)")
        elif json_kind(path) != kind:
            refuse_foreign(path, option, f"this file exists and is not the JSON output of "
                           f"`pmabayes {kind}`")
    if kind == "data" and path.suffix.lower() == ".csv":  # and its JSON sidecar
        sidecar = path.with_suffix(".json")
        _not_an_input(sidecar, option, inputs)
        if sidecar.exists() and not (path.exists() and is_own_data(path)):
            refuse_foreign(sidecar, f"{option} {path}: its sidecar", "this file exists and "
                           "is not one pmabayes wrote")
    check_writable(path.parent, option, path)
    return path


def _not_a_file(out: Path, option: str) -> None:
    """Refuse an output folder's name that a file has."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out}: this is a file, not a folder; give the name of a "
                          "folder (it is created if missing)")


def check_folder(path: str | Path, kind: str, option: str = "--out",
                 inputs: Sequence[str | Path] = ()) -> Path:
    """An output folder's path, checked before any work.

    It must be writable, not a file, hold none of ``inputs``, and be new, empty, or
    pmabayes' output of ``kind`` (its :data:`MARK`).

    Parameters
    ----------
    path : str or Path
        The folder (created later, if missing).
    kind : str
        The command whose output it is.
    option : str
        The option that named it, for the messages.
    inputs : sequence of str or Path
        The inputs of the work.

    Returns
    -------
    Path
        ``path``, checked; :func:`created` or :func:`staged` makes it.

    Raises
    ------
    OutputError
        Naming the folder, why it is refused, and the fix.
    """
    out = Path(path)
    _not_a_file(out, option)
    if out.is_dir() and any(out.iterdir()):
        for item in inputs:
            if Path(item).resolve().is_relative_to(out.resolve()):
                raise OutputError(f"{option} {out} holds the input {item}; give another "
                                  "folder for the outputs")
        found = folder_kind(out)
        if found != kind:
            refuse_foreign(out, option, "this folder exists and holds files that `pmabayes "
                           f"{kind}` did not write" + (f" (it is the output of `pmabayes "
                                                       f"{found}`)" if found else ""))
    check_writable(out, option, out)
    return out


def check_folder_for_new_files(path: str | Path, option: str) -> Path:
    """A folder that new files are added to (never over a file there: the writer chooses
    a free name), checked before any work: not a file, and writable.

    Parameters
    ----------
    path : str or Path
        The folder (created later, if missing).
    option : str
        The option or argument that named it.

    Returns
    -------
    Path
        ``path``, checked; the writer makes it where missing.

    Raises
    ------
    OutputError
        If it is a file or cannot be written in.
    """
    folder = Path(path)
    if folder.is_file():
        raise OutputError(f"{option} {path}: this is a file, not a folder")
    check_writable(folder, option, path)
    return folder


def check_chains(fit: str | Path, option: str = "--out") -> None:
    """The chains' folder beside a fit (``FIT.nc.chains``) must be a folder too.

    Parameters
    ----------
    fit : str or Path
        The fit file.
    option : str
        The option that named the fit.

    Raises
    ------
    OutputError
        If a file stands where the chains go.
    """
    fit = Path(fit)
    chains = fit.with_name(fit.name + ".chains")
    if chains.exists() and not chains.is_dir():
        raise OutputError(f"{option} {fit}: {chains}, where its chains go, is a file; move it "
                          "away or give another name")


def check_fits_folder(out: str | Path, fits: Mapping[str, str], option: str = "--out") -> Path:
    """A folder of fits (a batch's), and every fit it will hold, checked before any work.

    Parameters
    ----------
    out : str or Path
        The folder.
    fits : mapping of str to str
        Each fit's file name in ``out`` and the data file it is fitted from.
    option : str
        The option that named the folder.

    Returns
    -------
    Path
        ``out``, checked.

    Raises
    ------
    OutputError
        If ``out`` is a file, a fit's name is taken by anything but a pmabayes fit, or
        nothing can be written there.
    """
    out = Path(out)
    _not_a_file(out, option)
    for name, source in fits.items():
        path = out / name
        if path.is_dir() or (path.exists() and not _is_fit(path)):
            refuse_foreign(path, option, f"{path.name} exists there and is not a pmabayes "
                           f"fit, and the fit of {source} would go there")
    check_writable(out, option, out)
    return out


def mark_folder(out: str | Path, kind: str) -> None:
    """Mark a folder as the output of ``kind`` (its :data:`MARK` file).

    Parameters
    ----------
    out : str or Path
        An existing folder.
    kind : str
        The command whose output it is.
    """
    (Path(out) / MARK).write_text(json.dumps(stamp(kind)) + "\n")


@contextlib.contextmanager
def created(out: str | Path, kind: str) -> Iterator[Path]:
    """Create the folder ``out``, marked as the output of ``kind``; on failure remove it
    again if this call made it and nothing else was written.

    Parameters
    ----------
    out : str or Path
        A folder checked by :func:`check_folder`.
    kind : str
        The command whose output it is.

    Yields
    ------
    Path
        The folder.
    """
    out = Path(out)
    existed = out.exists()
    out.mkdir(parents=True, exist_ok=True)
    mark_folder(out, kind)
    try:
        yield out
    except BaseException:
        if not existed and {p.name for p in out.iterdir()} <= {MARK}:
            shutil.rmtree(out, ignore_errors=True)
        raise


@contextlib.contextmanager
def staged(out: str | Path, kind: str, written: list[str]) -> Iterator[Path]:
    """A temporary folder beside ``out`` to write a page into.

    On success its files move into ``out`` (made and marked if missing), the HTML
    last; their names are appended to ``written``. On failure or Ctrl-C it is removed
    and ``out`` is as it was.

    Parameters
    ----------
    out : str or Path
        The folder the page goes to, checked by :func:`check_folder`.
    kind : str
        The command whose output it is.
    written : list of str
        Receives the names of the files moved in.

    Yields
    ------
    Path
        The temporary folder.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    tmp.chmod(0o777 & ~umask)  # mkdtemp's is private; the folder it becomes is not
    try:
        yield tmp
        mark_folder(tmp, kind)
        names = sorted((p.name for p in tmp.iterdir() if p.name != MARK),
                       key=lambda n: (n.endswith(".html"), n))
        if not out.exists():
            os.replace(tmp, out)  # the whole folder at once
        else:
            for name in [MARK, *names]:
                os.replace(tmp / name, out / name)
        written += names
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_json(path: str | Path, obj: Mapping, kind: str) -> None:
    """Write a JSON output, marked as ``kind``'s (its ``"pmabayes"`` key).

    Parameters
    ----------
    path : str or Path
        A file checked by :func:`check_file` (its folder is created if missing).
    obj : mapping
        The JSON object.
    kind : str
        The command whose output it is.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"pmabayes": stamp(kind), **obj}, indent=2) + "\n")
