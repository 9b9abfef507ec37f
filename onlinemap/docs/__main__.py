"""``python -m onlinemap.docs [--out DIR]``: build the documentation site (see :mod:`onlinemap.docs`)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from onlinemap.docs import DEFAULT_OUT, REQUIREMENTS, DocsError, build


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m onlinemap.docs",
                                     description="Build the documentation site (MkDocs, strict: any warning fails).")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    try:
        path = build(args.out)
    except DocsError as error:
        print(f"onlinemap.docs: error: {error}", file=sys.stderr)
        return 1
    except ImportError as error:  # the docs extra is not installed
        print(f"onlinemap.docs: error: {error}; install {REQUIREMENTS} (in a clone: pip install -e '.[docs]')",
              file=sys.stderr)
        return 2
    print(f"wrote {path / 'index.html'} in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
