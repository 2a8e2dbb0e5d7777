"""Compatibility name: the reassembler lives in :mod:`lidarpkt.sources.reassembly`."""

from .sources.reassembly import *  # noqa: F401,F403
from .sources.reassembly import __all__  # noqa: F401
