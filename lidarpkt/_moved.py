"""Old import paths of modules that moved (issue 18), kept working for scripts outside the repository.

The writers moved to :mod:`lidarpkt.writers`. Rather than a re-export file at each old path (a
second module object, whose private names and module state would differ from the new one's), this
finder resolves each old module name to the new module object itself, on first import: classes,
module state and monkeypatching are shared. Code inside the repository imports the new paths.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys

MOVED: dict[str, str] = {
    "lidarpkt.pcapwrite": "lidarpkt.writers.pcap",
    "recorder.mcap_writer": "lidarpkt.writers.mcap.writer",
    "recorder.schemas": "lidarpkt.writers.mcap.schemas",
    "recorder.pointcloud": "lidarpkt.writers.mcap.pointcloud",
}


class _MovedModuleFinder:
    """Finds an old module name in :data:`MOVED` and loads it as the module at its new name.

    A meta path finder and loader by protocol (``find_spec``, ``create_module``, ``exec_module``):
    not a subclass of ``importlib.abc``'s, whose import (importlib.resources, tempfile...) every
    command's start-up would pay."""

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
