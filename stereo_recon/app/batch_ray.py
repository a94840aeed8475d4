"""Batch jobs on Ray: an existing cluster (``--address`` / ``RAY_ADDRESS``) or a local instance.

Every path is made absolute on the driver (``batch.resolve_job``). A task runs its job in a
scratch folder on whatever node Ray picks and returns each output folder as bytes (an
uncompressed tar); the driver unpacks it into its own ``--out`` through
``manifest.staged_output_dir`` (nothing half-written) and rewrites the scratch paths that text
outputs (JSON, HTML, logs) recorded into the driver's paths, so the output tree is the one
``--executor local`` writes, whichever node ran the job. Inputs are read in place when the node
has the same file at the same absolute path (a shared mount, or the driver's own machine), else
shipped from the driver through Ray's object store (``ship_inputs``).

Nodes need the ``stereo-recon`` package (same version) installed; Ray's own errors come back
as one line naming the job, never a traceback.
"""

from __future__ import annotations

import collections
import contextlib
import html
import io
import json
import logging
import os
import re
import shutil
import socket
import sys
import tarfile
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

from stereo_recon.app.jobs import Job, call_job, one_line, substitute_paths
from stereo_recon.core.errors import ConfigError
from stereo_recon.core.atomic import staged_output_dir, write_json_atomic

log = logging.getLogger(__name__)

SHIP_MODES = ("auto", "always", "never")
# Outputs whose text may record the job's own paths; binary files (PLY, PNG) are copied as they are.
_TEXT_SUFFIXES = {".json", ".html", ".htm", ".txt", ".log", ".csv", ".tsv", ".yaml", ".yml", ".md", ".xml", ".toml"}


@dataclass(frozen=True)
class RayOptions:
    """How ``batch --executor ray`` uses Ray."""

    address: str | None = None              # cluster: 'auto', 'HOST:PORT' or 'ray://HOST:10001'; None: RAY_ADDRESS, else a local instance
    cpus_per_job: float = 1.0               # CPUs Ray reserves for each job (per task, never at connection time)
    memory_per_job_gb: float | None = None  # memory Ray reserves for each job: a scheduling hint, not a limit; None: none
    ship_inputs: str = "auto"               # 'auto': ship an input only to a node that lacks it; 'always'; 'never'


def _import_ray():
    try:
        import ray
    except ImportError as err:
        raise ConfigError("--executor ray: Ray is not installed (pip install 'stereo-recon[ray]')") from err
    return ray


def _check_options(options: RayOptions) -> None:
    if options.ship_inputs not in SHIP_MODES:
        raise ConfigError(f"--ship-inputs: unknown mode '{options.ship_inputs}' (use {', '.join(SHIP_MODES)})")
    if not options.cpus_per_job > 0:
        raise ConfigError(f"--cpus-per-job: must be > 0, got {options.cpus_per_job}")
    if options.memory_per_job_gb is not None and not options.memory_per_job_gb > 0:
        raise ConfigError(f"--memory-per-job-gb: must be > 0, got {options.memory_per_job_gb}")


def connect(options: RayOptions, workers: int | None) -> bool:
    """Connect to the cluster (or start a local instance); True when this call started Ray (and must shut it down).

    A local instance gets ``workers`` job slots (``workers × cpus_per_job`` CPUs; None: this
    machine's CPUs); an existing cluster is used as it is: resources are asked per task.
    """
    ray = _import_ray()
    if ray.is_initialized():
        return False
    address = options.address or os.environ.get("RAY_ADDRESS") or None
    quiet = {"include_dashboard": False, "log_to_driver": False, "logging_level": logging.ERROR}
    with _stderr_captured() as noise:  # Ray's C++ core retries loudly on stderr while it connects
        try:
            if address:
                # Ray Client (ray://) takes no driver-side settings: they would go to the cluster's init.
                ray.init(address=address, **({} if address.startswith("ray://") else quiet))
            else:
                # address='local' always starts a fresh instance, even beside a cluster running on this machine.
                cpus = None if workers is None else max(1, round(workers * options.cpus_per_job))
                ray.init(address="local", num_cpus=cpus, **quiet)
        except Exception as err:  # Ray raises ConnectionError, ValueError, RuntimeError, TimeoutError...
            failure = err
        else:
            failure = None
    if failure is not None:
        where = f"--address {address}" if address else "--executor ray (local instance)"
        said = _last_message(noise["text"])
        hint = ""
        if "auth" in said.lower() and not os.environ.get("RAY_AUTH_MODE"):
            hint = "; a cluster with token authentication needs RAY_AUTH_MODE=token and its token (RAY_AUTH_TOKEN or ~/.ray/auth_token)"
        raise ConfigError(f"{where}: cannot start or reach Ray ({one_line(failure)}{'; ' + said if said else ''}{hint})") from failure
    _check_feasible(ray, options, address)
    return True


@contextlib.contextmanager
def _stderr_captured():
    """Send this process's fd 2 to a temporary file for the block; yields a dict whose 'text' is what was written."""
    captured = {"text": ""}
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(tmp.fileno(), 2)
        try:
            yield captured
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            captured["text"] = tmp.read().decode("utf-8", "replace")
    for line in captured["text"].splitlines():
        log.debug("ray: %s", line)


def _last_message(text: str) -> str:
    """The last line Ray's core printed, without its '[time level pid] file:line:' prefix."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not lines:
        return ""
    return re.sub(r"^\[[^\]]*\]\s*\S+:\d+:\s*", "", lines[-1])


@contextlib.contextmanager
def _ray_messages_to_log():
    """Route the messages Ray's driver prints about failed workers (stdout, many lines) to this module's
    log: every failure is already reported once, in one line, with its job."""
    try:
        from ray._private import worker as ray_worker

        original = ray_worker.print_to_stdstream
    except (ImportError, AttributeError):  # another Ray layout: leave its printing alone
        yield
        return

    def to_log(data, ignore_prefix=False):
        if data.get("pid") == "raylet":
            for line in data.get("lines", []):
                log.debug("ray: %s", line)
        else:
            original(data, ignore_prefix=ignore_prefix)

    ray_worker.print_to_stdstream = to_log
    try:
        yield
    finally:
        ray_worker.print_to_stdstream = original


def _check_feasible(ray, options: RayOptions, address: str | None) -> None:
    """A job no node can hold would wait forever: say so now."""
    try:
        nodes = [n for n in ray.nodes() if n.get("Alive")]
    except Exception:  # some clients cannot list nodes: let Ray schedule
        return
    most = max((n.get("Resources", {}).get("CPU", 0.0) for n in nodes), default=0.0)
    if nodes and most < options.cpus_per_job:
        ray.shutdown()
        where = address or "the local instance"
        raise ConfigError(f"--cpus-per-job {options.cpus_per_job:g}: no node of {where} has that many CPUs (largest: {most:g})")


def _pack(path: str) -> bytes:
    """A file or folder as an uncompressed tar (videos and clouds do not compress)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        tar.add(path, arcname=os.path.basename(path.rstrip("/")) or ".")
    return buf.getvalue()


def _unpack(blob: bytes, dest_parent: Path) -> None:
    with tarfile.open(fileobj=io.BytesIO(blob), mode="r") as tar:
        tar.extractall(dest_parent, filter="data")


def _input_state(path: str) -> tuple[str, int | None]:
    """('file', size) / ('dir', None) / ('missing', None) as this machine sees ``path``."""
    if os.path.isfile(path):
        return "file", os.path.getsize(path)
    return ("dir", None) if os.path.isdir(path) else ("missing", None)


def _node_lacks(path: str, state: tuple[str, int | None]) -> bool:
    """Whether this node's ``path`` is not the driver's: absent, or a file of another size."""
    kind, size = state
    if kind == "missing":  # the driver cannot see it either: the node's own copy (if any) is the input
        return False
    here = _input_state(path)
    return here[0] != kind or (kind == "file" and here[1] != size)


_SCRATCH_PREFIX = "stereo-recon-job-"


def _scratch_dir() -> Path:
    """A fresh scratch folder named after this process; first removes those of dead processes
    (a worker killed mid-job, e.g. by the OOM killer, cannot clean up after itself)."""
    for old in Path(tempfile.gettempdir()).glob(f"{_SCRATCH_PREFIX}*-*"):
        pid = old.name[len(_SCRATCH_PREFIX):].split("-")[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(old, ignore_errors=True)
    return Path(tempfile.mkdtemp(prefix=f"{_SCRATCH_PREFIX}{os.getpid()}-"))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def run_on_node(job: Job, states: dict, ship_mode: str, shipped: tuple[str, ...], *blobs: bytes) -> dict:
    """Ray task body: run ``job`` in a scratch folder of this node and return its outputs as tar bytes.

    states : driver's view of each input (``_input_state``), to spot inputs this node lacks.
    shipped : the inputs whose tar bytes follow in ``blobs``; then, with ``job.reuse_outputs``,
        one blob (or None) per output folder.
    Returns ``{"missing": [...]}`` when inputs must be shipped first, else
    ``{"result": dict, "outputs": {driver_path: bytes | None}}``.
    """
    lacking = [p for p in job.inputs if p not in shipped and _node_lacks(p, tuple(states[p]))]
    if lacking:
        if ship_mode == "auto":
            return {"missing": lacking}
        return {"result": {"name": job.name, **job.info, "host": socket.gethostname(), "ok": False, "time_s": 0.0,
                           "error": f"{lacking[0]}: not on node {socket.gethostname()} (the same absolute path on every "
                                    f"node, or --ship-inputs auto)"}, "outputs": {}}
    scratch = _scratch_dir()
    try:
        to_node: dict[str, str] = {}
        for k, (path, blob) in enumerate(zip(shipped, blobs)):
            dest = scratch / "in" / str(k)
            dest.mkdir(parents=True)
            _unpack(blob, dest)
            to_node[path] = str(dest / os.path.basename(path.rstrip("/")))
        reused = blobs[len(shipped):]
        for k, path in enumerate(job.outputs):
            dest = scratch / "out" / str(k)
            dest.mkdir(parents=True)
            if job.reuse_outputs and k < len(reused) and reused[k] is not None:
                _unpack(reused[k], dest)
            to_node[path] = str(dest / os.path.basename(path.rstrip("/")))
        result = call_job(replace(job, args=substitute_paths(job.args, to_node)))
        outputs = {p: _pack(to_node[p]) if os.path.exists(to_node[p]) else None for p in job.outputs}
        return {"result": result, "outputs": outputs, "moved": {v: k for k, v in to_node.items()}}
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _relocate_text(text: str, moved: dict[str, str], suffix: str) -> str:
    """Node scratch paths -> driver paths inside one text output, in each form that format writes them."""
    for node_path, driver_path in moved.items():
        forms = [(node_path, driver_path)]
        if suffix == ".json":  # json.dump escapes non-ASCII (ensure_ascii) and quotes/backslashes
            forms = [(json.dumps(node_path)[1:-1], json.dumps(driver_path)[1:-1]),
                     (json.dumps(node_path, ensure_ascii=False)[1:-1], json.dumps(driver_path, ensure_ascii=False)[1:-1])]
        elif suffix in {".html", ".htm"}:
            forms = [(html.escape(node_path), html.escape(driver_path)), *forms]
        for old, new in dict(forms).items():
            text = text.replace(old, new)
    return text


def _relocate_value(obj, moved: dict[str, str]):
    """Node scratch paths -> driver paths in a result dict (prefix match on strings)."""
    if isinstance(obj, str):
        for node_path, driver_path in moved.items():
            if obj == node_path or obj.startswith(node_path + os.sep):
                return driver_path + obj[len(node_path):]
        return obj
    if isinstance(obj, dict):
        return {k: _relocate_value(v, moved) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_relocate_value(v, moved) for v in obj)
    return obj


def _refresh_output_record(folder: Path, changed: list[Path]) -> None:
    """Re-record the size and sha256 of relocated files in the job's job.json, so that ``run --resume``
    (which checks them) still reuses the reconstruction the node made."""
    from stereo_recon.app.pipeline import output_record
    from stereo_recon.core.paths import RunPaths

    job = RunPaths(folder).summary
    names = [f.name for f in changed if f.parent == folder]
    if not names or not job.is_file():
        return
    rec = json.loads(job.read_text(encoding="utf-8"))
    outputs = rec.get("outputs")
    if not isinstance(outputs, dict) or not any(n in outputs for n in names):
        return
    outputs.update(output_record(folder, [n for n in names if n in outputs]))
    write_json_atomic(job, rec)


def land(reply: dict) -> dict:
    """Unpack a task's output folders into the driver's paths (atomically) and return its result."""
    moved = reply.get("moved") or {}
    for driver_path, blob in reply["outputs"].items():
        if blob is None:
            continue
        with staged_output_dir(driver_path) as stage:
            _unpack(blob, stage)
            inner = stage / os.path.basename(driver_path.rstrip("/"))
            changed = []
            for f in inner.rglob("*"):
                if f.is_file() and f.suffix.lower() in _TEXT_SUFFIXES:
                    try:
                        text = f.read_text(encoding="utf-8")
                    except UnicodeDecodeError:
                        continue
                    new = _relocate_text(text, moved, f.suffix.lower())
                    if new != text:
                        f.write_text(new, encoding="utf-8")
                        changed.append(f)
            _refresh_output_record(inner, changed)
            for item in inner.iterdir():  # the staged folder's contents are the job folder's
                os.replace(item, stage / item.name)
            inner.rmdir()
    return _relocate_value(reply["result"], moved)


def _ray_error_line(err: BaseException) -> str:
    """One line for a Ray-side failure (worker crash, lost node, package missing on a node, ...).

    Ray packs a remote traceback into its messages: keep the traceback's last line (the error
    itself) and the first sentence of Ray's own words.
    """
    cause = getattr(err, "cause", None)
    base = cause if isinstance(cause, BaseException) and cause is not err else err
    lines = [ln.strip() for ln in str(base).splitlines() if ln.strip()]
    starts = [i for i, ln in enumerate(lines) if ln.startswith("Traceback (most recent call last)")]
    if not starts:
        return one_line(base)
    final = lines[-1]
    intro = " ".join(lines[:starts[0]]).split(". ")[0].rstrip(":. ")
    if "ModuleNotFoundError" in final or "ImportError" in final:
        intro += "; is the same stereo-recon installed on every node?"
    return f"{final} ({intro})" if intro else final


def run_jobs_ray(jobs: Sequence[Job], options: RayOptions, workers: int | None = None,
                 progress: Callable[[dict], None] | None = None) -> list[dict]:
    """Run (driver-resolved) jobs on Ray; ``progress`` sees each result as it finishes (``ray.wait``).

    workers : the most jobs submitted at once (None: all; Ray queues them by resources).
    Returns the results in the order of ``jobs``.
    """
    _check_options(options)
    ray = _import_ray()
    started = connect(options, workers)
    states = [{p: _input_state(p) for p in j.inputs} for j in jobs]
    task = ray.remote(run_on_node)
    # Resources are asked per task (an existing cluster refuses them at connection time); memory
    # only steers scheduling. One retry covers a lost node without repeating a crashing job 4 times.
    resources = {"num_cpus": options.cpus_per_job, "max_retries": 1,
                 **({"memory": int(options.memory_per_job_gb * 2**30)} if options.memory_per_job_gb else {})}
    results: dict[int, dict] = {}
    pending: dict = {}
    queue = collections.deque((i, ()) for i in range(len(jobs)))

    def submit(i: int, ship: tuple[str, ...]) -> None:
        job = jobs[i]
        if options.ship_inputs == "always":
            ship = tuple(p for p in job.inputs if states[i][p][0] != "missing")
        try:
            blobs = [ray.put(_pack(p)) for p in ship]
            if job.reuse_outputs:
                blobs += [ray.put(_pack(p)) if os.path.isdir(p) else None for p in job.outputs]
        except OSError as err:  # unreadable here: this job fails, the others go on
            finish(i, _failed(job, f"cannot send its files to the cluster: {one_line(err)}"))
            return
        ref = task.options(name=f"stereo-recon:{job.name}", **resources).remote(job, states[i], options.ship_inputs, ship, *blobs)
        pending[ref] = (i, ship)

    def finish(i: int, result: dict) -> None:
        results[i] = result
        if progress:
            progress(result)

    with _ray_messages_to_log():  # also while shutting down: Ray's notices about dead workers arrive late
        try:
            _drain(ray, jobs, queue, pending, workers, submit, finish)
        finally:
            for ref in pending:  # interrupted: do not leave work running on a shared cluster
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            if started:
                ray.shutdown()
    return [results[i] for i in range(len(jobs))]


def _drain(ray, jobs, queue, pending, workers, submit, finish) -> None:
    """Submit up to ``workers`` jobs at a time and hand each reply to ``finish`` as it arrives (``ray.wait``)."""
    while queue or pending:
        while queue and (workers is None or len(pending) < workers):
            submit(*queue.popleft())
        if not pending:  # every job just taken failed before reaching Ray
            continue
        [ref], _ = ray.wait(list(pending), num_returns=1)
        i, ship = pending.pop(ref)
        try:
            reply = ray.get(ref)
        except Exception as err:  # Ray-side: a crashed worker, a lost node, a package missing there
            finish(i, _failed(jobs[i], _ray_error_line(err)))
            continue
        if "missing" in reply:
            queue.appendleft((i, (*ship, *reply["missing"])))
            continue
        try:
            finish(i, land(reply))
        except OSError as err:
            finish(i, _failed(jobs[i], f"copying its outputs back failed: {one_line(err)}"))


def _failed(job: Job, error: str) -> dict:
    return {"name": job.name, **job.info, "ok": False, "error": error, "time_s": 0.0}
