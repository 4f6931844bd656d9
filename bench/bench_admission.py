"""One busy model must not slow the others (``python -m bench.bench_admission [--quick]``), issue 14.

A real ``contextweb serve`` process on SQLite (bench_service's ``Server``,
``synchronous=FULL``, default settings: ``model_write_queue`` 32, no rate limit)
with two trained paper-world models (bench_service's training set and
``SERVING`` hyperparameters, warmed up past their initial growth checks):

- ``quiet``: model B's robot, one lean keep-alive client (bench_service's
  ``LeanClient``), posts 5-object concept scenes alone: p50 / p99;
- ``loaded``: the same robot again while :data:`HAMMERS` clients hammer model A,
  each on its own keep-alive connection, with maximum-size scenes: one raw-level
  object whose point clouds fill the request up to ``CONTEXTWEB_MAX_BODY_BYTES``
  (the recording of a paper-world object, its clouds' points repeated with a
  little noise; base64 float32, as the bridge sends them), the heaviest scene the
  schemas allow (seconds of feature extraction each). A's answers are counted by
  status (201, 429 ``model_busy``; anything else is reported);
- ``rss_mb``: the server's resident memory before the load, its peak during
  (sampled every 0.2 s from ``/proc``) and after.

Goals (issue 14): B's ``p50_loaded / p50_quiet`` ≤ 2 and ``p99_loaded / p99_quiet`` ≤ 3,
RSS bounded. Writes ``bench/results/admission.json``.
"""

from __future__ import annotations

import argparse
import base64
import http.client
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from app.settings import Settings
from bench import RESULTS
from bench.bench_service import (
    BIRTH_CHECK_INTERVAL,
    SERVING,
    LeanClient,
    Server,
    _summary,
    _trained_model,
    concept_scenes,
    paper_world_features,
    training_objects,
)
from core.payloads import ObjectRecording
from sim.world import World

HAMMERS = 20
GOALS = {"p50_ratio": 2.0, "p99_ratio": 3.0}


def _base64(values: np.ndarray) -> str:
    return base64.b64encode(np.asarray(values, dtype="<f4").tobytes()).decode()


def maximum_raw_scene(recording: ObjectRecording, limit_bytes: int, seed: int = 0) -> bytes:
    """The JSON of a one-object raw scene as close under ``limit_bytes`` as whole repeats of the
    recording's points allow (each repeat shifted by a little noise, so the clouds stay plausible)."""
    rng = np.random.default_rng(seed)

    def cloud(points: np.ndarray, size: int) -> dict[str, str]:
        repeated = np.resize(points, (size, 3)) + rng.normal(0.0, 1e-4, (size, 3))
        return {"points": _base64(repeated.ravel())}

    def scene(scale: float) -> bytes:
        interactions = []
        for interaction in recording.interactions:
            item: dict[str, Any] = {
                "behaviour": interaction.behaviour,
                "before": cloud(interaction.before.points, int(len(interaction.before.points) * scale)),
                "after": cloud(interaction.after.points, int(len(interaction.after.points) * scale)),
            }
            if interaction.audio is not None:
                item["audio"] = {
                    "samples": _base64(interaction.audio.samples),
                    "sample_rate": interaction.audio.sample_rate,
                }
            if interaction.finger is not None:
                finger = interaction.finger
                item["finger"] = {"haptic": _base64(finger.haptic), "proprioceptive": _base64(finger.proprioceptive)}
            interactions.append(item)
        look = cloud(recording.look.points, int(len(recording.look.points) * scale))
        return json.dumps({"objects": [{"raw": {"look": look, "interactions": interactions}}]}).encode()

    base = len(scene(1.0))
    scale = limit_bytes / base
    body = scene(scale)
    while len(body) > limit_bytes:
        scale *= 0.99
        body = scene(scale)
    return body


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class _Hammer(threading.Thread):
    """One client posting ``body`` to ``model_id`` again and again until ``stop`` is set."""

    def __init__(self, port: int, model_id: str, body: bytes, stop: threading.Event) -> None:
        super().__init__(daemon=True)
        self._port, self._path, self._body, self._halt = port, f"/v1/models/{model_id}/scenes", body, stop
        self.statuses: Counter[int | str] = Counter()
        self.seconds: list[float] = []

    def run(self) -> None:
        connection = http.client.HTTPConnection("127.0.0.1", self._port, timeout=300)
        headers = {"Content-Type": "application/json"}
        while not self._halt.is_set():
            started = time.perf_counter()
            try:
                connection.request("POST", self._path, body=self._body, headers=headers)
                response = connection.getresponse()
                response.read()
                self.statuses[response.status] += 1
                self.seconds.append(time.perf_counter() - started)
                if response.status == 429:  # as bridge.Client does; the server drops idle connections after 5 s
                    time.sleep(float(response.headers.get("Retry-After", "1")))
                    connection.close()
            except (OSError, http.client.HTTPException) as error:
                self.statuses[f"transport:{type(error).__name__}"] += 1
                connection.close()
                connection = http.client.HTTPConnection("127.0.0.1", self._port, timeout=300)
        connection.close()


def _post_for(lean: LeanClient, model_id: str, scenes: list[dict], seconds: float) -> list[float]:
    """B's robot: the scenes in turn (cycling) for ``seconds``."""
    latencies: list[float] = []
    deadline = time.monotonic() + seconds
    position = 0
    while time.monotonic() < deadline:
        chunk = scenes[position : position + 20] or scenes[:20]
        position = (position + 20) % len(scenes)
        latencies += lean.post_all(model_id, chunk)
    return latencies


def _profile(pid: int, seconds: float) -> subprocess.Popen[bytes]:
    """py-spy sampling the server (every thread, idle ones too) while B is timed under load."""
    RESULTS.mkdir(exist_ok=True)
    command = [str(Path(sys.executable).parent / "py-spy"), "record", "--pid", str(pid), "--idle", "--threads"]
    command += ["--duration", str(int(seconds)), "--format", "raw", "--output", str(RESULTS / "admission-profile.txt")]
    return subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)


def run(folder: Path, sizes: dict[str, Any], *, profile: bool = False) -> dict[str, Any]:
    world = World.paper(0)
    started = time.perf_counter()
    features = paper_world_features(world)
    print(f"features of {len(features)} recorded objects in {time.perf_counter() - started:.0f} s", flush=True)
    train = training_objects(world, features)
    recording = next(iter(world.recordings(seed=0).values()))
    limit = Settings().max_body_bytes
    heavy = maximum_raw_scene(recording, limit)
    warmup = concept_scenes(world, BIRTH_CHECK_INTERVAL, seed=1)
    scenes = concept_scenes(world, sizes["quiet"], seed=2)
    server = Server(f"sqlite:///{folder / 'admission.sqlite3'}", folder / "server.log")
    try:
        with httpx.Client(base_url=server.url, timeout=300) as client:
            model_a = _trained_model(client, train, SERVING)
            model_b = _trained_model(client, train, SERVING)
            for model_id in (model_a, model_b):
                for body in warmup:
                    client.post(f"/v1/models/{model_id}/scenes", json=body).raise_for_status()
            probe = client.post(
                f"/v1/models/{model_a}/scenes", content=heavy, headers={"Content-Type": "application/json"}
            )
            probe.raise_for_status()
            heavy_seconds = probe.elapsed.total_seconds()
        lean = LeanClient(server.port)
        try:
            quiet = _summary(lean.post_all(model_b, scenes))
            rss_before = _rss_mb(server.process.pid)
            stop = threading.Event()
            hammers = [_Hammer(server.port, model_a, heavy, stop) for _ in range(HAMMERS)]
            peak = [rss_before]

            def sample() -> None:
                while not stop.is_set():
                    peak.append(_rss_mb(server.process.pid))
                    time.sleep(0.2)

            sampler = threading.Thread(target=sample, daemon=True)
            for thread in [*hammers, sampler]:
                thread.start()
            time.sleep(sizes["ramp_seconds"])  # every hammer has sent its first scene
            profiler = _profile(server.process.pid, sizes["loaded_seconds"]) if profile else None
            loaded = _summary(_post_for(lean, model_b, scenes, sizes["loaded_seconds"]))
            if profiler is not None:
                profiler.wait(timeout=120)
            stop.set()
            for thread in [*hammers, sampler]:
                thread.join(timeout=300)
            rss_after = _rss_mb(server.process.pid)
        finally:
            lean.close()
    except BaseException:
        print(f"server exit status: {server.process.poll()}", flush=True)
        raise
    finally:
        server.stop()
    statuses: Counter[int | str] = Counter()
    for hammer in hammers:
        statuses.update(hammer.statuses)
    a_seconds = [seconds for hammer in hammers for seconds in hammer.seconds]
    return {
        "heavy_scene_bytes": len(heavy),
        "heavy_scene_alone_seconds": round(heavy_seconds, 3),
        "quiet": quiet,
        "loaded": loaded,
        "p50_ratio": round(loaded["median_ms"] / quiet["median_ms"], 2),
        "p99_ratio": round(loaded["p99_ms"] / quiet["p99_ms"], 2),
        "model_a": {
            "clients": HAMMERS,
            "statuses": {str(key): value for key, value in sorted(statuses.items(), key=str)},
            "median_seconds": round(float(np.median(a_seconds)), 2) if a_seconds else None,
        },
        "rss_mb": {"before": round(rss_before, 1), "peak": round(max(peak), 1), "after": round(rss_after, 1)},
    }


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a short load (a smoke run, not a measurement)")
    parser.add_argument("--profile", action="store_true", help="py-spy the server under load (admission-profile.txt)")
    args = parser.parse_args(sys.argv[1:])
    sizes = (
        {"quiet": 300, "loaded_seconds": 8.0, "ramp_seconds": 3.0}
        if args.quick
        else {"quiet": 2_000, "loaded_seconds": 25.0, "ramp_seconds": 3.0}
    )
    # The ramp stays under uvicorn's 5 s keep-alive timeout: B's robot is idle during it, and a
    # longer ramp had the server close its connection (a broken pipe on its next post).
    results: dict[str, Any] = {"sizes": sizes, "goals": GOALS, "cpus": os.cpu_count()}
    results["load_average_before"] = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="contextweb-bench-") as folder:
        try:
            results["sqlite"] = run(Path(folder), sizes, profile=args.profile)
        except BaseException:
            log = Path(folder) / "server.log"
            print(f"the server's log ends with:\n{log.read_text(errors='replace')[-4000:] if log.exists() else ''}")
            raise
    results["load_average_after"] = os.getloadavg()
    figures = results["sqlite"]
    print(
        f"model B quiet: p50 {figures['quiet']['median_ms']:.2f} ms, p99 {figures['quiet']['p99_ms']:.2f} ms; "
        f"while {HAMMERS} clients hammer A: p50 {figures['loaded']['median_ms']:.2f} ms, "
        f"p99 {figures['loaded']['p99_ms']:.2f} ms, max {figures['loaded']['max_ms']:.1f} ms "
        f"(ratios {figures['p50_ratio']} and {figures['p99_ratio']}; goals ≤ {GOALS['p50_ratio']:g} and "
        f"≤ {GOALS['p99_ratio']:g}); A: {figures['model_a']['statuses']}; RSS {figures['rss_mb']} MB"
    )
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "admission.json").write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return results


if __name__ == "__main__":
    main()
