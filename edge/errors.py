"""One error hierarchy for the whole package.

Library code raises these with a message that names the file, key or row at fault; only ``edge.cli`` turns them
into a one-line message and exit code 2.
"""

from __future__ import annotations

from pydantic import ValidationError


class EdgeIpsError(Exception):
    """Base class of every error a user can cause and fix."""


class ConfigError(EdgeIpsError):
    """Invalid configuration file, key, value or environment override."""


class CalibrationError(EdgeIpsError):
    """Calibration input or file that cannot give a trustworthy mapping."""


class SourceError(EdgeIpsError):
    """A frame source (camera, video, stream, simulator) that cannot be opened or read."""


class MessageError(EdgeIpsError):
    """A message that does not conform to the versioned contract in ``shared/schema``."""


class BrokerError(EdgeIpsError):
    """An MQTT broker that cannot be started, reached or authenticated against."""


class SimulationError(EdgeIpsError):
    """A simulator scenario or parameter that cannot be rendered."""


class FlashError(EdgeIpsError):
    """A rover board that cannot be reached, flashed or provisioned (tools/flash.py)."""


class EnrollmentError(EdgeIpsError):
    """Marker colours that cannot be enrolled from the images given (no marker, a marker in the background...)."""


def describe_validation(exc: ValidationError, top_level: str = "(top level)") -> str:
    """``key.path: what is wrong`` for the first error pydantic found (``top_level`` when it is about the whole
    input), ``unknown key`` for a key the model does not have, and how many more errors there are."""
    errors = exc.errors()
    first = errors[0]
    where = ".".join(str(p) for p in first["loc"]) or top_level
    message = "unknown key" if first["type"] == "extra_forbidden" else first["msg"].removeprefix("Value error, ")
    if first["type"] == "too_short" and isinstance(first.get("input"), str):  # a secret: pydantic says "items"
        message = f"at least {first.get('ctx', {}).get('min_length', '?')} characters"
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return f"{where}: {message}{more}"
