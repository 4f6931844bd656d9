"""The dashboard in headless Chromium: simulated scenes stream in, the contexts and the charts follow.

Needs Debian's ``chromium`` and ``chromium-driver`` (``make test`` installs them where it can, see
docs/deployment.md) and selenium; skipped, saying so, only where no browser is installed.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from bridge import Client
from bridge.simulate import simulate, train
from core.world import World, WorldConfig
from tests.test_bridge_live import READ_KEY, WRITE_KEY, ServiceProcess

CHROMIUM = os.environ.get("CONTEXTWEB_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("CONTEXTWEB_CHROMEDRIVER", "/usr/bin/chromedriver")

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _browser_or_skip() -> None:
    missing = [path for path in (CHROMIUM, CHROMEDRIVER) if shutil.which(path) is None]
    if missing:
        pytest.skip(
            f"no headless browser here ({', '.join(missing)} missing): apt-get install -y chromium chromium-driver"
        )
    pytest.importorskip("selenium", reason="selenium is not installed (pip install selenium)")


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    _browser_or_skip()
    process = ServiceProcess(tmp_path_factory.mktemp("dashboard")).start()
    try:
        page = httpx.get(f"{process.url}/")
        if page.status_code != 200 or "Contextweb" not in page.text:
            pytest.fail(
                "GET / does not serve the dashboard: app/main.py must mount app/static at / (docs/deployment.md)"
            )
        yield process
    finally:
        process.stop()


@pytest.fixture
def browser(tmp_path: Path):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        "--window-size=1400,1500",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()


def _wait(condition: Callable[[], object], what: str, timeout: float = 45.0) -> object:
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.2)


def _data(driver, element_id: str, name: str) -> str:
    return driver.find_element("id", element_id).get_attribute(f"data-{name}") or ""


def test_dashboard_follows_simulated_scenes_live(service: ServiceProcess, browser, tmp_path: Path) -> None:
    world = World(WorldConfig.paper(), seed=0)
    robot = Client(service.url, WRITE_KEY)
    model_id = robot.models.create("dashboard-test", seed=1).id
    # One training object per noun: enough for the planner's behaviour effects and a concept web.
    one_per_noun = [next(obj for obj in world.train_objects if obj.noun == noun) for noun in world.vocabulary.nouns]
    train(robot, model_id, world, level="features", rng=np.random.default_rng(0), objects=one_per_noun, progress=False)
    first = world.scenes(10, seed=1, contexts=["kitchen", "playroom"])
    simulate(robot, model_id, world, [first], level="concepts", train_level=None, progress=False)

    browser.get(f"{service.url}/?key={READ_KEY}&model={model_id}")
    _wait(lambda: _data(browser, "connection", "mode") == "live", "the websocket to open")
    _wait(lambda: _data(browser, "posterior-chart", "points") == "10", "the posterior chart to show 10 scenes")
    _wait(lambda: int(_data(browser, "contexts", "count") or 0) >= 1, "the contexts to appear")
    contexts_before = browser.find_element("id", "contexts").text
    assert "χ0" in contexts_before and "grasp" in contexts_before, "every object of the paper's world can be grasped"
    assert _data(browser, "concept-web", "nodes") == "29"
    _wait(lambda: _data(browser, "plan", "status") == "solved", "the plan")
    assert int(_data(browser, "plan", "pruned")) > 0, "a kitchen or playroom context prunes behaviours (Fig. 15)"

    second = world.scenes(10, seed=2, contexts=["workshop"])
    simulate(robot, model_id, world, [second], level="concepts", train_level=None, progress=False)
    _wait(lambda: _data(browser, "posterior-chart", "points") == "20", "the chart to follow the stream")
    _wait(lambda: _data(browser, "contexts", "scenes") == "20", "the contexts to be read again")
    assert _data(browser, "k-chart", "points") == "20"
    assert browser.find_element("id", "contexts").text != contexts_before
    assert int(_data(browser, "concept-web", "edges")) > 0

    screenshot = tmp_path / "dashboard.png"
    browser.save_screenshot(str(screenshot))
    print(f"dashboard screenshot: {screenshot}")

    # Without the websocket the page polls and still follows.
    browser.get(f"{service.url}/?key={READ_KEY}&model={model_id}&transport=polling")
    _wait(lambda: _data(browser, "posterior-chart", "points") == "20", "the polling page to load")
    _wait(lambda: _data(browser, "connection", "mode") == "polling", "the page to poll")
    simulate(robot, model_id, world, [world.scenes(3, seed=3)], level="concepts", train_level=None, progress=False)
    _wait(lambda: _data(browser, "posterior-chart", "points") == "23", "polling to fetch the new scenes")
    _wait(lambda: _data(browser, "contexts", "scenes") == "23", "polling to read the contexts again")
    robot.close()


def test_dashboard_without_a_key_asks_for_one(service: ServiceProcess, browser) -> None:
    browser.get(f"{service.url}/")
    _wait(lambda: browser.find_element("id", "key-form").is_displayed(), "the key form")
    assert "read key" in browser.find_element("id", "message").text
    assert _data(browser, "connection", "mode") == "offline"
