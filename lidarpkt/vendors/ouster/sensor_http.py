"""The Ouster sensor's HTTP API, both sides: fetch a sensor's metadata, or serve it as a sensor would.

* :func:`fetch_metadata` — ``GET http://HOST[:PORT]/api/v1/sensor/metadata`` (urllib, with a
  timeout), parsed into :class:`~lidarpkt.vendors.ouster.metadata.OusterMetadata`; what
  ``record --sensor`` and ``view --sensor`` use instead of a JSON file.
* :class:`MetadataHttpServer` — serves one metadata JSON at that path (``http.server`` in a
  thread): ``replay --http`` runs it beside the UDP stream, so the whole live flow is testable
  on loopback.
"""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from lidarpkt.errors import MetadataError, SensorConnectionError, UsageError

METADATA_PATH = "/api/v1/sensor/metadata"
DEFAULT_HTTP_PORT = 80


def parse_sensor(text: str, flag: str = "--sensor") -> tuple[str, int]:
    """``"HOST[:PORT]"`` → (host, port), port 80 by default; port 0 (any free port) only for the
    server side (``--http``). Raises :class:`~lidarpkt.errors.UsageError` naming ``flag``."""
    host, sep, port = text.rpartition(":")
    if not sep or "]" in port:  # no port (or a bare IPv6 address in brackets)
        host, port = text, str(DEFAULT_HTTP_PORT)
    lowest = 0 if flag == "--http" else 1
    if not host or not port.isdigit() or not lowest <= int(port) <= 65535:
        raise UsageError(f"{flag} {text!r}: expected HOST or HOST:PORT, e.g. os-122201000001.local or 10.5.6.101:80")
    return host.strip("[]"), int(port)


def metadata_url(host: str, port: int = DEFAULT_HTTP_PORT) -> str:
    h = f"[{host}]" if ":" in host else host
    return f"http://{h}:{port}{METADATA_PATH}"


def fetch_metadata_text(host: str, port: int = DEFAULT_HTTP_PORT, *, timeout_s: float = 5.0) -> str:
    """The metadata JSON text the sensor at ``host:port`` serves.

    Raises:
        SensorConnectionError: no answer within ``timeout_s``, connection refused, an HTTP error status
            or a body that is not JSON; the message names the host and the URL tried.
    """
    url = metadata_url(host, port)
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            body = response.read(16 << 20)  # a metadata JSON is a few kB; a bound against a wrong server
    except urllib.error.HTTPError as exc:
        raise SensorConnectionError(f"--sensor {host}:{port}: GET {url} answered HTTP {exc.code} {exc.reason}; is this "
                                    "an Ouster sensor (firmware 2.x or later)? Or give its metadata with --metadata") from exc
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise SensorConnectionError(f"--sensor {host}:{port}: no answer to GET {url} within {timeout_s:g} s ({reason}); "
                                    "check the address and that the sensor is on, or give --metadata M.json") from exc
    text = body.decode("utf-8", errors="replace")
    try:
        json.loads(text)
    except ValueError as exc:
        raise SensorConnectionError(f"--sensor {host}:{port}: GET {url} did not return JSON; is this an Ouster sensor? "
                                    "Or give its metadata with --metadata") from exc
    return text


def fetch_metadata(host: str, port: int = DEFAULT_HTTP_PORT, *, timeout_s: float = 5.0):
    """:func:`fetch_metadata_text`, parsed. Raises :class:`~lidarpkt.errors.SensorConnectionError`, or
    :class:`MetadataError` when the JSON is not usable Ouster metadata."""
    from .metadata_json import load_metadata

    text = fetch_metadata_text(host, port, timeout_s=timeout_s)
    try:
        return load_metadata(text)
    except MetadataError as exc:
        raise MetadataError(f"--sensor {host}:{port}: the metadata it served is not usable: {exc}") from exc


class MetadataHttpServer:
    """Serves ``metadata_text`` at ``GET /api/v1/sensor/metadata`` on ``host:port`` (port 0: any free
    one, see :attr:`port`), in a daemon thread; 404 elsewhere. Use as a context manager or :meth:`close`.

    Raises:
        UsageError: the address cannot be bound.
    """

    def __init__(self, metadata_text: str, host: str = "127.0.0.1", port: int = 0) -> None:
        body = metadata_text.encode("utf-8")
        fetched = self.fetched = threading.Event()  # set once the metadata has been served

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (http.server's name)
                if self.path.split("?", 1)[0].rstrip("/") != METADATA_PATH:
                    self.send_error(404, "only /api/v1/sensor/metadata is served here")
                    return
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
                fetched.set()

            def log_message(self, *args) -> None:  # quiet: replay prints its own summary
                pass

        try:
            self._httpd = ThreadingHTTPServer((host, port), Handler)
        except OSError as exc:
            raise UsageError(f"--http {host}:{port}: cannot serve there ({exc.strerror or exc}); "
                             "choose another HOST:PORT") from exc
        self._httpd.daemon_threads = True
        self.host = host
        self.port = self._httpd.server_address[1]
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1},
                                        name="lidarpkt-sensor-http", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop serving and release the port. Idempotent."""
        if self._thread.is_alive():
            self._httpd.shutdown()
            self._thread.join(5)
        self._httpd.server_close()

    def __enter__(self) -> "MetadataHttpServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
