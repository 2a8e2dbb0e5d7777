"""Every error and warning lidarpkt raises on bad input.

Catch :class:`LidarpktError` to handle them all. Each message names the file,
packet or field at fault and says what was found, so that a user can act on it.
Conditions that do not stop a run (a truncated last record, a skipped malformed
packet) are reported as :class:`LidarpktWarning` and counted in the statistics
of the reader or decoder concerned.
"""

from __future__ import annotations


class LidarpktError(Exception):
    """Base of every error lidarpkt raises on bad input or a failed operation."""


# --- command line and files ------------------------------------------------------
class UsageError(LidarpktError):
    """A command-line flag has a value that cannot be used (out of range, malformed)."""


class InputFileError(LidarpktError):
    """An input file is missing or unreadable."""


class OutputError(LidarpktError):
    """An output cannot be written where asked: missing or unwritable folder, unknown suffix."""


class DiskFullError(OutputError):
    """The output file could not be written because the disk is full; what was written stays readable."""


# --- input files and containers -------------------------------------------------
class CaptureFormatError(LidarpktError):
    """A file is not a capture lidarpkt can read (wrong magic, unsupported link type, corrupt block)."""


class UnsupportedContainerError(CaptureFormatError):
    """A file is none of the containers lidarpkt opens (pcap, pcapng, MCAP, ROS bag)."""


# --- packets and sensors ----------------------------------------------------------
class PacketFormatError(LidarpktError):
    """A packet does not have the layout its sensor and mode define."""


class SensorMismatchError(LidarpktError):
    """Packets disagree with the metadata or calibration given for them (size, profile, init_id, serial)."""


class UnknownSensorError(LidarpktError):
    """No stream in the input could be identified as a supported sensor."""


class MetadataError(LidarpktError):
    """A sensor file given (``metadata=``) is of no kind lidarpkt reads, or its metadata is missing a field or
    has a wrong one."""


class CalibrationError(LidarpktError):
    """A calibration file (ROS YAML, VeloView XML) is malformed or not for this sensor."""


class SensorConnectionError(LidarpktError):
    """A sensor did not answer over the network (its HTTP API), or answered with something that is not
    what a sensor serves."""


class NMEAError(LidarpktError):
    """An NMEA sentence is malformed or its checksum does not match."""


# --- live sources and recording ---------------------------------------------------
class ReceiveError(LidarpktError):
    """Live UDP reception failed: a socket could not be opened, joined or read."""


class RecorderError(LidarpktError):
    """Recording (or replaying) failed, or its flags do not go together."""


class PortInUseError(ReceiveError):
    """The UDP port to listen on is already bound by another process."""


class SerialPortError(RecorderError):
    """The serial GPS port could not be opened or read."""


# --- analysis ----------------------------------------------------------------------
class AnalysisError(LidarpktError):
    """An analysis cannot run on the data given (too few frames, pixel out of range, no returns)."""


# --- warnings -----------------------------------------------------------------------
class LidarpktWarning(UserWarning):
    """Base of the warnings lidarpkt emits for damage it skipped over and counted."""


class TruncatedCaptureWarning(LidarpktWarning):
    """A capture ends inside a record, or a record claims more bytes than the file holds."""


class SkippedPacketWarning(LidarpktWarning):
    """Malformed packets were counted and skipped."""


class DroppedPacketsWarning(LidarpktWarning):
    """At the end of a capture: packets that were skipped, lost or discarded, and why (one summary)."""


class UnusedSensorFileWarning(LidarpktWarning):
    """A sensor file given (``metadata=``, ``--metadata``) fits no stream of the capture: it was not used."""


class UnsupportedFilterError(LidarpktError, TypeError):
    """A packet filter that the reader of this container does not know, or cannot apply (a ROS bag
    records no UDP ports or addresses)."""
