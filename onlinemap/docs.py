"""Build the API reference (HTML, from the docstrings) with pdoc:

    python -m onlinemap.docs [--out docs/api]

Every public module of ``onlinemap`` and ``policies`` is documented; any warning pdoc gives (an
annotation it cannot resolve, a module that fails to import, ...) is an error, so the reference
builds cleanly or not at all (``tests/test_release.py`` checks it). Needs pdoc, the ``docs``
extra (``pip install -e '.[docs]'`` in a clone); without it, one error line and exit status 2.
"""

from __future__ import annotations

import argparse
import inspect
import sys
import typing
import warnings
from pathlib import Path

MODULES = ("onlinemap", "policies")
DEFAULT_OUT = Path("docs") / "api"


def _resolve_named_tuples(module_names) -> None:
    """Give every NamedTuple constructor its fields' resolved annotations: with ``from __future__
    import annotations`` they are strings that pdoc would evaluate in the generated constructor's
    namespace, where names such as ``np`` do not exist."""
    for name in module_names:
        module = sys.modules[name]
        for value in vars(module).values():
            if inspect.isclass(value) and issubclass(value, tuple) and hasattr(value, "_fields") \
                    and value.__module__ == name:
                value.__new__.__annotations__ = typing.get_type_hints(value)


def documented_modules() -> list[str]:
    """Every module of :data:`MODULES`, subpackages included, but ``__main__`` and the modules
    that only say where they moved (a package's ``MOVED``) (imported)."""
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


def build(out: Path = DEFAULT_OUT) -> Path:
    """Write the HTML reference into ``out``; raise ``RuntimeError`` listing pdoc's warnings, if any.
    Cost: imports every module (a few seconds)."""
    import pdoc
    import pdoc.extract

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        names = documented_modules()
        _resolve_named_tuples(names)
        specs, covered = [], set()
        for name in names:  # a package's spec covers the submodules in its __all__: name the others
            if name not in covered:
                specs.append(name)
                covered.update(pdoc.extract.walk_specs([name]))
        pdoc.render.configure(docformat="markdown", footer_text="onlinemap API reference")
        pdoc.pdoc(*specs, output_directory=Path(out))
    problems = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
    if problems:
        raise RuntimeError("the API reference built with warnings:\n" + "\n".join(problems))
    return Path(out)



def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m onlinemap.docs", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    args = parser.parse_args(argv)
    try:
        path = build(args.out)
    except RuntimeError as error:
        print(f"onlinemap.docs: error: {error}", file=sys.stderr)
        return 1
    except ImportError as error:  # the docs extra is not installed
        print(f"onlinemap.docs: error: {error}; install it with: pip install pdoc (in a clone: pip install "
              f"-e '.[docs]')", file=sys.stderr)
        return 2
    print(f"wrote {path / 'index.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
