"""Packages whose public names are imported on first use (PEP 562), so that a command imports only
the modules it needs: ``lidarpkt info`` reads ``lidarpkt.vendors.velodyne.detect`` and
``lidarpkt.vendors.ouster.detect``, not the frame assembly, encoders or XYZ beside them."""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable


def lazy_names(package: str, names: dict[str, str], public: list[str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package``.

    Args:
        package: the package's ``__name__``.
        names: public name -> the submodule (relative name) that defines it.
        public: the package's ``__all__``.

    ``__getattr__`` imports the submodule of a public name, keeps the value in the package, and
    also gives the package's submodules (``lidarpkt.vendors.ouster.frames``) not imported yet; any other
    name raises AttributeError.
    """

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            try:
                return importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{package}.{name}":
                    raise
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(public))

    return __getattr__, __dir__
