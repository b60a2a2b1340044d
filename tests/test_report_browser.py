"""The report as a reader sees it: the index and one rendered notebook opened from disk in headless
Chromium with the network off. Header and headline present, every image loaded, every link
resolving, no element wider than the page.

Skipped with a reason without a browser (Debian: ``apt-get install chromium``, or ``make browser``);
under CI=true a missing browser is a failure (``.ci/run`` installs it).
"""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import unquote, urlparse

import pytest

from bench.browser import PAGE_CHECKS, Browser, find_browser

pytestmark = pytest.mark.notebook


@pytest.fixture(scope="module")
def browser():
    exe = find_browser()
    if exe is None:
        msg = "no Chromium-family browser on PATH (apt-get install chromium, or make browser)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"CI=true requires the browser test: {msg}")
        pytest.skip(msg)
    with Browser(exe, width=1280, height=900) as b:
        yield b


def _inspect(b: Browser, page: Path) -> dict:
    b.open(page)
    info = b.evaluate(PAGE_CHECKS)
    info["requests"] = list(b.requests.values())
    return info


def _assert_page_sound(info: dict, page: Path) -> None:
    # the network is off: the page must need nothing but local files (and inline data)
    remote = [r["url"] for r in info["requests"] if not r["url"].startswith(("file:", "data:"))]
    assert not remote, f"{page.name} requests remote resources: {remote[:5]}"
    failed = [r["url"] for r in info["requests"] if r["failed"]]
    assert not failed, f"{page.name}: failed loads {failed[:5]}"
    assert all(i["ok"] for i in info["images"]), [i["src"] for i in info["images"] if not i["ok"]][:5]
    for link in info["links"]:
        u = urlparse(link)
        if u.scheme == "file":
            target = Path(unquote(u.path))
            assert target.exists(), f"{page.name}: link to a missing file {target}"
            if u.fragment and target == page.resolve():
                assert u.fragment in info["ids"], f"{page.name}: link to a missing anchor #{u.fragment}"
        else:
            assert u.scheme in ("http", "https", "mailto"), link  # external references stay plain links
    assert info["n_overflowing"] == 0, f"{page.name}: elements wider than the page: {info['overflowing']}"
    assert info["scrollWidth"] <= info["width"], (info["scrollWidth"], info["width"])


def test_index_opens_offline_with_header_headline_images_and_links(main_run, browser):
    index = main_run.out / "report" / "index.html"
    info = _inspect(browser, index)
    _assert_page_sound(info, index)
    text = info["text"]
    for label in ("Input", "Params digest", "Code version", "Packages", "Date", "Headline", "Our release"):
        assert label in text, label
    assert "synthetic mini-world" in text and "Self-test on the mini-world" in text
    assert "Answer-interface audit of the reference release" in text
    assert {"run", "headline", "paper", "exclusions", "examples", "figures", "tables", "notebooks",
            "release"} <= set(info["ids"])
    assert "changes" not in info["ids"]  # the session run is its own baseline: nothing changed
    # the panel: the report's claims on v5 with their status (real data), near the top
    assert "The ReSTI report against what we measure" in text
    assert info["ids"].index("paper") < info["ids"].index("figures")
    if (main_run.out / "answer_interface" / "paper_claims_v5.csv").exists():
        assert "20.5% (38/185)" in text and "38/185 = 20.5%" in text and "leak not in the report" in text
    assert "not checkable here" in text
    # one example of each verdict, legacy beside repaired, and the page of every task's examples
    examples = text.split("Before and after: examples", 1)[1].split("\nFigures\n", 1)[0]
    for verdict in ("retained", "corrected", "re-contracted", "excluded"):
        assert verdict in examples, verdict
    assert "Legacy (STI-Bench)" in examples and "Repaired (ours)" in examples and "Source evidence" in examples
    figures = list((main_run.out / "figures").glob("*.png"))
    assert len(info["images"]) == len(figures) > 5
    # figures are drawn for the page width: the overview fills the content column
    widest = max(i["width"] for i in info["images"])
    assert widest > 900


def test_rendered_notebook_opens_offline_and_links_back(main_run, browser):
    page = main_run.out / "report" / "notebooks" / "99_release_report.html"
    info = _inspect(browser, page)
    _assert_page_sound(info, page)
    back = [u for u in info["links"] if u.endswith("/report/index.html")]
    assert back, "no link back to the report index"
    assert "99 · Release and report" in info["text"]
    assert info["images"] and all(i["ok"] for i in info["images"])


def test_examples_page_opens_offline_with_every_task(main_run, browser):
    from resti_lib.tasks import names

    page = main_run.out / "report" / "examples.html"
    info = _inspect(browser, page)
    _assert_page_sound(info, page)
    assert any(u.endswith("/report/index.html") for u in info["links"])
    for task in names():
        assert task in info["text"], task


def test_what_changed_section_when_params_change(dimensional_edit, browser):
    """One task's tolerance edited: the report opens with the What changed section, offline, sound."""
    index = dimensional_edit.edited / "report" / "index.html"
    info = _inspect(browser, index)
    _assert_page_sound(info, index)
    assert info["ids"].index("changes") < info["ids"].index("headline")  # first, above the headline
    section = info["text"].split("What changed", 2)[2].split("Headline", 1)[0]
    assert "rule.abs_tol" in section and "0.002" in section and "0.3" in section and "03_dimensional" in section
    assert "no_valid_options" in section and "rows changed" in section
