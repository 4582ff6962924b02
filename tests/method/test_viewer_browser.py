"""The viewer panel in a real browser: ns-viewer on a tiny poisoned run, driven by headless Chromium.

The module trains a tiny run itself (64x48 orbit scene, 200 iterations of stealth-splat-lite with the
"horse" illusion, and nerfstudio's viewer on, so the panel is also installed during ns-train), starts
``ns-viewer`` on 127.0.0.1, opens it in Debian's ``chromium`` through Playwright (WebGL on SwiftShader,
no GPU, no browser download), and uses the StealthAttack panel like a person would: jump to the poisoned
view, hide the poison Gaussians, jump to an innocent view. Frames are read from screenshots of the 3D
canvas.

"A rendered frame is shown" means: the viewer reports a render resolution (it does so when it sends a
frame) and the canvas is no longer the empty scene (an empty viser scene is one flat colour with a few
grid lines: one colour covers most of the canvas).

Environment (optional): ``STEALTH_NS_VIEWER_RUN=<run>/config.yml`` uses an existing attacked run
instead of training one; ``STEALTH_NS_SCREENSHOT_DIR=<dir>`` also saves full-page screenshots there
(``viewer_poisoned.png``, ``viewer_innocent.png``; how ``docs/img`` was made).
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import free_port, stop_process, train_tiny
from scipy import ndimage

from stealth_ns.attack.record import AttackRecord

pytestmark = pytest.mark.slow

BIN = Path(sys.executable).parent
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
]
VIEWPORT = {"width": 1024, "height": 768}  # SwiftShader draws every pixel on the CPU: keep it small
DOCS_VIEWPORT = {"width": 1280, "height": 1000}  # for the screenshots in docs/img
CANVAS = (
    "canvas:not([style*='pointer-events'])"  # the 3D canvas (viser's 2D overlay has pointer-events: none)
)


# ----------------------------------------------------------------------------------------------- set-up
def find_chromium() -> str:
    """Debian's chromium: found on PATH, else installed with apt-get when running as root, else skip."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    if os.name == "posix" and os.geteuid() == 0 and shutil.which("apt-get"):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        subprocess.run(["apt-get", "update", "-qq"], env=env, capture_output=True, timeout=900)
        proc = subprocess.run(
            ["apt-get", "install", "-y", "-qq", "chromium"],
            env=env,
            capture_output=True,
            text=True,
            timeout=1800,
        )
        path = shutil.which("chromium")
        if path:
            return path
        pytest.skip(f"cannot install Debian's chromium with apt-get: {proc.stderr.strip()[-500:]}")
    pytest.skip("Debian's chromium is not installed and cannot be installed here (needs root and apt-get)")


def wait_for(condition: Callable[[], object], timeout: float, what: str, interval: float = 0.25) -> object:
    deadline = time.time() + timeout
    while time.time() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


@pytest.fixture(scope="module")
def run_config(tiny_orbit_scene, tmp_path_factory) -> Path:
    """config.yml of a tiny attacked run, trained with nerfstudio's viewer (and so the panel) on."""
    if os.environ.get("STEALTH_NS_VIEWER_RUN"):
        return Path(os.environ["STEALTH_NS_VIEWER_RUN"])
    return train_tiny(
        tiny_orbit_scene, tmp_path_factory.mktemp("viewer_browser"), "run",
        "--viewer.quit-on-train-completion", "True",
        "--viewer.websocket-host", "127.0.0.1", "--viewer.websocket-port", str(free_port()),
        "--pipeline.model.num-downscales", "0", "--pipeline.attack.illusion", "horse",
        iterations=200, vis="viewer",
    )  # fmt: skip


@pytest.fixture(scope="module")
def viewer_url(run_config: Path, tmp_path_factory) -> Iterator[str]:
    """ns-viewer on 127.0.0.1 (a free port); always stopped afterwards."""
    port = free_port()
    log_path = tmp_path_factory.mktemp("ns_viewer") / "ns-viewer.log"
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "TORCHDYNAMO_DISABLE": "1"}
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            [
                str(BIN / "ns-viewer"), "--load-config", str(run_config),
                "--viewer.websocket-host", "127.0.0.1", "--viewer.websocket-port", str(port),
            ],
            stdout=log, stderr=subprocess.STDOUT, env=env,
        )  # fmt: skip
    url = f"http://127.0.0.1:{port}"

    def serving() -> bool:
        if proc.poll() is not None:
            raise AssertionError(f"ns-viewer exited with {proc.returncode}:\n{log_path.read_text()[-3000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                return response.status == 200
        except OSError:
            return False

    try:
        wait_for(serving, 180, "ns-viewer to serve HTTP", interval=1.0)
        yield url
    finally:
        stop_process(proc)
    assert not unexpected_tracebacks(log_path.read_text()), log_path.read_text()[-3000:]


def unexpected_tracebacks(log: str) -> list[str]:
    """The Python tracebacks in ``log`` other than viser 0.2.7's disconnect race: a GUI update that
    arrives as the browser closes is handled after its client was removed, and viser's own thread
    prints ``KeyError: <client id>`` from ``_handle_gui_updates`` (seen once in CI; not our code)."""
    blocks = re.findall(r"Traceback \(most recent call last\):\n(?:[ \t].*\n)*.*", log)
    return [
        block
        for block in blocks
        if not ("_handle_gui_updates" in block and re.fullmatch(r"KeyError: \d+", block.splitlines()[-1]))
    ]


@pytest.fixture(scope="module")
def page(viewer_url: str):
    """A headless Chromium page on the viewer; browser closed afterwards."""
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="playwright is in the dev extras (pip install -e .[dev])"
    )
    executable = find_chromium()
    os.environ.setdefault("PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD", "1")
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=executable, headless=True, args=CHROMIUM_ARGS)
        try:
            pg = browser.new_page(
                viewport=DOCS_VIEWPORT if os.environ.get("STEALTH_NS_SCREENSHOT_DIR") else VIEWPORT
            )
            pg.set_default_timeout(90_000)
            pg.goto(
                viewer_url, wait_until="domcontentloaded"
            )  # the page's analytics script never loads offline
            yield pg
        finally:
            browser.close()


# ----------------------------------------------------------------------------------------------- frames
def canvas_frame(pg) -> np.ndarray:
    """[H, W, 3] float in [0, 1]: a screenshot of the 3D canvas (CSS pixels)."""
    from PIL import Image

    box = pg.locator(CANVAS).bounding_box()
    png = pg.screenshot(clip=box)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float32) / 255.0


def looks_rendered(frame: np.ndarray) -> bool:
    """Not the empty scene: no single (quantised) colour covers half of the canvas."""
    q = (frame * 255).astype(np.int32) // 8
    keys = (q[..., 0] * 32 + q[..., 1]) * 32 + q[..., 2]
    return np.bincount(keys.ravel()).max() / keys.size < 0.5


def stable_frame(pg, settle: float = 1.5, timeout: float = 90.0) -> np.ndarray:
    """The canvas once it stops changing (the viewer refines low-res frames to its full resolution)."""
    time.sleep(settle)
    previous = canvas_frame(pg)
    calm = 0
    deadline = time.time() + timeout
    while time.time() < deadline:
        time.sleep(0.75)
        frame = canvas_frame(pg)
        calm = calm + 1 if np.abs(frame - previous).mean() < 0.004 else 0
        if calm >= 2:
            return frame
        previous = frame
    raise AssertionError("the viewer's frame never settled")


def magenta_pixels(frame: np.ndarray) -> int:
    """Number of canvas pixels in the poison centres' colour (pure magenta)."""
    r, g, b = frame[..., 0], frame[..., 1], frame[..., 2]
    return int(((r > 0.8) & (b > 0.8) & (g < 0.3)).sum())


def panel_text(pg) -> str:
    return pg.locator("body").inner_text()


def dolly_out_of_view(pg, turns: int = 4, timeout: float = 15.0) -> None:
    """Turn the mouse wheel (dolly out a little) until the panel says the camera left the view.

    CI failed once waiting 60 s for that read-out after a single turn (perhaps undone by the view
    jump's camera move still in flight), so the wheel is turned again while the read-out has not come.
    """
    for _ in range(turns):
        pg.mouse.wheel(0, 250)
        try:
            wait_for(lambda: "Camera: free" in panel_text(pg), timeout, "the camera to leave the view")
            return
        except AssertionError:
            continue
    raise AssertionError(f"the camera did not leave the view after {turns} wheel turns")


def choose(pg, label: str, option: str) -> None:
    """Pick ``option`` in the panel dropdown labelled ``label``, as a user would."""
    pg.get_by_label(label, exact=True).click()
    pg.get_by_role("option", name=option, exact=True).click()


def image_samples(frame: np.ndarray, mask: np.ndarray, fy: float, cx: float, cy: float) -> np.ndarray:
    """[M, 3] canvas colours at the (eroded) mask pixels of a dataset view the camera sits on.

    The viewer renders with the view's vertical field of view and a centred principal point, so image
    pixel (u, v) lands at canvas ``(Wc / 2 + (u + 0.5 - cx) s, Hc / 2 + (v + 0.5 - cy) s)``, ``s = Hc / H``.
    """
    height = mask.shape[0]
    hc, wc = frame.shape[:2]
    s = hc / height
    v, u = np.nonzero(mask)
    x = np.clip(np.round(wc / 2 + (u + 0.5 - cx) * s).astype(int), 0, wc - 1)
    y = np.clip(np.round(hc / 2 + (v + 0.5 - cy) * s).astype(int), 0, hc - 1)
    return frame[y, x]


# ----------------------------------------------------------------------------------------------- the test
def test_panel_in_chromium_jumps_and_filters(page, run_config: Path):
    from PIL import Image

    view = AttackRecord.read(run_config.parent / "attack").views[0]
    target, mask = view.target.numpy(), view.mask.numpy()
    inner = ndimage.binary_erosion(mask, iterations=1)  # away from the illusion's edge
    data = Path(yaml.load(run_config.read_text(), Loader=yaml.Loader).pipeline.datamanager.dataparser.data)
    transforms = json.loads((data / "transforms.json").read_text())
    clean = np.asarray(Image.open(data / view.name).convert("RGB"), dtype=np.float32) / 255.0
    ratio = mask.shape[0] / transforms["h"]  # in case the dataparser downscaled the images
    fy, cx, cy = (transforms[k] * ratio for k in ("fl_y", "cx", "cy"))
    shots = (
        Path(os.environ["STEALTH_NS_SCREENSHOT_DIR"]) if os.environ.get("STEALTH_NS_SCREENSHOT_DIR") else None
    )

    # the panel is there and a rendered frame is shown
    page.get_by_text("Jump to view", exact=True).wait_for()
    wait_for(lambda: re.search(r"Resolution: [1-9]\d*\D[1-9]\d*px", panel_text(page)), 90, "a first render")
    wait_for(lambda: looks_rendered(canvas_frame(page)), 90, "a rendered frame on the canvas")
    assert f"Poisoned:\n{view.name}" in panel_text(page) or view.name in panel_text(page)

    # jump to the poisoned view: its role, the masked-PSNR read-out, and the illusion on screen
    choose(page, "Jump to view", f"poisoned: {view.name}")
    page.get_by_text("poisoned training view", exact=False).wait_for()
    psnr_text = wait_for(
        lambda: re.search(r"masked PSNR vs illusion: ([\d.]+) dB \(poison shown", panel_text(page)),
        90,
        "the masked-PSNR read-out",
    )
    assert float(psnr_text.group(1)) > 20.0, psnr_text.group(0)  # the illusion is learned (measured ~26 dB)
    poisoned_frame = stable_frame(page)
    assert looks_rendered(poisoned_frame)
    if shots:
        shots.mkdir(parents=True, exist_ok=True)
        page.get_by_text("masked PSNR vs illusion").scroll_into_view_if_needed()
        page.screenshot(path=str(shots / "viewer_poisoned.png"))
    seen = image_samples(poisoned_frame, inner, fy, cx, cy)
    to_target = np.abs(seen - target[inner]).mean()
    to_clean = np.abs(seen - clean[inner]).mean()
    assert to_target < 0.15 and to_target < 0.6 * to_clean, (to_target, to_clean)

    # same camera, poison Gaussians hidden: the illusion vanishes (the clean scene is closer than it)
    choose(page, "Poison Gaussians", "hidden")
    wait_for(lambda: "poison hidden" in panel_text(page), 90, "the read-out with poison hidden")
    hidden = image_samples(stable_frame(page), inner, fy, cx, cy)
    assert np.abs(hidden - clean[inner]).mean() < np.abs(hidden - target[inner]).mean()
    choose(page, "Poison Gaussians", "shown")
    wait_for(lambda: "poison shown" in panel_text(page), 90, "the read-out with poison shown")

    # jump to an innocent view: another role, no PSNR, a different frame without the illusion's colours
    page.get_by_label("Jump to view", exact=True).click()
    options = page.get_by_role("option").all_inner_texts()
    innocents = sorted(o for o in options if o.startswith("innocent: "))
    after = [o for o in innocents if o.split(": ", 1)[1] > view.name]  # the next view along the path
    page.get_by_role("option", name=(after or innocents)[0], exact=True).click()
    page.get_by_text("innocent training view", exact=False).wait_for()
    wait_for(lambda: "Camera on innocent view" in panel_text(page), 90, "the read-out on the innocent view")
    innocent_frame = stable_frame(page)
    if shots:
        page.get_by_text("Camera on innocent view").scroll_into_view_if_needed()
        page.screenshot(path=str(shots / "viewer_innocent.png"))
    assert looks_rendered(innocent_frame)
    assert np.abs(innocent_frame - poisoned_frame).mean() > 0.03
    assert np.abs(image_samples(innocent_frame, inner, fy, cx, cy) - target[inner]).mean() > 2 * to_target

    # overlays, seen from a little behind the poisoned camera with the frusta hidden (their images would
    # cover it): the poison centres (magenta) just in front of the poisoned camera, then the KDE's core
    choose(page, "Jump to view", f"poisoned: {view.name}")
    wait_for(
        lambda: "Camera on poisoned view" in panel_text(page), 90, "the camera back on the poisoned view"
    )
    box = page.locator(CANVAS).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    stable_frame(page)  # the jump's camera move is over (a wheel during it could be undone by it)
    dolly_out_of_view(page)
    page.get_by_role("button", name="Hide Train Cams").click()  # frustum images would hide the poison
    page.get_by_label("Poisoned cameras", exact=True).uncheck()
    before = magenta_pixels(stable_frame(page))
    page.get_by_label("Poison centres", exact=True).check()
    wait_for(lambda: re.search(r"[1-9]\d* poison centres", panel_text(page)), 60, "the poison centres")
    assert magenta_pixels(stable_frame(page)) > before + 50
    page.get_by_label("KDE density", exact=True).check()
    wait_for(lambda: re.search(r"\d+ KDE voxels", panel_text(page)), 60, "the KDE voxels")
    if shots:
        stable_frame(page)
        page.get_by_text("KDE voxels", exact=False).scroll_into_view_if_needed()
        page.screenshot(path=str(shots / "viewer_overlays.png"))
    page.get_by_label("Poisoned cameras", exact=True).check()
    page.get_by_role("button", name="Show Train Cams").click()


def test_only_visers_disconnect_race_is_tolerated_in_the_viewer_log():
    race = (
        "(viser) Connection closed (0, 0 total)\n"
        "Traceback (most recent call last):\n"
        '  File "/x/viser/infra/_infra.py", line 139, in _handle_incoming_message\n'
        "    cb(client_id, message)\n"
        '  File "/x/viser/_gui_api.py", line 253, in _handle_gui_updates\n'
        "    client = self._owner.get_clients()[client_id]\n"
        "KeyError: 0\n"
    )
    ours = (
        "Traceback (most recent call last):\n"
        '  File "/x/stealth_ns/method/viewer/panel.py", line 1, in on_update\n'
        "    raise ValueError('bad')\n"
        "ValueError: bad\n"
    )
    assert unexpected_tracebacks("ok\n" + race) == []
    assert len(unexpected_tracebacks(race + ours)) == 1
    assert "ValueError: bad" in unexpected_tracebacks(race + ours)[0]
