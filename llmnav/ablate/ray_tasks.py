"""Episodes as Ray tasks: a private local Ray on loopback (`--ray local`) or an existing cluster.

`--ray local` starts a Ray instance for this sweep alone and shuts it down afterwards. Ray picks the
address it listens on from `RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER`: on macOS and Windows it is off by default
and every Ray process then listens on 127.0.0.1 only; on Linux it is on and Ray listens on the machine's
address and on every interface (checked on Ray 2.60, where `_node_ip_address="127.0.0.1"` did not change
that). Setting it to 0 before Ray is imported (it is read at import) keeps a Linux instance on loopback
too; `start_local` does that and then checks the node address Ray chose.

`--ray local` also brings its own token for Ray's token authentication (`RAY_AUTH_MODE=token` and
`RAY_AUTH_TOKEN`, in this process and the Ray processes it starts): left to itself a new local Ray
writes one to `~/.ray/auth_token` and leaves it there (and a `ray start` on this machine then turns
token authentication on, because the file exists), and it prints a banner saying so.

`--ray ADDRESS` (`host:6379`, `ray://host:10001`) or `auto` connects to a running cluster, with what the
driver needs and nobody should have to set by hand: for a loopback address the loopback switch (else
Ray replaces 127.0.0.1 with the machine's address and retries that for minutes), and, when a token is
at hand (`RAY_AUTH_TOKEN`, `RAY_AUTH_TOKEN_PATH` or `~/.ray/auth_token`, as `ray start` uses it), token
authentication. Joining is given `JOIN_TIMEOUT_S`; a cluster that cannot be joined by then is one line
and exit 2, not a hang. No shared filesystem is assumed:
- a task gets everything as values: the episode spec, and a custom scenario file's content;
- backend settings (`OLLAMA_HOST`, `OPENAI_BASE_URL`, `LLMNAV_*`) and the thread caps travel in the
  task's `runtime_env={"env_vars": ...}`; keys (`*_API_KEY`) travel as a task argument the task puts in
  its environment for the episode, because Ray's runtime-env agent writes every env_vars value into its
  session log (`runtime_env_agent.log`, seen with Ray 2.60); neither is part of the spec, so no run log
  or manifest can hold them, and `--ray local` deletes its private Ray folder (sessions, logs) at the end;
- a task runs its episode in a temporary folder on its node and returns the folder's files; the driver
  writes them under `--out` (summary.json last), so resume and tables read the driver's disk only;
- a task reserves the CPUs its model uses (`num_cpus`) and caps the model's threads to them.
A task that crashes (its worker died, ran out of memory, could not import llmnav) is an error for that
episode, never an exception out of the sweep.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import re
import secrets
import shutil
import socket
import sys
import tempfile
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from llmnav.ablate.executors import _WORKER_THREAD_VARS, Result, Runner, execute_episode
from llmnav.backends.base import parse_spec
from llmnav.backends.local import THREADS_ENV
from llmnav.core.safefiles import write_bytes
from llmnav.errors import BadInputError, one_line
from llmnav.runs.locking import LOCK_FILE
from llmnav.runs.runlog import SUMMARY_FILE, write_json_atomic

if TYPE_CHECKING:
    from llmnav.ablate.grid import Episode
    from llmnav.runs.runner import EpisodeSpec

LOCAL = "local"
LOOPBACK_SWITCH = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
AUTH_MODE = "RAY_AUTH_MODE"
AUTH_TOKEN = "RAY_AUTH_TOKEN"
AUTH_TOKEN_PATH = "RAY_AUTH_TOKEN_PATH"
JOIN_TIMEOUT_S = 15.0  # [s] joining a cluster that answers; Ray itself would retry for minutes
# Environment variables a task needs from the driver: keys and server settings of the backends.
_FORWARDED = re.compile(r"^(?:[A-Z0-9_]+_API_KEY|OLLAMA_HOST|OPENAI_BASE_URL|LLMNAV_[A-Z0-9_]+)$")
_SECRET = re.compile(r"^[A-Z0-9_]+_API_KEY$")
_CONNECT_TIMEOUT_S = 5.0  # [s] a cluster address that does not answer this fast is reported, not waited on


@dataclass
class TaskResult:
    """What a task sends back: the episode's result, its run folder's files, and where it ran."""

    result: Result
    files: dict[str, bytes] = field(default_factory=dict)  # path relative to the run folder → content
    node: str = ""
    workdir: str = ""  # the temporary run folder on the node (rewritten to the driver's in summary.json)


def forwarded_env(environ: dict[str, str] | None = None) -> dict[str, str]:
    """The backend keys and settings to hand to every task (values never leave the runtime env)."""
    source = os.environ if environ is None else environ
    return {name: value for name, value in source.items() if _FORWARDED.match(name)}


def model_threads(backend: str, environ: dict[str, str] | None = None) -> int:
    """CPUs one task reserves: its local model's threads ($LLMNAV_LOCAL_THREADS, default 1), else 1."""
    if parse_spec(backend)[0] != "local":
        return 1
    value = (os.environ if environ is None else environ).get(THREADS_ENV, "")
    return int(value) if value.isdigit() and int(value) > 0 else 1


def task_env(backend: str, environ: dict[str, str] | None = None) -> tuple[int, dict[str, str], dict[str, str]]:
    """(CPUs to reserve, env_vars for the runtime env, keys) for one episode's task.

    env_vars: the forwarded settings and the thread caps; keys: the `*_API_KEY` variables, kept out of the
    runtime env (Ray logs it).
    """
    cpus = model_threads(backend, environ)
    forwarded = forwarded_env(environ)
    keys = {name: value for name, value in forwarded.items() if _SECRET.match(name)}
    env = {name: value for name, value in forwarded.items() if name not in keys}
    env.update({name: "1" for name in _WORKER_THREAD_VARS})
    env[THREADS_ENV] = str(cpus)
    return cpus, env, keys


def _scenario_payload(scenario: str) -> tuple[str, bytes] | None:
    """(file name, content) of a custom scenario file; None for a bundled scenario name."""
    path = Path(scenario)
    if scenario.endswith((".yaml", ".yml")) and path.is_file():
        return path.name, path.read_bytes()
    return None


def run_task(runner: Runner, spec: EpisodeSpec, scenario: tuple[str, bytes] | None, keys: dict[str, str]) -> TaskResult:
    """The body of one Ray task: run the episode in a temporary folder here, return its files."""
    node = socket.gethostname()
    workdir = Path(tempfile.mkdtemp(prefix="llmnav-task-"))
    saved = {name: os.environ.get(name) for name in keys}
    os.environ.update(keys)  # for this episode only: a Ray worker process serves many tasks
    try:
        updates: dict[str, Any] = {"out_dir": workdir / spec.out_dir.name}
        if scenario is not None:
            name, content = scenario
            (workdir / "scenario").mkdir()
            scenario_path = workdir / "scenario" / name
            scenario_path.write_bytes(content)
            updates["scenario"] = str(scenario_path)
        local_spec = spec.model_copy(update=updates)
        result = execute_episode(runner, local_spec)
        run_dir = local_spec.out_dir
        files = {
            str(path.relative_to(run_dir)): path.read_bytes()
            for path in sorted(run_dir.rglob("*"))
            if path.is_file() and path.name != LOCK_FILE
        } if run_dir.is_dir() else {}  # fmt: skip
        summary, error, fatal = result
        if error is not None:
            result = (summary, f"on Ray node {node}: {error}", fatal)
        return TaskResult(result, files, node, str(run_dir))
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        shutil.rmtree(workdir, ignore_errors=True)


def write_files(task: TaskResult, run_dir: Path) -> None:
    """Write a task's files into `run_dir` on this disk; summary.json last, each file atomically.

    A sweep killed while writing leaves a folder without a summary, which a resume runs again.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    for name in sorted(task.files, key=lambda n: n == SUMMARY_FILE):
        target = run_dir / name
        if Path(name).is_absolute() or ".." in Path(name).parts:
            continue  # only files inside the run folder
        target.parent.mkdir(parents=True, exist_ok=True)
        if name == SUMMARY_FILE:
            _write_summary(task, target)
            continue
        write_bytes(target, task.files[name])


def _write_summary(task: TaskResult, target: Path) -> None:
    """summary.json with the paths it names moved from the node's temporary folder to this one."""
    try:
        summary = json.loads(task.files[SUMMARY_FILE].decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        summary = None
    if not isinstance(summary, dict):
        write_bytes(target, task.files[SUMMARY_FILE])
        return
    for key in ("run_dir", "trajectory"):
        value = summary.get(key)
        if isinstance(value, str) and value.startswith(task.workdir):
            summary[key] = str(target.parent) + value[len(task.workdir) :]
    write_json_atomic(target, summary)


def _reachable(address: str) -> None:
    """Refuse at once a `host:port` (or `ray://host:port`) nothing answers on (Ray would retry for a minute)."""
    parts = _split(address)
    if parts is None:
        raise BadInputError(f"--ray {address}: expected 'local', 'auto', HOST:PORT or ray://HOST:PORT")
    try:
        with socket.create_connection(parts, timeout=_CONNECT_TIMEOUT_S):
            pass
    except OSError as err:
        reason = err.strerror or type(err).__name__
        raise BadInputError(f"--ray {address}: cannot reach the Ray cluster ({reason})") from None


def _split(address: str) -> tuple[str, int] | None:
    """(host, port) of `host:port` or `ray://host:port`; None when it is not of that form."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit() or not host:
        return None
    return host.strip("[]"), int(port)


def is_loopback(address: str) -> bool:
    """Whether a cluster address names this machine's loopback interface."""
    parts = _split(address)
    if parts is None:
        return False
    if parts[0] == "localhost":
        return True
    try:
        return ipaddress.ip_address(parts[0]).is_loopback
    except ValueError:
        return False


def _token_at_hand(environ: dict[str, str] | None = None) -> bool:
    """Whether a Ray token is available the way Ray looks for one (variable, path variable, home file)."""
    source = os.environ if environ is None else environ
    if source.get(AUTH_TOKEN, "").strip():
        return True
    path = source.get(AUTH_TOKEN_PATH) or str(Path.home() / ".ray" / "auth_token")
    return Path(path).is_file()


def _import_ray(address: str) -> Any:
    # Ray reads these when it is imported (its config is fixed then), so they are set first.
    if address == LOCAL or is_loopback(address):
        os.environ[LOOPBACK_SWITCH] = "0"  # keep the driver on loopback
    if address == LOCAL:
        _private_token()
    else:
        if AUTH_MODE not in os.environ and _token_at_hand():
            os.environ[AUTH_MODE] = "token"  # what `ray start` does when it finds the token
    try:
        # deferred: Ray is the optional 'ray' extra (about 0.6 s to import)
        import ray
    except ImportError:
        raise BadInputError("--ray needs Ray: pip install 'llmnav[ray]' (on every node of a cluster)") from None
    return ray


_private_dirs: list[str] = []


def _private_dir() -> str:
    """A fresh folder for a private Ray's sessions and logs (short: Ray puts socket paths in it)."""
    path = tempfile.mkdtemp(prefix="llmnav-ray-")
    _private_dirs.append(path)
    return path


_saved_auth: dict[str, str | None] = {}


def _private_token() -> None:
    """Token authentication for a private Ray with a token of its own, in the environment only."""
    for name in (AUTH_MODE, AUTH_TOKEN, AUTH_TOKEN_PATH):
        _saved_auth.setdefault(name, os.environ.get(name))
    os.environ.pop(AUTH_TOKEN_PATH, None)
    os.environ[AUTH_MODE] = "token"
    os.environ[AUTH_TOKEN] = secrets.token_hex(32)


def _restore_auth() -> None:
    for name, value in _saved_auth.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value
    _saved_auth.clear()


def disconnect(ray: Any, address: str) -> None:
    """Shut down a Ray this sweep started; for `local`, delete its folder (sessions, logs) too."""
    ray.shutdown()
    if address == LOCAL:
        while _private_dirs:
            shutil.rmtree(_private_dirs.pop(), ignore_errors=True)
        _restore_auth()


def _mute_fd2() -> int | None:
    """Point file descriptor 2 at /dev/null; the saved descriptor, or None when there is no fd 2."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        return None
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
    os.close(null)
    return saved


def _unmute_fd2(saved: int, *, keep_muted: bool) -> None:
    """Give fd 2 back; a join still running would go on logging there, so then only `sys.stderr` gets it."""
    if keep_muted:
        try:
            real = sys.stderr.fileno() == 2
        except (AttributeError, OSError, ValueError):
            real = False  # a captured stream (tests): it never reaches fd 2 anyway
        if real:
            sys.stderr = os.fdopen(saved, "w", buffering=1, encoding="utf-8", errors="replace")
        else:
            os.close(saved)
        return
    os.dup2(saved, 2)
    os.close(saved)


class _DropMessage(logging.Filter):
    """Drops log records whose message starts with a given text."""

    def __init__(self, start: str) -> None:
        super().__init__()
        self.start = start

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(self.start)


def _join(ray: Any, address: str, timeout_s: float = JOIN_TIMEOUT_S) -> None:
    """`ray.init(address)` within `timeout_s`, else one-line BadInputError (Ray's own retries take minutes)."""
    failure: list[BaseException] = []

    def init() -> None:
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
        except BaseException as err:  # noqa: BLE001 - handed to the caller's thread
            failure.append(err)

    # Ray warns that a thread other than the main one cannot set its SIGTERM handler: llmnav keeps its own.
    quiet = _DropMessage("SIGTERM handler is not set")
    worker_log = logging.getLogger("ray._private.worker")
    worker_log.addFilter(quiet)
    joiner = threading.Thread(target=init, name="llmnav-ray-join", daemon=True)
    # Ray's core logs each failed attempt to join straight to file descriptor 2, before any of its
    # logging can be configured: the one line that matters is ours, so fd 2 is muted while joining.
    muted = _mute_fd2()
    joiner.start()
    try:
        joiner.join(timeout_s)
    finally:
        worker_log.removeFilter(quiet)
        if muted is not None:
            _unmute_fd2(muted, keep_muted=joiner.is_alive())
    if joiner.is_alive():
        hint = "" if _token_at_hand() else "; if it uses token authentication, set RAY_AUTH_TOKEN"
        raise BadInputError(
            f"--ray {address}: the port answers but no Ray cluster could be joined within {timeout_s:g} s{hint}"
        )
    if failure:
        err = failure[0]
        if isinstance(err, ConnectionError | RuntimeError | ValueError) or "auth" in type(err).__name__.lower():
            raise BadInputError(f"--ray {address}: cannot connect: {one_line(err)}") from None
        raise err


def connect(address: str) -> tuple[Any, bool]:
    """Start (`local`) or join a Ray cluster; (the ray module, whether this call started it)."""
    ray = _import_ray(address)
    if ray.is_initialized():  # a caller (or a test) connected already
        _restore_auth()
        return ray, False
    if address == LOCAL:
        # deferred: Ray is the optional 'ray' extra
        from ray._private import ray_constants

        if ray_constants.ENABLE_RAY_CLUSTER:
            _restore_auth()
            raise BadInputError(
                f"--ray local: Ray was imported before {LOOPBACK_SWITCH}=0 could keep it on loopback; "
                f"set {LOOPBACK_SWITCH}=0 in the environment"
            )
        try:
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, _temp_dir=_private_dir())
        except (ConnectionError, RuntimeError, ValueError) as err:
            _restore_auth()
            raise BadInputError(f"--ray local: Ray did not start: {one_line(err)}") from None
        node_ip = ray.util.get_node_ip_address()
        if node_ip != "127.0.0.1":
            disconnect(ray, LOCAL)
            raise BadInputError(f"--ray local: Ray chose {node_ip}, not loopback; not running the sweep")
        return ray, True
    if is_loopback(address):
        # deferred: Ray is the optional 'ray' extra
        from ray._private import ray_constants

        if ray_constants.ENABLE_RAY_CLUSTER:
            raise BadInputError(
                f"--ray {address}: Ray was imported before {LOOPBACK_SWITCH}=0 could keep it on loopback; "
                f"set {LOOPBACK_SWITCH}=0 in the environment"
            )
    if address != "auto":
        _reachable(address)
    _join(ray, address)
    return ray, True


def run_ray(
    runner: Runner, specs: Sequence[tuple[Episode, EpisodeSpec]], address: str
) -> Iterator[tuple[Episode, Result]]:
    """Run episodes as Ray tasks; yield each (episode, result) once its files are on this disk."""
    ray, started = connect(address)
    try:
        _check_cpus(ray, specs)
        remote = ray.remote(max_retries=0)(run_task)
        pending: dict[Any, tuple[Episode, EpisodeSpec]] = {}
        for ep, spec in specs:
            cpus, env, keys = task_env(spec.backend)
            scenario = _scenario_payload(spec.scenario)
            options = remote.options(num_cpus=cpus, runtime_env={"env_vars": env})
            ref = options.remote(runner, spec, scenario, keys)
            pending[ref] = (ep, spec)
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    ep, spec = pending.pop(ref)
                    yield ep, _collect(ray, ref, spec)
        finally:  # Ctrl-C or a fatal episode: what has not finished stays pending for a resume
            for ref in pending:
                ray.cancel(ref, force=True)
    finally:
        if started and address == LOCAL:
            disconnect(ray, LOCAL)


def _check_cpus(ray: Any, specs: Sequence[tuple[Episode, EpisodeSpec]]) -> None:
    """Refuse tasks no node could ever schedule (Ray would wait for such a node forever)."""
    largest = max((node.get("Resources", {}).get("CPU", 0) for node in ray.nodes() if node.get("Alive")), default=0)
    wanted = max((model_threads(spec.backend) for _, spec in specs), default=0)
    if wanted > largest:
        raise BadInputError(
            f"--ray: a task needs {wanted} CPUs ($LLMNAV_LOCAL_THREADS) but the largest Ray node has {largest:g}"
        )


def _collect(ray: Any, ref: Any, spec: EpisodeSpec) -> Result:
    """A finished task's result, its files written under the driver's run folder; a crash as an error."""
    try:
        task: TaskResult = ray.get(ref)
    except ray.exceptions.RayError as err:
        cause = getattr(err, "cause", None) or err
        return None, f"crash: Ray task failed: {type(cause).__name__}: {one_line(cause)}", False
    if task.files:
        write_files(task, spec.out_dir)
    summary, error, fatal = task.result
    if summary is not None:
        summary = {**summary, "run_dir": str(spec.out_dir)}
    return summary, error, fatal
