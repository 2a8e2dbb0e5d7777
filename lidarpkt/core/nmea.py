"""NMEA $GPRMC / $GPGGA sentences as a GPS receiver sends them, and lidar position packets carry them
(checksum verified), and the UTC time of a fix.

Only what the decoders and the recorder need: UTC date and time, fix validity, latitude and longitude.
$GPGGA carries a time of day and no date: the day comes from a reference (the capture clock), so that
the decoders and the recorder's GPS reader cannot disagree about which day a fix is on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.errors import NMEAError


@dataclass(frozen=True)
class NMEAFix:
    """One parsed sentence.

    Attributes:
        sentence: ``"RMC"`` or ``"GGA"`` (talker id stripped).
        talker: e.g. ``"GP"``.
        time_of_day_s: UTC seconds since midnight (fraction kept), ``None`` if the field is empty.
        date: ``(year, month, day)`` from $GPRMC, ``None`` for $GPGGA or an empty field.
        valid: RMC status ``A``, or GGA fix quality > 0.
        latitude_deg, longitude_deg: signed degrees (north, east positive), ``None`` if empty.
    """

    sentence: str
    talker: str
    time_of_day_s: float | None
    date: tuple[int, int, int] | None
    valid: bool
    latitude_deg: float | None
    longitude_deg: float | None

    @property
    def utc_ns(self) -> int | None:
        """UTC time as ns since the Unix epoch when both date and time are known, else ``None``."""
        if self.date is None or self.time_of_day_s is None:
            return None
        import calendar  # here: only fixes with a date ask

        y, m, d = self.date
        midnight = calendar.timegm((y, m, d, 0, 0, 0, 0, 0, 0))
        return midnight * 1_000_000_000 + round(self.time_of_day_s * 1e9)


def checksum(body: str) -> int:
    """XOR of the characters between ``$`` and ``*``."""
    value = 0
    for ch in body.encode("ascii", errors="replace"):
        value ^= ch
    return value


def _coord(value: str, hemi: str, deg_digits: int, what: str) -> float | None:
    if not value:
        return None
    try:
        deg = int(value[:deg_digits])
        minutes = float(value[deg_digits:])
    except ValueError:
        raise NMEAError(f"bad {what} field {value!r}") from None
    out = deg + minutes / 60.0
    if hemi in ("S", "W"):
        out = -out
    elif hemi not in ("N", "E"):
        raise NMEAError(f"bad {what} hemisphere {hemi!r}")
    return out


def _time_of_day(value: str) -> float | None:
    if not value:
        return None
    try:
        h, m, s = int(value[0:2]), int(value[2:4]), float(value[4:])
    except ValueError:
        raise NMEAError(f"bad UTC time field {value!r}") from None
    if h > 23 or m > 59 or s >= 61:
        raise NMEAError(f"UTC time out of range: {value!r}")
    return h * 3600 + m * 60 + s


def parse_nmea(sentence: str | bytes) -> NMEAFix:
    """Parse one $--RMC or $--GGA sentence (trailing CR LF and NUL padding allowed).

    Raises:
        NMEAError: no ``$``/``*``, checksum mismatch (message shows both values), another
            sentence type, or a malformed field.
    """
    if isinstance(sentence, bytes):
        sentence = sentence.split(b"\x00", 1)[0].decode("ascii", errors="replace")
    text = sentence.strip().rstrip("\x00")
    if not text.startswith("$") or "*" not in text:
        raise NMEAError(f"not an NMEA sentence (needs $…*hh): {text[:60]!r}")
    body, _, given = text[1:].rpartition("*")
    try:
        expected = int(given[:2], 16)
    except ValueError:
        raise NMEAError(f"bad NMEA checksum field {given!r} in {text[:60]!r}") from None
    actual = checksum(body)
    if actual != expected:
        raise NMEAError(f"NMEA checksum mismatch: sentence says {expected:02X}, content gives {actual:02X}: {text[:60]!r}")
    fields = body.split(",")
    head = fields[0]
    talker, kind = head[:2], head[2:]
    if kind == "RMC":
        if len(fields) < 10:
            raise NMEAError(f"$--RMC with {len(fields)} fields (needs ≥ 10): {text[:60]!r}")
        date = None
        if fields[9]:
            ds = fields[9]
            try:
                d, m, y = int(ds[0:2]), int(ds[2:4]), int(ds[4:6])
            except ValueError:
                raise NMEAError(f"bad RMC date {ds!r}") from None
            date = (2000 + y if y < 80 else 1900 + y, m, d)
        return NMEAFix("RMC", talker, _time_of_day(fields[1]), date, fields[2] == "A",
                       _coord(fields[3], fields[4], 2, "latitude"), _coord(fields[5], fields[6], 3, "longitude"))
    if kind == "GGA":
        if len(fields) < 7:
            raise NMEAError(f"$--GGA with {len(fields)} fields (needs ≥ 7): {text[:60]!r}")
        quality = int(fields[6]) if fields[6].isdigit() else 0
        return NMEAFix("GGA", talker, _time_of_day(fields[1]), None, quality > 0,
                       _coord(fields[2], fields[3], 2, "latitude"), _coord(fields[4], fields[5], 3, "longitude"))
    raise NMEAError(f"unsupported NMEA sentence {head!r} (lidarpkt reads RMC and GGA)")


def parse_sentence_rows(rows: np.ndarray) -> tuple[list[NMEAFix | None], np.ndarray]:
    """Parse the NUL-padded sentences of ``uint8[N, L]`` rows (position packets' NMEA fields), each
    distinct one once: a sentence changes once per second while packets come far more often.

    Returns (the fix of each distinct row, ``None`` where it does not parse; ``intp[N]`` index of
    each row's fix in that list).
    """
    uniq, inverse = np.unique(rows, axis=0, return_inverse=True)
    fixes: list[NMEAFix | None] = []
    for row in uniq:
        try:
            fixes.append(parse_nmea(row.tobytes()))
        except NMEAError:
            fixes.append(None)
    return fixes, inverse.ravel()


DAY_NS = 24 * 3_600_000_000_000


def on_nearest_day_ns(time_of_day_ns: int, reference_ns: int) -> int:
    """ns since the epoch of a UTC time of day (ns past midnight) on the day that puts it nearest
    ``reference_ns`` (the host clock, say). Exactly half a day away goes to the later day."""
    return time_of_day_ns + (reference_ns - time_of_day_ns + DAY_NS // 2) // DAY_NS * DAY_NS


def fix_time_ns(fix, reference_ns: int | None) -> int | None:
    """UTC of an :class:`NMEAFix`, ns since the epoch: its date and time
    ($GPRMC), else its time of day on the day nearest ``reference_ns`` ($GPGGA), else ``None``
    (no time in the sentence, or a time of day and no reference)."""
    if fix.utc_ns is not None:
        return int(fix.utc_ns)
    if fix.time_of_day_s is None or not reference_ns:
        return None
    return on_nearest_day_ns(round(fix.time_of_day_s * 1e9), int(reference_ns))
