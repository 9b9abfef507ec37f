"""The documentation site: the user guide, the notebooks with their stored outputs and the API
reference from the docstrings, built by MkDocs (Material theme, mkdocstrings, mkdocs-jupyter):

    python -m onlinemap.docs [--out site]

The site's sources live in this package (``pages/`` and ``mkdocs.yml``) rather than at the top of
the repository, whose layout is fixed. :func:`assemble` lays them out in a temporary folder: the
pages, the notebooks copied from the clone's ``notebooks/`` (rendered as stored, never executed),
one API page per public module of ``onlinemap`` and ``policies``, and the configuration with its
navigation completed; :func:`build` runs ``mkdocs build --strict`` on it, so any warning (a broken
link, a page missing from the navigation, a docstring mkdocstrings cannot read) is an error.
Needs the ``docs`` extra (``pip install -e '.[docs]'`` in a clone); without it, one error line
and exit status 2.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
PAGES = HERE / "pages"
CONFIG = HERE / "mkdocs.yml"
ROOT = HERE.parents[1]  # the clone: the notebooks live in its notebooks/ folder
NOTEBOOKS = ROOT / "notebooks"
MODULES = ("onlinemap", "policies")
DEFAULT_OUT = Path("site")
REQUIREMENTS = "mkdocs-material, mkdocstrings[python] and mkdocs-jupyter"


class DocsError(RuntimeError):
    """The site did not build cleanly (the message lists MkDocs' warnings and errors)."""


def documented_modules() -> list[str]:
    """Every module of :data:`MODULES`, subpackages included, but ``__main__`` and the modules
    that only say where they moved (a package's ``MOVED``) (imported, so that a module that
    fails to import fails here, not as a blank page)."""
    import importlib
    import pkgutil
    names = []
    for top in MODULES:
        package = importlib.import_module(top)
        moved = {f"{top}.{name}" for name in getattr(package, "MOVED", {})}
        names.append(top)
        names += [info.name for info in pkgutil.walk_packages(package.__path__, f"{top}.")
                  if not info.name.endswith("__main__") and info.name not in moved]
    for name in names:
        importlib.import_module(name)
    return names


def _api_pages(docs: Path, names: list[str]) -> list:
    """Write one page per module under ``docs/api/`` and return their navigation: each package
    a section that opens with its face, its modules and subpackages inside it."""
    nav: list = []
    sections: dict[str, list] = {}
    for name in names:
        path = Path("api", *name.split(".")).with_suffix(".md")
        (docs / path).parent.mkdir(parents=True, exist_ok=True)
        (docs / path).write_text(f"# `{name}`\n\n::: {name}\n")
        entry: dict = {name: path.as_posix()}
        if any(other.startswith(name + ".") for other in names):  # a package: a section of its own
            sections[name] = [entry]
            entry = {name: sections[name]}
        sections.get(name.rpartition(".")[0], nav).append(entry)
    return nav


def assemble(site: Path) -> Path:
    """Lay out the site's sources in ``site`` (an empty folder): pages, notebooks, API pages and
    ``mkdocs.yml``; return the configuration's path. Cost: imports every module (a few seconds)."""
    import yaml

    shutil.copytree(PAGES, site / "docs", dirs_exist_ok=True)
    shutil.copy2(ROOT / "CHANGELOG.md", site / "docs" / "changelog.md")
    if not NOTEBOOKS.is_dir():
        raise DocsError(f"no notebooks/ folder beside the package ({NOTEBOOKS}): build the site in a clone")
    (site / "docs" / "notebooks").mkdir(exist_ok=True)
    for notebook in sorted(NOTEBOOKS.glob("*.ipynb")):
        shutil.copy2(notebook, site / "docs" / "notebooks" / notebook.name)
    config = yaml.safe_load(CONFIG.read_text())
    names = documented_modules()
    api = _api_pages(site / "docs", names)
    config["nav"] = [entry if entry != "API reference" else {"API reference": api} for entry in config["nav"]]
    config["docs_dir"] = "docs"
    config["hooks"] = [str(HERE / "hooks.py")]
    path = site / "mkdocs.yml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


class _Collect(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record):
        self.messages.append(f"{record.levelname}: {record.getMessage()}")


def build(out: Path = DEFAULT_OUT) -> Path:
    """Assemble the site in a temporary folder and build it into ``out`` with ``mkdocs build
    --strict``; return ``out``. Raise :class:`DocsError` listing every warning, if any (nothing
    is written to ``out`` then)."""
    from mkdocs.commands.build import build as mkdocs_build
    from mkdocs.config import load_config
    from mkdocs.exceptions import MkDocsException

    out = Path(out).resolve()
    collect = _Collect()
    logger = logging.getLogger("mkdocs")
    logger.addHandler(collect)
    try:
        with tempfile.TemporaryDirectory(prefix="onlinemap-docs-") as folder:
            staged = Path(folder) / "site"
            config = load_config(str(assemble(Path(folder))), strict=True, site_dir=str(staged))
            try:
                mkdocs_build(config)
            except MkDocsException as error:
                collect.messages.append(f"ERROR: {error}")
            if collect.messages:
                raise DocsError("the site built with warnings:\n" + "\n".join(collect.messages))
            if out.exists():
                shutil.rmtree(out)
            shutil.copytree(staged, out)
    finally:
        logger.removeHandler(collect)
    return out
