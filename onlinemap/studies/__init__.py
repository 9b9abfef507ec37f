"""The studies: every experiment that a table, figure, notebook or the CLI reports, one module
per family, each a sweep spec run on the engine (:mod:`onlinemap.sweeps`: dask, resume, parquet
and provenance for free) and summarised one way (:mod:`.base`: intervals over seeds).

- :mod:`.corridor`: the literature's corridor (DESIGN.md section 5.1): Murphy's scripted run
  and random corridors;
- :mod:`.accuracy`: approximate estimators against exact Bayes (section 5.2; ``onlinemap compare``);
- :mod:`.mapping`: the EM-mapping claims (loop, annealing, blocking walls);
- :mod:`.exploration`: planners exploring (the paper's world, blocking walls, buildings, replays);
- :mod:`.navigation`: goal planners through changing doors, against the oracle;
- :mod:`.floors`: real floors read from files and generated buildings, with the told-location anchor;
- :mod:`.hindsight`: flat against layered EM on recorded runs in 32 x 32 floors (issue 41);

Modules load on first use (``onlinemap.studies.exploration`` imports ``policies``).
The layer sits above the engine and ``policies``; nothing below imports it.
"""

from __future__ import annotations

import importlib

MODULES = ("base", "corridor", "accuracy", "mapping", "exploration", "navigation", "floors", "hindsight")


def __getattr__(name: str):
    if name not in MODULES:
        raise AttributeError(f"module 'onlinemap.studies' has no attribute {name!r}")
    return importlib.import_module(f".{name}", __name__)
