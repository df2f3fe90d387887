"""Episodes on a Ray cluster (``collect --ray``, ``eval --ray``): connecting, the files a job
sends with it, and tasks with retries.

- :func:`ray_session`: Ray for one command. No address: a local Ray is started for the command
  (or the cluster ``RAY_ADDRESS`` names); ``auto`` or ``host:port`` connects to a running
  cluster, as ``ray.init(address=...)`` does. On a cluster the package's code travels with the
  job (Ray's ``py_modules``), so every node runs the driver's code; its dependencies (the
  set-up's venv) must be installed on every node. A local Ray's workers import the driver's
  package from where it is (``PYTHONPATH``): no runtime environment to build per worker.
- :class:`Bundle`: the files the episodes read (layouts, their asset folders with the splat, a
  policy file) as one zip in Ray's object store, unpacked once per node under the temporary
  folder; no shared filesystem is assumed. Paths in a task's arguments are mapped onto the
  node's copy, and paths in its results and error messages back onto the driver's
  (:class:`Paths`).
- :func:`remote_task`: a task as Ray runs it, on the node's copy of the files. A task whose
  worker process dies (killed, out of memory, its node lost) runs again, up to
  :data:`TASK_RETRIES` times; an exception a task raises comes back as it was raised (its
  message naming the driver's files; :class:`CarriedError`), not as Ray's traceback, and so
  does its ``sys.exit`` (:class:`TaskExit`), which would otherwise end its worker process. The
  episode executor's Ray backend (``pipelines/on_ray.py``) submits them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import io
import os
import pickle
import re
import shutil
import tempfile
import threading
import zipfile
from collections.abc import Callable, Iterable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import embodied_envs

RAY_LOCAL = "local"  # --ray without an address: a Ray of this machine, started for the command
WORKER_NICENESS = 0  # a local Ray's worker processes: the command's priority (Ray's default 15)
TASK_RETRIES = 3  # runs again of a task whose worker process died (Ray's max_retries)
LOCAL_OBJECT_STORE_BYTES = 256 * 2**20  # a local Ray's object store (job files, results)
MAX_BUNDLE_BYTES = 128 * 2**20  # the job's files, zipped: held once per node in the store
BUNDLE_FOLDER = "embodied_envs-ray"  # per node, under the temporary folder: unpacked bundles
EARLY_POLL_SECONDS = 0.05  # how often a session looks whether start_early's Ray is up
ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # every zip member's date: a bundle's bytes follow its files


class ClusterError(RuntimeError):
    """Ray cannot run the job (no cluster at the address, too large a job, a worker lost)."""


_EARLY: dict[tuple, tuple[threading.Thread, dict]] = {}  # start_early's Ray starts, by args


def start_early(address: str | None, cpus: int | None = None, warm: tuple[str, ...] = ()) -> None:
    """Begins :func:`ray_session`'s start of Ray in a thread, so that Ray's processes come up
    while the command imports the simulator and checks its inputs (a Ray start took 4-22 s
    on the busy 2-core machine); the session with the same arguments waits for it. Once Ray
    is up, a task per CPU imports the modules ``warm`` names, so that the worker processes
    the episodes then run in have imported the simulator meanwhile (5-8 s each here), not
    after the driver is ready (:func:`_warm`).

    The thread lives until the session ends: the processes a local Ray starts die with the
    thread that started them (their parent-death signal follows the thread). A command that
    stops before its session leaves it to Ray's exit handler (the thread is a daemon)."""
    outcome: dict[str, Any] = {"release": threading.Event()}

    def init() -> None:
        try:
            _init(address, cpus)
            _warm(warm)
        except BaseException as e:  # raised again by the session, in the command's thread
            outcome["error"] = e
            return
        finally:
            outcome["ready"] = True
        outcome["release"].wait()

    thread = threading.Thread(target=init, name="ray-start", daemon=True)
    thread.start()
    _EARLY[(address, cpus)] = (thread, outcome)


def _import(modules: tuple[str, ...]) -> None:
    """A warm-up task: imports ``modules`` in this worker process (kept for the next tasks)."""
    for name in modules:
        importlib.import_module(name)


def _warm(modules: tuple[str, ...]) -> None:
    """Starts a task per CPU of the cluster that imports ``modules`` (not waited for: the
    episodes' tasks queue behind them and reuse their worker processes, which Ray keeps)."""
    if not modules:
        return
    import ray  # only where a command runs on Ray

    remote = ray.remote(num_cpus=1)(_import)
    for _ in range(cluster_cpus()):
        remote.remote(modules)


def starting(address: str | None, cpus: int | None = None) -> bool:
    """Whether :func:`start_early` began a start of Ray for these arguments."""
    return (address, cpus) in _EARLY


@contextmanager
def ray_session(address: str | None, cpus: int | None = None):
    """Ray for one command, shut down (or disconnected) after it.

    Args:
        address: None: a local Ray with ``cpus`` CPUs (default: the machine's), unless
            ``RAY_ADDRESS`` names a cluster; ``auto`` or ``host:port``: a running cluster.
        cpus: a local Ray's CPUs.

    Raises:
        ClusterError: no running cluster at ``address``.
    """
    import ray  # only where a command runs on Ray

    early = _EARLY.pop((address, cpus), None)
    if early is None:
        _init(address, cpus)
    else:
        thread, outcome = early
        while thread.is_alive() and "ready" not in outcome:
            thread.join(EARLY_POLL_SECONDS)
        if "error" in outcome:
            raise outcome["error"]
    try:
        yield
    finally:
        ray.shutdown()
        if early is not None:
            early[1]["release"].set()


def _init(address: str | None, cpus: int | None) -> None:
    """``ray.init`` for :func:`ray_session`."""
    import ray  # only where a command runs on Ray
    from ray.exceptions import AuthenticationError  # Ray's token authentication (2.52 on)

    package = str(Path(embodied_envs.__file__).parent)
    kwargs: dict[str, Any] = dict(
        log_to_driver=False,  # workers' warnings would break the progress bar's line
    )
    local = address is None and not os.environ.get("RAY_ADDRESS")
    if local:
        # a new Ray even where a cluster runs ("local"); its workers at the command's priority,
        # as --workers processes (Ray's default nice 15 starves them on a busy machine: their
        # imports took 5-7x a plain process's)
        address = "local"
        kwargs.update(num_cpus=cpus, include_dashboard=False,
                      object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                      _system_config={"worker_niceness": WORKER_NICENESS})  # fmt: skip
    else:  # other machines get the driver's code with the job
        kwargs["runtime_env"] = {"py_modules": [package]}
    try:
        # this machine's workers import the driver's package from where it is (no runtime
        # environment: one held each worker's start ~10 s, and Ray's idle workers go unused)
        with _python_path(str(Path(package).parent) if local else None):
            ray.init(address=address, **kwargs)
    except (ConnectionError, AuthenticationError) as e:
        said = _refusal(e)
        if said is not None:  # the cluster is up and refused: not "no cluster there"
            raise ClusterError(_refused_line(named(address), said)) from None
        if isinstance(e, AuthenticationError):  # RAY_AUTH_MODE=token, and no token to send
            raise ClusterError(
                f"{named(address)}: this machine has no authentication token to send "
                f"(RAY_AUTH_MODE=token; Ray: {' '.join(e.message.split())}). Fix: {TOKEN_FIX}"
            ) from None
        raise ClusterError(
            f"{named(address)}: no running Ray cluster there ({' '.join(str(e).split())}). Fix: "
            "start one (ray start --head), give its address, or give --ray without a value for "
            "a Ray of this machine alone"
        ) from None


TOKEN_FIX = (  # a token refused or missing: where Ray reads the cluster's token
    "give this machine the cluster's token (`ray get-auth-token` on its head) in RAY_AUTH_TOKEN "
    "or ~/.ray/auth_token, with RAY_AUTH_MODE=token"
)


def named(address: str | None) -> str:
    """How the command names the cluster ``address`` gives (None or ``auto``: the one
    ``RAY_ADDRESS`` names, if set)."""
    env = os.environ.get("RAY_ADDRESS")
    text = "--ray" if address is None else f"--ray {address}"
    return text + (f" (RAY_ADDRESS={env})" if address in (None, "auto") and env else "")


def _refusal(error: BaseException) -> str | None:
    """Ray's words, when ``ray.init``'s ``ConnectionError`` (or an error it chains) says that
    the cluster refused this machine's authentication (gRPC's ``Unauthenticated``: a wrong
    token, or none); None for any other failure."""
    texts = []
    while error is not None and len(texts) < 8:
        texts.append(str(error))
        error = error.__cause__ or error.__context__
    text = "\n".join(texts)
    found = re.search(r"InvalidAuthToken: ([^.\n]+)", text)
    if found is not None:
        return found.group(1).strip()
    return "Unauthenticated" if "Unauthenticated" in text else None


def _refused_line(where: str, said: str) -> str:
    """The line for a cluster that refused this machine: its token (or that none was sent:
    Ray sends one only with ``RAY_AUTH_MODE=token``), Ray's words and the fix."""
    if os.environ.get("RAY_AUTH_MODE", "").lower() != "token":  # Ray sets it where it sends one
        return (
            f"{where}: the Ray cluster there requires an authentication token and this machine "
            f"sent none (RAY_AUTH_MODE is not token here; Ray: {said}). Fix: {TOKEN_FIX}"
        )
    source = ("RAY_AUTH_TOKEN" if os.environ.get("RAY_AUTH_TOKEN")
              else os.environ.get("RAY_AUTH_TOKEN_PATH") or "~/.ray/auth_token")  # fmt: skip
    return (
        f"{where}: the Ray cluster there refused this machine's authentication token (from "
        f"{source}; Ray: {said}). Fix: {TOKEN_FIX}"
    )


@contextmanager
def _python_path(folder: str | None):
    """``PYTHONPATH`` with ``folder`` first while Ray starts (its processes inherit it)."""
    before = os.environ.get("PYTHONPATH")
    if folder is not None:
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (folder, before) if p)
    try:
        yield
    finally:
        if folder is not None:
            if before is None:
                os.environ.pop("PYTHONPATH", None)
            else:
                os.environ["PYTHONPATH"] = before


def cluster_cpus() -> int:
    """The connected cluster's CPUs (at least 1)."""
    import ray  # only where a command runs on Ray

    return max(1, int(ray.cluster_resources().get("CPU", 1)))


# --- the job's files -----------------------------------------------------------------------
def _walk(paths: Iterable) -> list[tuple[Path, Path]]:
    """Every file under ``paths`` as (the name it travels by, where it is read). An entry is a
    path, or a pair (the name a layout gives a folder, the folder it resolves to): a folder
    reached through a symbolic link (a checkout's ``./assets``) travels by the layout's name
    for it, so the layout's relative paths hold in the node's copy, which has no link."""
    files: dict[Path, Path] = {}
    for entry in paths:
        name, source = entry if isinstance(entry, tuple) else (entry, entry)
        name, source = Path(os.path.abspath(name)), Path(source).resolve()
        if source.is_dir():
            for q in source.rglob("*"):
                if q.is_file():
                    files[name / q.relative_to(source)] = q
        elif source.is_file():
            files[name] = source
    return sorted(files.items())


@dataclasses.dataclass(frozen=True)
class Bundle:
    """The job's files in the object store: groups of files, each under its driver folder
    (``roots``: the group's common folder), their zip (``ref``: a Ray object reference to its
    bytes) and their hash (``digest``)."""

    roots: tuple[str, ...]
    digest: str
    ref: Any

    @classmethod
    def put(cls, *groups: Iterable) -> Bundle:
        """Zips each group of files and folders (relative to the group's common folder: a
        layout and its asset folders keep their relative places) into the object store; an
        entry is a path or a pair (its name, the path it resolves to: :func:`_walk`).

        Raises:
            ClusterError: a group's files share no folder but ``/``, or the zip is over
                ``MAX_BUNDLE_BYTES``.
        """
        import ray  # only where a command runs on Ray

        digest, buffer, roots = hashlib.sha256(), io.BytesIO(), []
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as z:
            for group in groups:
                files = _walk(group)
                if not files:
                    continue
                root = os.path.commonpath([str(f.parent) for f, _ in files])
                if root == os.sep:
                    raise ClusterError(
                        f"{files[0][0]} and {files[-1][0]} share no folder but {os.sep}: a Ray "
                        "job sends a layout and its asset folders as one folder. Fix: keep "
                        "them under one folder"
                    )
                roots.append(root)
                for f, source in files:
                    name = f"{len(roots) - 1}/{f.relative_to(root).as_posix()}"
                    data = source.read_bytes()
                    digest.update(f"{name}\0{len(data)}\0".encode() + data)
                    z.writestr(zipfile.ZipInfo(name, ZIP_TIME), data, zipfile.ZIP_DEFLATED)
        if buffer.tell() > MAX_BUNDLE_BYTES:
            raise ClusterError(
                f"the files under {', '.join(roots)} that the episodes read (layouts, asset "
                f"folders, splat) are {buffer.tell() / 2**20:.0f} MiB zipped, over the "
                f"{MAX_BUNDLE_BYTES // 2**20} MiB a Ray job sends. Fix: smaller asset folders "
                "(a lighter splat), or run without --ray"
            )
        return cls(tuple(roots), digest.hexdigest(), ray.put(buffer.getvalue()))

    def unpacked(self) -> Paths:
        """On a worker: this node's copy of the files (unpacked once per node), as the map
        from the driver's folders to it."""
        import ray  # only where a command runs on Ray

        folder = Path(tempfile.gettempdir()) / BUNDLE_FOLDER / self.digest
        if not folder.is_dir():
            folder.parent.mkdir(parents=True, exist_ok=True)
            work = Path(tempfile.mkdtemp(prefix=f".{self.digest}.", dir=folder.parent))
            data = ray.get(self.ref)
            zipfile.ZipFile(io.BytesIO(data)).extractall(work)
            try:
                work.rename(folder)
            except OSError:  # another worker of this node unpacked it first
                shutil.rmtree(work, ignore_errors=True)
        return Paths(tuple((root, str(folder / str(k))) for k, root in enumerate(self.roots)))


@dataclasses.dataclass(frozen=True)
class Paths:
    """Maps paths between the driver's folders and a node's copies of them (``pairs``: driver
    folder, node folder), in strings, containers and dataclasses (their fields): a folder's
    name followed by ``/`` or ending the string, longest first, in one pass."""

    pairs: tuple[tuple[str, str], ...]

    def to_node(self, value):
        return _mapped(value, dict(self.pairs))

    def to_driver(self, value):
        return _mapped(value, {node: driver for driver, node in self.pairs})


def _mapped(value, table: dict[str, str]):
    if not table:
        return value
    if isinstance(value, str):
        names = sorted(table, key=len, reverse=True)
        pattern = "|".join(re.escape(n) for n in names)
        return re.sub(f"({pattern})(?=/|$)", lambda m: table[m.group(1)], value)
    if isinstance(value, list | tuple):
        return type(value)(_mapped(v, table) for v in value)
    if isinstance(value, dict):
        return {_mapped(k, table): _mapped(v, table) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        changes = {f.name: _mapped(getattr(value, f.name), table)
                   for f in dataclasses.fields(value) if f.init}  # fmt: skip
        return dataclasses.replace(value, **changes)
    return value


# --- tasks ---------------------------------------------------------------------------------
def _task(fn: Callable, bundle: Bundle, args: tuple):
    """A Ray task: ``fn(*args)`` on this node's copy of the files; the result (paths back on
    the driver's), this node's id and this process's id."""
    import ray  # only where a command runs on Ray

    os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
    paths = bundle.unpacked()
    try:
        result = fn(*paths.to_node(args))
    except Exception as e:  # the message names the driver's files, as the local run's does
        e.args = paths.to_driver(e.args)
        e.__dict__.update({k: paths.to_driver(v) for k, v in vars(e).items() if isinstance(v, str)})
        try:  # an exception whose __init__ takes other arguments than its args is carried
            pickle.loads(pickle.dumps(e))
        except Exception:
            raise CarriedError.of(e) from None
        raise
    except SystemExit as e:  # the task's code asked its process to end (sys.exit)
        if hasattr(e, "ray_terminate_msg"):  # Ray's own: this worker told to stop
            raise
        raise TaskExit(*paths.to_driver(e.args)) from None  # not a worker lost: said as is
    return paths.to_driver(result), ray.get_runtime_context().get_node_id(), os.getpid()


class TaskExit(Exception):
    """A task's ``SystemExit`` (its args), carried back as an exception: Ray would end the
    worker process and run the task again as a lost worker's. The driver raises the
    ``SystemExit`` again, as a local run's code raises it (:meth:`rebuilt`)."""

    def rebuilt(self) -> SystemExit:
        return SystemExit(*self.args)


class CarriedError(Exception):
    """A task's exception that pickle cannot rebuild (its ``__init__`` takes other arguments
    than its ``args``, as ``PlacementError``'s does), carried as its class's name, its args
    and its attributes; the driver raises the same class again (:meth:`rebuilt`)."""

    @classmethod
    def of(cls, e: Exception) -> CarriedError:
        return cls(type(e).__module__, type(e).__qualname__, e.args, dict(e.__dict__))

    def rebuilt(self) -> Exception:
        """The exception as it was raised (its class, message and attributes); itself when
        its class cannot be found here."""
        module, name, args, attributes = self.args
        try:
            kind = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError):
            return self
        e = kind.__new__(kind)
        e.args = args
        e.__dict__.update(attributes)
        return e


def remote_task():
    """The Ray remote function of a task (:func:`_task`: ``fn(*args)`` on the node's copy of a
    bundle's files), one CPU each, run again up to :data:`TASK_RETRIES` times when its worker
    process dies."""
    import ray  # only where a command runs on Ray

    return ray.remote(num_cpus=1, max_retries=TASK_RETRIES)(_task)
