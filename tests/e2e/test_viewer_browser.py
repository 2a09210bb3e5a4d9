"""The three.js viewer in headless Chromium against the real demo stack.

``skelfuse demo`` runs as a subprocess (the ``demo_stack`` fixture: server + 3 simulated Kinect
agents, 2 simulated people); Debian's Chromium loads ``/`` and the tests read the viewer's test
hook ``window.skelfuseViewer``, the HUD, and the pixels of a screenshot. Nothing is mocked.

Chromium and the ``playwright`` Python package are required: the tests skip with a reason when
either is missing, and fail when the ``CI`` environment variable is set (CI must install them).
"""

from __future__ import annotations

import os
import re
import shutil
import struct
import time
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np
import numpy.typing as npt
import pytest

if TYPE_CHECKING:
    from playwright.sync_api import Browser, Page

    from tests.conftest import DemoStack

PROJECT_ROOT = Path(__file__).resolve().parents[2]
VIEWER_JS = PROJECT_ROOT / "server" / "static" / "viewer.js"
ARTIFACTS = PROJECT_ROOT / "artifacts"

# The demo stack can take up to 60 s to start fusing (fixture) and 20 s to stop; every test
# bounds its own waits well below this.
pytestmark = [pytest.mark.e2e, pytest.mark.browser, pytest.mark.timeout(180)]

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
VIEWPORT = {"width": 1280, "height": 720}
DEMO_SENSORS = 3
DEMO_PERSONS = 2
HOOK = "window.skelfuseViewer"


def _unavailable(reason: str, ci_hint: str) -> NoReturn:
    if os.environ.get("CI"):
        pytest.fail(f"{reason}: {ci_hint}", pytrace=False)
    pytest.skip(reason)


def _chromium_executable() -> str:
    if Path("/usr/bin/chromium").is_file():
        return "/usr/bin/chromium"
    found = shutil.which("chromium")
    if found is None:
        _unavailable(
            "Chromium not found (/usr/bin/chromium or `chromium` on PATH)",
            "CI must install Debian's `chromium` package (apt-get install chromium)",
        )
    return found


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """Headless Debian Chromium driven by Playwright; closed at the end of the module."""
    executable = _chromium_executable()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _unavailable(
            "the playwright Python package is not installed",
            "CI must install the dev extras (pip install -e '.[dev]')",
        )
    manager = sync_playwright().start()
    try:
        chromium = manager.chromium.launch(
            executable_path=executable, args=CHROMIUM_ARGS, headless=True, timeout=30_000
        )
        try:
            yield chromium
        finally:
            chromium.close()
    finally:
        manager.stop()


class ViewerPage:
    """A browser page on the viewer, with the page's errors collected."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.page_errors: list[str] = []
        self.console_errors: list[str] = []
        page.on("pageerror", lambda exc: self.page_errors.append(str(exc)))
        page.on(
            "console",
            lambda msg: self.console_errors.append(msg.text) if msg.type == "error" else None,
        )

    def hook(self) -> dict[str, Any]:
        state: dict[str, Any] = self.page.evaluate(f"({{...{HOOK}, errors: [...{HOOK}.errors]}})")
        return state

    def wait_for(self, expression: str, timeout_s: float) -> None:
        """Waits until the JS ``expression`` is truthy; fails with the hook's state if not."""
        try:
            self.page.wait_for_function(expression, timeout=timeout_s * 1000, polling=50)
        except Exception as exc:
            pytest.fail(
                f"not true within {timeout_s} s: {expression}\nhook: {self.hook()}\n{exc}",
                pytrace=False,
            )

    def assert_no_errors(self) -> None:
        state = self.hook()
        assert state["errors"] == [], f"viewer reported errors: {state['errors']}"
        assert self.page_errors == [], f"uncaught page errors: {self.page_errors}"
        assert self.console_errors == [], f"console errors: {self.console_errors}"


@pytest.fixture
def viewer(browser: Browser, demo_stack: DemoStack) -> Iterator[ViewerPage]:
    """A fresh page on the demo's viewer, streaming (more than 30 frames received)."""
    context = browser.new_context(viewport=VIEWPORT, device_scale_factor=1)
    try:
        page = context.new_page()
        page.set_default_timeout(15_000)
        vp = ViewerPage(page)
        page.goto(demo_stack.http_url + "/", wait_until="load", timeout=15_000)
        vp.wait_for(f"{HOOK} && {HOOK}.framesReceived > 30", timeout_s=30)
        yield vp
    finally:
        context.close()


# --- hook state -------------------------------------------------------------------------------


def test_viewer_streams_and_draws_the_demo(viewer: ViewerPage, demo_stack: DemoStack) -> None:
    # Sample the hook for a while: both people must be drawn at some point (the demo has 2;
    # one may be hidden for a moment), never more than 2 (a ghost or a duplicated track).
    samples: list[dict[str, Any]] = []
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        samples.append(viewer.hook())
        if len(samples) >= 30 and any(s["personsDrawn"] == DEMO_PERSONS for s in samples):
            break
        time.sleep(0.1)
    persons_seen = [s["personsDrawn"] for s in samples]
    assert max(persons_seen) == DEMO_PERSONS, f"personsDrawn over {len(samples)}: {persons_seen}"

    state = viewer.hook()
    assert state["connected"] is True
    assert state["webgl"] is True
    assert state["skeletonName"] == "kinect_v2_25"
    assert state["framesReceived"] > 30
    assert 1 <= state["personsDrawn"] <= DEMO_PERSONS, state
    # Kinect v2 has 25 joints; fused joints no sensor sees are null, so allow a few missing.
    assert state["jointsDrawn"] >= 15 * state["personsDrawn"], state
    assert state["bonesDrawn"] > 0, state
    assert state["sensorsDrawn"] == DEMO_SENSORS, state
    assert state["rawEnabled"] is False
    assert state["rawViewsDrawn"] == 0, state

    # The viewer shows the server's own stream, and is up to date with it.
    health = demo_stack.get_json("/api/health")
    assert 0 < state["lastSeq"] <= int(str(health["fused_frames"])), (state, health)
    assert int(str(health["ws_clients"])) >= 1, health

    # The HUD says the same as the hook.
    page = viewer.page
    assert page.inner_text("#hud-conn") == "connected"
    assert page.locator("#hud-sensor-rows tr:not(.empty)").count() == DEMO_SENSORS
    assert page.locator("#hud-person-chips .chip").count() >= 1
    viewer.assert_no_errors()


# --- screenshot -------------------------------------------------------------------------------

RGB = tuple[int, int, int]


def decode_png(data: bytes) -> npt.NDArray[np.uint8]:
    """Decodes an 8-bit, non-interlaced PNG (as Chromium writes them) to an (H, W, C) array."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos = 8
    header: tuple[int, ...] | None = None
    idat: list[bytes] = []
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        pos += 12 + length  # length, type, data, CRC
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
    assert header is not None, "PNG without IHDR"
    width, height, depth, color_type, _, _, interlace = header
    assert depth == 8, f"bit depth {depth} not supported"
    assert interlace == 0, "interlaced PNG not supported"
    channels = {0: 1, 2: 3, 4: 2, 6: 4}.get(color_type)
    assert channels is not None, f"colour type {color_type} not supported"
    bpp = channels  # bytes per pixel at 8 bits per sample
    stride = width * bpp
    raw = zlib.decompress(b"".join(idat))
    assert len(raw) == height * (stride + 1), "truncated image data"
    out = bytearray(height * stride)
    prev = bytearray(stride)
    for y in range(height):
        start = y * (stride + 1)
        kind_ = raw[start]
        line = bytearray(raw[start + 1 : start + 1 + stride])
        if kind_ == 1:  # Sub
            for i in range(bpp, stride):
                line[i] = (line[i] + line[i - bpp]) & 0xFF
        elif kind_ == 2:  # Up
            line = bytearray(
                (np.frombuffer(line, np.uint8) + np.frombuffer(prev, np.uint8)).tobytes()
            )
        elif kind_ == 3:  # Average
            for i in range(stride):
                left = line[i - bpp] if i >= bpp else 0
                line[i] = (line[i] + ((left + prev[i]) >> 1)) & 0xFF
        elif kind_ == 4:  # Paeth
            for i in range(stride):
                a = line[i - bpp] if i >= bpp else 0
                b = prev[i]
                c = prev[i - bpp] if i >= bpp else 0
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                predictor = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[i] = (line[i] + predictor) & 0xFF
        else:
            assert kind_ == 0, f"unknown PNG filter type {kind_}"
        out[y * stride : (y + 1) * stride] = line
        prev = line
    return np.frombuffer(bytes(out), np.uint8).reshape(height, width, channels)


def parse_css_rgb(text: str) -> RGB:
    m = re.fullmatch(r"rgba?\((\d+),\s*(\d+),\s*(\d+)(?:,\s*[\d.]+)?\)", text.strip())
    assert m, f"unexpected CSS colour {text!r}"
    return (int(m[1]), int(m[2]), int(m[3]))


def viewer_palette(name: str) -> list[RGB]:
    """The hex colours of ``const NAME = [...]`` in viewer.js."""
    source = VIEWER_JS.read_text(encoding="utf-8")
    m = re.search(rf"const {name} = \[(.*?)\]", source, re.S)
    assert m, f"{name} not found in {VIEWER_JS}"
    hexes = re.findall(r"'#([0-9a-fA-F]{6})'", m[1])
    assert len(hexes) >= 6, f"{name}: {hexes}"
    return [(int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)) for h in hexes]


def colour_counts(
    image: npt.NDArray[np.uint8],
    mask: npt.NDArray[np.bool_],
    candidates: list[RGB],
    others: list[RGB],
    min_brightness: int = 150,
    tolerance: float = 0.15,
) -> dict[RGB, int]:
    """Pixels of each candidate colour, among bright pixels where ``mask`` is True.

    A pixel's chromaticity is its RGB divided by its largest channel, which makes the Lambert-
    shaded joint spheres (colour × light) and the anti-aliased edges of the bone lines (colour
    blended with the near-black background) look like the flat colour they were drawn with.
    Each bright pixel (largest channel > ``min_brightness``: not the background #111418, nor the
    grid lines #5a6470/#2c333c) goes to the nearest colour among ``candidates`` + ``others``
    and counts if it is within ``tolerance``. ``others`` (the sensors' colours) take their own
    pixels, so the sensor #ffcc80 is not counted as the person colour #ffd740.
    """
    rgb = image[..., :3].astype(np.float64)
    brightest = rgb.max(axis=2)
    selected = mask & (brightest > min_brightness)
    chroma = rgb[selected] / brightest[selected][:, None]
    refs = np.array([np.array(c, np.float64) / max(c) for c in [*candidates, *others]])
    distances = np.linalg.norm(chroma[:, None, :] - refs[None, :, :], axis=2)
    nearest = distances.argmin(axis=1)
    close = distances.min(axis=1) < tolerance
    return {c: int(np.sum(close & (nearest == i))) for i, c in enumerate(candidates)}


def test_screenshot_shows_the_fused_skeletons(viewer: ViewerPage) -> None:
    page = viewer.page
    viewer.wait_for(f"{HOOK}.personsDrawn === {DEMO_PERSONS}", timeout_s=20)

    def drawn_colours() -> tuple[list[RGB], list[RGB]]:
        chips = page.eval_on_selector_all(
            "#hud-person-chips .chip", "els => els.map(e => getComputedStyle(e).backgroundColor)"
        )
        swatches = page.eval_on_selector_all(
            "#hud-sensor-rows .swatch", "els => els.map(e => getComputedStyle(e).backgroundColor)"
        )
        return [parse_css_rgb(c) for c in chips], [parse_css_rgb(c) for c in swatches]

    # The people on screen (the HUD chips, one per drawn person, in the person's colour) must
    # be the same before and after the shot, or the pixel counts below would not mean much.
    for _ in range(10):
        before = drawn_colours()
        png = page.screenshot(type="png", timeout=15_000)
        after = drawn_colours()
        if before == after and len(before[0]) == DEMO_PERSONS:
            break
        time.sleep(0.3)
    else:
        pytest.fail(f"the drawn people kept changing around the screenshot: {before} / {after}")
    person_colours, sensor_colours = before
    ARTIFACTS.mkdir(exist_ok=True)
    (ARTIFACTS / "viewer.png").write_bytes(png)

    palette = viewer_palette("PERSON_PALETTE")
    for colour in person_colours:
        assert colour in palette, f"person colour {colour} is not in viewer.js PERSON_PALETTE"
    assert len(set(person_colours)) == len(person_colours), "two people share a colour"
    assert len(sensor_colours) == DEMO_SENSORS
    assert not set(sensor_colours) & set(palette), "a sensor colour is a person colour"

    image = decode_png(png)
    height, width = image.shape[:2]
    assert (width, height) == (VIEWPORT["width"], VIEWPORT["height"])

    # Not a blank or uniform canvas: many distinct colours, and real contrast.
    rgb = image[..., :3]
    distinct = len(np.unique(rgb.reshape(-1, 3), axis=0))
    assert distinct > 100, f"only {distinct} distinct colours"
    assert float(rgb.std()) > 5, f"nearly uniform image (std {float(rgb.std()):.1f})"

    # Pixels in the fused people's colours, outside the HUD panel (its chips use them too).
    hud = page.locator("#hud").bounding_box()
    assert hud is not None
    mask = np.ones((height, width), dtype=bool)
    x0, y0 = max(0, int(hud["x"]) - 2), max(0, int(hud["y"]) - 2)
    x1, y1 = int(hud["x"] + hud["width"]) + 3, int(hud["y"] + hud["height"]) + 3
    mask[y0:y1, x0:x1] = False
    counts = colour_counts(image, mask, palette, sensor_colours)
    drawn = {c: counts[c] for c in person_colours}
    absent = {c: n for c, n in counts.items() if c not in person_colours}
    report = f"drawn people {drawn}, palette colours not in use {absent}"
    # A person 3-6 m from the default camera covers ~700-1000 such pixels at 1280×720 (24 bones,
    # 25 joints, the "#id" label); 150 each leaves room for partial occlusion.
    for colour, n in drawn.items():
        assert n >= 150, f"person colour {colour}: {n} pixels; {report}"
    assert sum(drawn.values()) >= 400, report
    # Specificity: palette colours nobody has are (nearly) absent, so the counts above come
    # from the skeletons, not from any bright colour.
    for colour, n in absent.items():
        assert n < 60, f"unused person colour {colour}: {n} pixels; {report}"
    viewer.assert_no_errors()


# --- raw views --------------------------------------------------------------------------------


def test_raw_views_toggle(viewer: ViewerPage) -> None:
    page = viewer.page
    toggle = page.locator("#raw-toggle")
    assert not toggle.is_checked()
    assert viewer.hook()["rawViewsDrawn"] == 0

    toggle.click()
    assert toggle.is_checked()
    # 3 sensors × at least one body each (2 people, each seen by most sensors).
    viewer.wait_for(f"{HOOK}.rawEnabled && {HOOK}.rawViewsDrawn >= {DEMO_SENSORS}", timeout_s=10)
    # Each simulated sensor reports each person at most once: no more raw bodies than that.
    for _ in range(10):
        raw = viewer.hook()["rawViewsDrawn"]
        assert raw <= DEMO_SENSORS * DEMO_PERSONS, f"{raw} raw bodies drawn"
        time.sleep(0.05)

    toggle.click()
    assert not toggle.is_checked()
    viewer.wait_for(f"!{HOOK}.rawEnabled && {HOOK}.rawViewsDrawn === 0", timeout_s=5)
    # And it stays off while frames keep arriving.
    frames = viewer.hook()["framesReceived"]
    viewer.wait_for(f"{HOOK}.framesReceived > {frames + 10}", timeout_s=5)
    assert viewer.hook()["rawViewsDrawn"] == 0
    viewer.assert_no_errors()
