"""Exceptions of the nimbus package.

Every failure of a call carries the gRPC status code and, when the server's
message starts with one, the spec field it is about, e.g.
"grid.resolution[1]: must be positive, got 0" -> field "grid.resolution[1]".
"""

import re

import grpc

# A field path is dotted names, each optionally indexed ("maps[2]", "xyz")
# or keyed; it ends at the first ": ". Anything else at the start of a
# message (a sentence, a file name with spaces) is not a path.
_FIELD_RE = re.compile(r"^([A-Za-z_]\w*(?:\[\d+\])*(?:\.[A-Za-z_]\w*(?:\[\d+\])*)*): ")


def parse_field_path(message):
    """The field path a server message starts with, or None."""
    m = _FIELD_RE.match(message or "")
    return m.group(1) if m else None


class NimbusError(Exception):
    """A call to nimbusd failed, or a result could not be used.

    code:    a grpc.StatusCode
    field:   the spec field the message names ("grid.resolution[1]"), or None
    details: the server's (or the client's) message
    """

    def __init__(self, code, details, field=None):
        self.code = code
        self.details = details
        self.field = field if field is not None else parse_field_path(details)
        name = code.name if isinstance(code, grpc.StatusCode) else str(code)
        super().__init__(f"{name}: {details}")

    @classmethod
    def from_rpc(cls, err, context=None):
        """Wraps a grpc.RpcError; `context` (e.g. "SubmitJob") prefixes nothing
        in `details`, so the field path stays parseable, but is kept."""
        code = err.code() if hasattr(err, "code") else grpc.StatusCode.UNKNOWN
        details = err.details() if hasattr(err, "details") else str(err)
        e = cls(code, details or "")
        e.rpc = context
        return e


class JobFailedError(NimbusError):
    """A job ended FAILED or CANCELLED; `job` is its final state and `code`
    the code of the job's status (CANCELLED for a cancel)."""

    def __init__(self, job, code, details):
        super().__init__(code, details)
        self.job = job


_CODES = {c.value[0]: c for c in grpc.StatusCode}


def status_code(number):
    """grpc.StatusCode of a google.rpc.Code number (Job.status.code)."""
    return _CODES.get(number, grpc.StatusCode.UNKNOWN)
