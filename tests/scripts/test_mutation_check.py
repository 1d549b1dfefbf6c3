"""The mutation check's machinery, on a tiny project of its own: a mutation is applied in
a scratch copy (never in the tree), the copy's code is what the tests import, and caught,
survived and stale mutations are reported as such."""

from __future__ import annotations

import json

import pytest

SOURCE = "LIMIT = 10\n\n\ndef over(x):\n    return x > LIMIT  # the threshold\n"
TEST = ("from pkg.rules import over\n\n\ndef test_limit():\n    assert over(11) and not over(10)\n"
        "\n\ndef test_big():\n    assert over(100)\n")


@pytest.fixture
def project(tmp_path):
    root = tmp_path / "project"
    (root / "pkg").mkdir(parents=True)
    (root / "pkg" / "__init__.py").write_text("")
    (root / "pkg" / "rules.py").write_text(SOURCE)
    (root / "tests").mkdir()
    (root / "tests" / "test_rules.py").write_text(TEST)
    return root


def test_mutations_are_caught_survive_or_are_stale_in_a_scratch_copy(project, script_module,
                                                                     tmp_path, capsys):
    check = script_module("bench/mutation_check")
    m = check.Mutation
    mutations = (
        m("limit", "pkg/rules.py", "LIMIT = 10", "LIMIT = 11", ("tests/test_rules.py",)),
        m("comment", "pkg/rules.py", "# the threshold", "# a threshold", ("tests/test_rules.py",)),
        m("stale", "pkg/rules.py", "LIMIT = 12", "LIMIT = 13", ("tests/test_rules.py",)),
    )
    out = tmp_path / "out.json"
    assert check.main(["--root", str(project), "--json", str(out), "--no-baseline"],
                      mutations) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:2] == ["limit", "caught"]
    assert lines[0].split()[-1] == "tests/test_rules.py::test_limit"
    assert lines[1].split()[:2] == ["comment", "survived"]
    assert lines[2].split()[:2] == ["stale", "error"] and "occurs 0 times" in lines[2]
    assert lines[3] == "3 mutations: 1 caught, 1 survived, 0 timed out, 1 errors"
    data = json.loads(out.read_text())
    assert [o["result"] for o in data["mutations"]] == ["caught", "survived", "error"]
    assert (project / "pkg" / "rules.py").read_text() == SOURCE  # the tree is untouched
    assert not list(project.rglob("__pycache__"))  # nothing ran in the tree


def test_a_failing_baseline_and_bad_arguments_exit_2(project, script_module, capsys):
    check = script_module("bench/mutation_check")
    (project / "tests" / "test_rules.py").write_text(TEST.replace("over(100)", "over(1)"))
    mutation = check.Mutation("limit", "pkg/rules.py", "LIMIT = 10", "LIMIT = 11",
                              ("tests/test_rules.py",))
    assert check.main(["--root", str(project)], (mutation,)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "test_big" in err
    assert check.main(["--only", "nonsense"]) == 2
    assert capsys.readouterr().err == ("mutation_check: unknown mutation 'nonsense'; --list "
                                       "shows the names\n")
    assert check.main(["--timeout", "-1"]) == 2
    assert "--timeout must be > 0, got -1.0" in capsys.readouterr().err


def test_every_listed_mutation_applies_to_the_tree(script_module, capsys):
    """Each mutation's text occurs exactly once in its file, and names are unique."""
    check = script_module("bench/mutation_check")
    names = [m.name for m in check.MUTATIONS]
    assert len(names) == len(set(names)) and len(names) >= 26
    for mutation in check.MUTATIONS:
        text = (check.ROOT / mutation.path).read_text()
        assert text.count(mutation.original) == 1, mutation.name
        assert mutation.replacement != mutation.original
    assert check.main(["--list"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == len(names)
