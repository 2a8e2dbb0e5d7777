"""The Foxglove live view: frames in, Foxglove messages out, over foxglove-sdk's WebSocket server.

* :mod:`lidarpkt.view.messages` — frames as ``foxglove.PointCloud`` / ``RawImage`` / ``FrameTransform``;
* :mod:`lidarpkt.view.server` — :class:`ViewServer`, the channels of each sensor;
* :mod:`lidarpkt.view.sources` — a capture at its own pace, live batches to frames;
* :mod:`lidarpkt.view.tap` — decoding off the recorder's receive path;
* :mod:`lidarpkt.cli.view` — the ``lidarpkt view`` verb.

Needs the ``view`` extra (``pip install 'lidarpkt[view]'``, foxglove-sdk); importing this
package does not import foxglove-sdk.
"""

from __future__ import annotations

__all__ = ["ViewServer", "play_capture", "LiveDecoder"]


def __getattr__(name: str):
    if name == "ViewServer":
        from .server import ViewServer

        return ViewServer
    if name in ("play_capture", "LiveDecoder"):
        from . import sources

        return getattr(sources, name)
    raise AttributeError(name)
