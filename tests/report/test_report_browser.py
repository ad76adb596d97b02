"""The report in headless Chromium: the 3D view renders, no console errors, skeletons on the
screenshot; a 250-frame, 10-person scene stays under 10 MB and opens in under 3 s; a rig's page
renders its first instant."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from test_report import make_scene  # noqa: E402

from mvm.report import write_report  # noqa: E402
from mvm.report.analysis import person_colors  # noqa: E402

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (apt-get install -y chromium)")

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--force-device-scale-factor=1", "--window-size=1400,1800"]
MAX_BYTES = 10_000_000
MAX_OPEN_MS = 3000


def chromium(page: Path, *args: str, timeout: float = 60) -> tuple[str, list[str], float]:
    """Run headless Chromium on ``page``: stdout, the page's console lines (from the browser's
    log on stderr) and the wall time in seconds."""
    with tempfile.TemporaryDirectory() as profile:
        t = time.perf_counter()
        done = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr",
                               "--v=0", *args, page.resolve().as_uri()],
                              capture_output=True, text=True, timeout=timeout)
        wall = time.perf_counter() - t
    console = [line for line in done.stderr.splitlines() if ":CONSOLE" in line]
    return done.stdout, console, wall


def page_status(page: Path) -> tuple[dict, list[str], float]:
    """The attributes the page writes on ``#mvm-status`` after loading, its console lines and
    the wall time of loading it."""
    dom, console, wall = chromium(page, "--dump-dom")
    tag = re.search(r'<div id="mvm-status"[^>]*>', dom)
    assert tag, "no #mvm-status in the rendered page"
    return dict(re.findall(r'data-([a-z-]+)="([^"]*)"', tag.group(0))), console, wall


def test_harness_sees_console_errors(tmp_path):
    """The checks below can fail: a page that logs an error is caught both ways."""
    page = tmp_path / "broken.html"
    page.write_text('<div id="mvm-status" data-state="loading"></div><script>'
                    'window.mvmErrors=[];console.error("broken on purpose");'
                    'document.getElementById("mvm-status").setAttribute("data-state","error");</script>')
    status, console, _ = page_status(page)
    assert status["state"] == "error"
    assert any("broken on purpose" in line for line in console)


@pytest.fixture(scope="module")
def big_report(tmp_path_factory):
    path = tmp_path_factory.mktemp("browser") / "scene"
    make_scene(path, people=10, frames=250, seed=11, points=5000)
    return write_report(path)


def test_report_renders_skeletons_in_chromium(big_report, tmp_path):
    size = big_report.stat().st_size
    assert size < MAX_BYTES, f"report is {size / 1e6:.1f} MB"
    status, console, wall = page_status(big_report)
    assert not console, f"console output: {console}"
    assert status["state"] == "rendered", status
    assert int(status["segments"]) > 100
    render_ms = float(status["render-ms"])
    assert render_ms < MAX_OPEN_MS, f"3D view drawn {render_ms:.0f} ms after navigation"
    print(f"\nreport: {size / 1e6:.2f} MB, 3D view drawn {render_ms:.0f} ms after navigation, "
          f"chromium --dump-dom wall time {wall:.2f} s")

    shot = tmp_path / "report.png"
    _, console, _ = chromium(big_report, f"--screenshot={shot}", "--virtual-time-budget=2000")
    assert not console, f"console output: {console}"
    image = cv2.imread(str(shot))
    assert image is not None, "no screenshot"
    x, y, w, h = (int(v) for v in status["canvas"].split(","))
    canvas = image[y:y + h, x:x + w].astype(int)
    assert canvas.shape[0] > 100 and canvas.shape[1] > 100
    background = np.array([0xfb, 0xfb, 0xfb])
    assert (np.abs(canvas - background).sum(-1) > 60).mean() > 0.002     # something drawn
    persons = len(re.findall(r'"head":', big_report.read_text()))
    seen = 0
    for rgb in person_colors(persons):
        bgr = np.array([rgb[2], rgb[1], rgb[0]], dtype=int)
        seen += int((np.abs(canvas - bgr).sum(-1) < 40).sum() >= 15)
    assert seen >= 0.8 * persons, f"only {seen} of {persons} skeleton colours on the 3D view"


def test_blank_canvas_fails_the_pixel_check(tmp_path):
    """A page whose viewer draws nothing shows none of the person colours."""
    page = tmp_path / "blank.html"
    page.write_text('<body style="margin:0;background:#fbfbfb"><canvas width="400" height="300"></canvas></body>')
    shot = tmp_path / "blank.png"
    chromium(page, f"--screenshot={shot}", "--virtual-time-budget=500")
    canvas = cv2.imread(str(shot))[:300, :400].astype(int)
    hits = [(np.abs(canvas - rgb[::-1].astype(int)).sum(-1) < 40).sum() for rgb in person_colors(10)]
    assert max(hits) == 0


def test_rig_report_renders_in_chromium(tmp_path):
    """A simulated rig's page (3 cameras, 2 people, 30 instants) in headless Chromium: no console
    output, the 3D view drawn at the first instant with every person's bones, within 3 s."""
    from click.testing import CliRunner

    from mvm.cli.main import main
    from mvm.core.config import Config
    from mvm.io.rig_simulation import write_rig_simulation
    from mvm.rig.options import RigOptions
    from mvm.rig.reconstruct_rig import reconstruct_rig
    from mvm.sim.rig_scene import RigSimConfig, simulate_rig

    root = tmp_path / "rig"
    write_rig_simulation(root, simulate_rig(RigSimConfig(cameras=3, people=2, frames=30, seed=5)))
    reconstruct_rig(root, Config(refine=False), RigOptions(workers=1))
    result = CliRunner().invoke(main, ["report", str(root)])
    assert result.exit_code == 0, result.output
    page = root / "mvm" / "report.html"
    first = json.loads(re.search(r'<script type="application/json" id="mvm-data">(.*?)</script>',
                                 page.read_text(), re.S).group(1))["view"]["instants"][0]
    status, console, _ = page_status(page)
    assert not console, f"console output: {console}"
    assert status["state"] == "rendered" and status["instant"] == "0", status
    assert int(status["segments"]) >= 16 * len(first["persons"]) > 0
    assert float(status["render-ms"]) < MAX_OPEN_MS
    shot = tmp_path / "rig.png"
    _, console, _ = chromium(page, f"--screenshot={shot}", "--virtual-time-budget=2000")
    assert not console, f"console output: {console}"
    x, y, w, h = (int(v) for v in status["canvas"].split(","))
    canvas = cv2.imread(str(shot))[y:y + h, x:x + w].astype(int)
    assert canvas.shape[0] > 100 and canvas.shape[1] > 100
    assert (np.abs(canvas - np.array([0xfb, 0xfb, 0xfb])).sum(-1) > 60).mean() > 0.002     # something drawn
