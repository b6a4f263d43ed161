"""Pictures of the viewer for docs/: a 2-peer 3D dam break, composited by depth.

    .venv/bin/python scripts/screenshots.py [--out docs/img] [--spacing 0.02] [--until 0.5]

Runs the dam break as 2 peer processes with the viewer recording (twice: coloured by speed and by
peer rank), reads the recordings back and writes
    composite_speed.png     the composited frame at the last rendered step, coloured by speed
    compositing.png         peer 0's framelet, peer 1's framelet and their depth composite (by rank)
    surface_dam_break.png   the fluid surface (sph run --vtk + sph render) at the last output step
"""
import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from nodes.recording import images  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def run(tmp: Path, colour: str, args) -> Path:
    out = tmp / colour
    subprocess.run([sys.executable, "-m", "launch.cli", "run", "configs/dam_break.toml", "--peers", "2",
                    "--until", str(args.until), "--precision", "f32", "--out", str(out), "--quiet",
                    "--set", f"particles.spacing={args.spacing}", "--set", f"render.color_by={colour}",
                    "--set", "render.every=100", "--set", "decomposition.balance_every=100"], cwd=ROOT, check=True)
    return out / "run.rrd"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    parser.add_argument("--spacing", type=float, default=0.02)
    parser.add_argument("--until", type=float, default=0.5)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        speed = images(run(Path(tmp), "speed", args))
        last = max(speed)
        plt.imsave(args.out / "composite_speed.png", speed[last])
        rrd = run(Path(tmp), "rank", args)
        comp = images(rrd)
        step = max(comp)
        peers = [images(rrd, f"/peers/{r}/rgb")[step] for r in range(2)]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for r, (ax, im) in enumerate(zip(axes[:2], peers)):
        ax.imshow(im)
        ax.set_title(f"peer {r}: its framelet ({im.shape[1]} x {im.shape[0]} px)")
    axes[2].imshow(comp[step])
    axes[2].set_title(f"composite by depth, step {step}")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    axes[2].add_patch(Rectangle((0, 0), comp[step].shape[1] - 1, comp[step].shape[0] - 1, fill=False, ec="w", lw=0.5))
    fig.tight_layout()
    fig.savefig(args.out / "compositing.png", dpi=90)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "surface"
        subprocess.run([sys.executable, "-m", "launch.cli", "run", "configs/dam_break.toml", "--until", str(args.until),
                        "--precision", "f32", "--out", str(out), "--quiet", "--no-viewer", "--vtk", "400",
                        "--set", f"particles.spacing={args.spacing}", "--set", "output.surface=true"],
                       cwd=ROOT, check=True)
        subprocess.run([sys.executable, "-m", "launch.cli", "render", str(out), "--no-mp4"],
                       cwd=ROOT, check=True)
        frames = sorted((out / "frames").glob("surface_*.png"))
        (args.out / "surface_dam_break.png").write_bytes(frames[-1].read_bytes())
    print(f"wrote {args.out / 'composite_speed.png'} (step {last}), {args.out / 'compositing.png'} and "
          f"{args.out / 'surface_dam_break.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
