"""Old import paths of modules that moved into the layer folders (docs/architecture.md §1).

A user's script that says ``import sssbench.runner`` or ``from sssbench.report import ...``
keeps working: the old dotted name is an alias of the module at its new place (the same
module object, so monkeypatching either name patches both), and the import warns once with a
:class:`FutureWarning` naming the new path. New code uses the new paths.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from types import ModuleType

__all__ = ["MOVED", "install"]

#: old dotted name -> new dotted name
MOVED = {
    "sssbench.pipeline": "sssbench.ops.pipeline",
    "sssbench.metrics": "sssbench.score.metrics",
    "sssbench.verdict": "sssbench.score.verdict",
    "sssbench.budget": "sssbench.score.budget",
    "sssbench.previews": "sssbench.score.previews",
    "sssbench.tracking": "sssbench.store.tracking",
    "sssbench.mlflow_mirror": "sssbench.store.mlflow_mirror",
    "sssbench.refcache": "sssbench.store.refcache",
    "sssbench.kernels.optimise": "sssbench.tune.optimise",
    "sssbench.spec": "sssbench.run.spec",
    "sssbench.registry": "sssbench.run.registry",
    "sssbench.runner": "sssbench.run.runner",
    "sssbench.warm": "sssbench.run.warm",
    "sssbench.runmemo": "sssbench.run.runmemo",
    "sssbench.html_report": "sssbench.report.html",
}


class _Alias(importlib.abc.Loader):
    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(
            f"{spec.name} moved to {self.new} (docs/architecture.md); the old path is an alias",
            FutureWarning,
            stacklevel=2,
        )
        return importlib.import_module(self.new)

    def exec_module(self, module: ModuleType) -> None:  # the new module is already executed
        return None


class _MovedFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: object = None, target: object = None):
        new = MOVED.get(fullname)
        if new is None:
            return None
        return importlib.util.spec_from_loader(fullname, _Alias(new))


def install() -> None:
    """Put the alias finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())
