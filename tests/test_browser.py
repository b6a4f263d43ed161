"""The web viewer in a real browser (scripts/browser_check.py): sph run --serve-web on a small scene,
Chromium under Xvfb with the WebGL renderer, a screenshot that shows the composite. Slow (a minute),
and it needs Debian's chromium and xvfb packages: skipped without them."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("chromium") is None or shutil.which("Xvfb") is None,
                    reason="needs chromium and Xvfb (apt-get install chromium xvfb)")
def test_the_web_viewer_shows_the_composite_in_chromium(tmp_path):
    done = subprocess.run([sys.executable, "scripts/browser_check.py", "--out", str(tmp_path / "run"), "--png",
                           str(tmp_path / "viewer.png")], cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "shows the composite" in done.stdout
    assert (tmp_path / "viewer.png").stat().st_size > 10_000
