"""``station report`` on the demo's calibration and verification, read in headless Chromium (Debian's
``chromium`` driven by Playwright) as a person reads it and as it prints: every picture loads, nothing
is fetched beyond the page, no figure or table is wider than an A4 page's print area or cut by a page
break, each section starts a page. ``STATION_CERTIFICATE_PNG=docs/certificate.png`` also saves the
calibration certificate's first screen there (docs/how-to/certificate.md's)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

import configs
from station.cli import main

CHROMIUM = Path("/usr/bin/chromium")
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]
PRINT_WIDTH_PX = round((210 - 28) / 25.4 * 96)  # A4 less the page's 14 mm side margins, CSS pixels
PRINT_HEIGHT_PX = round((297 - 30) / 25.4 * 96)  # less its 14 mm top and 16 mm bottom margins

pytestmark = pytest.mark.skipif(
    not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium (apt-get install chromium)"
)


@pytest.fixture(scope="module")
def certificates(tmp_path_factory):
    """The demo's report.json and verify.json as certificates, its two verifications (of the
    corrected and of the nominal table on the demo's verification samples) recorded in a history of
    the test's own."""
    folder = tmp_path_factory.mktemp("certificate")
    demo, db = folder / "demo", folder / "history.sqlite"
    assert main(["demo", "--out", str(demo), "--no-viewer"]) == 0
    verify = [demo / "verify.csv", "--table", demo / "corrected.toml", "--db", db]
    verify += ["--robot", configs.path("robots/hsr_jr680.toml"), "--setup", configs.path("setups/sim.toml")]
    assert main(["verify", *map(str, verify)]) == 0
    nominal = [*verify[:2], configs.path("robots/hsr_jr680.toml"), *verify[3:]]
    assert main(["verify", *map(str, nominal)]) == 3  # as the demo's second check: the nominal table drifted
    pages = {}
    for name in ("report", "verify"):
        pages[name] = folder / f"{name}.html"
        assert main(["report", str(demo / f"{name}.json"), "--out", str(pages[name]), "--db", str(db)]) == 0
    return pages


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (pip install -e '.[dev]')")
    with sync_api.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        yield chromium
        chromium.close()


def _open(browser, html: str, requests: list[str]):
    """A page of the print area's width showing ``html``; every request it makes is listed in
    ``requests`` and refused (a data: URI is the page's own and never reaches the network)."""
    page = browser.new_page(viewport={"width": PRINT_WIDTH_PX, "height": PRINT_HEIGHT_PX})
    page.on("request", lambda r: None if r.url.startswith("data:") else requests.append(r.url))
    page.route("**/*", lambda route: route.abort())
    page.set_content(html, wait_until="load")
    return page


LAYOUT = """() => ({
  images: [...document.images].map(i => [i.complete, i.naturalWidth, i.getBoundingClientRect().height]),
  wide: [...document.querySelectorAll('figure, table, img, dl')]
        .filter(e => e.getBoundingClientRect().right > document.documentElement.clientWidth + 0.5)
        .map(e => e.outerHTML.slice(0, 80)),
  breaks: [...document.querySelectorAll('section')].map(s => getComputedStyle(s).breakBefore),
  kept: [...document.querySelectorAll('figure, tr')].every(e => getComputedStyle(e).breakInside === 'avoid'),
})"""


@pytest.mark.parametrize("name, pictures", [("report", 5), ("verify", 2)])
def test_the_certificate_reads_and_prints_whole_in_chromium(certificates, browser, tmp_path, name, pictures):
    requests: list[str] = []
    page = _open(browser, certificates[name].read_text(), requests)
    page.emulate_media(media="print")
    layout = page.evaluate(LAYOUT)
    assert len(layout["images"]) >= pictures
    assert all(done and width > 0 for done, width, _ in layout["images"]), layout["images"]
    assert all(height < PRINT_HEIGHT_PX for *_, height in layout["images"])  # each fits on one page
    assert layout["wide"] == []
    assert layout["breaks"] == ["page"] * len(layout["breaks"]) and len(layout["breaks"]) == 3
    assert layout["kept"]
    pdf = page.pdf(format="A4", print_background=True)
    assert len(re.findall(rb"/Type\s*/Page[^s]", pdf)) >= 1 + len(layout["breaks"])  # the sections' pages
    page.emulate_media(media="screen")
    shot = tmp_path / f"{name}.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 50_000
    if name == "report" and os.environ.get("STATION_CERTIFICATE_PNG"):
        page.screenshot(path=os.environ["STATION_CERTIFICATE_PNG"])
    shutil.copy(shot, certificates[name].with_suffix(".png"))  # beside the page, for a person to look at
    page.close()
    assert requests == []
