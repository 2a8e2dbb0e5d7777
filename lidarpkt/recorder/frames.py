"""Frames while recording: ``record --points`` and ``record --view``, decoded off the receive path.

:class:`LiveFrames` gets the batches the recorder has just written (:meth:`LiveFrames.offer`
never waits) and decodes them in a :class:`lidarpkt.pipeline.live.FrameTap` thread. Each frame
then goes, as chosen, to

* ``--points``: ``sensor_msgs/PointCloud2`` per return slot (:mod:`lidarpkt.writers.mcap.pointcloud`)
  in each sensor's frame (``--frame-id``), and its mount on ``--base-frame`` on ``/tf_static``
  (:class:`lidarpkt.writers.mcap.frames.SensorFrames`, as ``decode`` writes them),
  encoded in the decoding thread and written by the recorder's loop
  (:meth:`LiveFrames.write_points`: the MCAP writer is used from one thread only); log time =
  host receive time of the last packet of the batch that completed the frame;
* ``--view``: the Foxglove server (:class:`lidarpkt.view.server.ViewServer`), through a :class:`lidarpkt.view.tap.FrameDropper` that
  drops frames for the viewer (counted) when publishing falls behind.

If decoding falls behind, batches are dropped for the frames (counted in the summary as
``packets_not_decoded``); the packets themselves are already in the file.
"""

from __future__ import annotations

import queue
import time

from lidarpkt.containers import rosmsgs



class LiveFrames:
    """Off-path frame decoding for points and view (see the module doc).

    Args:
        metadata: the sensor files of the sensors (list, possibly empty), as ``lidarpkt.open`` takes them.
        points: encode PointCloud2 messages for the MCAP.
        view: a started view server (:class:`~lidarpkt.view.server.ViewServer`), ``None`` for no view;
            closed with this object.
        queue_bytes: payload bytes allowed to wait for decoding (beyond: dropped for the frames, counted).
        sensors: the frame ids and mounts (:class:`~lidarpkt.writers.mcap.frames.SensorFrames`);
            default: the vendors' frame ids, no ``/tf_static``.
        decoder_options: the decoders' other options (``model``), as ``lidarpkt.open`` takes them.
    """

    def __init__(self, metadata: list, *, points: bool, view=None, queue_bytes: int = 64 << 20,
                 sensors=None, decoder_options: dict | None = None) -> None:
        from lidarpkt.pipeline.live import FrameTap, LiveDecoder
        from lidarpkt.view.tap import FrameDropper
        from lidarpkt.writers.mcap.frames import FrameTopics, SensorFrames

        self.sensors = sensors or SensorFrames()

        self.view, self.dropper = view, None
        self._last_status = time.monotonic()
        self.points_frames = 0
        self._points: queue.SimpleQueue = queue.SimpleQueue()
        self._topics = FrameTopics(_QueuedMessages(self._points), ("points",), self.sensors)
        consumers = []
        if points:
            consumers.append(self._encode_points)
        if view is not None:
            def dropped(n: int) -> None:
                view.frames_dropped = n

            self.dropper = FrameDropper(view.publish, on_drop=dropped)
            consumers.append(self.dropper)
        on_batch = (lambda b: view.count_packets(str(b.src), len(b))) if self.view is not None else None
        self.tap = FrameTap(LiveDecoder(metadata, **(decoder_options or {})), consumers, on_batch=on_batch,
                            queue_bytes=queue_bytes)

    def _encode_points(self, frame) -> None:  # runs in the tap's thread
        # decode's own frames → messages (FrameTopics: each new sensor's latched mount, then its clouds),
        # encoded here and queued for the recorder's thread, which owns the MCAP writer
        self._topics.write(frame, self.tap.host_time_ns)
        self.points_frames += 1

    def offer(self, batches: list) -> None:
        """Hand the batches just written over for decoding; never waits."""
        self.tap.offer(batches)

    def write_points(self, writer) -> None:
        """Write the point clouds encoded so far (call from the thread that owns ``writer``)."""
        while True:
            try:
                topic, data, t, latch_key = self._points.get_nowait()
            except queue.Empty:
                return
            if latch_key is not None:
                writer.write_latched(topic, data, t, key=latch_key)
            else:
                writer.write(topic, data, t)

    def tick(self, lost_packets: int) -> None:
        """Publish the view's status once a second (call often); ``lost_packets`` = the recorder's count."""
        now = time.monotonic()
        if self.view is not None and now - self._last_status >= 1.0:
            self._last_status = now
            self.view.publish_status(lost_packets)

    def finish(self, writer) -> None:
        """Decode what is queued and the last partial frames; write their points; publish the last frames."""
        self.tap.close()
        if self.dropper is not None:
            self.dropper.close()
        self.write_points(writer)

    def close(self) -> None:
        """Stop the threads and the view server. Idempotent."""
        self.tap.close()
        if self.dropper is not None:
            self.dropper.close()
        if self.view is not None:
            self.view.close()

    def summary(self) -> dict:
        """Counts for the recorder's summary."""
        error = self.tap.error or (self.dropper.error if self.dropper is not None else None)
        return {
            "frames_decoded": self.tap.frames,
            "points_frames_written": self.points_frames,
            "view_frames_dropped": self.dropper.dropped if self.dropper is not None else 0,
            "packets_not_decoded": self.tap.dropped_packets,
            "frames_error": str(error) if error is not None else None,
        }


class _QueuedMessages:
    """What :class:`~lidarpkt.writers.mcap.frames.FrameTopics` writes to, as an MCAP writer would take it:
    encoded here, queued as ``(topic, data, log time, latch key or None)`` for :meth:`LiveFrames.write_points`."""

    def __init__(self, out: queue.SimpleQueue) -> None:
        self.out = out

    def write_message(self, topic, message, log_time_ns: int) -> None:
        self.out.put((topic, rosmsgs.encode(topic.msgtype, message), log_time_ns, None))

    def write_latched(self, topic, data: bytes, log_time_ns: int, *, key: str = "") -> None:
        self.out.put((topic, data, log_time_ns, key))
