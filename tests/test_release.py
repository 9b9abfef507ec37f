"""Release hygiene: the docs site builds without warnings, the version lives in one place,
the licence and the type marker ship."""

import re
import tomllib
from pathlib import Path

import pytest

import onlinemap
from onlinemap import docs

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # imports every module, renders the notebooks and every module's page
def test_docs_site_builds_strictly(tmp_path):
    """The site builds with ``mkdocs build --strict`` (any warning, e.g. a broken link, raises
    DocsError) and holds the guide, the notebooks with their stored outputs and the reference."""
    out = docs.build(tmp_path / "site")
    pages = {path.relative_to(out).as_posix() for path in out.rglob("index.html")}
    for page in ("index.html", "guide/model/index.html", "guide/estimators/index.html", "results/index.html",
                 "references/index.html", "notebooks/corridor_em_failure/index.html",
                 "api/onlinemap/estimators/rbpf/index.html", "api/policies/index.html"):
        assert page in pages
    assert "Rao-Blackwellised" in (out / "api/onlinemap/estimators/rbpf/index.html").read_text()  # docstrings
    notebook = (out / "notebooks/corridor_em_failure/index.html").read_text()
    assert "data:image/png;base64," in notebook  # the stored figures, not a re-execution


def test_the_docs_build_fails_on_a_broken_link(tmp_path, monkeypatch):
    """Strict mode is on: a page linking to a missing page makes the build raise, naming it."""
    pages = tmp_path / "pages"
    pages.mkdir()
    (pages / "index.md").write_text("# Home\n\n[gone](missing.md)\n")
    monkeypatch.setattr(docs, "PAGES", pages)
    monkeypatch.setattr(docs, "documented_modules", lambda: ["onlinemap.errors"])
    config = docs.CONFIG.read_text().split("\nnav:")[0] + "\nnav:\n  - Home: index.md\n  - API reference\n"
    (tmp_path / "mkdocs.yml").write_text(config)
    monkeypatch.setattr(docs, "CONFIG", tmp_path / "mkdocs.yml")
    monkeypatch.setattr(docs, "NOTEBOOKS", tmp_path / "no-notebooks")
    (tmp_path / "no-notebooks").mkdir()
    with pytest.raises(docs.DocsError, match="missing.md"):
        docs.build(tmp_path / "site")
    assert not (tmp_path / "site").exists()


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
    extras = project["project"]["optional-dependencies"]
    for tool in ("mkdocs-material", "mkdocstrings[python]", "mkdocs-jupyter"):  # the suite builds the site
        assert any(dep.startswith(tool) for dep in extras["test"]) and any(dep.startswith(tool) for dep in extras["docs"])


def test_the_site_without_mkdocs_is_one_error_line(monkeypatch, tmp_path, capsys):
    """After the base install, ``python -m onlinemap.docs`` says what to install, in one line."""
    import sys

    from onlinemap.docs.__main__ import main
    monkeypatch.setitem(sys.modules, "mkdocs.commands.build", None)  # importing it now raises ImportError
    assert main(["--out", str(tmp_path / "site")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("onlinemap.docs: error: ") and "pip install -e '.[docs]'" in err[0]


def test_the_sites_hook_drops_sphinx_roles_from_rendered_docstrings():
    from onlinemap.docs.hooks import on_page_content
    html = "see :func:<code>~policies.navigation.check_goal</code>, :class:<code>Belief</code> and <code>:x:</code>"
    assert on_page_content(html) == "see <code>check_goal</code>, <code>Belief</code> and <code>:x:</code>"
