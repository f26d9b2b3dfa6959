"""Run a program only as far as its options: argparse parses them, then it stops.

Usage: ``python tests/_options_only.py SCRIPT.py ARGS...`` or
``python tests/_options_only.py -m MODULE ARGS...``. Exits 0 when the program's
``ArgumentParser.parse_args`` accepted the arguments, with argparse's own status and
message (2) when it did not, and 3 when the program ended without parsing any (a
program this check cannot stop, which must not be marked ``# ci: options only``).
Used by ``tests/doc_commands.py`` for the docs' long commands.
"""

from __future__ import annotations

import argparse
import runpy
import sys

_parse_args = argparse.ArgumentParser.parse_args


def _parse_and_stop(self, args=None, namespace=None):
    _parse_args(self, args, namespace)
    print(f"options accepted: {' '.join(sys.argv[1:])}")
    raise SystemExit(0)


def main() -> None:
    """Run the program named by ``sys.argv`` with ``parse_args`` stopping it."""
    argparse.ArgumentParser.parse_args = _parse_and_stop
    if sys.argv[1] == "-m":
        module = sys.argv[2]
        sys.argv = [module, *sys.argv[3:]]
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    else:
        script = sys.argv[1]
        sys.argv = sys.argv[1:]
        sys.path.insert(0, str(__import__("pathlib").Path(script).resolve().parent))
        runpy.run_path(script, run_name="__main__")
    print("the program ended without parsing its options", file=sys.stderr)
    raise SystemExit(3)


if __name__ == "__main__":
    main()
