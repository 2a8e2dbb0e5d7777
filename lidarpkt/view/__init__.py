"""The Foxglove live view: frames in, Foxglove messages out, over foxglove-sdk's WebSocket server.

* :mod:`lidarpkt.view.messages` — frames as ``foxglove.PointCloud`` / ``RawImage`` / ``FrameTransform``;
* :mod:`lidarpkt.view.server` — :class:`ViewServer`, the channels of each sensor;
* :mod:`lidarpkt.view.sources` — a capture at its own pace (live packets become frames in
  :mod:`lidarpkt.pipeline.live`);
* :mod:`lidarpkt.view.tap` — frames dropped for a viewer that falls behind;
* :mod:`lidarpkt.cli.view` — the ``lidarpkt view`` verb.

Needs the ``view`` extra (``pip install 'lidarpkt[view]'``, foxglove-sdk); importing this
package does not import foxglove-sdk.
"""

from __future__ import annotations

__all__ = ["ViewServer", "play_capture"]


def __getattr__(name: str):
    if name == "ViewServer":
        from .server import ViewServer

        return ViewServer
    if name == "play_capture":
        from .sources import play_capture

        return play_capture
    raise AttributeError(name)
