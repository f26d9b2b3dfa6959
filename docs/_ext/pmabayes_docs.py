"""pmabayes' own Sphinx helpers: the layout table from the code, and re-exported names.

* ``layers-table``, a directive: the table of the package's layers, generated at
  build time from :data:`pmabayes._layers.LAYERS` (rank, folder, job) and the
  files in each folder, so the code, ``tests/test_layout.py`` and the docs cannot
  disagree.
* ``sidecar-keys``, a directive: the sidecar reference (every key pmabayes reads, its
  type, unit, default and page), generated from :mod:`pmabayes.data.keys` and the
  rig's :data:`pmabayes.data.rig.RIG_KEYS`.
* :func:`reexports`: for each package, the public names it imports from its
  modules (the reference documents each object once, in the module that defines
  it; a package page lists what it re-exports).
* a ``missing-reference`` handler: a reference to a re-exported name
  (``pmabayes.fit``, ``pmabayes.control.tune_gains``) resolves to the object's own
  documentation, wherever the object is defined, so docstrings and pages may name
  an object as users import it.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
import sys
from pathlib import Path

from docutils import nodes
from sphinx.util.docutils import SphinxDirective

import pmabayes
from pmabayes._layers import LAYERS

PACKAGE_DIR = Path(pmabayes.__file__).parent


def _assigned_names(module) -> set[str]:
    """Names bound at the top level of a module's own source (not by imports)."""
    try:
        tree = ast.parse(inspect.getsource(module))
    except (OSError, TypeError):
        return set()
    names = set()
    for node in tree.body:
        targets = (node.targets if isinstance(node, ast.Assign)
                   else [node.target] if isinstance(node, ast.AnnAssign) else [])
        for target in targets:
            names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            names.add(node.name)
    return names


def _own(module, name: str) -> bool:
    """Whether a package documents ``name`` itself: defined there, or in one of its
    private modules (``pmabayes/model/effects/_numerics.py``), which get no page."""
    obj = vars(module)[name]
    if inspect.isfunction(obj) or inspect.isclass(obj) or hasattr(obj, "py_func"):
        home = getattr(obj, "__module__", None) or ""
        private = home.startswith(module.__name__ + "._") and home.count(".") == \
            module.__name__.count(".") + 1
        return home == module.__name__ or private
    return name in _assigned_names(module)


def reexports(root: str) -> dict[str, dict[str, list[str]]]:
    """Each package's public names (``__all__``) by where they are documented.

    ``own``: names the package's page documents although its module's own filter
    would not list them (objects of its private modules); ``imported``: classes and
    functions it imports from its public modules, which document them;
    ``imported_data``: the other names it imports (constants, tables), listed by name
    only, since an object such as a float carries no docstring of its own. Names that a package
    computes on first use (a module ``__getattr__``) are left out: looking them up
    would run them.

    Parameters
    ----------
    root : str
        The top package, ``"pmabayes"``.

    Returns
    -------
    dict
        Package name to ``{"own": [...], "imported": [...], "imported_data": [...]}``,
        in ``__all__`` order.
    """
    out = {}
    top = importlib.import_module(root)
    names = [root] + [m.name for m in pkgutil.walk_packages(top.__path__, root + ".")
                      if m.ispkg]
    for name in names:
        module = importlib.import_module(name)
        public = [n for n in getattr(module, "__all__", ()) if n in vars(module)]
        private_origin = [
            n for n in public if _own(module, n)
            and getattr(vars(module)[n], "__module__", name) != name]
        imported = [n for n in public if not _own(module, n)]
        callable_ = [n for n in imported if inspect.isclass(vars(module)[n])
                     or inspect.isfunction(vars(module)[n]) or hasattr(vars(module)[n], "py_func")]
        out[name] = {"own": private_origin, "imported": callable_,
                     "imported_data": [n for n in imported if n not in callable_]}
    return out


def _layer_files(name: str) -> str:
    folder = PACKAGE_DIR / name
    if not folder.is_dir():
        return f"{name}.py"
    files = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*.py")
                   if p.name != "__init__.py" and not p.name.startswith("_"))
    return ", ".join(files)


class LayersTable(SphinxDirective):
    """``layers-table``: the layers of :data:`pmabayes._layers.LAYERS`, as a table."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        self.env.note_dependency(str(PACKAGE_DIR / "_layers.py"))
        header = ("rank", "layer", "what it holds", "its modules")
        rows = []
        for name, (rank, job) in sorted(LAYERS.items(), key=lambda kv: kv[1][0]):
            rows.append((str(rank), name, job, _layer_files(name)))
        table = nodes.table(classes=["pmabayes-layers"])
        group = nodes.tgroup(cols=len(header))
        table += group
        for width in (6, 12, 50, 32):
            group += nodes.colspec(colwidth=width)
        head = nodes.thead()
        group += head
        head += self._row(header, literal=())
        body = nodes.tbody()
        group += body
        for row in rows:
            body += self._row(row, literal=(1, 3), link=True)
        return [table]

    def _row(self, cells, literal, link=False) -> nodes.row:
        row = nodes.row()
        for i, text in enumerate(cells):
            entry = nodes.entry()
            para = nodes.paragraph()
            if link and i == 1:
                ref = self._module_ref(f"pmabayes.{text}")
                para += ref
            elif i in literal:
                for j, part in enumerate(text.split(", ")):
                    if j:
                        para += nodes.Text(", ")
                    para += nodes.literal(text=part)
            else:
                para += nodes.Text(text)
            entry += para
            row += entry
        return row

    def _module_ref(self, target: str) -> nodes.Node:
        from sphinx.addnodes import pending_xref

        ref = pending_xref("", refdomain="py", reftype="mod", reftarget=target,
                           refexplicit=True, refwarn=True)
        ref += nodes.literal(text=target.split(".", 1)[1])
        return ref


def _lookup(target: str):
    """The object a dotted pmabayes name stands for, and the module it was found in."""
    parts = target.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            module = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        obj = module
        try:
            for attr in parts[cut:]:
                owner, obj = obj, inspect.getattr_static(obj, attr)
                if not isinstance(obj, property | staticmethod | classmethod):
                    obj = getattr(owner, attr)
        except AttributeError:
            return None, None
        return obj, module
    return None, None


def _defining_module(obj, found_in) -> str:
    """Where an object is defined: its ``__module__``, else the module that assigns it."""
    name = getattr(obj, "__module__", None)
    if isinstance(name, str) and name.startswith("pmabayes"):
        return name
    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("pmabayes"):
            for attr, value in list(vars(module).items()):
                if value is obj and attr in _assigned_names(module):
                    return module.__name__
    return found_in.__name__


def _candidates(node) -> list[str]:
    """Full names a reference may mean, from the most specific context outwards."""
    target = node.get("reftarget", "")
    module, cls = node.get("py:module"), node.get("py:class")
    out = []
    if module and cls:
        out.append(f"{module}.{cls}.{target}")
    if module:
        out.append(f"{module}.{target}")
    out.append(target)
    return [name for name in out if name.startswith("pmabayes")]


def _attribute_of(cls, attr: str) -> bool:
    """Whether ``attr`` is an instance attribute the class declares (a field, an
    annotation, or a name its docstring documents) though it has no entry of its own."""
    fields = getattr(cls, "__dataclass_fields__", {})
    annotations = getattr(cls, "__annotations__", {})
    return attr in fields or attr in annotations or attr in (cls.__doc__ or "")


def _resolve(app, env, node, contnode):
    """Resolve a pmabayes reference the Python domain did not.

    In this order: a name imported where it is used, or re-exported by a package
    (to the object's own entry); an object without an entry of its own, such as a
    private helper (to its module's page); a short name that one documented object
    ends with (a docstring naming an object of a neighbouring module); an instance
    attribute its class declares but does not document (to the class). Anything
    else stays unresolved, and the build fails on it.
    """
    if node.get("refdomain") != "py":
        return None
    domain = env.get_domain("py")

    def link(full: str, kind: str = "obj"):
        return domain.resolve_xref(env, node["refdoc"], app.builder, kind, full, node,
                                   contnode)

    for name in _candidates(node):
        obj, found_in = _lookup(name)
        if found_in is None:
            continue
        last = name.rsplit(".", 1)[-1]
        qualname = getattr(obj, "__qualname__", None)
        owner = getattr(obj, "__module__", None)
        documented = []
        if isinstance(qualname, str) and isinstance(owner, str):
            documented.append(f"{owner}.{qualname}")
        documented += [full for full in domain.objects
                       if full.rsplit(".", 1)[-1] == last and full != name
                       and _lookup(full)[0] is obj]
        for full in documented:
            if full in domain.objects:
                return link(full)
        home = obj.__name__ if inspect.ismodule(obj) else _defining_module(obj, found_in)
        if home in domain.modules:
            return link(home, "mod")
    target = node.get("reftarget", "")
    matches = {full for full in domain.objects
               if full.startswith("pmabayes.") and full.endswith("." + target)}
    if len(matches) == 1:
        return link(matches.pop())
    for name in _candidates(node) + sorted(matches):
        parent, _, attr = name.rpartition(".")
        cls, _ = _lookup(parent)
        if inspect.isclass(cls) and parent in domain.objects and _attribute_of(cls, attr):
            return link(parent)
    return None


_BARS = re.compile(r"(``.*?``)|(?<!\\)\|([A-Za-z_][\w.]*)\|")


def _escape_bars(app, what, name, obj, options, lines):
    """``|z|`` in a docstring is an absolute value, not a reStructuredText
    substitution (the package defines none): escape the bars outside literals."""
    for i, line in enumerate(lines):
        lines[i] = _BARS.sub(lambda m: m.group(1) or rf"\|{m.group(2)}\|", line)


def _cli_help(args: list[str]) -> str:
    """What ``pmabayes ARGS --help`` prints, 80 columns wide."""
    import contextlib
    import io
    import os

    from pmabayes.cli import main

    out = io.StringIO()
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "80"
    try:
        with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
            main([*args, "--help"])
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old
    return out.getvalue().rstrip()


class CliHelp(SphinxDirective):
    """``cli-help``: ``pmabayes --help`` and every subcommand's, generated at build
    time from the command line's own parser, so the page cannot drift from it."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        for path in sorted((PACKAGE_DIR / "cli").glob("*.py")):
            self.env.note_dependency(str(path))
        top = _cli_help([])
        commands = re.findall(r"^    ([a-z][a-z_-]*)(?:\s|$)", top, flags=re.MULTILINE)
        if not commands:
            raise self.error("pmabayes --help lists no subcommands")
        out = [nodes.literal_block(top, top, language="text")]
        for command in commands:
            section = nodes.section(ids=[f"pmabayes-{command}"])
            section += nodes.title(text=f"pmabayes {command}")
            text = _cli_help([command])
            section += nodes.literal_block(text, text, language="text")
            out.append(section)
        return out


def _inline(text: str) -> list[nodes.Node]:
    """Text with ``code`` between backticks, as nodes."""
    return [nodes.literal(text=part) if i % 2 else nodes.Text(part)
            for i, part in enumerate(text.split("`")) if part]


class SidecarKeys(SphinxDirective):
    """``sidecar-keys``: the sidecar reference, generated from the code that reads the
    sidecar: :data:`pmabayes.data.keys.SIDECAR_KEYS` (every key of
    :data:`pmabayes.data.METADATA_KEYS`) or, with the option ``:rig:``,
    :data:`pmabayes.data.rig.RIG_KEYS` (the keys of a ``"rig"``)."""

    has_content = False
    option_spec = {"rig": lambda arg: True}

    def run(self) -> list[nodes.Node]:
        from pmabayes.data.keys import SIDECAR_KEYS
        from pmabayes.data.rig import RIG_KEYS

        self.env.note_dependency(str(PACKAGE_DIR / "data" / "keys.py"))
        self.env.note_dependency(str(PACKAGE_DIR / "model" / "model.py"))
        keys = RIG_KEYS if "rig" in self.options else SIDECAR_KEYS
        header = ("key", "type", "unit", "default", "meaning", "explained in")
        table = nodes.table(classes=["pmabayes-sidecar"])
        group = nodes.tgroup(cols=len(header))
        table += group
        for width in (16, 14, 6, 14, 40, 10):
            group += nodes.colspec(colwidth=width)
        head = nodes.thead()
        group += head
        head += self._row([[nodes.Text(h)] for h in header])
        body = nodes.tbody()
        group += body
        for key, doc in keys.items():
            meaning = doc.meaning + (" Written by pmabayes, not declared." if doc.written
                                     else "")
            body += self._row([[nodes.literal(text=key)], _inline(doc.type),
                               _inline(doc.unit), _inline(doc.default), _inline(meaning),
                               [self._doc_ref(doc.page)]])
        return [table]

    @staticmethod
    def _row(cells: list[list[nodes.Node]]) -> nodes.row:
        row = nodes.row()
        for cell in cells:
            entry = nodes.entry()
            para = nodes.paragraph()
            para.extend(cell)
            entry += para
            row += entry
        return row

    @staticmethod
    def _doc_ref(page: str) -> nodes.Node:
        from sphinx.addnodes import pending_xref

        ref = pending_xref("", refdomain="std", reftype="doc", reftarget=f"/{page}",
                           refexplicit=False, refwarn=True)
        ref += nodes.inline(text=page)
        return ref


def setup(app):
    """Register the directives and the reference handler."""
    app.add_directive("layers-table", LayersTable)
    app.add_directive("sidecar-keys", SidecarKeys)
    app.add_directive("cli-help", CliHelp)
    app.connect("missing-reference", _resolve)
    app.connect("autodoc-process-docstring", _escape_bars)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
