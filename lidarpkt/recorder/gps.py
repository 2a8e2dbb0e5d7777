"""Serial NMEA GPS: sentences read with pyserial, checksums verified, stamped with host time.

:class:`GpsReader` reads a serial port (any pyserial URL: ``/dev/ttyUSB0``, a pty,
``socket://…``) in a background thread, splits it into lines, and keeps every sentence
whose ``*hh`` checksum matches (the checksum is :func:`lidarpkt.core.nmea.checksum`,
the one the VLP-16 position packets are verified with). Sentences with a wrong or missing
checksum, and lines that are not NMEA, are counted (``bad``) and dropped. Lines longer than
NMEA allows are cut off (memory stays bounded whatever arrives).

Each sentence is logged at the host time its line ended (ns since the epoch); the recorder
writes it as ``nmea_msgs/msg/Sentence`` on ``/gps/nmea_sentence`` with ``header.stamp`` = the
GPS's own UTC time where the sentence gives it (:func:`sentence_time_ns`), else the host time.
"""

from __future__ import annotations

import queue
import threading
import time

from lidarpkt.errors import NMEAError, SerialPortError
from lidarpkt.core.nmea import checksum, fix_time_ns, parse_nmea

MAX_LINE = 512  # NMEA 0183 allows 82 characters; proprietary sentences run a little longer


def verify_sentence(line: bytes | str) -> str:
    """The sentence of one line (``$…*hh`` or ``!…*hh``, CR LF stripped) if its checksum matches.

    Raises:
        NMEAError: not an NMEA sentence, no checksum, or a checksum mismatch (both values shown).
    """
    if isinstance(line, bytes):
        try:
            line = line.decode("ascii")
        except UnicodeDecodeError:
            raise NMEAError(f"not ASCII, so not NMEA: {line[:40]!r}") from None
    text = line.strip()
    if len(text) < 4 or text[0] not in "$!" or "*" not in text:
        raise NMEAError(f"not an NMEA sentence (needs $…*hh): {text[:60]!r}")
    body, _, given = text[1:].rpartition("*")
    try:
        expected = int(given, 16)
        if len(given) != 2:
            raise ValueError
    except ValueError:
        raise NMEAError(f"bad NMEA checksum field {given!r} in {text[:60]!r}") from None
    actual = checksum(body)
    if actual != expected:
        raise NMEAError(f"NMEA checksum mismatch: sentence says {expected:02X}, content gives {actual:02X}: "
                        f"{text[:60]!r}")
    return text


def sentence_time_ns(sentence: str, host_time_ns: int) -> int:
    """The UTC time a $--RMC / $--GGA sentence reports, ns since the epoch; ``host_time_ns`` for
    other sentences and for empty time fields. GGA has no date: the day nearest the host time
    (:func:`lidarpkt.core.nmea.fix_time_ns`, as the VLP-16 decoder resolves it)."""
    try:
        fix = parse_nmea(sentence)
    except NMEAError:
        return host_time_ns
    t = fix_time_ns(fix, host_time_ns)
    return host_time_ns if t is None else t


class GpsReader:
    """Reads NMEA sentences from a serial port in a thread.

    Args:
        port: device path or pyserial URL.
        baud: baud rate.

    Raises:
        SerialPortError: the port cannot be opened (with the reason).
    """

    def __init__(self, port: str, baud: int = 9600) -> None:
        import serial

        self.port = port
        try:
            self._serial = serial.serial_for_url(port, baudrate=baud, timeout=0.1)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SerialPortError(f"cannot open GPS serial port {port} at {baud} baud: {exc}") from None
        self.sentences = 0
        self.bad = 0
        self.error: str | None = None
        self._queue: queue.SimpleQueue[tuple[int, str]] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="lidarpkt-gps", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import serial

        buf = b""
        while not self._stop.is_set():
            try:
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError) as exc:
                self.error = f"GPS serial port {self.port} failed: {exc}"
                return
            if not chunk:
                continue
            now = time.time_ns()
            buf += chunk
            *lines, buf = buf.split(b"\n")
            if len(buf) > MAX_LINE:  # no line end in sight: garbage, drop it
                self.bad += 1
                buf = b""
            for line in lines:
                self._take(line, now)

    def _take(self, line: bytes, now: int) -> None:
        if not line.strip():
            return
        try:
            sentence = verify_sentence(line[:MAX_LINE])
        except NMEAError:
            self.bad += 1
            return
        self.sentences += 1
        self._queue.put((now, sentence))

    def drain(self) -> list[tuple[int, str]]:
        """``(host_time_ns, sentence)`` of the sentences read since the last call, oldest first."""
        out = []
        try:
            while True:
                out.append(self._queue.get_nowait())
        except queue.Empty:
            return out

    def close(self) -> None:
        """Stop reading and close the port (sentences read stay drainable). Safe to call twice."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        try:
            self._serial.close()
        except Exception:  # closing a port whose device vanished
            pass
