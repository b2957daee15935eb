"""Headless Chromium helpers for the report tests (Debian package ``chromium``)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
SKIP_REASON = ("Chromium is not installed (apt-get install chromium; .ci/run installs it), so "
               "the report cannot be rendered in a browser")


def _base(width: int, height: int) -> list[str]:
    return [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--no-first-run", "--disable-extensions", "--mute-audio",
            f"--window-size={width},{height}"]


def screenshot(html: Path, png: Path, *, width: int = 1200, height: int = 2400) -> None:
    """Render ``html`` in headless Chromium and save a screenshot of the top of the page."""
    subprocess.run(_base(width, height) + [f"--screenshot={png}", html.resolve().as_uri()],
                   check=True, capture_output=True, timeout=120)


def dump_dom(html: Path) -> str:
    """The DOM after Chromium has parsed and laid out the page."""
    return subprocess.run(_base(1200, 800) + ["--dump-dom", html.resolve().as_uri()],
                          capture_output=True, text=True, timeout=120, check=True).stdout


def check_not_blank(png: Path) -> None:
    """A blank or broken page is one colour; the report has a dark header, text, coloured
    plots on white."""
    from PIL import Image

    im = np.asarray(Image.open(png).convert("RGB"), float)
    assert im.shape[0] > 1000 and im.shape[1] >= 1000, im.shape
    grey = im.mean(axis=2)
    assert grey.std() > 20, grey.std()
    dark = np.mean(grey < 100)
    assert 0.02 < dark < 0.6, dark
    chroma = im.max(axis=2) - im.min(axis=2)            # plot lines and bands are coloured
    assert np.mean(chroma > 60) > 0.005
