"""Recording a live sensor (and a serial GPS) to MCAP without losing a packet.

The live packet source (:mod:`lidarpkt.containers.udp`) reads the sockets in its thread; :func:`record`
polls it, writes the packets through :class:`lidarpkt.writers.mcap.packets.PacketSink`, counts loss, and
says what it sees through its callbacks (a status once a second, notices when the sensor falls silent or
comes back). It stops when ``should_stop`` says why, after ``duration_s`` or ``max_frames``, and closes the file
with its summary and index. Killed outright, it leaves a file readable up to its last complete chunk
(``chunk_seconds``).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from lidarpkt.containers import rosmsgs
from lidarpkt.containers.udp import UdpSource
from lidarpkt.core.checks import Number
from lidarpkt.errors import LidarpktError, UsageError
from lidarpkt.vendors import registry
from lidarpkt.writers.mcap import schemas
from lidarpkt.writers.mcap.packets import PacketSink
from lidarpkt.writers.mcap.writer import McapWriter

__all__ = ["Recording", "RecordStatus", "record"]


@dataclass
class RecordStatus:
    """What a recording has done so far, given to ``on_status`` once a second.

    Attributes:
        seconds: since the recording started.
        packets_per_s: packets written per second since the last status.
        frames: complete rotations seen.
        lost_gaps: packets missing from the sensors' own counters.
        kernel_drops, queue_overflow: datagrams dropped by the kernel's buffer, and by the writer falling behind.
        lost_total: the larger of ``lost_gaps`` and the local drops (which leave gaps too).
        bytes_written: MCAP bytes written.
    """

    seconds: float
    packets_per_s: float
    frames: int
    lost_gaps: int
    kernel_drops: int
    queue_overflow: int
    lost_total: int
    bytes_written: int


@dataclass
class Recording:
    """What :func:`record` did: ``summary`` (JSON-ready: files, counts, loss, GPS, per stream; see
    :func:`record`) and ``report_lines``, the sink's lines on what it did not decode or could not place."""

    summary: dict[str, Any]
    report_lines: list[str] = field(default_factory=list)


#: what the numeric options of :func:`record` take (``None`` passes: no limit)
LIMITS = {
    "chunk_seconds": Number(0.01, 60, example="0.5"),
    "rotate_bytes": Number(100_000, whole=True, optional=True, example="512_000_000"),
    "rotate_seconds": Number(0.5, optional=True, example="60"),
    "duration_s": Number(0, low_open=True, optional=True, example="10"),
    "max_frames": Number(1, whole=True, optional=True, example="10"),
    "gps_baud": Number(50, 4_000_000, whole=True, example="9600"),
}


def _check_limits(**values: Any) -> None:
    for name, value in values.items():
        try:
            LIMITS[name].check(value, name)
        except UsageError as exc:
            raise UsageError(f"record(): {exc}") from None


def record(output: str | os.PathLike[str], *, ports: Sequence[int] = (), bind: str | None = None,
           multicast: str | None = None, interface: str | None = None, rcvbuf_bytes: int = 32 << 20,
           queue_bytes: int = 256 << 20, metadata: Sequence[Any] = (), decoder_options: dict[str, Any] | None = None,
           chunk_seconds: float = 0.5, rotate_bytes: int | None = None, rotate_seconds: float | None = None,
           gps: str | None = None, gps_baud: int = 9600, points: bool = False, sensors: Any = None,
           view: Callable[[], Any] | None = None, duration_s: float | None = None, max_frames: int | None = None,
           should_stop: Callable[[], str | None] | None = None, on_listening: Callable[[UdpSource], None] | None = None,
           on_status: Callable[[RecordStatus], None] | None = None,
           on_notice: Callable[[str], None] | None = None) -> Recording:
    """Record the UDP packets arriving on ``ports`` (and a serial GPS) to the MCAP file ``output``.

    Args:
        output: the MCAP file (``OUT_0000.mcap``, ``OUT_0001.mcap`` ... with ``rotate_*``).
        ports: UDP ports to listen on; empty: the ports the sensor files of ``metadata`` name.
        bind, multicast, interface: the local address (default all), an IPv4 multicast group to join,
            and the interface (name or address) to join it on.
        rcvbuf_bytes: kernel receive buffer to ask for; queue_bytes: payload bytes allowed to wait for
            the writer before drops are counted.
        metadata: the sensor files of the sensors, as ``lidarpkt.open`` takes them (paths or loaded, any vendor's,
            told apart by content): stored in the file, and what the live frames use.
        decoder_options: the live frames' other decoder options (``model``), as ``lidarpkt.open`` takes them.
        chunk_seconds: close an MCAP chunk this often: at most that much is lost if the process is killed.
        rotate_bytes, rotate_seconds: start a new file after this many bytes or seconds.
        gps, gps_baud: serial port (a pyserial URL) and baud rate of an NMEA GPS.
        points: also write ``PointCloud2`` frames, decoded off the receive path.
        sensors: the frame ids and mounts of the point clouds
            (:class:`~lidarpkt.writers.mcap.frames.SensorFrames`).
        view: starts a live view (a :class:`~lidarpkt.view.server.ViewServer`) once the sockets are bound;
            the recording gives it every frame it can without waiting for it.
        duration_s, max_frames: stop after this many seconds, or complete rotations.
        should_stop: asked every few milliseconds: the reason to stop now (it becomes the summary's
            ``stopped_by``, e.g. the name of a signal received), or None to go on. What was received
            before is still written.
        on_listening: called with the bound packet source just before receiving starts.
        on_status: called once a second with a :class:`RecordStatus`.
        on_notice: called with a line for the user (silence, packets again, GPS failure, the sink's notes).

    Returns:
        a :class:`Recording`; its summary has ``stopped_by``, ``seconds``, ``files``, ``bytes_written``,
        ``messages_written``, ``datagrams_received``, ``packets``, ``frames``, ``lost_gaps``,
        ``out_of_order``, ``interruptions``, ``corrupted``, ``kernel_drops``, ``queue_overflow``,
        ``lost_total``, ``rcvbuf_requested``, ``rcvbuf_granted``, ``gps_*``, ``streams``, and with
        ``points`` or ``view`` the live frames' counts (``frames_decoded`` ...).

    Raises:
        lidarpkt.errors.UsageError: a size, time or count out of its range (:data:`LIMITS`), before anything opens.
        lidarpkt.errors.LidarpktError: a port in use, a GPS port that cannot be opened, a view that cannot
            serve (each before the file is created), a write that fails (disk full).
    """
    _check_limits(chunk_seconds=chunk_seconds, rotate_bytes=rotate_bytes, rotate_seconds=rotate_seconds,
                  duration_s=duration_s, max_frames=max_frames, gps_baud=gps_baud)
    notice = on_notice or (lambda text: None)
    capture = gps_reader = writer = frames = None
    try:
        files = registry.load_sensor_files(list(metadata))
        ports = list(ports) or [p for f in files for p in f.ports]
        capture = UdpSource(ports, bind=bind, multicast=multicast, interface=interface,
                            rcvbuf_bytes=rcvbuf_bytes, queue_bytes=queue_bytes)
        if gps:  # opened before the file, so that a wrong port leaves no empty recording
            from .gps import GpsReader

            gps_reader = GpsReader(gps, gps_baud)
            gps_reader.start()
        if points or view is not None:  # before the file: a view that cannot serve leaves no empty recording
            from .frames import LiveFrames

            frames = LiveFrames(files, points=points, view=view() if view is not None else None,
                                sensors=sensors, decoder_options=decoder_options)
        writer = McapWriter(output, chunk_seconds=chunk_seconds, rotate_bytes=rotate_bytes,
                            rotate_seconds=rotate_seconds)
        sink = PacketSink(writer, metadata=files, log_time_ns=time.time_ns())
        if on_listening is not None:
            on_listening(capture)
        capture.start()
        loop = _Loop(capture, writer, sink, gps_reader, frames, should_stop or (lambda: None), notice, on_status)
        return loop.run(duration_s, max_frames)
    finally:
        if gps_reader is not None:
            gps_reader.close()
        if capture is not None:
            capture.close()
        if frames is not None:
            frames.close()
        if writer is not None:
            try:
                writer.close()
            except LidarpktError:
                pass  # the error that stopped the loop is the one raised


@dataclass
class _Loop:
    capture: UdpSource
    writer: McapWriter
    sink: PacketSink
    gps: Any
    frames: Any
    should_stop: Callable[[], str | None]
    notice: Callable[[str], None]
    on_status: Callable[[RecordStatus], None] | None

    def run(self, duration_s: float | None, max_frames: int | None) -> Recording:
        capture, sink, writer, frames = self.capture, self.sink, self.writer, self.frames
        start = last_status = time.monotonic()
        last_packets = 0
        reason = None
        gps_failed = False
        notes_shown = 0
        last_rx: float | None = None  # when a datagram last arrived
        silent = False
        while reason is None:
            batches = capture.poll(timeout=0.05)
            now = time.monotonic()
            if batches:
                if silent and last_rx is not None:  # silent is only ever set after a datagram
                    self.notice(f"packets again after {now - last_rx:.1f} s of silence")
                    silent = False
                last_rx = now
            elif last_rx is not None and not silent and now - last_rx > 1.0:
                silent = True  # the sensor stopped, restarted or was unplugged: keep recording
                self.notice(f"no packets for {now - last_rx:.1f} s (sensor stopped or unplugged?); still listening")
            for batch in batches:
                sink.push(batch)
            if frames is not None:  # after the packets are written; never waits (see recorder.frames)
                frames.offer(batches)
                frames.write_points(writer)
            for note in sink.notes[notes_shown:]:
                self.notice(f"note: {note}")
            notes_shown = len(sink.notes)
            if self.gps is not None:
                _write_gps(writer, self.gps)
                if self.gps.error and not gps_failed:  # the lidar recording goes on without it
                    gps_failed = True
                    self.notice(f"warning: {self.gps.error}; recording continues without GPS")
            writer.tick()
            now = time.monotonic()
            reason = self.should_stop()
            if reason is None and duration_s is not None and now - start >= duration_s:
                reason = f"duration {duration_s:g} s"
            elif reason is None and max_frames is not None and sink.frames > max_frames:
                # the first wrap ends the rotation under way when recording began: N + 1 wraps hold N whole ones
                reason = f"{max_frames} frames"
            if frames is not None:
                frames.tick(self._lost_total())
            if now - last_status >= 1.0:
                rate = (sink.packets - last_packets) / (now - last_status)
                last_packets, last_status = sink.packets, now
                if self.on_status is not None:
                    self.on_status(self._status(now - start, rate))
        # stop receiving, then write whatever was already received
        capture.stop()
        while True:
            batches = capture.poll(timeout=0.0, max_items=65536)
            if not batches:
                break
            for batch in batches:
                sink.push(batch)
            if frames is not None:
                frames.offer(batches)
        if frames is not None:
            frames.finish(writer)  # decodes what is queued and the last partial frames, writes their points
        if self.gps is not None:
            self.gps.close()
            _write_gps(writer, self.gps)
        sink.finish()
        writer.close()
        summary = self._summary(time.monotonic() - start, reason)
        if frames is not None:
            summary.update(frames.summary())
        return Recording(summary, sink.report_lines())

    def _lost_total(self) -> int:
        s = self.capture.stats
        return max(self.sink.lost, s.kernel_dropped + s.queue_overflow)

    def _status(self, seconds: float, rate: float) -> RecordStatus:
        s = self.capture.stats
        return RecordStatus(seconds, rate, self.sink.frames, self.sink.lost, s.kernel_dropped, s.queue_overflow,
                            self._lost_total(), self.writer.bytes_written)

    def _summary(self, elapsed: float, reason: str | None) -> dict:
        s, sink, writer, gps = self.capture.stats, self.sink, self.writer, self.gps
        return {
            "stopped_by": reason,
            "seconds": round(elapsed, 3),
            "files": [str(p) for p in writer.files],
            "bytes_written": writer.bytes_written,
            "messages_written": writer.messages_written,
            "datagrams_received": s.received,
            "packets": sink.packets,
            "frames": sink.frames,
            "lost_gaps": sink.lost,
            "out_of_order": sink.out_of_order,
            "interruptions": sum(r.count.interruptions for r in sink.streams.values()),
            # packets whose own counters jumped off both neighbours (lidarpkt.core.continuity): recorded, not counted
            "corrupted": sum(r.count.corrupted for r in sink.streams.values()),
            "kernel_drops": s.kernel_dropped,
            "queue_overflow": s.queue_overflow,
            # datagrams dropped here (kernel, queue) leave gaps in the stream counters too: counting both
            # would count them twice; gaps beyond the local drops were lost before reaching this machine
            "lost_total": self._lost_total(),
            "rcvbuf_requested": s.rcvbuf_requested,
            "rcvbuf_granted": {str(k): v for k, v in s.rcvbuf_granted.items()},
            "gps_sentences": gps.sentences if gps is not None else 0,
            "gps_bad_checksum": gps.bad if gps is not None else 0,
            "gps_error": gps.error if gps is not None else None,
            "streams": [
                {"kind": r.kind, "src": r.src, "dst": r.dst, "payload_size": r.payload_size,
                 "packets": r.count.packets, "lost": r.count.lost, "out_of_order": r.count.out_of_order,
                 "frames": r.count.frames, "interruptions": r.count.interruptions, "corrupted": r.count.corrupted,
                 "messages": r.messages}
                for r in sink.streams.values()
            ],
        }


def _write_gps(writer: McapWriter, gps) -> None:
    store = rosmsgs.typestore()
    from .gps import sentence_time_ns

    for host_ns, sentence in gps.drain():
        stamp = sentence_time_ns(sentence, host_ns)  # the GPS's own time where it says it
        msg = store.types[schemas.NMEA_SENTENCE](header=rosmsgs.header(stamp, "gps"), sentence=sentence)
        writer.write_message(schemas.NMEA, msg, host_ns)
