"""Release hygiene: the API reference builds without warnings, the version lives in one place,
the licence and the type marker ship."""

import re
import tomllib
from pathlib import Path

import pytest

import onlinemap
from onlinemap import docs

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # imports and documents every module
def test_api_reference_builds_without_warnings(tmp_path):
    out = docs.build(tmp_path / "api")  # raises RuntimeError listing pdoc's warnings, if any
    pages = {path.relative_to(out).as_posix() for path in out.rglob("*.html")}
    for page in ("index.html", "onlinemap.html", "onlinemap/estimators/rbpf.html", "onlinemap/belief.html",
                 "onlinemap/plots.html", "onlinemap/cli/common.html", "policies.html"):
        assert page in pages
    rbpf = (out / "onlinemap/estimators/rbpf.html").read_text()
    assert "Rao-Blackwellised" in rbpf  # the docstrings made it in


def test_version_lives_in_one_place_and_the_changelog_names_it():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "onlinemap._version.__version__"}
    newest = re.search(r"^## (\S+)", (ROOT / "CHANGELOG.md").read_text(), re.MULTILINE).group(1)
    assert newest == onlinemap.__version__


def test_licence_and_type_marker_ship():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["license"] == "MIT" and "MIT License" in (ROOT / "LICENSE").read_text()
    assert (ROOT / "onlinemap" / "py.typed").exists()
    assert "py.typed" in project["tool"]["setuptools"]["package-data"]["onlinemap"]
    assert any(dep.startswith("pdoc") for dep in project["project"]["optional-dependencies"]["test"])


def test_the_reference_without_pdoc_is_one_error_line(monkeypatch, tmp_path, capsys):
    """Issue 24 item 12: after the base install, ``python -m onlinemap.docs`` ended in a traceback."""
    import sys
    monkeypatch.setitem(sys.modules, "pdoc", None)  # import pdoc now raises ImportError
    assert docs.main(["--out", str(tmp_path / "api")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("onlinemap.docs: error: ") and "pip install pdoc" in err[0]
