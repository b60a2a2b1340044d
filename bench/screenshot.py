"""Render outputs/report/index.html in headless Chromium and save a full-page PNG, so the rendering
is seen (``make screenshot``, after ``make report``).

Needs Debian's ``chromium`` (``apt-get install chromium``); the page is opened from disk (file://)
with the network off. ``python -m bench.screenshot [HTML [PNG]]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from bench.browser import Browser, BrowserError, find_browser
from resti_lib import paths


def screenshot(html: Path, png: Path, *, width: int = 1280) -> Path:
    if find_browser() is None:
        raise SystemExit("screenshot: no chromium on PATH (Debian: apt-get install chromium)")
    if not html.exists():
        raise SystemExit(f"screenshot: {html} not found; run `make report` first")
    try:
        with Browser(width=width) as b:
            b.open(html)
            b.screenshot(png, full_page=True)
    except BrowserError as e:
        raise SystemExit(f"screenshot: {e}") from None
    return png


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    html = Path(argv[0]) if argv else paths.OUTPUTS / "report" / "index.html"
    png = Path(argv[1]) if len(argv) > 1 else html.parent / "screenshot.png"
    screenshot(html, png)
    import struct

    width, height = struct.unpack(">II", png.read_bytes()[16:24])  # the PNG header's IHDR chunk
    print(f"screenshot: {png} ({png.stat().st_size:,} bytes, {width}x{height} px, full page)")


if __name__ == "__main__":
    main()
