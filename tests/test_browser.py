"""The HTML replay (``kilonet animate DIR --out x.html``) and the HTML sweep report
(``kilonet report DIR --out r.html``) opened in a real browser: Debian's Chromium, headless,
driven by Playwright with the system browser (Playwright downloads none).

Each page must render (its elements there, a drawn frame, every image decoded), the replay's
Play and scrub must change the drawn frame, and no script error may be logged. Without
Chromium or Playwright these tests are skipped, except in CI (``CI`` set), where they fail:
``.ci/run`` installs Chromium and the test extras install Playwright.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

import kilonet.app.cli
from kilonet import scenarios
from kilonet.protocols.localize.program import LocalizeRobot

pytestmark = pytest.mark.browser

#: How Chromium is started: headless as root in a closed network (no sandbox, no GPU, no
#: background connections), with a fresh profile each time.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]

# Three cells of one seed each, 3 s of 12 robots: a report with a table of three rows.
SWEEP = """
name = "browser"
scenario = "gradient"
seeds = 1
[fixed]
duration_s = 3.0
"placement.robots" = 12
[grid]
"medium.loss_prob" = [0.0, 0.2, 0.4]
"""


def _unavailable(reason: str) -> None:
    if os.environ.get("CI"):
        pytest.fail(f"{reason}, and CI must run the browser tests (.ci/run installs it)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def browser(tmp_path_factory) -> Iterator:
    """A headless Chromium context (one per module), or a skip (a failure in CI)."""
    chromium = shutil.which("chromium")
    if chromium is None:
        _unavailable("no chromium on the PATH (Debian: apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _unavailable("Playwright is not installed (pip install -e '.[test]')")
    profile = tmp_path_factory.mktemp("chromium-profile")
    with sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            str(profile), executable_path=chromium, headless=True, args=CHROMIUM_ARGS
        )
        yield context
        context.close()


class Page:
    """A page opened from a file, with every script error and error message it logs."""

    def __init__(self, context, path: Path) -> None:
        self.errors: list[str] = []
        self.page = context.new_page()
        self.page.on("pageerror", lambda exc: self.errors.append(f"uncaught: {exc}"))
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.goto(path.as_uri())

    def canvas_digest(self) -> str:
        """A hash of the replay canvas's pixels: equal digests, equal drawn frames."""
        data = self.page.evaluate("document.getElementById('stage').toDataURL('image/png')")
        return hashlib.sha256(data.encode()).hexdigest()

    def drawn_leds(self) -> list[list[int]]:
        """The colour each robot's disc is drawn in now (RGB of a pixel inside the disc, beside
        its centre: the estimate's cross is drawn at the centre)."""
        return self.page.evaluate(
            """() => {
                const c = document.getElementById('stage');
                const k = window.devicePixelRatio || 1;
                const [x, y] = positions(now);
                return x.map((_, i) => Array.from(c.getContext('2d').getImageData(
                    (px(x[i]) + 0.4 * D.radius_mm * scale) * k, py(y[i]) * k, 1, 1).data
                ).slice(0, 3));
            }"""
        )

    def led_colours(self, t_s: str) -> list[list[int]]:
        """Each robot's LED colour at simulated time ``t_s`` (a JavaScript expression), as the
        recorded LED changes give it."""
        colours = self.page.evaluate(f"D.x0.map((_, i) => ledColour(i, {t_s}))")
        return [[int(v) for v in c[4:-1].split(",")] for c in colours]


@pytest.fixture(scope="module")
def replay_file(tmp_path_factory) -> Path:
    """The HTML replay of a small localize run: LEDs change as robots are located and done."""
    tmp = tmp_path_factory.mktemp("replay")
    result = scenarios.run(scenarios.get("localize"), {"placement.robots": 14}, seed=4)
    scenarios.write_outputs(result, tmp / "run")
    out = tmp / "replay.html"
    assert kilonet.app.cli.main(["animate", str(tmp / "run"), "--out", str(out)]) == 0
    return out


def test_the_replay_renders_its_robots_and_controls(browser, replay_file, tmp_path):
    page = Page(browser, replay_file)
    p = page.page
    assert p.title() == "localize — kilonet replay"
    size = p.evaluate("[document.getElementById('stage').width, N]")
    assert size[0] > 0 and size[1] == 14
    assert p.locator("#play").inner_text() == "Play"
    assert p.locator("#clock").inner_text().startswith("0.00 s / ")
    toggles = p.locator("#toggles input[type=checkbox]")
    assert toggles.count() == len(p.evaluate("D.overlays")) >= 2
    # Each robot is drawn in its LED colour at the start.
    assert page.drawn_leds() == page.led_colours("D.start_s")
    # The LED key: a disc in each colour of the program's key, and what it means.
    key = p.locator("#key > span")
    meanings = [meaning for _, meaning in LocalizeRobot.LED_KEY]
    assert [key.nth(k).inner_text().strip() for k in range(key.count())] == meanings
    discs = p.locator("#key .led")
    colours = [discs.nth(k).evaluate("d => getComputedStyle(d).backgroundColor") for k in
               range(discs.count())]  # fmt: skip
    assert colours == [
        f"rgb({r * 85}, {g * 85}, {b * 85})" for (r, g, b), _ in LocalizeRobot.LED_KEY
    ]
    p.screenshot(path=tmp_path / "replay.png")
    assert page.errors == []


def test_the_replay_has_a_scale_bar_and_a_key_for_estimates_and_frames(browser, replay_file):
    page = Page(browser, replay_file)
    p = page.page
    assert {"estimates", "frames"} <= set(p.evaluate("D.overlays"))
    entries = p.locator("#overlay-key > span")
    names = [entries.nth(k).get_attribute("data-overlay") for k in range(entries.count())]
    assert names == ["estimates", "frames"]
    assert entries.nth(0).inner_text().replace(" ", "").startswith("×estimate")
    assert "frame" in entries.nth(1).inner_text()
    swatches = p.locator("#overlay-key .swatch")
    drawn = [swatches.nth(k).evaluate("s => getComputedStyle(s).backgroundColor") for k in
             range(swatches.count())]  # fmt: skip
    hexes = p.evaluate("D.frames.colours.slice(0, 4)")
    assert drawn == [f"rgb({int(h[1:3], 16)}, {int(h[3:5], 16)}, {int(h[5:7], 16)})" for h in hexes]
    # The scale bar: the longest of the round lengths that fits in 150 px, drawn in black.
    bar_mm, bar_px, lengths = p.evaluate("[barMm, barMm * scale, D.scale_bars_mm]")
    assert bar_mm in lengths and bar_px <= 150
    longer = [v for v in lengths if v > bar_mm]
    assert not longer or longer[0] * bar_px / bar_mm > 150
    row = p.evaluate(
        """() => {
            const k = window.devicePixelRatio || 1, c = document.getElementById('stage');
            const g = c.getContext('2d'), y = Math.round((H - 8) * k);
            const at = x => Array.from(g.getImageData(Math.round(x * k), y, 1, 1).data).slice(0, 3);
            const x1 = W - 12, x0 = x1 - barMm * scale;
            return [at(x0 + 2), at((x0 + x1) / 2), at(x1 - 2), at(x0 - 6)];
        }"""
    )
    assert row[:3] == [[0, 0, 0]] * 3
    assert row[3] != [0, 0, 0]  # left of the bar: the table
    assert page.errors == []


def test_play_and_scrub_change_the_drawn_frame(browser, replay_file):
    page = Page(browser, replay_file)
    p = page.page
    start, end = page.led_colours("D.start_s"), page.led_colours("D.duration_s")
    assert start != end  # the run changed some LEDs: the frames must differ
    first = page.canvas_digest()
    # Scrub: the keyboard moves the range input as a user would, and fires its input event.
    p.locator("#scrub").focus()
    p.keyboard.press("End")
    assert p.locator("#scrub").input_value() == "1000"
    assert page.drawn_leds() == end
    last = page.canvas_digest()
    assert p.locator("#clock").inner_text().split(" / ")[0] == p.evaluate("fmt(D.duration_s)")
    p.keyboard.press("Home")
    assert page.drawn_leds() == start
    assert page.canvas_digest() == first  # the same moment draws the same frame
    # Play at the fastest speed: the player runs to the end and stops by itself.
    p.locator("#speed").select_option(index=p.locator("#speed option").count() - 1)
    p.locator("#play").click()
    assert p.locator("#play").inner_text() == "Pause"
    p.wait_for_function("document.getElementById('play').textContent === 'Play'", timeout=60_000)
    assert p.locator("#scrub").input_value() == "1000"
    assert page.drawn_leds() == end
    assert page.canvas_digest() == last
    # Play from the start at the slowest speed and pause: a frame of its own, drawn as recorded.
    p.locator("#speed").select_option(index=0)
    p.locator("#scrub").focus()
    p.keyboard.press("Home")
    p.locator("#play").click()
    p.wait_for_function("document.getElementById('scrub').value > 0", timeout=60_000)
    p.locator("#play").click()
    assert p.locator("#play").inner_text() == "Play"
    assert page.canvas_digest() not in (first, last)
    assert page.drawn_leds() == page.led_colours("now")
    assert page.errors == []


def test_the_sweep_report_renders_its_figures_and_tables(browser, tmp_path):
    sweep_file = tmp_path / "small.toml"
    sweep_file.write_text(SWEEP)
    out = tmp_path / "sweep"
    argv = ["sweep", str(sweep_file), "--out", str(out), "--workers", "1", "--no-progress"]
    assert kilonet.app.cli.main(argv) == 0
    report = tmp_path / "report.html"
    assert kilonet.app.cli.main(["report", str(out), "--out", str(report)]) == 0
    page = Page(browser, report)
    p = page.page
    assert p.locator("h1").inner_text() == "Sweep browser"
    figures = p.locator("img")
    assert figures.count() >= 1
    for k in range(figures.count()):  # every figure decoded, at its size
        size = figures.nth(k).evaluate("i => [i.complete, i.naturalWidth, i.naturalHeight]")
        assert size[0] and size[1] > 100 and size[2] > 100
    # One table row per cell (three loss values) under each metric's heading.
    metrics = p.locator("h2")
    assert metrics.count() >= 1
    first_table = p.locator("h2 ~ table").first
    assert first_table.locator("tbody tr").count() == 3
    p.screenshot(path=tmp_path / "report.png", full_page=True)
    assert page.errors == []
