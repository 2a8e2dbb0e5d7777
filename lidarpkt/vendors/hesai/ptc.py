"""Hesai's PTC (Pandar TCP Commands) on TCP port 9347: the sensor's calibration read live, and a small
server that answers as a sensor does (``lidarpkt replay --ptc``, tests).

A request and its response have the same 8-byte header (Hesai "TCP API Reference"; nebula's
``HesaiHwInterface::send_receive``): bytes 0x47 0x74, the command, a status (0 in a request; in a
response 0 = done, else the sensor's error code), the payload length (u32 big-endian), then the
payload. Command 0x05 returns the angle-correction CSV (:mod:`lidarpkt.vendors.hesai.calibration`).
"""

from __future__ import annotations

import socket
import struct
import threading

from lidarpkt.errors import CalibrationError, LidarpktError
from .calibration import HesaiCalibration, parse_calibration

PTC_PORT = 9347
GET_LIDAR_CALIBRATION = 0x05
HEADER = struct.Struct(">BBBBI")  # 0x47, 0x74, command, status, payload length
MAGIC = (0x47, 0x74)
MAX_PAYLOAD = 1 << 20  # a calibration is a few kB; a longer answer is no sensor's
ERRORS = {1: "invalid input parameter", 2: "server connection failed", 3: "invalid data", 4: "out of memory",
          5: "unsupported command", 6: "FPGA communication failed"}


class PtcError(LidarpktError):
    """A PTC exchange failed: no connection, a timeout, an answer that is no PTC, or the sensor's error code."""


def _recv_exact(sock: socket.socket, n: int, where: str) -> bytes:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise PtcError(f"{where}: the connection closed after {len(buf)} of {n} bytes")
        buf += chunk
    return bytes(buf)


def ptc_request(host: str, command: int, payload: bytes = b"", *, port: int = PTC_PORT, timeout_s: float = 3.0) -> bytes:
    """Send one PTC command to ``host:port`` and return the answer's payload.

    Raises :class:`PtcError` (naming ``host:port``) when the sensor cannot be reached or answers
    with an error code, another command, a header that is no PTC's, or more than 1 MB.
    """
    where = f"PTC {host}:{port}"
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as sock:
            sock.sendall(HEADER.pack(*MAGIC, command, 0, len(payload)) + payload)
            m0, m1, cmd, status, length = HEADER.unpack(_recv_exact(sock, HEADER.size, where))
            if (m0, m1) != MAGIC or cmd != command:
                raise PtcError(f"{where}: the answer is no PTC answer to command 0x{command:02x} "
                               f"(header {m0:02x} {m1:02x}, command 0x{cmd:02x})")
            if length > MAX_PAYLOAD:
                raise PtcError(f"{where}: an answer of {length} bytes announced; a sensor sends at most a few kB")
            body = _recv_exact(sock, length, where)
    except OSError as exc:
        raise PtcError(f"{where}: {exc.strerror or exc}; is the sensor on and its address right?") from exc
    if status:
        raise PtcError(f"{where}: the sensor answered command 0x{command:02x} with error {status} "
                       f"({ERRORS.get(status, 'unknown')})")
    return body


def fetch_calibration(host: str, *, port: int = PTC_PORT, timeout_s: float = 3.0) -> HesaiCalibration:
    """The sensor's angle-correction CSV, read over PTC (command 0x05).

    Raises :class:`~lidarpkt.errors.CalibrationError` when it cannot be read or parsed (the cause chained).
    """
    try:
        body = ptc_request(host, GET_LIDAR_CALIBRATION, port=port, timeout_s=timeout_s)
        text = body.decode("utf-8")
    except (PtcError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"cannot read the calibration of the Hesai sensor at {host}:{port}: {exc}") from exc
    return parse_calibration(text, f"PTC {host}:{port}")


class PtcServer:
    """Answers PTC commands as a sensor does, from ``answers`` (command → payload); other commands get
    error 5 (unsupported). Serves in a thread until :meth:`close` (or the end of a ``with`` block).

    Args:
        answers: the payload of each command, e.g. ``{0x05: csv_bytes}``.
        host, port: where to listen (port 0: any free port; see :attr:`port`).
    """

    def __init__(self, answers: dict[int, bytes], host: str = "127.0.0.1", port: int = 0) -> None:
        self.answers = dict(answers)
        self._sock = socket.create_server((host, port))
        self._sock.settimeout(0.2)
        self.host, self.port = host, int(self._sock.getsockname()[1])
        self.served = threading.Event()  # set once an answer was sent
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="lidarpkt-ptc", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            with conn:
                conn.settimeout(2.0)
                try:
                    m0, m1, cmd, _, length = HEADER.unpack(_recv_exact(conn, HEADER.size, "PTC client"))
                    if (m0, m1) != MAGIC or length > MAX_PAYLOAD:
                        continue
                    _recv_exact(conn, length, "PTC client")
                    body = self.answers.get(cmd)
                    status = 0 if body is not None else 5
                    conn.sendall(HEADER.pack(*MAGIC, cmd, status, len(body or b"")) + (body or b""))
                    self.served.set()
                except (OSError, PtcError):
                    continue

    def close(self) -> None:
        """Stop serving and close the socket. Idempotent."""
        self._stop.set()
        self._sock.close()
        self._thread.join(timeout=2.0)

    def __enter__(self) -> PtcServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
