"""Module paths that a run's ``config.yml`` may name from before the package layout of today.

nerfstudio saves a run's config with PyYAML python tags that spell each class's module path
(``!!python/object:stealth_ns.pipeline.StealthPipelineConfig``). Runs written before the modules
moved into packages name the old paths; :data:`MOVED` maps each such module to where it lives now.
:func:`current_name` translates a dotted name, and :func:`install` lets ``import`` (nerfstudio's own
YAML loader in ``ns-eval``, ``ns-viewer``, ``ns-render``) find an old path as the module of today.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
from types import ModuleType

MOVED: dict[str, str] = {
    "stealth_ns.pipeline": "stealth_ns.method.pipeline",
    "stealth_ns.model": "stealth_ns.method.model",
    "stealth_ns.datamanager": "stealth_ns.method.datamanager",
    "stealth_ns.trainer": "stealth_ns.method.trainer",
    "stealth_ns.optimizers": "stealth_ns.method.optimizers",
    "stealth_ns.schedulers": "stealth_ns.method.schedulers",
}
"""Old module path -> today's, for every module whose classes a saved ``config.yml`` names."""


def current_name(dotted: str) -> str:
    """``dotted`` (a module, or ``module.attribute``) with an old module path replaced by today's."""
    for old, new in MOVED.items():
        if dotted == old or dotted.startswith(old + "."):
            return new + dotted[len(old) :]
    return dotted


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old module path as the module of today (the same object under both names)."""

    def find_spec(self, fullname: str, path: object = None, target: object = None):  # noqa: ANN201
        if fullname not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        return importlib.import_module(MOVED[spec.name])

    def exec_module(self, module: ModuleType) -> None:
        """The module of today is already executed."""


def install() -> None:
    """Let ``import`` resolve the old paths of :data:`MOVED` (once per process)."""
    if not any(isinstance(finder, _Alias) for finder in sys.meta_path):
        sys.meta_path.append(_Alias())
