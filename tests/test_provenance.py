"""``benchmarks/provenance/``: the host, CPU, commit and dirty flag every result JSON carries."""

from __future__ import annotations

import doctest
import json
import subprocess

import pytest

from benchmarks import provenance as prov


def test_the_module_examples_run():
    assert doctest.testmod(prov).failed == 0


def _git(tree, *args):
    subprocess.run(["git", "-C", str(tree), *args], check=True, capture_output=True)


@pytest.fixture
def tree(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "benchmarks" / "results").mkdir(parents=True)
    files = {"code.py": "x = 1\n", "docs/page.md": "a\n", "benchmarks/results/r.json": "{}\n"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", ".")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    return tmp_path


def test_the_commit_and_a_code_edit_make_the_record_and_docs_or_results_do_not(tree):
    head = subprocess.run(
        ["git", "-C", str(tree), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    record = prov.provenance(tree)
    assert record["commit"] == head[:12] and record["dirty"] is False
    (tree / "docs/page.md").write_text("b\n")  # what the benchmarks themselves rewrite
    (tree / "benchmarks/results/r.json").write_text('{"a": 1}\n')
    (tree / "new.py").write_text("untracked\n")
    assert prov.provenance(tree)["dirty"] is False
    (tree / "code.py").write_text("x = 2\n")
    assert prov.provenance(tree)["dirty"] is True


def test_outside_a_checkout_the_commit_is_unknown_not_invented(tmp_path):
    record = prov.provenance(tmp_path)
    assert (record["commit"], record["dirty"]) == ("?", None)
    assert prov.crossing([{"provenance": record}]) == "commit not recorded"


def test_the_host_id_is_a_salted_hash_not_the_machine_id(monkeypatch):
    host = prov.host_id()
    assert len(host) == 16 and int(host, 16) >= 0
    for path in ("/etc/machine-id", "/var/lib/dbus/machine-id"):
        try:
            machine = open(path).read().strip()
        except OSError:
            continue
        assert machine[:16] != host and host not in machine
    monkeypatch.setattr(prov, "cpu_model", lambda: "another CPU")
    assert prov.host_id() != host  # the same image on another CPU is another host


def test_write_json_stamps_dicts_and_wraps_lists(tmp_path):
    prov.write_json(tmp_path / "d.json", {"ms": 1.5})
    prov.write_json(tmp_path / "l.json", [{"ms": 1.5}], indent=2)
    d, rows = (json.loads((tmp_path / n).read_text()) for n in ("d.json", "l.json"))
    assert d["ms"] == 1.5 and d["provenance"]["host"] == prov.host_id()
    assert rows["rows"] == [{"ms": 1.5}] and set(rows["provenance"]) == set(d["provenance"])
