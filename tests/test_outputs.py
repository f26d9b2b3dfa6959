"""The rules of outputs below the command line (:mod:`pmabayes.outputs`), and the Python
API obeying them: it writes only where it is told, never over a file pmabayes did not
make, and checks the place before any work."""

from __future__ import annotations

import json

import pytest

import pmabayes as pb
from pmabayes import outputs
from pmabayes.outputs import OutputError
from pmabayes.synthetic import Chirp, HiddenDrag, generate_chirp_dataset


def test_a_file_is_written_over_only_when_it_is_pmabayes_own_of_that_kind(tmp_path):
    mine = tmp_path / "notes.json"
    mine.write_text('{"my": "notes"}')
    with pytest.raises(OutputError, match=r"--json .*notes.json: this file exists and is not "
                       r"the JSON output of `pmabayes track`.*Give a new name"):
        outputs.check_file(mine, "track", "--json")
    own = tmp_path / "track.json"
    outputs.write_json(own, {"x": 1}, "track")
    assert json.loads(own.read_text())["pmabayes"]["kind"] == "track"
    assert outputs.check_file(own, "track", "--json") == own
    with pytest.raises(OutputError, match="not the JSON output of `pmabayes batch`"):
        outputs.check_file(own, "batch", "--json")  # its own, but of another kind
    with pytest.raises(OutputError, match="is one of the command's inputs"):
        outputs.check_file(own, "track", "--json", inputs=[own])
    with pytest.raises(OutputError, match="this is a folder"):
        outputs.check_file(tmp_path, "track", "--json")
    assert mine.read_text() == '{"my": "notes"}'


def test_a_folder_is_new_empty_or_marked_as_the_same_kind(tmp_path):
    users = tmp_path / "users"
    users.mkdir()
    (users / "thesis.tex").write_text("keep")
    with pytest.raises(OutputError, match="holds files that `pmabayes report` did not write"):
        outputs.check_folder(users, "report")
    page = tmp_path / "page"
    written: list[str] = []
    with outputs.staged(page, "compare", written) as tmp:
        (tmp / "index.html").write_text("<html/>")
        (tmp / "figure.png").write_bytes(b"png")
    assert written == ["figure.png", "index.html"]  # the HTML last
    assert outputs.folder_kind(page) == "compare"
    assert outputs.check_folder(page, "compare") == page
    with pytest.raises(OutputError, match=r"\(it is the output of `pmabayes compare`\)"):
        outputs.check_folder(page, "validate")
    with pytest.raises(OutputError, match="this is a file, not a folder"):
        outputs.check_folder(users / "thesis.tex", "report")
    assert (users / "thesis.tex").read_text() == "keep"


def test_diagnose_checks_plugin_dir_before_any_work(tmp_path, monkeypatch):
    import pmabayes.criticism.diagnosis as diagnosis

    def work(*args, **kwargs):
        raise AssertionError("the diagnosis ran before plugin_dir was checked")

    monkeypatch.setattr(diagnosis, "_diagnose", work)
    ds = generate_chirp_dataset(n_trials=2, seed=0, chirp=Chirp(duration_s=1.0))
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    with pytest.raises(OutputError, match=r"plugin_dir .*afile: this is a file, not a folder"):
        pb.diagnose(ds, plugin_dir=afile)
    assert afile.read_text() == "keep me"


@pytest.fixture(scope="module")
def drag_problem():
    """A missing drag seen through the base model at its true values: a clear proposal."""
    from pmabayes.criticism.observed import simulate_states
    from pmabayes.inference.likelihood import Likelihood
    from pmabayes.inference.noise import group_noise

    ds = generate_chirp_dataset(n_trials=4, seed=32,
                                chirp=Chirp(duration_s=3.0, f0_hz=0.3, f1_hz=3.0),
                                effects={HiddenDrag: {"c_hidden": 300.0}})
    model = pb.Model()
    lik = Likelihood(model, ds)
    noise, _ = group_noise([lik], "auto")
    values = dict(model.defaults)
    sim, _ = simulate_states(lik, model, values, None, 1)
    return lik, noise, values, sim


def test_the_proposal_is_written_only_where_told(drag_problem, tmp_path, monkeypatch):
    from pmabayes.criticism.discrepancy import estimate_discrepancy

    here = tmp_path / "current"
    here.mkdir()
    monkeypatch.chdir(here)
    found = estimate_discrepancy(*drag_problem, verify=False)  # no plugin_dir: not kept
    assert found.proposal is not None, found.text
    assert found.proposal.plugin is None and list(here.iterdir()) == []
    kept = tmp_path / "kept"
    found = estimate_discrepancy(*drag_problem, verify=False, plugin_dir=kept)
    assert found.proposal.plugin is not None
    assert [p.name for p in kept.iterdir()] == [f"{found.proposal.effect}.py"]
    assert list(here.iterdir()) == []
    with pytest.raises(OutputError, match="plugin_dir .*: this is a file, not a folder"):
        estimate_discrepancy(*drag_problem, verify=False, plugin_dir=found.proposal.plugin)
