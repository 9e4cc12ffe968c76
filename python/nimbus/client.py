"""A Python client of nimbusd, matching the behaviour of the nimbus CLI
(client/nimbus_client.cc): local assets are uploaded and pinned by sha256,
watches ride out a restarting server, downloads resume and are checked."""

import hashlib
import json
import os
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Dict, Iterator, List, Optional

import grpc
from google.protobuf import json_format, text_format

from . import _stubs
from .errors import JobFailedError, NimbusError, status_code

pb2, pb2_grpc = _stubs.load()
from nimbus.v1 import spec_pb2  # noqa: E402  (importable only after _stubs.load)

JobSpec = spec_pb2.JobSpec
Job = pb2.Job
JobState = pb2.JobState

TEXT_FORMAT_SUFFIXES = (".txtpb", ".textproto", ".pbtxt")
TERMINAL_STATES = (pb2.JOB_STATE_SUCCEEDED, pb2.JOB_STATE_FAILED, pb2.JOB_STATE_CANCELLED)
# Codes after which the same call may succeed once the server is back.
RETRYABLE = (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED)
UPLOAD_CHUNK = 1 << 20
# Previews of large grids exceed gRPC's default 4 MiB message limit.
MAX_MESSAGE_BYTES = 256 << 20


def state_name(state):
    """"SUCCEEDED" for JOB_STATE_SUCCEEDED."""
    return pb2.JobState.Name(state).replace("JOB_STATE_", "")


def _job_id(job):
    return job if isinstance(job, str) else job.id


def _sha256_file(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def load_spec(spec, base_dir=None):
    """A JobSpec and the folder its relative asset paths resolve against.

    `spec` is a JobSpec, a dict (protobuf's JSON mapping), a JSON string, or
    the path of a .json / .txtpb / .textproto / .pbtxt file. Unknown fields
    are errors, as in the CLI."""
    if isinstance(spec, JobSpec):
        out = JobSpec()
        out.CopyFrom(spec)
        return out, Path(base_dir or os.getcwd())
    if isinstance(spec, dict):
        try:
            return json_format.ParseDict(spec, JobSpec()), Path(base_dir or os.getcwd())
        except json_format.ParseError as e:
            raise NimbusError(grpc.StatusCode.INVALID_ARGUMENT, f"spec: {e}", field="") from None
    if isinstance(spec, str) and spec.lstrip().startswith("{"):
        try:
            return json_format.Parse(spec, JobSpec()), Path(base_dir or os.getcwd())
        except json_format.ParseError as e:
            raise NimbusError(grpc.StatusCode.INVALID_ARGUMENT, f"spec: {e}", field="") from None
    path = Path(spec)
    try:
        text = path.read_text()
    except OSError as e:
        raise NimbusError(grpc.StatusCode.NOT_FOUND,
                          f"{path}: cannot read the spec: {e.strerror}", field="") from None
    try:
        if path.suffix.lower() in TEXT_FORMAT_SUFFIXES:
            msg = text_format.Parse(text, JobSpec())
        else:
            msg = json_format.Parse(text, JobSpec())
    except (json_format.ParseError, text_format.ParseError) as e:
        raise NimbusError(grpc.StatusCode.INVALID_ARGUMENT, f"{path}: {e}", field="") from None
    return msg, Path(base_dir) if base_dir else path.resolve().parent


def _visit_source(src, field_path, fn):
    kind = src.WhichOneof("kind")
    if kind == "mesh":
        fn(field_path + ".mesh.asset", src.mesh.asset)
    elif kind == "grid":
        fn(field_path + ".grid.asset", src.grid.asset)
    elif kind == "random_balls":
        if src.random_balls.HasField("inside"):
            _visit_source(src.random_balls.inside, field_path + ".random_balls.inside", fn)
    elif kind == "union":
        for i, part in enumerate(src.union.parts):
            _visit_source(part, f"{field_path}.union.parts[{i}]", fn)


def for_each_asset(spec, fn):
    """Calls fn(field_path, asset) for every Asset message of the spec, the
    same walk as ForEachAsset in proto/asset_paths.cc."""
    generator = spec.WhichOneof("generator")
    if generator == "fractal_field":
        f = spec.fractal_field
        if f.HasField("shape") and f.shape.HasField("source"):
            _visit_source(f.shape.source, "fractal_field.shape.source", fn)
        return
    if generator != "set_ifs":
        return
    s = spec.set_ifs
    for i, m in enumerate(s.maps):
        if m.HasField("condensation"):
            _visit_source(m.condensation, f"set_ifs.maps[{i}].condensation", fn)
    if s.HasField("start"):
        _visit_source(s.start, "set_ifs.start", fn)


@dataclass
class PreviewFile:
    """One preview a watch received. `index` numbers them densely from 1 in
    the order received, whatever sequence numbers the server skipped."""
    index: int
    sequence: int
    done: int
    total: int
    unit: str
    resolution: List[int]
    vdb: bytes = field(repr=False)
    path: Optional[Path] = None
    # Jobs with an image: the preview picture (8-bit PNG) and where it went.
    png: bytes = field(default=b"", repr=False)
    png_path: Optional[Path] = None


class PreviewSaver:
    """Numbers a watch's previews densely from 1 in the order received,
    whatever sequence numbers the server skipped for a slow watcher, and
    with `previews_dir` saves them as NAME.preview.0001.vdb, 0002, ...
    (each through a temporary file renamed into place) listed in
    NAME.previews.json with the sequence and progress each reflects. The
    server also writes both into each file's metadata
    (nimbus_preview_sequence, nimbus_preview_done). A preview not newer
    than the last one (a re-attached watch repeats the latest) is dropped;
    a second watch into the same folder continues the numbering."""

    def __init__(self, previews_dir, job_id):
        self.dir = Path(previews_dir) if previews_dir is not None else None
        if self.dir is not None:
            self.dir.mkdir(parents=True, exist_ok=True)
        self.job_id = job_id
        self.manifest = None
        self.entries = []
        self.last_sequence = 0

    def add(self, job, p):
        """The PreviewFile for preview message `p` of `job`, or None for a repeat."""
        if p.sequence <= self.last_sequence:
            return None
        self.last_sequence = p.sequence
        name = job.name or "nimbus"
        if self.dir is not None and self.manifest is None:
            self.manifest = self.dir / f"{name}.previews.json"
            self.entries = _read_manifest(self.manifest, self.job_id)
        preview = PreviewFile(
            index=len(self.entries) + 1, sequence=p.sequence, done=p.done,
            total=job.progress.total, unit=job.progress.unit,
            resolution=list(p.resolution), vdb=p.vdb, png=p.png)
        if self.dir is None:
            self.entries.append(None)
            return preview
        preview.path = self.dir / f"{name}.preview.{preview.index:04d}.vdb"
        entry = {"file": preview.path.name, "sequence": p.sequence,
                 "done": p.done, "total": preview.total, "unit": preview.unit,
                 "resolution": preview.resolution}
        if p.png:
            preview.png_path = preview.path.with_suffix(".png")
            _write_atomic(preview.png_path, p.png)
            entry["png"] = preview.png_path.name
        _write_atomic(preview.path, p.vdb)
        self.entries.append(entry)
        _write_atomic(self.manifest, json.dumps(
            {"job_id": self.job_id, "previews": self.entries}, indent=1).encode())
        return preview


@dataclass(frozen=True)
class LogEvent:
    """One entry of a job's event log (nimbus.v1.JobEvent; the kinds and
    their fields are in docs/operator_guide.md "Job event log").

    seq:    1, 2, ... per job, in the order the events happened
    time:   when it was recorded (a datetime in UTC)
    kind:   "submitted", "claimed", "lease_lost", "released", "cancelled", ...
    fields: what happened, by name ("worker", "attempt", "reason", ...)"""
    seq: int
    time: datetime
    kind: str
    fields: Dict[str, str]

    @classmethod
    def from_proto(cls, e):
        return cls(seq=e.seq, time=e.time.ToDatetime(tzinfo=timezone.utc), kind=e.kind,
                   fields=dict(e.fields))

    @property
    def worker(self):
        """The worker ("REPLICA/wN") the event names, or ""."""
        return self.fields.get("worker", "")

    @property
    def detail(self):
        """The other non-empty fields as "name=value", in name order."""
        return " ".join(f"{k}={v}" for k, v in sorted(self.fields.items())
                        if v and k != "worker")

    def __str__(self):
        """The line `nimbus events` prints: seq, time, kind, the non-empty fields."""
        text = "".join(f" {k}={v}" for k, v in sorted(self.fields.items()) if v)
        return f"{self.seq:5d} {self.time:%Y-%m-%dT%H:%M:%SZ} {self.kind:<16}{text}"


@dataclass
class WatchEvent:
    """A state change of the job, with a preview when one arrived. With
    watch(events=True), `events` holds the LogEvents recorded since the
    previous WatchEvent, oldest first."""
    job: "pb2.Job"
    preview: Optional[PreviewFile] = None
    events: List[LogEvent] = field(default_factory=list)

    @property
    def progress(self):
        return self.job.progress

    @property
    def state(self):
        return state_name(self.job.state)

    @property
    def fraction(self):
        """Progress of the current phase in [0, 1], or None without a total."""
        p = self.job.progress
        return min(1.0, p.done / p.total) if p.total else None


@dataclass
class FetchResult:
    path: Path
    size: int
    sha256: str
    resumed_from: int   # bytes already on disk when the download started
    received: int       # bytes received over the wire


@dataclass
class RenderResult:
    job: "pb2.Job"
    path: Path
    sha256: str
    previews: List[PreviewFile]


def _read_pem(what, path):
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise NimbusError(grpc.StatusCode.INVALID_ARGUMENT,
                          f"{what} {path}: cannot read the file: {e.strerror}", field="") from None


class Client:
    """A connection to one nimbusd, e.g. Client("127.0.0.1:50051").

    For a server with TLS give `tls_ca` (the PEM file of the CA that signed
    its certificate), and `tls_cert` and `tls_key` when it requires client
    certificates. `token` (default $NIMBUS_TOKEN) is sent with every call as
    `authorization: Bearer TOKEN`."""

    def __init__(self, address, reconnect_timeout=30.0, timeout=60.0, tls_ca=None,
                 tls_cert=None, tls_key=None, token=None):
        self.address = address
        self.reconnect_timeout = reconnect_timeout
        self.timeout = timeout  # per unary call, seconds
        token = token if token is not None else os.environ.get("NIMBUS_TOKEN", "")
        # Metadata rather than call credentials: gRPC sends those only over
        # TLS, and a token to a loopback server without TLS is legitimate.
        self._metadata = (("authorization", f"Bearer {token}"),) if token else ()
        options = [("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
                   ("grpc.max_send_message_length", MAX_MESSAGE_BYTES)]
        if (tls_cert is None) != (tls_key is None):
            raise NimbusError(grpc.StatusCode.INVALID_ARGUMENT,
                              "tls_cert and tls_key go together", field="")
        if tls_ca is not None:
            creds = grpc.ssl_channel_credentials(
                root_certificates=_read_pem("tls_ca", tls_ca),
                private_key=_read_pem("tls_key", tls_key) if tls_key else None,
                certificate_chain=_read_pem("tls_cert", tls_cert) if tls_cert else None)
            self._channel = grpc.secure_channel(address, creds, options=options)
        elif tls_cert is not None:
            raise NimbusError(grpc.StatusCode.INVALID_ARGUMENT,
                              "tls_cert needs tls_ca (the server's CA)", field="")
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        self._stub = pb2_grpc.NimbusServiceStub(self._channel)

    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _unary(self, name, request):
        try:
            return getattr(self._stub, name)(request, timeout=self.timeout, wait_for_ready=True,
                                             metadata=self._metadata)
        except grpc.RpcError as e:
            raise NimbusError.from_rpc(e, name) from None

    # --- assets -------------------------------------------------------------

    def upload_file(self, path):
        """Uploads a mesh or grid file; returns its sha256."""
        path = Path(path)
        try:
            data = path.read_bytes()
        except OSError as e:
            raise NimbusError(grpc.StatusCode.NOT_FOUND,
                              f"{path}: cannot read the file: {e.strerror}") from None
        sha = hashlib.sha256(data).hexdigest()

        def requests():
            first = pb2.UploadAssetRequest(sha256=sha, size_bytes=len(data), file_name=path.name)
            if not data:
                yield first
            for pos in range(0, len(data), UPLOAD_CHUNK):
                req = first if pos == 0 else pb2.UploadAssetRequest()
                req.data = data[pos:pos + UPLOAD_CHUNK]
                yield req

        try:
            resp = self._stub.UploadAsset(requests(), timeout=max(self.timeout, 600),
                                          wait_for_ready=True, metadata=self._metadata)
        except grpc.RpcError as e:
            err = NimbusError.from_rpc(e, "UploadAsset")
            raise NimbusError(err.code, f"upload of {path}: {err.details}", field="") from None
        return resp.sha256

    def upload_spec_assets(self, spec, base_dir):
        """Uploads every Asset given by path (relative to base_dir) and
        replaces it by its sha256, with the file name as label. Each file is
        uploaded once however often it is named. Changes `spec` in place."""
        uploaded = {}

        def pin(field_path, asset):
            if asset.WhichOneof("source") != "path" or not asset.path:
                return
            p = Path(asset.path)
            if not p.is_absolute():
                p = Path(os.path.normpath(Path(base_dir) / p))
            key = str(p)
            if key not in uploaded:
                try:
                    uploaded[key] = self.upload_file(p)
                except NimbusError as e:
                    raise NimbusError(e.code, f"{field_path}.path: {e.details}") from None
            asset.label = p.name
            asset.sha256 = uploaded[key]  # replaces the path (one of)

        for_each_asset(spec, pin)
        return spec

    # --- jobs ---------------------------------------------------------------

    def submit(self, spec, request_id=None, base_dir=None, priority=None):
        """Queues a spec (JobSpec, dict, JSON text or spec file path) after
        uploading its local assets; returns the Job. `priority` 0..100
        (higher runs first; the server's default, 50, when None)."""
        msg, base = load_spec(spec, base_dir)
        self.upload_spec_assets(msg, base)
        req = pb2.SubmitJobRequest(spec=msg, request_id=request_id or "")
        if priority is not None:
            req.priority = priority
        return self._unary("SubmitJob", req).job

    def set_priority(self, job, priority):
        """Changes a queued job's priority (0..100); returns the job."""
        req = pb2.SetJobPriorityRequest(job_id=_job_id(job), priority=priority)
        return self._unary("SetJobPriority", req).job

    def retry(self, job):
        """Queues a FAILED or CANCELLED job again; returns the new Job
        (its retried_from names the original)."""
        return self._unary("RetryJob", pb2.RetryJobRequest(job_id=_job_id(job))).job

    def get(self, job):
        return self._unary("GetJob", pb2.GetJobRequest(job_id=_job_id(job))).job

    def cancel(self, job):
        return self._unary("CancelJob", pb2.CancelJobRequest(job_id=_job_id(job))).job

    def pin(self, job, pinned=True):
        """Keeps the job's result past the server's retention age (or, with
        pinned=False, lets it expire again); returns the job."""
        return self._unary("PinJob", pb2.PinJobRequest(job_id=_job_id(job), pinned=pinned)).job

    def unpin(self, job):
        return self.pin(job, pinned=False)

    def workers(self):
        """The replicas sharing the server's job store (nimbus.v1.Worker)."""
        return list(self._unary("ListWorkers", pb2.ListWorkersRequest()).workers)

    def events(self, job, after_seq=0, page_size=500):
        """The job's event log as LogEvents, oldest first, every page: those
        after seq `after_seq` (0: from the oldest kept; each job keeps its
        newest 1,000)."""
        out, after = [], after_seq
        while True:
            page = self._unary("GetJobEvents", pb2.GetJobEventsRequest(
                job_id=_job_id(job), after_seq=after, page_size=page_size))
            out.extend(LogEvent.from_proto(e) for e in page.events)
            after = page.next_after_seq
            if not after:
                return out

    def delete(self, job):
        """Deletes a finished job and its result files; returns the bytes freed."""
        return self._unary("DeleteJob", pb2.DeleteJobRequest(job_id=_job_id(job))).freed_bytes

    def poke(self, job, body, impulse=None, drag_target=None, drag_stiffness=0.0,
             drag_frames=0):
        """Pushes (`impulse`) or drags (`drag_target`) body `body` of a
        running jelly job; vectors are (x, y, z). Returns the
        PokeJobResponse (its `earliest_frame` is the first frame that can
        show the poke)."""
        if (impulse is None) == (drag_target is None):
            raise ValueError("give exactly one of impulse or drag_target")
        req = pb2.PokeJobRequest(job_id=_job_id(job))
        req.push.body = body
        req.push.drag_stiffness = drag_stiffness
        req.push.drag_frames = drag_frames
        target = req.push.impulse if impulse is not None else req.push.drag_target
        target.x, target.y, target.z = (float(c) for c in (impulse or drag_target))
        return self._unary("PokeJob", req)

    def list(self, state=None, limit=None, page_size=100):
        """Jobs newest first, all pages (or the first `limit`). `state` is a
        JobState value or a name such as "RUNNING"."""
        if isinstance(state, str):
            state = pb2.JobState.Value("JOB_STATE_" + state.upper().replace("JOB_STATE_", ""))
        out, token = [], ""
        while True:
            resp = self._unary("ListJobs", pb2.ListJobsRequest(
                page_size=page_size, page_token=token, state=state or 0))
            out.extend(resp.jobs)
            token = resp.next_page_token
            if not token or (limit and len(out) >= limit):
                return out[:limit] if limit else out

    def watch(self, job, previews_dir=None, preview_resolution=64, preview_interval=1.0,
              want_previews=None, events=False, events_after_seq=0) -> Iterator[WatchEvent]:
        """Yields a WatchEvent for the job's state now and every change until
        it ends; reconnects while the server is unreachable for up to
        `reconnect_timeout` seconds.

        With `previews_dir`, previews are saved as NAME.preview.0001.vdb,
        0002, ... (dense, in the order received) and listed with the progress
        `done` each reflects in NAME.previews.json; a second watch of the same
        job into the same folder continues the numbering. Previews are asked
        for when `previews_dir` is given or `want_previews` is true.

        With `events`, each WatchEvent's `events` carries the job's event
        log as it grows (LogEvents, seq increasing), starting after seq
        `events_after_seq` (0: from the oldest kept). Across reconnects every
        event is yielded exactly once: the watch resumes after the last seq
        it yielded. The watch's last WatchEvent carries the events recorded
        by the time the job's end was sent, its recorded end (succeeded,
        failed, cancelled) among them; one written later (a later
        "pinned") is read with
        events(job, after_seq=LAST_SEQ)."""
        job_id = _job_id(job)
        if want_previews is None:
            want_previews = previews_dir is not None
        req = pb2.WatchJobRequest(job_id=job_id,
                                  preview_resolution=preview_resolution if want_previews else 0,
                                  preview_interval_seconds=preview_interval,
                                  include_events=events, events_after_seq=events_after_seq)
        saver = PreviewSaver(previews_dir, job_id)
        last = None
        give_up_at = time.monotonic() + self.reconnect_timeout
        while True:
            got_any = False
            call = self._stub.WatchJob(req, wait_for_ready=True, metadata=self._metadata)
            try:
                for resp in call:
                    got_any = True
                    last = resp.job
                    preview = saver.add(resp.job, resp.preview) if resp.HasField("preview") \
                        else None
                    log = [LogEvent.from_proto(e) for e in resp.events]
                    if log:  # a reconnect asks for the events after these
                        req.events_after_seq = max(req.events_after_seq, *(e.seq for e in log))
                    yield WatchEvent(job=resp.job, preview=preview, events=log)
                status = None
            except grpc.RpcError as e:
                status = e
            if last is not None and last.state in TERMINAL_STATES:
                return
            if status is not None and status.code() not in RETRYABLE:
                raise NimbusError.from_rpc(status, "WatchJob")
            if got_any:
                give_up_at = time.monotonic() + self.reconnect_timeout
            if time.monotonic() > give_up_at:
                why = status.details() if status is not None else "stream ended"
                raise NimbusError(grpc.StatusCode.UNAVAILABLE,
                                  f"lost the server while watching job {job_id}: {why}")
            time.sleep(0.2)

    def wait(self, job, **watch_args):
        """Watches the job to its end; returns its final state."""
        last = None
        for ev in self.watch(job, **watch_args):
            last = ev.job
        return last

    def fetch(self, job, path, file_name=""):
        """Downloads the job's result (or one of Job.result.files) to `path`.

        A partial download in PATH.part, or a shorter PATH itself (e.g. a
        truncated earlier download), is resumed from its size. The file is
        checked against the server's sha256; if a resumed file does not match,
        it is fetched once more from the start before giving up."""
        path = Path(path)
        part = Path(str(path) + ".part")
        if not part.exists() and path.exists():
            os.replace(path, part)
        resumed_from = part.stat().st_size if part.exists() else 0
        received = 0
        for whole_again in (False, True):
            if whole_again:
                part.unlink(missing_ok=True)
                resumed_from = 0
            offset, total, expected = self._download(_job_id(job), part, file_name)
            received += offset - (0 if whole_again else resumed_from)
            if offset != total:
                raise NimbusError(grpc.StatusCode.DATA_LOSS,
                                  f"{path}: downloaded {offset} of {total} bytes")
            got = _sha256_file(part)
            if got == expected:
                os.replace(part, path)
                return FetchResult(path=path, size=total, sha256=got,
                                   resumed_from=resumed_from, received=received)
            if resumed_from == 0 or whole_again:
                part.unlink(missing_ok=True)
                raise NimbusError(grpc.StatusCode.DATA_LOSS,
                                  f"sha256 mismatch for {path}: got {got}, server says {expected}")

    def _download(self, job_id, part, file_name):
        """Appends the file from part's size on; returns (size, total, sha256)."""
        offset = part.stat().st_size if part.exists() else 0
        total, expected = None, ""
        attempts = 0
        while True:
            req = pb2.FetchResultRequest(job_id=job_id, offset=offset, file_name=file_name)
            try:
                with open(part, "ab") as out:
                    for chunk in self._stub.FetchResult(req, wait_for_ready=True,
                                                        metadata=self._metadata):
                        if chunk.sha256:
                            expected = chunk.sha256
                        if chunk.total_size:
                            total = chunk.total_size
                        if chunk.offset != offset:
                            raise NimbusError(grpc.StatusCode.DATA_LOSS,
                                              f"server sent offset {chunk.offset}, "
                                              f"expected {offset}")
                        out.write(chunk.data)
                        offset += len(chunk.data)
                if total is None:
                    total = offset  # an empty file's only message may carry no size
                return offset, total, expected
            except grpc.RpcError as e:
                if e.code() == grpc.StatusCode.OUT_OF_RANGE and offset > 0:
                    # The partial file is longer than the result: not ours.
                    part.unlink(missing_ok=True)
                    offset = 0
                    continue
                attempts += 1
                if e.code() not in RETRYABLE or attempts > 20:
                    raise NimbusError.from_rpc(e, "FetchResult") from None
                time.sleep(0.25)
            except OSError as e:
                raise NimbusError(grpc.StatusCode.RESOURCE_EXHAUSTED,
                                  f"cannot write {part}: {e.strerror}") from None

    def render(self, spec, path, previews_dir=None, on_event=None, base_dir=None,
               preview_resolution=64, preview_interval=1.0, request_id=None, priority=None,
               events=False):
        """Submits, watches (saving previews if asked), and fetches the result
        to `path`. Raises JobFailedError when the job fails or is cancelled.

        `on_event` is called with each WatchEvent; with `events`, their
        `events` carry the job's event log as watch(events=True) does, e.g.

            client.render(spec, "out.vdb", events=True,
                          on_event=lambda ev: [print(e) for e in ev.events])
        """
        job = self.submit(spec, request_id=request_id, base_dir=base_dir, priority=priority)
        previews = []
        final = job
        for ev in self.watch(job, previews_dir=previews_dir,
                             preview_resolution=preview_resolution,
                             preview_interval=preview_interval,
                             want_previews=previews_dir is not None or on_event is not None,
                             events=events):
            final = ev.job
            if ev.preview is not None:
                previews.append(ev.preview)
            if on_event is not None:
                on_event(ev)
        raise_for_job(final)
        got = self.fetch(final, path)
        return RenderResult(job=final, path=got.path, sha256=got.sha256, previews=previews)


def raise_for_job(job):
    """Raises JobFailedError unless the job SUCCEEDED."""
    if job.state == pb2.JOB_STATE_SUCCEEDED:
        return
    if job.state == pb2.JOB_STATE_CANCELLED:
        code = grpc.StatusCode.CANCELLED
    else:
        code = status_code(job.status.code) if job.status.code else grpc.StatusCode.UNKNOWN
    raise JobFailedError(job, code, f"job {job.id} {state_name(job.state)}: "
                         f"{job.status.message or job.error or 'no reason given'}")


def _read_manifest(path, job_id):
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return data.get("previews", []) if data.get("job_id") == job_id else []


def _write_atomic(path, data):
    tmp = Path(str(path) + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)
