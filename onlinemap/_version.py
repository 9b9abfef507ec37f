"""The package version, in one place (``pyproject.toml`` reads it; ``onlinemap.__version__``
re-exports it). A module of its own so that the modules that record it (checkpoints, tables,
benchmarks) need not import the package face. Imports: nothing."""

__version__ = "0.1.0"
