"""Old ways in still work: the old import path of the effects (for plugins written
against it) and ``pmabayes.__main__`` imported without running the command line.

Each check runs in a fresh interpreter, since an import runs its module once per
process and these tests are about what that first import does.
"""

from __future__ import annotations

import json
import subprocess
import sys

OLD_PLUGIN = '''
from pmabayes.effects import Effect, HalfNormal, Parameter, register_effect
from pmabayes.effects.base import Effect as BaseEffect

assert BaseEffect is Effect


def drag(q, x, v, p):
    return q[0] * v * abs(v), 0.0, 2.0 * q[0] * abs(v)


class OldPathDrag(Effect):
    name = "old_path_drag"
    stage = "force"
    parameters = (Parameter("c_old_path", "N s^2/m^2", 50.0, HalfNormal(200.0),
                            bounds=(0.0, 1e5), null=0.0, description="quadratic drag"),)
    description = "Drag growing with the square of the velocity."
    physics = staticmethod(drag)


register_effect(OldPathDrag)
'''

CHECK_OLD_PATH = '''
import json, sys, warnings

with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    from pmabayes.model.effects import get_effect, load_plugin
    import pmabayes.model.effects as new

    plugin = load_plugin(sys.argv[1])  # the first import of the old path
    import pmabayes.effects as old
    from pmabayes.effects import register_effect
    from pmabayes.effects.registry import get_effect as old_get_effect
    import pmabayes.model.parameters as parameters

same = ([name for name in new.__all__ if getattr(old, name) is not getattr(new, name)]
        + [name for name in ("Parameter", "HalfNormal") if getattr(old, name)
           is not getattr(parameters, name)])
print(json.dumps({
    "warnings": [[w.category.__name__, str(w.message), w.filename] for w in caught
                 if issubclass(w.category, FutureWarning)],
    "not_same": same,
    "all": old.__all__ == new.__all__,
    "registered": get_effect("old_path_drag") is plugin.OldPathDrag,
    "one_registry": register_effect is new.register_effect
                    and old_get_effect is get_effect and old.base is new.base,
}))
'''


def test_the_old_effects_path_loads_a_plugin_and_warns_once(tmp_path):
    plugin = tmp_path / "old_path_plugin.py"
    plugin.write_text(OLD_PLUGIN)
    out = subprocess.run([sys.executable, "-c", CHECK_OLD_PATH, str(plugin)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["not_same"] == [] and got["all"]
    assert got["registered"] and got["one_registry"]
    [(category, message, filename)] = got["warnings"]  # once, though imported 4 times
    assert category == "FutureWarning"
    assert "import from pmabayes.model.effects instead" in message
    assert filename == str(plugin)  # the line to change, not the import machinery


def test_importing_main_runs_no_command():
    # the documentation's build imports every module, with sphinx-build's own argv
    code = ("import sys; sys.argv = ['sphinx-build', 'html']; import pmabayes.__main__; "
            "print('imported')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert (out.returncode, out.stdout, out.stderr) == (0, "imported\n", "")
    run = subprocess.run([sys.executable, "-m", "pmabayes", "--version"],
                         capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.startswith("pmabayes "), run.stderr
