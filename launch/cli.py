"""The ``sph`` command line.

    sph run CONFIG.toml [--precision f32|f64] [--steps S | --until T] [--out DIR] [--set section.key=value ...]
    sph bench [--sizes ...] [--precisions ...] [--threads ...] [--external]
    sph scene CONFIG.toml            print the fully resolved scene (after --set overrides)

Exit codes: 0 success, 2 bad input (scene, option or override; nothing is written), 3 the simulation
became unphysical (the message names step, cause and particles), 130 interrupted.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

EXIT_BAD_INPUT = 2
EXIT_SIMULATION = 3


class UsageError(Exception):
    pass


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be >= 0")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sph",
        description="Distributed SPH fluid simulator: run scenes, benchmark, inspect configurations.",
        epilog="Scenes are TOML files (see configs/); every key is documented in docs/USAGE.md.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    run = sub.add_parser(
        "run", help="run a scene and write summary.json, final.npz and scene.toml",
        description="Run a scene. Writes OUT/summary.json (timings, counts, leaks), OUT/final.npz "
                    "(id, x, v, rho sorted by id) and OUT/scene.toml (the resolved scene) when the run ends.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    run.add_argument("config", type=Path, help="scene file (TOML), e.g. configs/dam_break.toml")
    length = run.add_mutually_exclusive_group()
    length.add_argument("--steps", type=_positive_int, default=None,
                        help="number of steps (default: the scene's time.steps)")
    length.add_argument("--until", type=_positive_float, default=None, metavar="T",
                        help="run until simulated time T (s)")
    run.add_argument("--out", type=Path, default=None, help="output folder (default: runs/<scene name>)")
    run.add_argument("--precision", choices=("f32", "f64"), default=None,
                     help="floating point precision (default: the scene's run.precision)")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                     help="override a scene key, validated like the file (repeatable), "
                          "e.g. --set particles.spacing=0.02 --set sph.kernel=cubic_spline")
    run.add_argument("--threads", type=_positive_int, default=None,
                     help="numba threads (default: all cores)")
    run.add_argument("--backend", choices=("cpu", "cuda"), default="cpu",
                     help="compute backend (cuda: not available yet)")
    run.add_argument("--peers", type=_positive_int, default=1,
                     help="number of peer processes (only 1 until the distributed runner lands)")
    run.add_argument("--record", type=Path, default=None, metavar="FILE.rrd",
                     help="Rerun recording (not available until the viewer lands)")
    run.add_argument("--no-viewer", action="store_true", help="run without a viewer (the only mode for now)")
    run.add_argument("--quiet", action="store_true", help="no progress output")

    scene = sub.add_parser("scene", help="validate a scene and print it fully resolved (TOML)")
    scene.add_argument("config", type=Path)
    scene.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")

    bench = sub.add_parser(
        "bench", help="particle-steps/s of the 3D dam break against N, precision and threads",
        description="Benchmark the 3D dam break (configs/dam_break.toml) at several particle counts, "
                    "precisions and thread counts; optionally the same scene in PySPH and SPlisHSPlasH "
                    "side by side (needs scripts/setup_bench.sh). Prints a table and ratios, writes JSON.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    bench.add_argument("--sizes", type=_positive_int, nargs="+", default=[10_000, 50_000, 200_000],
                       help="target particle counts (the spacing is chosen to match)")
    bench.add_argument("--precisions", nargs="+", choices=("f32", "f64"), default=["f32", "f64"])
    bench.add_argument("--threads", type=_positive_int, nargs="+", default=[1, 2])
    bench.add_argument("--steps", type=_positive_int, default=100, help="timed steps per case")
    bench.add_argument("--external", action="store_true",
                       help="also run PySPH and SPlisHSPlasH on the same scene (if installed)")
    bench.add_argument("--config", type=Path, default=None, help="scene to benchmark (default: dam_break)")
    bench.add_argument("--json", type=Path, default=None, help="write results as JSON here")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s", datefmt="%H:%M:%S")
    from sphcore.scene import SceneError
    from sphcore.solver import SimulationError
    try:
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "scene":
            return _cmd_scene(args)
        if args.command == "bench":
            from launch.bench import run_bench
            return run_bench(args)
    except (SceneError, UsageError) as e:
        print(f"sph {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationError as e:
        print(f"sph {args.command}: simulation stopped: {e}", file=sys.stderr)
        return EXIT_SIMULATION
    except KeyboardInterrupt:
        print(f"sph {args.command}: interrupted", file=sys.stderr)
        return 130
    return 0


def _cmd_scene(args) -> int:
    import tomli_w

    from sphcore.scene import load_scene
    scene = load_scene(args.config, args.overrides)
    sys.stdout.write(tomli_w.dumps(scene.to_dict()))
    return 0


def _cmd_run(args) -> int:
    from sphcore.scene import load_scene
    if args.peers < 1:
        raise UsageError(f"--peers {args.peers}: at least one peer is needed")
    if args.peers > 1:
        raise UsageError(f"--peers {args.peers}: multi-peer runs are not available yet; use --peers 1")
    if args.backend != "cpu":
        raise UsageError(f"--backend {args.backend}: not available yet; use --backend cpu")
    if args.record is not None:
        raise UsageError("--record: the Rerun viewer is not available yet; run with --no-viewer")
    if args.threads is not None:
        import numba
        if not 1 <= args.threads <= numba.config.NUMBA_NUM_THREADS:
            raise UsageError(f"--threads {args.threads}: allowed 1..{numba.config.NUMBA_NUM_THREADS} on this machine")
    scene = load_scene(args.config, args.overrides)
    out = args.out if args.out is not None else Path("runs") / scene.scene.name
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {str(out)!r}: exists and is not a folder")
    from launch.run import run_scene
    summary = run_scene(scene, out, args.precision, args.steps, args.until, args.threads, progress=not args.quiet)
    if not args.quiet:
        print(f"{summary['particles']} particles, {summary['steps']} steps, t = {summary['sim_time']:.4g} s, "
              f"{summary['particle_steps_per_s']:.3g} particle-steps/s, leaks {summary['leaks']} -> {out}/",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
