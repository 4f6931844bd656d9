"""Scaling across processes (``python -m bench.bench_scaling [--quick] [--backends sqlite,postgresql]``).

For each database, real ``contextweb serve`` processes on loopback on one fresh
database, with trained paper-world models (bench_service's training set,
``SERVING`` hyperparameters, each model warmed up past its initial growth
checks like bench_service's):

- ``throughput``: 8 concurrent clients (threads, each its own keep-alive
  HTTP/1.1 connection, the standard library's ``http.client``) on 8 models (one
  each), concept-level scenes, against (a) ``single``: one process, (b)
  ``workers2``: one ``contextweb serve --workers 2``, (c) ``replicas2``: two
  ``contextweb serve`` processes on two ports, clients split 4/4; in the full run
  (a) is measured again after (c) (``single_again``) and the reference is the
  mean of the two, because the machine is shared. For ``--workers 2`` the
  connections each worker holds at the end of the run are counted from ``/proc``
  (which process holds each accepted socket; the workers even them out,
  app/connections.py), and the run's reconnections are counted. Every answer's status is counted: a refused
  scene is reported, never retried. The bodies are encoded as JSON before the
  clock starts (a robot's encoding is its own CPU, not the server's), and the
  connections are opened one after the other, as robots coming online do (at
  once, the first worker to wake accepted them all). ``--keyed``: each scene
  with a fresh ``Idempotency-Key``, as the robot-side bridge posts them. Where the 2 cores' time
  went is read from ``/proc`` around each run: CPU milliseconds per scene of the
  server processes, of the PostgreSQL backends serving this database (their
  command line names it), of PostgreSQL's shared processes (WAL writer,
  checkpointer: other databases' work included) and of the clients;
- ``catch_up``: two processes A and B (the replicas of (c)) and a third, C.
  B's first ``GET /v1/models/{id}`` after K scenes were posted to A (it catches
  up, ``app.registry.catch_up``) minus the median of ordinary GETs of a current
  model on B (``get_baseline_ms``), for K = 1, 100 and 10,000 (1,000 with
  ``--quick``). For the largest K the model is created after C started, and C's
  first GET of it loads it from scratch (``full_load``): the reference the
  catch-up should stay well below. B's answer is compared with A's;
- ``latency``: one process, one lean client alone, the concepts series (3,000
  scenes; 2,000 with ``--quick``), p50 / p99 beside the previous session's.

Writes ``bench/results/scaling.json``.
"""

from __future__ import annotations

import argparse
import collections
import http.client
import itertools
import json
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import uuid
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypedDict

import httpx
from sqlalchemy.engine import make_url

from bench import RESULTS
from bench.bench_service import (
    BIRTH_CHECK_INTERVAL,
    CLIENTS,
    PROJECT,
    SERVING,
    LeanClient,
    Server,
    _decimated,
    _fresh_postgres,
    _summary,
    _trained_model,
    concept_scenes,
    fsync_ms,
    pipeline_ms,
    training_objects,
)
from core.features.extract import recording_features
from sim.world import World

GOALS = {"ratio": 1.6, "scenes_per_second": 500.0}
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
PREVIOUS_LATENCY_MS = {"sqlite": (2.1, 7.5), "postgresql": (4.1, 8.5)}
"""p50 / p99 of the lean concepts series in the previous session (docs/operations.md)."""
PREVIOUS_PIPELINE_RATIO = {"sqlite": 5.6, "postgresql": 11.0}
"""The same p50 over the in-process pipeline then (its value: docs/benchmarks.md)."""
BASELINE_GETS = 50


class ScalingSizes(TypedDict):
    """How many scenes each part of the run posts, and how often it repeats (``--quick``: fewer)."""

    throughput: int
    latency: int
    behind_big: dict[str, int]
    repeats_small: int
    repeats_big: int
    again: bool


class ScalingServer(Server):
    """bench_service's :class:`Server` with ``--workers``; it waits until every worker has started
    (their start-up lines in the log) and knows their process ids."""

    sqlite_synchronous = "FULL"
    """SQLite's ``synchronous`` for every server of the run (``--sqlite-synchronous``): FULL, the
    default, makes each scene's commit wait for a WAL fsync under the database's one write lock."""

    def __init__(self, database_url: str, log: Path, workers: int = 1, project: Path = PROJECT) -> None:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = log
        self.workers = workers
        env = {key: value for key, value in os.environ.items() if not key.startswith("CONTEXTWEB_")}
        env |= {
            "CONTEXTWEB_DATABASE_URL": database_url,
            "CONTEXTWEB_PORT": str(self.port),
            "CONTEXTWEB_SQLITE_SYNCHRONOUS": self.sqlite_synchronous,
            "PYTHONPATH": str(project),  # another checkout's code (bench/compare.py), not the installed one's
        }
        # As `make run` and the container do: `contextweb migrate`, then `contextweb serve`.
        migrate = [sys.executable, "-m", "app.cli", "migrate"]
        subprocess.run(migrate, cwd=project, env=env, stdout=log.open("ab"), stderr=subprocess.STDOUT, check=True)
        # "info" adds only start-up and shutdown lines (no access log): they tell when each worker is up.
        command = [sys.executable, "-m", "app.cli", "serve", "--log-level", "info", "--workers", str(workers)]
        self._log_start = log.stat().st_size if log.exists() else 0
        started = time.perf_counter()
        self.process = subprocess.Popen(command, cwd=project, env=env, stdout=log.open("ab"), stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and self.process.poll() is None:
            if self._log_text().count("Application startup complete") >= workers:
                try:
                    if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                        self.start_seconds = round(time.perf_counter() - started, 1)
                        return
                except httpx.TransportError:
                    pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"the server did not start; see {log}")

    def _log_text(self) -> str:
        with self.log.open("rb") as handle:
            handle.seek(self._log_start)
            return handle.read().decode(errors="replace")

    def pids(self) -> list[int]:
        """The processes that serve requests: the workers, or the process itself."""
        if self.workers == 1:
            return [self.process.pid]
        return [int(pid) for pid in re.findall(r"Started server process \[(\d+)\]", self._log_text())]

    def problems(self) -> list[str]:
        """The log's error lines (tracebacks, errors, warnings other than the loopback notice)."""
        lines = self._log_text().splitlines()
        return [
            line
            for line in lines
            if re.search(r"Traceback|ERROR|CRITICAL|Exception|WARNING", line) and "no CONTEXTWEB_WRITE_KEY" not in line
        ]


def training_features(world: World) -> dict[str, Any]:
    """Entity and effect vectors of the world's training objects (an object's recording is
    independent of the others, so only theirs are recorded)."""
    recordings = world.recordings(world.train_objects, seed=0)
    return {key: recording_features(_decimated(recording)) for key, recording in recordings.items()}


def trained_models(server: ScalingServer, train: list[dict]) -> list[str]:
    """One model per client on ``server``, each fitted to ``train`` with the ``SERVING`` hyperparameters."""
    with httpx.Client(base_url=server.url, timeout=300) as client, ThreadPoolExecutor(2) as pool:
        return list(pool.map(lambda _: _trained_model(client, train, SERVING), range(CLIENTS)))


def _start(specs: list[tuple[str, Path, int]]) -> list[ScalingServer]:
    """Several servers started concurrently (a start-up mostly waits: docs/benchmarks.md has how long)."""
    with ThreadPoolExecutor(len(specs)) as pool:
        futures = [pool.submit(ScalingServer, url, log, workers) for url, log, workers in specs]
        servers, failure = [], None
        for future in futures:
            try:
                servers.append(future.result())
            except Exception as error:  # noqa: BLE001 - the others are stopped, then it is raised
                failure = error
    if failure is not None:
        for server in servers:
            server.stop()
        raise failure
    return servers


def socket_owners(port: int, client_ports: list[int], pids: list[int]) -> dict[str, int]:
    """How many of the clients' connections each process holds (their accepted sockets, from /proc)."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            local, remote, inode = fields[1], fields[2], fields[9]
            if int(local.rsplit(":", 1)[1], 16) == port and int(remote.rsplit(":", 1)[1], 16) in client_ports:
                inodes.add(f"socket:[{inode}]")
    owners = {}
    for pid in pids:
        count = 0
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    count += os.readlink(f"/proc/{pid}/fd/{fd}") in inodes
                except OSError:
                    continue
        except OSError:
            pass
        owners[str(pid)] = count
    return owners


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of one process so far (0 once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def _postgres_processes(database: str | None) -> dict[str, list[int]]:
    """The PostgreSQL server's processes on this machine: ``backends`` serving ``database`` and
    ``shared`` ones (the WAL writer, checkpointer and the like, without a client), by their command
    line: ``postgres: [CLUSTER:] USER DATABASE HOST(PORT) STATE`` for a backend (Debian names the
    cluster, ``15/main:``), ``postgres: [CLUSTER:] NAME`` for a shared process. Other databases'
    backends are in neither."""
    found: dict[str, list[int]] = {"backends": [], "shared": []}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if (entry / "comm").read_text().strip() != "postgres":
                continue
            words = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").split()
        except OSError:
            continue
        if words[:1] != ["postgres:"]:
            continue  # the postmaster (its own command line), which forks and waits
        words = words[2:] if len(words) > 1 and words[1].endswith(":") else words[1:]
        if len(words) >= 3 and "(" in words[2]:
            if words[1] == database:
                found["backends"].append(int(entry.name))
        else:
            found["shared"].append(int(entry.name))
    return found


class CpuMeter:
    """CPU seconds of the processes that share the machine's cores during one run (from /proc)."""

    def __init__(self, servers: list[ScalingServer], database: str | None) -> None:
        self._servers = servers
        self._database = database
        self._start = self._read()

    def _read(self) -> dict[str, dict[int, float]]:
        pids = {pid for server in self._servers for pid in {server.process.pid, *server.pids()}}
        groups = {"server": {pid: _cpu_seconds(pid) for pid in pids}}
        for name, found in _postgres_processes(self._database).items():
            groups[f"postgres_{name}"] = {pid: _cpu_seconds(pid) for pid in found}
        return groups

    def per_scene_ms(self, scenes: int, client_seconds: float, elapsed: float) -> dict[str, Any]:
        """Milliseconds of CPU per scene by group (a process new since the start counts whole), and
        how many of the cores they kept busy together."""
        end = self._read()
        seconds = {
            group: sum(value - self._start[group].get(pid, 0.0) for pid, value in values.items())
            for group, values in end.items()
        }
        seconds["client"] = client_seconds
        figures: dict[str, Any] = {group: round(1000 * value / max(scenes, 1), 3) for group, value in seconds.items()}
        figures["total"] = round(sum(figures[group] for group in seconds), 3)
        figures["cores_busy"] = round(sum(seconds.values()) / elapsed, 2)
        return figures


def _spread(
    targets: list[tuple[ScalingServer, str]],
    parts: list[list[dict]],
    database: str | None = None,
    *,
    keyed: bool = False,
) -> dict[str, Any]:
    """One thread and one keep-alive connection per (server, model id), each posting its part.

    Each connection's first scene is posted before the clock starts (it opens the connection), one
    connection after the other; then, for servers with several workers, which worker holds each
    connection is read from /proc. ``database``: the PostgreSQL database whose backends' CPU counts.
    ``keyed``: each scene with a fresh ``Idempotency-Key`` (unique to this run, client and scene)."""
    count = len(targets)
    connected, go = threading.Barrier(count + 1), threading.Barrier(count + 1)
    finished, counted = threading.Barrier(count + 1), threading.Barrier(count + 1)
    reconnections = [0] * count
    opened = [threading.Event() for _ in range(count + 1)]
    opened[0].set()
    client_ports: list[int] = [0] * count
    statuses: collections.Counter[Any] = collections.Counter()
    latencies: list[float] = []
    lock = threading.Lock()
    run_token = uuid.uuid4().hex

    def run(index: int) -> None:
        server, model_id = targets[index]
        connection = http.client.HTTPConnection("127.0.0.1", server.port, timeout=120)
        path, headers = f"/v1/models/{model_id}/scenes", {"Content-Type": "application/json"}
        own_latencies: list[float] = []
        own_statuses: collections.Counter[Any] = collections.Counter()
        sent = itertools.count()

        bodies = [json.dumps(body).encode() for body in parts[index]]

        def post(body: bytes) -> None:
            start = time.perf_counter()
            reconnections[index] += connection.sock is None  # closed by the server, or after an error
            if keyed:
                headers["Idempotency-Key"] = f"{run_token}-{index}-{next(sent)}"
            try:
                connection.request("POST", path, body=body, headers=headers)
                response = connection.getresponse()
                answer = response.read()
                status: Any = response.status
                if status != 201:
                    status = f"{status} {answer[:200].decode(errors='replace')}"
            except (http.client.HTTPException, OSError) as error:
                status = f"{type(error).__name__}: {error}"
                connection.close()  # http.client reconnects on the next request
            own_latencies.append(time.perf_counter() - start)
            own_statuses[status] += 1

        try:
            opened[index].wait()
            try:
                post(bodies[0])
            finally:
                opened[index + 1].set()
            connected.wait()
            own_latencies.clear()  # the untimed first scene is neither timed nor counted (a refusal would be)
            own_statuses.pop(201, None)
            reconnections[index] = 0
            go.wait()
            for body in bodies[1:]:
                post(body)
            client_ports[index] = connection.sock.getsockname()[1] if connection.sock else 0
            finished.wait()
            counted.wait()  # the connection stays open until the workers' connections are counted
        except threading.BrokenBarrierError:
            pass
        finally:
            connection.close()
            with lock:
                latencies.extend(own_latencies)
                statuses.update(own_statuses)

    threads = [threading.Thread(target=run, args=(index,)) for index in range(count)]
    for thread in threads:
        thread.start()
    connected.wait()
    servers = list({id(server): server for server, _ in targets}.values())
    meter = CpuMeter(servers, database)
    cpu = os.times()
    go.wait()
    start = time.perf_counter()
    finished.wait()
    elapsed = time.perf_counter() - start
    cpu_after = os.times()
    owners = {  # at the end of the run (the spread the run ended with: app/connections.py evens it out)
        server.url: socket_owners(server.port, client_ports, server.pids()) for server in servers if server.workers > 1
    }
    counted.wait()
    for thread in threads:
        thread.join()
    client_seconds = (cpu_after.user + cpu_after.system) - (cpu.user + cpu.system)
    accepted = statuses.pop(201, 0)
    timed = len(latencies)
    ms = sorted(1000 * value for value in latencies)
    result: dict[str, Any] = {
        "clients": count,
        "scenes": accepted,
        "seconds": round(elapsed, 2),
        "scenes_per_second": round(accepted / elapsed, 1),
        "latency_ms": {
            "median": round(statistics.median(ms), 2),
            "p99": round(ms[min(timed - 1, int(0.99 * timed))], 2),
            "max": round(ms[-1], 2),
        },
        # The benchmark's own CPU (http.client): it shares the machine's 2 cores.
        "client_cpu_seconds": round(client_seconds, 2),
        "cpu_ms_per_scene": meter.per_scene_ms(accepted, client_seconds, elapsed),
        "refused": dict(statuses),
    }
    if owners:
        result["connections_per_worker"] = owners
    result["reconnections"] = sum(reconnections)
    return result


class Getter:
    """One keep-alive connection for timed ``GET /v1/models/{id}``."""

    def __init__(self, port: int) -> None:
        self._connection = http.client.HTTPConnection("127.0.0.1", port, timeout=300)
        self._used = 0.0

    def get(self, model_id: str) -> tuple[float, dict]:
        if time.monotonic() - self._used > 2:  # uvicorn closes a connection idle for 5 s: a new one, untimed
            self._connection.close()
            self._connection.connect()
        start = time.perf_counter()
        self._connection.request("GET", f"/v1/models/{model_id}")
        response = self._connection.getresponse()
        answer = response.read()
        seconds = time.perf_counter() - start
        if response.status != 200:
            raise RuntimeError(f"GET refused: {response.status} {answer[:300]!r}")
        self._used = time.monotonic()
        return seconds, json.loads(answer)

    def close(self) -> None:
        self._connection.close()


COMPARED = ("scene_count", "context_count", "vocabulary_size", "training_object_count")


def _same(first: dict, second: dict) -> bool:
    return all(first[key] == second[key] for key in COMPARED)


def catch_up_series(
    a: ScalingServer,
    b: ScalingServer,
    c: ScalingServer,
    model_id: str,
    behind: int,
    data: dict,
    sizes: ScalingSizes,
    backend: str,
) -> dict[str, Any]:
    on_a, on_b = Getter(a.port), Getter(b.port)
    lean_a = LeanClient(a.port)
    result: dict[str, Any] = {"mismatches": []}
    try:
        # B wrote nothing to this model in phase (c): it is behind by what A wrote then.
        seconds, answer = on_b.get(model_id)
        result["initial_sync"] = {"behind": behind, "scenes": answer["scene_count"], "get_ms": round(1000 * seconds, 2)}
        lean_a.post_all(model_id, data["concepts"][:1])  # a first catch-up, untimed (warms its path)
        on_b.get(model_id)
        baseline = [on_b.get(model_id)[0] for _ in range(BASELINE_GETS)]
        base_ms = 1000 * statistics.median(baseline)
        result["get_baseline_ms"] = round(base_ms, 3)
        offset = 1
        for lag in (1, 100):
            times = []
            for _ in range(sizes["repeats_small"]):
                lean_a.post_all(model_id, data["concepts"][offset : offset + lag])
                offset += lag
                seconds, answer = on_b.get(model_id)
                times.append(1000 * seconds)
                if not _same(answer, on_a.get(model_id)[1]):
                    result["mismatches"].append({"behind": lag, "b": answer})
            result[str(lag)] = _catch_up_figures(times, base_ms, answer["scene_count"])
        big = sizes["behind_big"][backend]
        times, loads, posting = [], [], []
        with httpx.Client(base_url=a.url, timeout=300) as client:
            for _ in range(sizes["repeats_big"]):
                fresh = _trained_model(client, data["train"], SERVING)  # after C started: C never saw it
                on_b.get(fresh)  # B loads it, before any scene
                scenes = data["concepts"][:big]
                parts = [scenes[i::CLIENTS] for i in range(CLIENTS)]
                posting.append(_spread([(a, fresh)] * CLIENTS, parts))
                seconds, answer = on_b.get(fresh)
                times.append(1000 * seconds)
                if not _same(answer, on_a.get(fresh)[1]):
                    result["mismatches"].append({"behind": big, "b": answer})
                on_c = Getter(c.port)
                try:
                    seconds, loaded = on_c.get(fresh)
                    loads.append(1000 * seconds)
                    if not _same(loaded, answer):
                        result["mismatches"].append({"full_load": True, "c": loaded})
                    # C's next GET, now current: its own baseline (C runs beside B)
                    result.setdefault("get_baseline_ms_on_c", []).append(round(1000 * on_c.get(fresh)[0], 3))
                finally:
                    on_c.close()
        result[str(big)] = _catch_up_figures(times, base_ms, answer["scene_count"])
        result["full_load"] = {
            "scenes": answer["scene_count"],
            "get_ms": [round(value, 1) for value in loads],
            "median_ms": round(statistics.median(loads), 1),
            "median_ms_minus_get": round(statistics.median(loads) - base_ms, 1),
        }
        result["posting_behind_scenes"] = posting
    finally:
        on_a.close()
        on_b.close()
        lean_a.close()
    return result


def _catch_up_figures(times: list[float], base_ms: float, scenes: int) -> dict[str, Any]:
    return {
        "get_ms": [round(value, 2) for value in times],
        "median_get_ms": round(statistics.median(times), 2),
        "median_catch_up_ms": round(statistics.median(times) - base_ms, 2),
        "scenes_in_model": scenes,
    }


def run_backend(
    backend: str,
    url: str,
    folder: Path,
    data: dict,
    sizes: ScalingSizes,
    pending: Future | None,
    *,
    keyed: bool = False,
) -> dict[str, Any]:
    """(a) on process A alone; (b) on a ``--workers 2`` server while A idles; (c) on A and a replica
    B, with C started beside them for the catch-up's full-load reference; then (a) again on A alone.
    An idle process costs nothing (no request reaches it); one that was idle is behind, and the
    first, untimed scene of each connection catches it up."""
    problems: dict[str, list[str]] = {}
    servers: list[ScalingServer] = []
    result: dict[str, Any] = {"load_average": {}, "server_start_seconds": {}, "setup_seconds": {}}
    throughput: dict[str, Any] = {}
    result["throughput"] = throughput

    def log(name: str) -> Path:
        return folder / f"{backend}-{name}.log"

    def stop(*stopped: ScalingServer) -> None:
        for server in stopped:
            server.stop()
            servers.remove(server)
            if found := server.problems():
                problems[server.log.name] = found[:20]

    def phase(name: str) -> None:
        result["load_average"][name] = [round(value, 2) for value in os.getloadavg()]
        print(f"  [{time.strftime('%H:%M:%S')}] {backend} {name} (load {os.getloadavg()[0]:.1f})", flush=True)

    def measure(name: str, targets: list[tuple[ScalingServer, str]]) -> None:
        phase(name)
        throughput[name] = figures = _spread(targets, parts, database, keyed=keyed)
        print(f"    {figures['scenes_per_second']:.1f} scenes/s {json.dumps(figures)}", flush=True)

    database = make_url(url).database if backend == "postgresql" else None

    scenes = data["concepts"][: sizes["throughput"]]
    parts = [scenes[i::CLIENTS] for i in range(CLIENTS)]
    try:
        a = pending.result() if pending is not None else _start([(url, log("a"), 1)])[0]
        servers.append(a)
        result["server_start_seconds"]["a"] = a.start_seconds
        phase("models")
        started = time.perf_counter()
        models = trained_models(a, data["train"])
        result["setup_seconds"]["train_8_models"] = round(time.perf_counter() - started, 1)
        started = time.perf_counter()
        _spread([(a, model) for model in models], [data["warmup"]] * CLIENTS)
        result["setup_seconds"]["warm_up_8_models"] = round(time.perf_counter() - started, 1)
        print(f"    set-up {result['setup_seconds']}", flush=True)
        phase("latency")
        # On the first model, alone on the server; its corpus then holds more scenes than the others'
        # (the concept-level cost does not follow the corpus: bench_service's tenths).
        lean = LeanClient(a.port)
        try:
            result["latency"] = _summary(lean.post_all(models[0], data["concepts"][-sizes["latency"] :]))
        finally:
            lean.close()
        print(f"    p50 {result['latency']['median_ms']} / p99 {result['latency']['p99_ms']} ms", flush=True)
        measure("single", [(a, model) for model in models])

        phase("start workers2")
        (workers,) = _start([(url, log("workers2"), 2)])
        servers.append(workers)
        result["server_start_seconds"]["workers2"] = workers.start_seconds
        measure("workers2", [(workers, model) for model in models])
        stop(workers)

        phase("start replicas")
        b, c = _start([(url, log("b"), 1), (url, log("c"), 1)])
        servers.extend([b, c])
        result["server_start_seconds"]["b"] = b.start_seconds
        half = CLIENTS // 2
        measure("replicas2", [(a, m) for m in models[:half]] + [(b, m) for m in models[half:]])
        phase("catch_up")
        result["catch_up"] = catch_up_series(a, b, c, models[0], len(parts[0]), data, sizes, backend)
        stop(b, c)
        if sizes["again"]:
            measure("single_again", [(a, model) for model in models])
        stop(a)
    finally:
        for server in servers:
            stop(server)
        result["server_log_problems"] = problems
    reference = [throughput[name]["scenes_per_second"] for name in ("single", "single_again") if name in throughput]
    result["reference_scenes_per_second"] = round(statistics.mean(reference), 1)
    result["ratios"] = {
        name: round(throughput[name]["scenes_per_second"] / result["reference_scenes_per_second"], 2)
        for name in ("workers2", "replicas2")
    }
    return result


def _report(backend: str, result: dict[str, Any], pipeline: float) -> None:
    throughput, reference = result["throughput"], result["reference_scenes_per_second"]
    print(f"\n{backend}: throughput, 8 clients on 8 models (scenes/s; ratio to one process = {reference:.0f}/s)")
    for name, figures in throughput.items():
        ratio = figures["scenes_per_second"] / reference
        goal = ""
        if name in ("workers2", "replicas2"):
            met = ratio >= GOALS["ratio"] and figures["scenes_per_second"] >= GOALS["scenes_per_second"]
            goal = f"  goal (>= {GOALS['ratio']}x and >= {GOALS['scenes_per_second']:.0f}/s): "
            goal += "met" if met else "NOT met"
        spread = ""
        if "connections_per_worker" in figures:
            counts = [n for owners in figures["connections_per_worker"].values() for n in owners.values()]
            spread = f"  connections per worker {counts} ({figures.get('reconnections', 0)} reconnections)"
        refused = f"  REFUSED {figures['refused']}" if figures["refused"] else ""
        cpu = figures["cpu_ms_per_scene"]
        print(
            f"  {name:13s} {figures['scenes_per_second']:7.1f}  x{ratio:.2f}  "
            f"p50 {figures['latency_ms']['median']:.1f} / p99 {figures['latency_ms']['p99']:.1f} / "
            f"max {figures['latency_ms']['max']:.0f} ms{spread}{goal}{refused}\n"
            f"  {'':13s} CPU ms a scene: server {cpu['server']:.2f}, postgres backends {cpu['postgres_backends']:.2f}, "
            f"postgres shared {cpu['postgres_shared']:.2f}, client {cpu['client']:.2f}; total {cpu['total']:.2f} "
            f"({cpu['cores_busy']:.2f} of {os.cpu_count()} cores busy; client share "
            f"{100 * cpu['client'] / max(cpu['total'], 1e-9):.0f} %)"
        )
    catch = result["catch_up"]
    print(
        f"{backend}: catch-up (B's first GET after K scenes on A, minus an ordinary GET "
        f"{catch['get_baseline_ms']:.2f} ms); first GET on B after phase (c), "
        f"{catch['initial_sync']['behind']} behind: {catch['initial_sync']['get_ms']:.1f} ms"
    )
    for key, figures in catch.items():
        if key.isdigit():
            print(
                f"  {int(key):6,d} behind: {figures['median_catch_up_ms']:8.2f} ms "
                f"(GETs {figures['get_ms']} ms; model of {figures['scenes_in_model']:,} scenes)"
            )
    load = catch["full_load"]
    big = max((key for key in catch if key.isdigit()), key=int)
    print(
        f"  full load of that {load['scenes']:,}-scene model on a process that never saw it: "
        f"{load['median_ms_minus_get']:.1f} ms {load['get_ms']}; catch-up / full load = "
        f"{catch[big]['median_catch_up_ms'] / load['median_ms_minus_get']:.2f}"
    )
    if catch["mismatches"]:
        print(f"  MISMATCH between B and A: {catch['mismatches']}")
    latency, (p50, p99) = result["latency"], PREVIOUS_LATENCY_MS[backend]
    print(
        f"{backend}: latency, one process, {latency['scenes']:,} concept scenes, lean client: "
        f"p50 {latency['median_ms']:.2f} / p99 {latency['p99_ms']:.2f} ms (previous session {p50} / {p99} ms); "
        f"p50 = {latency['median_ms'] / pipeline:.1f}x the in-process pipeline "
        f"(previous session {PREVIOUS_PIPELINE_RATIO[backend]}x)"
    )
    if result["server_log_problems"]:
        print(f"{backend}: server log problems: {json.dumps(result['server_log_problems'], indent=1)[:2000]}")


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer scenes (a smoke run, not a measurement)")
    parser.add_argument("--backends", default="sqlite,postgresql", help="comma-separated: sqlite, postgresql")
    parser.add_argument(
        "--sqlite-synchronous",
        default="FULL",
        choices=["FULL", "NORMAL"],
        help="SQLite's durability: FULL (the default, as served) or NORMAL (no fsync at commit: a power loss "
        "may lose the last acknowledged scenes)",
    )
    parser.add_argument(
        "--keyed", action="store_true", help="each scene with a fresh Idempotency-Key, as the robot-side bridge posts"
    )
    args = parser.parse_args(sys.argv[1:])
    ScalingServer.sqlite_synchronous = args.sqlite_synchronous
    sizes: ScalingSizes = (
        {
            "throughput": 800,
            "latency": 2_000,
            "behind_big": {"sqlite": 1_000, "postgresql": 1_000},
            "repeats_small": 3,
            "repeats_big": 1,
            "again": False,
        }
        if args.quick
        else {
            "throughput": 1_600,
            "latency": 3_000,
            "behind_big": {"sqlite": 1_000, "postgresql": 10_000},
            "repeats_small": 5,
            "repeats_big": 1,
            "again": True,
        }
    )
    backends = args.backends.split(",")
    results: dict[str, Any] = {
        "sizes": sizes,
        "hyperparameters": SERVING,
        "goals": GOALS,
        "cpus": os.cpu_count(),
        "sqlite_synchronous": args.sqlite_synchronous,
        "keyed": args.keyed,
    }
    results["load_average_before"] = os.getloadavg()
    began = time.perf_counter()
    folder = Path(tempfile.mkdtemp(prefix="contextweb-scaling-"))  # the servers' logs stay there
    print(f"server logs in {folder}", flush=True)
    with ThreadPoolExecutor(1) as starter:
        urls = {
            backend: f"sqlite:///{folder / 'bench.sqlite3'}" if backend == "sqlite" else _fresh_postgres()
            for backend in backends
        }
        reachable = {backend: url for backend, url in urls.items() if url is not None}
        first = next(iter(reachable), None)
        # The first server starts while the training features are extracted (both take tens of seconds).
        pending = (
            starter.submit(lambda: _start([(reachable[first], folder / f"{first}-a.log", 1)])[0]) if first else None
        )
        world = World.paper(0)
        started = time.perf_counter()
        features = training_features(world)
        print(f"features of {len(features)} training objects in {time.perf_counter() - started:.0f} s", flush=True)
        train = training_objects(world, features)
        data = {
            "train": train,
            "warmup": concept_scenes(world, BIRTH_CHECK_INTERVAL, seed=1),
            "concepts": concept_scenes(
                world, max(*sizes["behind_big"].values(), sizes["latency"], sizes["throughput"]), seed=2
            ),
        }
        # The same scenes in this process, no HTTP, no database (bench_service's reference): ratios travel.
        pipeline = pipeline_ms(world, train, data["warmup"] + data["concepts"][:300], SERVING, len(data["warmup"]))
        results["pipeline_ms"] = round(pipeline, 3)
        print(f"in-process pipeline {pipeline:.2f} ms a scene (previous session 0.37 ms)", flush=True)
        for backend, url in reachable.items():
            try:
                pending_start = pending if backend == first else None
                results[backend] = run_backend(backend, url, folder, data, sizes, pending_start, keyed=args.keyed)
            except Exception as error:  # noqa: BLE001 - reported, and the other backend still runs
                traceback.print_exc()
                results[backend] = {"error": f"{type(error).__name__}: {error}"}
                continue
            _report(backend, results[backend], results["pipeline_ms"])
    # SQLite's ceiling: one durable commit (a WAL fsync) per scene under one database-wide write lock.
    results["fsync_ms"] = round(fsync_ms(folder, 100), 3)
    print(f"one 4 KiB write + fsync in the SQLite database's folder: {results['fsync_ms']:.2f} ms (median of 100)")
    for path in folder.glob("bench.sqlite3*"):
        path.unlink()
    results["load_average_after"] = os.getloadavg()
    results["seconds"] = round(time.perf_counter() - began, 1)
    before, after = (
        " ".join(f"{value:.2f}" for value in results[key]) for key in ("load_average_before", "load_average_after")
    )
    print(f"\n{results['seconds']:.0f} s; load average before {before}, after {after}")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "scaling.json").write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return results


if __name__ == "__main__":
    main()
