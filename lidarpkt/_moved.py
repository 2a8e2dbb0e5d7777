"""Old import paths of modules that moved, kept working without a file at the old path.

The writers moved to :mod:`lidarpkt.writers` (issue 18). A re-export file left at each old path
would stop git from seeing the moves as renames (a merge pairs a deleted path with an added
one), so edits made elsewhere to the old files would conflict instead of following them. This
finder instead resolves each old module name to the new module object itself (one module, not a
copy: classes and module state are shared), on first import.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

MOVED: dict[str, str] = {
    "lidarpkt.pcapwrite": "lidarpkt.writers.pcap",
    "recorder.mcap_writer": "lidarpkt.writers.mcap.writer",
    "recorder.schemas": "lidarpkt.writers.mcap.schemas",
    "recorder.pointcloud": "lidarpkt.writers.mcap.pointcloud",
}


class _MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old module name in :data:`MOVED` and loads it as the module at its new name."""

    def find_spec(self, fullname, path=None, target=None):  # noqa: D102 - importlib protocol
        if fullname not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):  # noqa: D102
        module = importlib.import_module(MOVED[spec.name])
        self._real_spec = module.__spec__
        return module

    def exec_module(self, module) -> None:  # noqa: D102
        # the import machinery stamped the alias spec on the real module: give it back its own
        module.__spec__ = self._real_spec


def install() -> None:
    """Put the finder on ``sys.meta_path`` once (idempotent)."""
    if not any(isinstance(f, _MovedModuleFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedModuleFinder())
