"""Python client of the Nimbus fractal volume service (nimbusd).

    import nimbus
    with nimbus.Client("127.0.0.1:50051") as c:
        c.render("examples/tree.json", "tree.vdb", previews_dir="previews")

See python/README.md. The protobuf messages are in nimbus.pb2 (the service)
and nimbus.spec_pb2 (JobSpec and friends), generated from proto/ on first
import when not installed with them.
"""

from .errors import JobFailedError, NimbusError, parse_field_path  # noqa: F401
from .client import (  # noqa: F401
    Client, FetchResult, Job, JobSpec, JobState, LogEvent, PreviewFile, PreviewSaver,
    RenderResult, WatchEvent,
    for_each_asset, load_spec, pb2, raise_for_job, spec_pb2, state_name, TERMINAL_STATES)
from . import vdb  # noqa: F401

__all__ = ["Client", "NimbusError", "JobFailedError", "JobSpec", "Job", "JobState",
           "WatchEvent", "LogEvent", "PreviewFile", "PreviewSaver", "FetchResult", "RenderResult",
           "load_spec", "for_each_asset", "parse_field_path", "raise_for_job", "state_name", "pb2",
           "spec_pb2", "vdb"]
