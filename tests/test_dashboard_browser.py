"""The dashboard in headless Chromium: simulated scenes stream in, the contexts and the charts follow;
contexts show their operators' labels and distinctive concepts; the latest object's three stages match
the scene's answer.

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
from sim.robot import simulate, train
from sim.world import World, WorldConfig
from storage.database import create_database_engine
from tests.test_bridge_live import READ_KEY, WRITE_KEY, ServiceProcess
from tests.test_damaged_storage import _execute

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
    """Poll ``condition`` until it is truthy. An element that the page re-rendered between finding it
    and reading it (selenium's stale element) counts as not yet: the page is still changing."""
    from selenium.common.exceptions import StaleElementReferenceException

    deadline = time.monotonic() + timeout
    while True:
        try:
            value = condition()
        except StaleElementReferenceException:
            value = None
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.2)


def _data(driver, element_id: str, name: str) -> str:
    return driver.find_element("id", element_id).get_attribute(f"data-{name}") or ""


def _texts(driver, css: str) -> list[str]:
    return [node.text for node in driver.find_elements("css selector", css)]


def _assert_contexts_as_the_api_lists_them(browser, listing: dict, every_concept: dict) -> None:
    """Each card: its label (or "context k"), then its distinctive concepts in the API's order with P(c | χ).

    ``every_concept`` lists each context's whole vocabulary: the concept most probable in all contexts
    (the largest least P(c | χ), e.g. "grasp": every object can be grasped) leads no card, and the
    cards lead with different concepts, which is what lets a person tell them apart."""
    assert len(listing["contexts"]) >= 2, "the workshop scenes make Incremental-LDA discover a context"
    least = {}
    for context in every_concept["contexts"]:
        for concept in context["top_concepts"]:
            least[concept["name"]] = min(least.get(concept["name"], 1.0), concept["probability"])
    most_shared = max(least, key=least.__getitem__)
    leaders = []
    for context in listing["contexts"]:
        card = f'#contexts .context[data-context="{context["context"]}"]'
        assert _texts(browser, f"{card} .context-name") == [context["label"] or f"context {context['context']}"]
        rows = browser.find_elements("css selector", f"{card} .distinctive .bar")
        distinctive = context["distinctive_concepts"]
        assert [row.get_attribute("data-concept") for row in rows] == [c["name"] for c in distinctive]
        for row, concept in zip(rows, distinctive, strict=True):
            shown = float(row.find_element("css selector", ".value").text)
            assert abs(shown - concept["probability"]) <= 0.0005 + 1e-9, (concept, shown)
        most_probable = browser.find_element("css selector", f"{card} .top-concepts").text
        assert context["top_concepts"][0]["name"] in most_probable
        leaders.append(rows[0].get_attribute("data-concept"))
    assert most_shared not in leaders, (most_shared, leaders)
    assert len(set(leaders)) == len(leaders), leaders


def _assert_stages_match_the_answer(browser, answer: dict, nouns: list[str]) -> None:
    """The latest object's rows: P(c) at perception, concept web and in context, as the scene's answer gave them."""
    stages = ("perception", "web", "in_context")
    obj = answer["objects"][-1]
    assert all(obj[stage] for stage in stages), "a fitted model answers all three stages for a features-level object"
    assert _texts(browser, "#stages thead th[data-stage]") == ["prototypes", "concept web", "in context"]
    rows = browser.find_elements("css selector", "#stages tbody tr")
    assert len(rows) >= 3
    shown = [row.get_attribute("data-concept") for row in rows]
    strongest = max(((p, name) for stage in stages for name, p in obj[stage].items()))[1]
    assert strongest in shown
    for row, name in zip(rows, shown, strict=True):
        for stage in stages:
            cell = row.find_element("css selector", f'td[data-stage="{stage}"] .value').text
            assert abs(float(cell) - obj[stage][name]) <= 0.005 + 1e-9, (name, stage, cell, obj[stage][name])
    for stage in stages:
        noun = max((name for name in nouns if name in obj[stage]), key=obj[stage].__getitem__)
        step = browser.find_element("css selector", f'#stages-nouns [data-stage="{stage}"]')
        assert step.get_attribute("data-noun") == noun
        assert abs(float(step.text.split()[-1]) - obj[stage][noun]) <= 0.005 + 1e-9


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
    assert _data(browser, "connection", "protocol") == "contextweb", "the stream's key goes in a subprotocol"
    assert READ_KEY not in browser.current_url, "the page takes the key out of its address"
    _wait(lambda: _data(browser, "posterior-chart", "points") == "10", "the posterior chart to show 10 scenes")
    _wait(lambda: int(_data(browser, "contexts", "count") or 0) >= 1, "the contexts to appear")
    contexts_before = browser.find_element("id", "contexts").text
    assert "context 0" in contexts_before, "an unlabelled context is named by its index"
    assert "grasp" in contexts_before, "every object of the paper's world can be grasped"
    assert _data(browser, "concept-web", "nodes") == "29"
    _wait(lambda: _data(browser, "plan", "status") == "solved", "the plan")
    assert int(_data(browser, "plan", "pruned")) > 0, "a kitchen or playroom context prunes behaviours (Fig. 15)"

    # The last scene at the feature level: its objects go through the prototypes, the web and the context.
    second = world.scenes(10, seed=2, contexts=["workshop"])
    simulate(robot, model_id, world, [second[:-1]], level="concepts", train_level=None, progress=False)
    simulate(robot, model_id, world, [second[-1:]], level="features", train_level=None, progress=False)
    _wait(lambda: _data(browser, "posterior-chart", "points") == "20", "the chart to follow the stream")
    _wait(lambda: _data(browser, "contexts", "scenes") == "20", "the contexts to be read again")
    assert _data(browser, "k-chart", "points") == "20"
    assert browser.find_element("id", "contexts").text != contexts_before
    assert int(_data(browser, "concept-web", "edges")) > 0

    with httpx.Client(base_url=f"{service.url}/v1/models/{model_id}", headers={"X-API-Key": WRITE_KEY}) as api:
        answer = api.get("/scenes/19").json()
        _wait(lambda: _data(browser, "stages", "scene") == "19", "the stages of the latest object")
        nouns = httpx.get(f"{service.url}/v1/models/{model_id}", headers=api.headers).json()["vocabulary"]["nouns"]
        _assert_stages_match_the_answer(browser, answer, nouns)

        # An operator names the latest scene's context; the open page picks the label up without a new scene.
        workshop = answer["map_context"]
        assert api.patch(f"/contexts/{workshop}", json={"label": "workshop"}).status_code == 200
        card = f'#contexts .context[data-context="{workshop}"] .context-name'
        _wait(lambda: _texts(browser, card) == ["workshop"], "the label in the context panel", timeout=30)
        legend = f'#overview .legend span[data-context="{workshop}"]'
        assert _texts(browser, legend) == ["workshop"], "the posterior chart's legend names the context"
        assert "Scene 19 in workshop" in browser.find_element("id", "stages-scene").text
        assert "in workshop" in browser.find_element("id", "web-caption").text
        assert "workshop (χ" in browser.find_element("id", "plan").text, "the plan names its context"
        listing = api.get("/contexts", params={"top": 8}).json()  # the dashboard's request
        every_concept = api.get("/contexts", params={"top": 1000}).json()
        _assert_contexts_as_the_api_lists_them(browser, listing, every_concept)

    screenshot = tmp_path / "dashboard.png"  # docs/dashboard.png is a copy of it
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


def test_dashboard_marks_a_scene_whose_stored_answer_is_damaged_and_follows_the_scenes_after_it(
    service: ServiceProcess, browser
) -> None:
    """A trigger damages scene 5's stored answer inside the commit that learns it (as in
    tests/test_stream_feed.py): the stream sends ``scene_unreadable`` in its place, and the page lists it
    there, marked, with the reason; the panels that read an answer stay on scene 4, and the scenes after
    it follow. A page opened later meets it in the history (a whole summary, a 500 for its answer) and
    marks it too."""
    world = World(WorldConfig.paper(), seed=0)
    scenes = world.scenes(9, seed=4, contexts=["kitchen", "playroom"])
    with Client(service.url, WRITE_KEY) as robot:
        model_id = robot.models.create("damaged-answer", seed=1).id
        simulate(robot, model_id, world, [scenes[:5]], level="concepts", train_level=None, progress=False)
        browser.get(f"{service.url}/?key={READ_KEY}&model={model_id}")
        _wait(lambda: _data(browser, "connection", "mode") == "live", "the websocket to open")
        _wait(lambda: _data(browser, "stages", "scene") == "4", "the panels of scene 4")

        engine = create_database_engine(service.env["CONTEXTWEB_DATABASE_URL"])
        try:
            _execute(
                engine,
                f"CREATE TRIGGER damage_dashboard_scene_5 AFTER INSERT ON scene "
                f"WHEN NEW.model_id = '{model_id}' AND NEW.id = 5 BEGIN "
                "UPDATE scene SET answer_zlib = X'0200000000' WHERE model_id = NEW.model_id AND id = 5; END",
            )
            simulate(robot, model_id, world, [scenes[5:6]], level="concepts", train_level=None, progress=False)
        finally:  # the module's other tests share the database
            _execute(engine, "DROP TRIGGER IF EXISTS damage_dashboard_scene_5")
            engine.dispose()

        marker = '#scene-list .scene.unreadable[data-scene="5"]'
        shown = _wait(lambda: _texts(browser, marker), "the unreadable scene's marker")[0]
        assert shown.startswith("scene 5: stored answer unreadable — the stored answer cannot be decompressed"), shown
        _wait(lambda: _data(browser, "contexts", "scenes") == "6", "the contexts to be read again after scene 5")
        assert _data(browser, "stages", "scene") == "4", "the stages stay on the last readable scene"
        assert browser.find_element("id", "web-caption").text.startswith("Scene 4 in")
        assert _data(browser, "posterior-chart", "points") == "5", "the charts show the readable scenes"
        assert _data(browser, "connection", "mode") == "live"
        assert "Could not reach" not in browser.find_element("id", "message").text
        assert "scene 5's stored answer is damaged" in service.log_path.read_text(errors="replace")

        simulate(robot, model_id, world, [scenes[6:]], level="concepts", train_level=None, progress=False)
        _wait(lambda: _data(browser, "stages", "scene") == "8", "the scenes after the damaged one")
        assert _data(browser, "posterior-chart", "points") == "8"
        listed = [item.get_attribute("data-scene") for item in browser.find_elements("css selector", "#scene-list li")]
        assert listed == [str(i) for i in range(8, -1, -1)], "each scene in its place, newest first"
        assert _texts(browser, "#scene-list .unreadable") == [shown]
        assert _data(browser, "scene-list", "unreadable") == "1"

    # A page opened now reads scene 5 in the history: its answer, read for the panels, is a 500.
    browser.get(f"{service.url}/?key={READ_KEY}&model={model_id}")
    _wait(lambda: _data(browser, "connection", "mode") == "live", "the reopened page's websocket")
    reread = _wait(lambda: _texts(browser, marker), "the marker of the scene read in the history")[0]
    assert reread.startswith("scene 5: stored answer unreadable — ") and "cannot be read" in reread, reread
    assert _data(browser, "posterior-chart", "points") == "9"
    _wait(lambda: _data(browser, "stages", "scene") == "8", "the reopened page's panels")


def test_dashboard_without_a_key_asks_for_one(service: ServiceProcess, browser) -> None:
    browser.get(f"{service.url}/")
    _wait(lambda: browser.find_element("id", "key-form").is_displayed(), "the key form")
    assert "read key" in browser.find_element("id", "message").text
    assert _data(browser, "connection", "mode") == "offline"
