"""Render outputs/report/index.html in headless Chromium and save a PNG, so the rendering is seen.

``make screenshot`` (after ``make report``). Needs Debian's ``chromium`` (``apt-get install chromium``);
the page is opened from disk (file://), with background networking off.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from resti_lib import paths


def screenshot(html: Path, png: Path, *, width: int = 1280, height: int = 2400) -> Path:
    exe = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if exe is None:
        raise SystemExit("screenshot: no chromium on PATH (Debian: apt-get install chromium)")
    if not html.exists():
        raise SystemExit(f"screenshot: {html} not found; run `make report` first")
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as profile:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--hide-scrollbars", f"--user-data-dir={profile}", f"--window-size={width},{height}",
               f"--screenshot={png}", html.resolve().as_uri()]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if r.returncode != 0 or not png.exists() or png.stat().st_size < 1000:
        raise SystemExit(f"screenshot: chromium failed ({r.returncode}): {r.stderr[-500:]}")
    return png


def main() -> None:
    html = paths.OUTPUTS / "report" / "index.html"
    png = screenshot(html, paths.OUTPUTS / "report" / "screenshot.png")
    print(f"screenshot: {png} ({png.stat().st_size:,} bytes)")


if __name__ == "__main__":
    sys.exit(main())
