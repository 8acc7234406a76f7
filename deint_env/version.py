"""The installed distribution's version, in a module of its own: the modules `deint_env/__init__.py`
imports (the runner, through `deint_env.evaluate`) read it without importing the package back."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("deint-bench")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0+unknown"
