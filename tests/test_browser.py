"""Every committed HTML report, opened in a real browser (headless Chromium from Debian's
packages; .ci/run installs it): it renders, every embedded figure decodes, every table is there,
the page leads with its conclusions, and the screenshot is not blank."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "reports").glob("*/report.html"))
# the flags a sandboxed root session needs, and none of Chromium's own network traffic
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--virtual-time-budget=5000"]
# on load, the page writes into its title what the browser made of it
PROBE = """<script>window.addEventListener("load", () => {
  const imgs = [...document.images];
  document.title = "PROBE images=" + imgs.length
    + " decoded=" + imgs.filter(i => i.complete && i.naturalWidth > 0).length
    + " tables=" + document.querySelectorAll("table").length
    + " first=" + (document.querySelector("h2") || {textContent: ""}).textContent.trim();
});</script>"""


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    if os.environ.get("CI"):
        pytest.fail("headless Chromium is missing: .ci/run installs Debian's chromium package")
    pytest.skip("no chromium on this machine (apt-get install chromium)")


def _browse(page: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([_chromium(), *FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                           *args, page.as_uri()], capture_output=True, text=True, timeout=120)


def _probe(page: Path, tmp_path: Path) -> re.Match:
    probed = tmp_path / "report.html"
    probed.write_text(page.read_text().replace("</body>", PROBE + "</body>"))
    dom = _browse(probed, tmp_path, "--dump-dom").stdout
    got = re.search(r"PROBE images=(\d+) decoded=(\d+) tables=(\d+) first=([^<]*)", dom)
    assert got, dom[:500]
    return got


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.parent.name)
def test_the_report_renders_in_a_real_browser(page, tmp_path):
    html = page.read_text()
    got = _probe(page, tmp_path)
    images, decoded, tables = (int(got.group(i)) for i in (1, 2, 3))
    assert images == html.count("<img") and decoded == images
    assert tables == html.count("<table")


# the generic report of a mechanism file opens with the nominal machine: it has no conclusions
# block yet (to come with the report that leads with the decision)
NO_CONCLUSIONS = ("khujand_feed", "spatial_crank_rocker", "spatial_crank_slider")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.parent.name)
def test_the_report_leads_with_its_conclusions(page, tmp_path, request):
    if page.parent.name in NO_CONCLUSIONS:
        request.applymarker(pytest.mark.xfail(strict=True, reason="opens with the nominal "
                                              "machine, not with conclusions"))
    first = _probe(page, tmp_path).group(4).strip().lower()
    assert first.startswith("conclusions"), first


@pytest.mark.parametrize("page", PAGES[:1], ids=lambda p: p.parent.name)
def test_the_screenshot_is_a_page_not_a_blank(page, tmp_path):
    import matplotlib.image as mpimg

    shot = tmp_path / "shot.png"
    _browse(page, tmp_path, f"--screenshot={shot}", "--window-size=1200,1600")
    pixels = mpimg.imread(shot)[..., :3]
    ink = np.mean(np.any(pixels < 0.9, axis=-1))
    assert 0.02 < ink < 0.9, ink
