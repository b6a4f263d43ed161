"""The web viewer in a real browser: start ``sph run --serve-web`` on a small scene, open the printed
URL in Chromium (Debian's ``chromium``) under Xvfb with Rerun's WebGL renderer, take a screenshot
and check that it shows the composite — the scene's colours over a good part of the composite view —
rather than a blank page, Rerun's loading screen or an image still decoding.

    .venv/bin/python scripts/browser_check.py [--out runs/browser] [--png docs/img/viewer.png]

Needs ``apt-get install chromium xvfb``. Exit 0 with the screenshot's path and its colour fraction,
1 if the screenshot does not show the composite, 2 if Chromium or Xvfb is missing. Run before a
release (``tests/test_browser.py`` runs it in the slow suite).
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

WIDTH, HEIGHT = 1600, 1000


def colour_fraction(png: Path) -> float:
    """Fraction of the composite view's part of the page (the left three fifths, between the top bar
    and the event log: the blueprint's layout) in saturated colours. The Rerun UI around it is
    grey, white or dark; the composite shows the speed colours; an image still loading is drawn
    washed out under a spinner (measured: 0.5 % while loading, 7.8 % shown)."""
    from PIL import Image
    hsv = np.asarray(Image.open(png).convert("HSV"), dtype=np.float64) / 255.0
    h, w = hsv.shape[:2]
    region = hsv[int(0.06 * h):int(0.75 * h), :int(0.58 * w)]
    return float(((region[..., 1] > 0.45) & (region[..., 2] > 0.3)).mean())


def screenshot(url: str, png: Path, wait_s: float) -> None:
    """Chromium under Xvfb, WebGL renderer, a window of WIDTH x HEIGHT; the screen grabbed after wait_s."""
    profile = tempfile.mkdtemp(prefix="sph-chromium-")
    display = f":{90 + os.getpid() % 50}"
    xvfb = subprocess.Popen(["Xvfb", display, "-screen", "0", f"{WIDTH}x{HEIGHT}x24", "-nolisten", "tcp"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    env = dict(os.environ, DISPLAY=display)
    browser = None
    try:
        time.sleep(1.0)
        browser = subprocess.Popen(
            [shutil.which("chromium"), "--no-sandbox", "--no-first-run", "--no-default-browser-check",
             f"--user-data-dir={profile}", f"--window-size={WIDTH},{HEIGHT}", "--window-position=0,0",
             "--ignore-gpu-blocklist", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
             "--disable-features=Translate", "--kiosk", url + "&renderer=webgl"],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(wait_s)
        from PIL import ImageGrab
        ImageGrab.grab(xdisplay=display).save(png)
    finally:
        if browser is not None:
            os.killpg(browser.pid, signal.SIGTERM)
            browser.wait(timeout=10)
        xvfb.terminate()
        xvfb.wait(timeout=10)
        shutil.rmtree(profile, ignore_errors=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("runs/browser"), help="the run's output folder")
    parser.add_argument("--png", type=Path, default=None, help="where the screenshot goes (default OUT/viewer.png)")
    parser.add_argument("--wait", type=float, default=40.0, help="seconds from opening the page to the screenshot")
    parser.add_argument("--replay", type=Path, default=None,
                        help="instead of a run: serve this recording with sph replay --serve-web")
    parser.add_argument("--min-fraction", type=float, default=0.03,
                        help="the least fraction of the composite view in the scene's colours")
    args = parser.parse_args(argv)
    missing = [tool for tool in ("chromium", "Xvfb") if shutil.which(tool) is None]
    if missing:
        print(f"browser_check: {' and '.join(missing)} not installed (apt-get install chromium xvfb)", file=sys.stderr)
        return 2
    png = args.png or args.out / "viewer.png"
    png.parent.mkdir(parents=True, exist_ok=True)
    from launch.local import free_ports
    grpc, web = free_ports(2)
    # a small scene, long enough to be running while the page loads, a frame every 100 steps (a
    # software-rendered browser on 2 busy cores falls behind a faster stream); stopped after the shot
    if args.replay is not None:
        command = ["replay", str(args.replay), "--serve-web"]
    else:
        command = ["run", "configs/dam_break.toml", "--set", "particles.spacing=0.04", "--set", "render.every=100",
                   "--steps", "100000", "--serve-web", "--out", str(args.out), "--quiet"]
    run = subprocess.Popen([sys.executable, "-m", "launch.cli", *command, "--web-port", str(web), "--grpc-port",
                            str(grpc)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           start_new_session=True)
    try:
        url = None
        deadline = time.monotonic() + 600
        for line in run.stdout:
            m = re.search(r"(http://127\.0\.0\.1:\d+/\?url=\S+)", line)
            if m:
                url = m.group(1)
                break
            if time.monotonic() > deadline:
                break
        if url is None:
            print("browser_check: sph run --serve-web printed no URL", file=sys.stderr)
            return 1
        screenshot(url, png, args.wait)
    finally:
        os.killpg(run.pid, signal.SIGTERM)
        try:
            run.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(run.pid, signal.SIGKILL)
    fraction = colour_fraction(png)
    ok = fraction >= args.min_fraction
    print(f"browser_check: {png}: {100 * fraction:.1f} % of the composite view in the scene's colours "
          f"({'shows the composite' if ok else 'blank or still loading'})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
