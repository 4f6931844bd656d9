"""The monitoring profile's Prometheus side for real: a Prometheus server (Debian's ``prometheus``,
the same program as the compose profile's stock image) scrapes a real ``contextweb serve`` with the
profile's own scrape settings, and every query of the provisioned Grafana dashboard is evaluated by
it and returns series. ``make test`` installs Prometheus where it can (``make monitoring-tools``);
where it cannot, this test skips and says why. Grafana itself is not run here (no Debian package,
no image registry on this machine): docs/deployment.md says what was and was not tried.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import yaml

from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes
from tests.servers import ServerProcess, free_port, running_server

ROOT = Path(__file__).resolve().parents[1]
DASHBOARD = ROOT / "docker" / "monitoring" / "grafana" / "dashboards" / "contextweb.json"
PROFILE_CONFIG = ROOT / "docker" / "monitoring" / "prometheus.yml"
PROMETHEUS = shutil.which("prometheus")
#: Long enough for two scrapes at the 1 s interval below, so that rate() has two points per series.
SCRAPED_SECONDS = 60.0
#: Prometheus's own start (opening its database) on a loaded 2-core machine.
READY_SECONDS = 60.0

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(PROMETHEUS is None, reason="no prometheus binary (make monitoring-tools installs Debian's)"),
]


def _config_for(server: ServerProcess) -> dict:
    """The profile's prometheus.yml with its targets pointed at the test's server and a 1 s interval
    (the profile's 10 s would make the test wait minutes); the job, path and labels stay the profile's."""
    config = yaml.safe_load(PROFILE_CONFIG.read_text())
    config["global"] = {"scrape_interval": "1s", "evaluation_interval": "1s"}
    (job,) = config["scrape_configs"]
    job["static_configs"] = [{"targets": [f"127.0.0.1:{server.port}"], "labels": {"service": "api"}}]
    return config


@pytest.fixture
def prometheus(tmp_path: Path) -> Iterator[tuple[ServerProcess, str]]:
    with running_server(f"sqlite:///{tmp_path / 'monitored.sqlite3'}", tmp_path) as server:
        config = tmp_path / "prometheus.yml"
        config.write_text(yaml.safe_dump(_config_for(server)))
        port = free_port()
        log = (tmp_path / "prometheus.log").open("wb")
        process = subprocess.Popen(
            [
                str(PROMETHEUS),
                f"--config.file={config}",
                f"--storage.tsdb.path={tmp_path / 'tsdb'}",
                f"--web.listen-address=127.0.0.1:{port}",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        url = f"http://127.0.0.1:{port}"
        try:
            _wait_ready(url, process, tmp_path / "prometheus.log")
            yield server, url
        finally:
            process.terminate()
            process.wait(timeout=10)
            log.close()


def _wait_ready(url: str, process: subprocess.Popen[bytes], log: Path) -> None:
    """Until Prometheus's /-/ready says 200 (it answers 503 while it opens its database)."""
    deadline = time.monotonic() + READY_SECONDS
    while time.monotonic() < deadline:
        assert process.poll() is None, log.read_text(errors="replace")[-2000:]
        try:
            if httpx.get(f"{url}/-/ready", timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    pytest.fail(f"Prometheus not ready in {READY_SECONDS} s: {log.read_text(errors='replace')[-2000:]}")


def _query(prometheus_url: str, expr: str) -> list[dict]:
    response = httpx.get(f"{prometheus_url}/api/v1/query", params={"query": expr}, timeout=5)
    response.raise_for_status()
    answer = response.json()
    assert answer["status"] == "success", (expr, answer)
    return answer["data"]["result"]


def test_every_dashboard_query_returns_series_from_a_real_scrape(
    prometheus: tuple[ServerProcess, str], tmp_path: Path
) -> None:
    server, prometheus_url = prometheus
    dashboard = json.loads(DASHBOARD.read_text())
    queries = {target["expr"]: panel["title"] for panel in dashboard["panels"] for target in panel["targets"]}
    with server.client() as client:
        model_id = client.post("/v1/models", json={"name": "m", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        deadline = time.monotonic() + SCRAPED_SECONDS
        missing = dict(queries)
        scenes = concept_scenes(200, seed=5)
        while missing and time.monotonic() < deadline:
            # Keep the series moving while Prometheus scrapes, as a robot would: rates need changes.
            for scene in scenes[:3]:
                assert client.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201
            scenes = scenes[3:] or concept_scenes(200, seed=6)
            with client.stream("GET", "/metrics"):
                pass
            for expr in list(missing):
                if _query(prometheus_url, expr):
                    del missing[expr]
            time.sleep(0.5)
        targets = httpx.get(f"{prometheus_url}/api/v1/targets", timeout=5).json()["data"]["activeTargets"]
    assert [target["health"] for target in targets] == ["up"], targets
    # Storage errors only have series once one happened; websocket subscribers once one subscribed.
    # Every panel has data, the storage-error and subscriber panels included (their series start at 0).
    assert not missing, {queries[expr]: expr for expr in missing}
    scenes_learned = _query(prometheus_url, f'contextweb_model_scenes{{model="{model_id}"}}')
    assert scenes_learned and float(scenes_learned[0]["value"][1]) >= 3
    assert scenes_learned[0]["metric"]["job"] == "contextweb" and scenes_learned[0]["metric"]["service"] == "api"
