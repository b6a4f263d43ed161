"""The ``sph`` command line.

    sph run CONFIG.toml [--peers N] [--precision f32|f64] [--steps S | --until T] [--out DIR] [--set section.key=value ...]
    sph peer CONFIG.toml --rank R --world N --listen ENDPOINT [--zenoh ENDPOINT ...] --run-id ID
    sph viewer | control | render | validate | study | replay   (see sph COMMAND --help)
    sph bench [--sizes ...] [--precisions ...] [--threads ...] [--external] [--peers 1 2]
    sph scene CONFIG.toml [--full]   check a scene as sph run does; a summary (--full: resolved TOML)
    sph control OUT_DIR COMMAND      pause, step N, set, reset, checkpoint ... a running run (OUT_DIR/run.json)
    sph examples                     the shipped scenes, one line each

Exit codes: 0 success, 2 bad input (scene, option or override; nothing is written), 3 the simulation
became unphysical (the message names step, cause and particles), 4 a peer was lost or timed out
(the message names the peer and the step), 130 interrupted.
"""
from __future__ import annotations

import argparse
import logging
import math
import os
import re
import sys
from pathlib import Path

from nodes.rerun_sinks import LIVE_FPS

EXIT_BAD_INPUT = 2
EXIT_SIMULATION = 3
EXIT_PEER = 4


class UsageError(Exception):
    pass


def _integer(least: int, most: int | None = None, unit: str = ""):
    """An argparse type: an integer from ``least`` to ``most`` (``unit`` names what ``most`` counts)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < least:
            raise argparse.ArgumentTypeError(f"{text!r} must be >= {least}")
        if most is not None and value > most:
            raise argparse.ArgumentTypeError(f"{text!r}: at most {most:,} {unit}")
        return value
    return parse


MAX_PIXELS = 16384  # a side of a rendered frame: the usual largest texture of an off-screen renderer
MAX_STEPS = 10**9  # as the scene's time.steps: a longer run is a typo, not a plan
_positive_int = _integer(0)
_count = _integer(1)                              # particles, peers, rounds, frames a second
_pixels = _integer(1, MAX_PIXELS, "pixels a side")
_steps = _integer(0, MAX_STEPS, "steps")
_bench_steps = _integer(1, MAX_STEPS, "steps")    # a benchmark times at least one step


def _skin(text: str) -> float:
    """run.neighbour_skin as sph bench --skins takes it: a number in [0, 1] (of the support radius), or
    -1 for the scene's automatic choice."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (0.0 <= value <= 1.0 or value == -1.0):
        raise argparse.ArgumentTypeError(f"{text!r}: a skin is from 0 to 1 (of the support radius), or -1 (auto)")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    if math.isinf(value):
        raise argparse.ArgumentTypeError(f"{text!r} must be finite")
    return value


TRUST_HELP = ("every link is mutually authenticated TLS with the run's own certificates (docs/USAGE.md "
              "'Security'); --insecure: plain TCP, no authentication, loopback only")


def _add_trust_options(parser, stdin: bool = False):
    """--tls DIR / --insecure (and --tls-stdin for the launchers' remote peers): how this process
    proves who it is to the run's other processes."""
    group = parser.add_argument_group("security", TRUST_HELP)
    group.add_argument("--tls", type=Path, default=None, metavar="DIR",
                       help="the run's credentials folder (made by sph run in OUT/tls, or by sph certs)")
    if stdin:
        group.add_argument("--tls-stdin", action="store_true",
                           help="read this process's credentials as one JSON line from stdin (sph run --hosts "
                                "does this over ssh, so no key is written on the remote host)")
    group.add_argument("--insecure", action="store_true",
                       help="plain TCP without authentication or encryption; listening on loopback only")


def _port(text: str) -> int:
    value = _positive_int(text)
    if not 1 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port (1..65535)")
    return value


def _add_port_options(parser, live: bool = True):
    parser.add_argument("--web-port", type=_port, default=None, metavar="PORT",
                        help="--serve-web: the web page's port (default 9090, or a free one if it is taken)")
    parser.add_argument("--grpc-port", type=_port, default=None, metavar="PORT",
                        help="--serve-web / --spawn: the Rerun stream's port (default 9876, or a free one)")
    if live:
        parser.add_argument("--live-fps", type=_live_fps, default=LIVE_FPS, metavar="F",
                            help=f"at most F frames per second to a live viewer, the newest (default {LIVE_FPS:g}; "
                                 "0 = every frame while it keeps up); the recording gets every frame")


def _live_fps(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (0.0 <= value <= 1000.0):
        raise argparse.ArgumentTypeError(f"{text!r}: use 0 (no limit) up to 1000 frames per second")
    return value


class _OldSpelling(argparse.Action):
    """An option's former spelling: appends to the new option's list and says once, on stderr,
    what to write instead."""

    def __init__(self, option_strings, dest, new: str = "", **kwargs):
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        if not getattr(namespace, "_warned_" + self.dest, False):
            print(f"{parser.prog}: {option_string} is deprecated here, use {self.new} (a Zenoh endpoint; in "
                  f"sph run --connect is a Rerun viewer's URL)", file=sys.stderr)
            setattr(namespace, "_warned_" + self.dest, True)
        setattr(namespace, self.dest, list(getattr(namespace, self.dest) or []) + [values])


def _add_zenoh_option(parser, help: str):
    """--zenoh ENDPOINT (repeatable): where this process connects to the run's peers; the old
    spelling --connect still works, with a deprecation message."""
    parser.add_argument("--zenoh", action="append", default=[], metavar="ENDPOINT", help=help)
    parser.add_argument("--connect", dest="zenoh", action=_OldSpelling, new="--zenoh", metavar="ENDPOINT",
                        help=argparse.SUPPRESS)


def _live_keys() -> list[str]:
    from sphcore.scene import live_keys
    return live_keys()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sph",
        description="Distributed SPH fluid simulator: run scenes, benchmark, inspect configurations.",
        epilog="Scenes are TOML files (see configs/); every key is documented in docs/USAGE.md.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    run = sub.add_parser(
        "run", help="run a scene (one process or N peers) and write summary.json, final.npz, scene.toml, run.rrd",
        description="Run a scene in one process or as N peer processes (--peers, --hosts). Writes OUT/summary.json (timings, counts, leaks), OUT/final.npz "
                    "(id, x, v, rho sorted by id) and OUT/scene.toml (the resolved scene) when the run ends.",
    )
    run.add_argument("config", type=Path, nargs="?", default=None,
                     help="scene file (TOML), e.g. configs/dam_break.toml (not with --resume)")
    length = run.add_mutually_exclusive_group()
    length.add_argument("--steps", type=_steps, default=None,
                        help="number of steps (default: the scene's time.steps)")
    length.add_argument("--until", type=_positive_float, default=None, metavar="T",
                        help="run until simulated time T (s)")
    run.add_argument("--out", type=Path, default=None,
                     help="output folder, checked before the first step (default: runs/<scene name>, for a name "
                          "that is a plain folder name)")
    run.add_argument("--precision", choices=("f32", "f64"), default=None,
                     help="floating point precision (default: the scene's run.precision; auto = f64 on the "
                          "CPU, f32 with --backend cuda)")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                     help="override a scene key, validated like the file (repeatable), "
                          "e.g. --set particles.spacing=0.02 --set sph.kernel=cubic_spline")
    run.add_argument("--threads", type=_positive_int, default=None,
                     help="numba threads per process (default: all cores, divided among the peers)")
    run.add_argument("--backend", choices=("cpu", "cuda"), default="cpu",
                     help="cpu: numba threads; cuda: the particles live on an NVIDIA GPU for the whole run "
                          "(one GPU per peer: peer r uses GPU r modulo the GPUs visible; see --device; default: cpu)")
    run.add_argument("--device", type=_positive_int, default=None, metavar="GPU",
                     help="--backend cuda with one peer: the GPU index to use (default 0)")
    run.add_argument("--peers", type=_positive_int, default=1,
                     help="number of peer processes on this machine, talking Zenoh over loopback; each owns one "
                          "block of the domain ([decomposition] in the scene; default: 1)")
    run.add_argument("--timeout", type=_positive_float, default=120.0,
                     help="seconds a peer waits for a message before giving up (names the missing peer; "
                          "default: 120)")
    run.add_argument("--vtk", type=_positive_int, default=None, metavar="K",
                     help="write ParaView files every K steps: OUT/particles.pvd (+ OUT/surface.pvd with "
                          "--set output.surface=true); same as --set output.vtk_every=K")
    run.add_argument("--checkpoint-every", type=_positive_int, default=None, metavar="K",
                     help="write a checkpoint to OUT/checkpoints every K steps (default: output.checkpoint_every)")
    run.add_argument("--resume", type=Path, default=None, metavar="DIR",
                     help="continue from the newest checkpoint of DIR (a run's OUT folder, its checkpoints/ or "
                          "a step_* folder), with the scene saved there; --steps/--until count from step 0")
    run.add_argument("--restarts", type=_positive_int, default=0, metavar="K",
                     help="with --peers N (N >= 2) or --hosts: when a peer dies or stops answering, stop the "
                          "others and restart the run, with the same peers, from the newest checkpoint "
                          "(--checkpoint-every; from the start if there is none yet), up to K times; the "
                          "result is bitwise the uninterrupted run's, and summary.json lists the restarts "
                          "(default: 0)")
    run.add_argument("--hosts", type=Path, default=None, metavar="FILE",
                     help="run one peer per line of FILE ('HOST PORT [THREADS]') over ssh instead of on this "
                          "machine; see docs/USAGE.md")
    run.add_argument("--ssh", default="ssh -o BatchMode=yes",
                     help="--hosts: the ssh command (default: 'ssh -o BatchMode=yes')")
    run.add_argument("--remote-dir", default=None, help="--hosts: the repository on the hosts (default: this folder)")
    run.add_argument("--remote-python", default="python3",
                     help="--hosts: the Python with sphfluid installed on the hosts, e.g. /shared/sph/.venv/bin/python "
                          "(default: python3)")
    run.add_argument("--listen-host", default=None,
                     help="--hosts: the address each peer listens on (default: its own name in the hosts file)")
    run.add_argument("--control", action="store_true",
                     help="one process: listen for sph control OUT COMMAND (pause, step N, set KEY=VALUE, reset, "
                          "checkpoint...) on a free loopback port, credentials in OUT/tls, where in OUT/run.json; "
                          "runs of several peers always listen")
    run.add_argument("--insecure", action="store_true",
                     help="plain TCP between the run's processes: no authentication, no encryption, loopback "
                          "only (by default the launcher makes a run CA and one certificate per process in "
                          "OUT/tls, and every link is mutually authenticated TLS)")
    view = run.add_argument_group("viewer", "frames composited by depth and logged to Rerun every render.every "
                                            "steps; by default recorded to OUT/run.rrd (sph replay OUT/run.rrd)")
    view.add_argument("--record", type=Path, default=None, metavar="FILE.rrd",
                      help="record to this file instead of OUT/run.rrd")
    view.add_argument("--no-viewer", action="store_true", help="no frames, no recording")
    view.add_argument("--spawn", action="store_true", help="also open the native Rerun viewer")
    view.add_argument("--serve-web", action="store_true",
                      help="also serve the web viewer on 127.0.0.1 (URL printed; ports: --web-port, --grpc-port)")
    _add_port_options(view)
    view.add_argument("--connect", dest="rerun_url", default=None, metavar="URL",
                      help="also stream to an already running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy "
                           "(a Rerun URL; the peers' Zenoh endpoints are --zenoh in sph peer/viewer/control)")
    run.add_argument("--quiet", action="store_true", help="no progress output")

    peer = sub.add_parser(
        "peer", help="start one peer of a multi-machine run by hand (rank R of N)",
        description="Start peer RANK of a WORLD-peer run. Every peer of the run gets the same CONFIG, --set, "
                    "--precision, --steps/--until and --run-id; each listens on its own endpoint and connects "
                    "to the others' (at least to every lower rank), e.g. on host B: sph peer dam.toml --rank 1 "
                    "--world 2 --run-id demo --tls certs/ --listen tls/hostB:7448 --zenoh tls/hostA:7447 "
                    "(certs/ made once with: sph certs certs/ --peer-host hostA --peer-host hostB). Rank 0 "
                    "gathers the result and writes OUT on its machine. See docs/USAGE.md.")
    peer.add_argument("config", type=Path, nargs="?", default=None,
                      help="scene file (TOML), the same on every peer (not with --resume)")
    peer.add_argument("--rank", type=_positive_int, required=True, help="this peer's rank, 0..WORLD-1")
    peer.add_argument("--world", type=_count, required=True, help="number of peers in the run")
    peer.add_argument("--run-id", required=True,
                      help="the run's name on the network (letters, digits, - and _); two runs never mix")
    peer.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                      help="Zenoh endpoint to listen on, e.g. tls/hostA:7447 (repeatable)")
    _add_zenoh_option(peer, "another peer's Zenoh endpoint, e.g. tls/hostB:7447 (repeatable)")
    peer.add_argument("--out", type=Path, default=None, help="output folder on rank 0 (default: runs/<scene name>)")
    peer.add_argument("--precision", choices=("f32", "f64"), default=None,
                      help="floating point precision (default: the scene's run.precision; auto = f64 on the "
                          "CPU, f32 with --backend cuda)")
    plen = peer.add_mutually_exclusive_group()
    plen.add_argument("--steps", type=_steps, default=None, help="number of steps (default: time.steps)")
    plen.add_argument("--until", type=_positive_float, default=None, metavar="T", help="run until simulated time T")
    peer.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                      help="override a scene key (repeatable; the same on every peer)")
    peer.add_argument("--threads", type=_positive_int, default=None, help="numba threads (default: all cores)")
    peer.add_argument("--timeout", type=_positive_float, default=120.0,
                      help="seconds to wait for the other peers to join, and for each message (default: 120)")
    peer.add_argument("--quiet", action="store_true", help="no progress output")
    peer.add_argument("--backend", choices=("cpu", "cuda"), default="cpu",
                      help="cpu: numba threads; cuda: this peer's particles live on a GPU for the whole run")
    peer.add_argument("--device", type=_positive_int, default=None, metavar="GPU",
                      help="--backend cuda: the GPU index (default: RANK modulo the GPUs visible)")
    peer.add_argument("--checkpoint-every", type=_positive_int, default=None, metavar="K",
                      help="write a checkpoint part every K steps into OUT/checkpoints (the same folder for "
                           "every peer: a shared file system across machines)")
    peer.add_argument("--resume", type=Path, default=None, metavar="DIR",
                      help="continue from the newest checkpoint of DIR (written by any number of peers)")
    peer.add_argument("--no-frames", action="store_true",
                      help="never render framelets (by default: every render.every steps while a viewer listens)")
    supervised = peer.add_argument_group("supervised", "set by the launchers (sph run); not needed by hand")
    supervised.add_argument("--watch-stdin", action="store_true",
                            help="stop (exit code 4) as soon as stdin reaches end-of-file: the launcher keeps "
                                 "a pipe open there, so a killed launcher (or a lost ssh connection) takes "
                                 "this peer down; do not use with a terminal or /dev/null as stdin")
    supervised.add_argument("--report-progress", action="store_true",
                            help="print 'sph-progress STEP' lines on stdout a few times a second")
    supervised.add_argument("--restart-history", default=None, metavar="JSON",
                            help="the launcher's restarts so far (a JSON list); rank 0 writes it into "
                                 "summary.json as 'restarts'")
    _add_trust_options(peer, stdin=True)

    viewer = sub.add_parser(
        "viewer", help="composite a run's framelets and stream them to Rerun (joins a running run too)",
        description="Subscribe to the framelets of run RUN_ID, composite them by depth and log them to Rerun. "
                    "Connect to one or more peers' endpoints (the ones they --listen on); the viewer can join "
                    "and leave at any time without disturbing the run. Stops when the run ends or on Ctrl-C.")
    viewer.add_argument("config", type=Path, help="the run's scene file (for the cameras, colours and the box)")
    viewer.add_argument("--run-id", required=True, help="the run to watch")
    _add_zenoh_option(viewer, "a peer's Zenoh endpoint, e.g. tls/10.0.0.1:7447 (repeatable)")
    viewer.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint for peers to connect to (repeatable)")
    viewer.add_argument("--world", type=_count, default=None,
                        help="number of peers (default: learnt from the first framelet)")
    viewer.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="the run's --set overrides (render settings may differ)")
    viewer.add_argument("--record", type=Path, default=None, metavar="FILE.rrd", help="record to this file")
    viewer.add_argument("--spawn", action="store_true", help="open the native Rerun viewer")
    viewer.add_argument("--serve-web", action="store_true", help="serve the web viewer on 127.0.0.1 (URL printed)")
    _add_port_options(viewer)
    viewer.add_argument("--rerun-url", default=None, metavar="URL", help="stream to a running Rerun viewer")
    viewer.add_argument("--idle-timeout", type=_positive_float, default=None,
                        help="stop after this many seconds without a framelet")
    viewer.add_argument("--stats", type=Path, default=None, metavar="FILE.json",
                        help="write frame counts and composite latency here at the end")
    viewer.add_argument("--watch-stdin", action="store_true",
                        help="stop (flushing the recording) when stdin reaches end-of-file: set by sph run, "
                             "whose pipe there closes if it is killed")
    _add_trust_options(viewer)

    control = sub.add_parser(
        "control", help="pause/resume a running run, switch its camera or change safe parameters",
        usage="sph control [-h] [--run-id ID --zenoh ENDPOINT --world N] [--timeout S] [--tls DIR | --insecure] "
              "[OUT_DIR] COMMAND [ARG ...]",
        description="Send a command to a running run (sph run --peers N, --hosts, or one process with --control; "
                    "connect to rank 0's endpoint) and wait for rank 0's answer: 'accepted at step N' (every peer "
                    "applies it after step N, and the viewer records it; exit 0) or 'rejected: REASON' (exit 2); no "
                    "answer within --timeout exits 4. Commands: pause | resume | step N (N more steps, then pause) | "
                    "reset (back to the initial particles) | checkpoint (write one now) | camera NAME | color_by "
                    "speed|density|pressure|rank | set KEY=VALUE with KEY one of " + ", ".join(_live_keys()) +
                    " (docs/USAGE.md says why the others cannot change). A paused run waits for resume as long as "
                    "it takes, and applies what it is sent meanwhile at once.")
    control.add_argument("--run-id", default=None,
                         help="the run's id (default: from OUT_DIR/run.json, written by sph run --peers/--hosts/"
                              "--control)")
    _add_zenoh_option(control, "rank 0's Zenoh endpoint, e.g. tls/127.0.0.1:7447 (default: from OUT_DIR/run.json)")
    control.add_argument("--world", type=_count, default=None,
                         help="number of peers in the run (needed with --tls: the access-control list names them; "
                              "default: from OUT_DIR/run.json)")
    control.add_argument("--timeout", type=_positive_float, default=10.0,
                         help="seconds to wait for rank 0 to listen and to answer (default: 10)")
    _add_trust_options(control)
    control.add_argument("words", nargs="+", metavar="WORD",
                         help="the run's output folder (its run.json gives --run-id, --zenoh, --world and --tls), "
                              "then the command, e.g. runs/dam_break pause, or set forces.external=[2,0,0]")

    certs = sub.add_parser(
        "certs", help="make a run's CA and certificates by hand (for sph peer / viewer / control)",
        description="Make a fresh certificate authority for one run in DIR (mode 0700) and one certificate per "
                    "peer, one for the viewer and one for the controller, then forget the CA's key (nobody can "
                    "add a member later). Give each peer's host name or address as others dial it (TLS "
                    "verifies it); copy DIR to the run's machines over a channel you trust. sph run makes "
                    "these itself (OUT/tls).")
    certs.add_argument("dir", type=Path, help="new folder for the credentials")
    who = certs.add_mutually_exclusive_group(required=True)
    who.add_argument("--peers", type=_positive_int, default=None, metavar="N", help="N peers, all on this machine")
    who.add_argument("--peer-host", action="append", default=[], metavar="HOST",
                     help="the host name or address of the next peer (rank order; repeat once per peer)")
    certs.add_argument("--viewer-host", action="append", default=[], metavar="HOST",
                       help="the viewer's host name or address, if peers connect to it (repeatable)")
    certs.add_argument("--days", type=_positive_int, default=30, help="validity in days (default: 30)")

    render = sub.add_parser(
        "render", help="PNG frames and an MP4 of a run's fluid surface (or particles), off-screen",
        description="Draw the VTK series of a finished run (sph run --vtk K --set output.surface=true) into "
                    "OUT/frames/*.png and OUT/surface.mp4 with PyVista, off-screen (no display needed).")
    render.add_argument("out", type=Path, help="the run's output folder")
    render.add_argument("--particles", action="store_true", help="draw the particles (coloured by speed) instead")
    render.add_argument("--frames", type=Path, default=None, help="folder for the PNG frames (default OUT/frames)")
    render.add_argument("--no-mp4", action="store_true", help="PNG frames only")
    render.add_argument("--size", type=_pixels, nargs=2, default=[960, 640], metavar=("W", "H"),
                        help="image width and height in pixels (default: 960 640)")
    render.add_argument("--fps", type=_count, default=20, help="frames per second of the MP4 (default: 20)")

    validate = sub.add_parser(
        "validate", help="compare with reference solutions and experiments; exit 1 if a metric fails",
        description="Run validation cases (hydrostatic and hydrostatic_3d, dam_break and dam_break_3d: the front vs "
                    "Martin & Moyce, taylor_green, oscillating_drop vs Monaghan & Rafiee, poiseuille and couette vs "
                    "Morris et al., floating_box vs Archimedes, floating_square: a square log rolling over to float "
                    "corner down, settling_cylinder: a cylinder's terminal velocity between two walls vs Faxen's "
                    "Stokes drag under a free surface, settling_cylinder_closed: the same in a closed full box with "
                    "the hydrostatic pressure removed, hydrostatic_probes: the tank's [[probes]] vs "
                    "rho0 g (H0 - y) and the fill height, cavity: the lid-driven cavity vs Ghia et al. 1982, "
                    "dam_break_pressure: wall pressure vs Buchner 2002, channel: an inlet's flow developing into "
                    "plane Poiseuille flow before an outlet, circular_couette: a turning cylinder vs A r + B / r, "
                    "wave_maker: a piston's waves vs linear wave-maker theory, dam_break_obstacle: a 3D dam break "
                    "against a box, four water-height gauges and four pressure sensors vs MARIN's experiment), print one line per metric (name "
                    "value tolerance PASS|FAIL) and write a plot per case.")
    validate.add_argument("cases", nargs="*", metavar="CASE",
                          help="hydrostatic, hydrostatic_3d, dam_break, dam_break_3d, taylor_green, oscillating_drop, "
                               "poiseuille, couette, floating_box, floating_square, settling_cylinder, "
                               "settling_cylinder_closed, hydrostatic_probes, cavity, dam_break_pressure, channel, "
                               "circular_couette, wave_maker, dam_break_obstacle")
    validate.add_argument("--all", action="store_true", help="every case")
    validate.add_argument("--quick", action="store_true", help="coarser resolution: a few minutes per case at most on 2 cores (the 3D "
                               "dam_break_obstacle about 4)")
    validate.add_argument("--out", type=Path, default=Path("runs/validate"), help="folder for the plots")
    validate.add_argument("--backend", choices=("cpu", "cuda"), default="cpu",
                          help="run the cases on the CPU or on a GPU (float64 either way)")
    validate.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                          help="override a key of every case's scene (repeatable), e.g. --set sph.density=summation; "
                               "the tolerances stay the same; particles.spacing is set by --quick")
    validate.add_argument("--orders", type=int, default=None, choices=range(1, 9), metavar="K",
                          help="run each case in K orders of the same sums (1-8): the case as configured, then "
                               "other neighbour-list skins and grid cells, which change only the order of each "
                               "particle's sums, so the last bits. Each metric becomes its mean over them, with the "
                               "spread and every order's figure in its note, and OUT/CASE_orders.png draws them: a "
                               "chaotic figure (the dam-break front's late speed) moves by per cents with its "
                               "rounding alone. Default: 4 for dam_break, 1 (once) for the other cases")

    study = sub.add_parser(
        "study", help="measure error and cost of every accuracy knob (solver, kernel, resolution, precision, CFL)",
        description="Run the validation cases over kernel x resolution, then precision, CFL and solver (DFSPH "
                    "at density tolerances 1e-3 and 1e-4) at every resolution, and time each optional term; write OUT/study.json, OUT/pareto.png (error "
                    "against wall seconds per simulated second) and OUT/study.md (tables, cheapest setting per "
                    "error budget). Takes about half an hour on 2 cores; --quick: a few minutes.")
    study.add_argument("cases", nargs="*", metavar="CASE", help="oscillating_drop, dam_break, taylor_green "
                       "(default: all three)")
    study.add_argument("--quick", action="store_true", help="coarsest resolution only (a few minutes)")
    study.add_argument("--out", type=Path, default=Path("runs/study"), help="output folder")
    study.add_argument("--docs", action="store_true", help="also update docs/ACCURACY.md and docs/img/pareto.png")
    study.add_argument("--no-terms", action="store_true", help="skip timing the optional terms")

    replay = sub.add_parser("replay", help="open a recording (.rrd) in the Rerun viewer",
                            description="Open FILE.rrd in the native Rerun viewer, or serve it to a browser.")
    replay.add_argument("file", type=Path, help="a recording, e.g. runs/dam_break/run.rrd")
    replay.add_argument("--serve-web", action="store_true", help="serve the web viewer on 127.0.0.1 instead")
    _add_port_options(replay, live=False)
    replay.add_argument("--port", type=_port, dest="web_port", metavar="PORT", help="the same as --web-port")

    scene = sub.add_parser(
        "scene", help="check a scene as sph run does and summarise it (--full: the resolved TOML)",
        description="Check a scene exactly as sph run does before its first step (every key, the blocks "
                    "against the domain, the particle count and memory) without running it, and print a "
                    "summary: particles per block, memory, neighbours per particle, the first time step. "
                    "Exit 2 with the problem on one line if sph run would refuse it.")
    scene.add_argument("config", type=Path, help="scene file (TOML), e.g. configs/tiny.toml")
    scene.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                       help="override a scene key, as sph run --set (repeatable)")
    scene.add_argument("--full", action="store_true",
                       help="print the fully resolved scene as TOML instead (every key, defaults included)")

    examples = sub.add_parser("examples", help="list the shipped scenes (configs/) with one line each",
                              description="List the scene files shipped in configs/ with their descriptions.")
    examples.add_argument("--dir", type=Path, default=None,
                          help="folder of scenes to list (default: configs/ of this checkout)")

    bench = sub.add_parser(
        "bench", help="particle-steps/s of the 3D dam break against N, precision and threads",
        description="Benchmark the 3D dam break (configs/dam_break.toml) at several particle counts, "
                    "precisions and thread counts; optionally the same scene in PySPH and SPlisHSPlasH "
                    "side by side (needs scripts/setup_bench.sh). Prints a table and ratios, writes JSON.")
    bench.add_argument("--sizes", type=_count, nargs="+", default=[10_000, 50_000, 200_000],
                       help="target particle counts (the spacing is chosen to match; default: 10000 50000 200000)")
    bench.add_argument("--precisions", nargs="+", choices=("f32", "f64"), default=["f32", "f64"],
                       help="floating point precisions to time (default: f32 f64)")
    bench.add_argument("--threads", type=_positive_int, nargs="+", default=[1, 2],
                       help="numba thread counts to time (default: 1 2)")
    bench.add_argument("--steps", type=_bench_steps, default=100, help="timed steps per case (default: 100)")
    bench.add_argument("--neighbours", nargs="+", choices=("lists", "walk"), default=["lists"],
                       help="neighbour search of each case: lists, walk (the 27-cell walk, no lists), or both "
                            "side by side with their ratio (default: lists)")
    bench.add_argument("--skins", type=_skin, nargs="+", default=[-1.0],
                       help="run.neighbour_skin of each case (also of --peers runs): 0 builds the lists every step, "
                            "0.2 reuses them until a particle moves 0.45 x 0.2 H, -1 is the scene's automatic "
                            "choice (0.2 for WCSPH, 0.45 for DFSPH, on the CPU); e.g. --skins 0 0.2 times both "
                            "side by side with their ratio; with --until each solver runs each skin (default: -1)")
    bench.add_argument("--after", type=_steps, default=0, metavar="STEPS",
                       help="run STEPS untimed steps before the timed ones, so that the flow has developed (the "
                            "timed steps otherwise start from rest, where lists are cheapest to build and to "
                            "reuse); not with --external, --peers, --until or --network (default: 0)")
    bench.add_argument("--external", action="store_true",
                       help="also run PySPH and SPlisHSPlasH on the same scene (if installed)")
    bench.add_argument("--peers", type=_count, nargs="+", default=[1],
                       help="also run each case as P peer processes over Zenoh (e.g. --peers 1 2; no viewer) and "
                            "print the speed-up over one peer; P x threads must fit the cores; with --backend cuda "
                            "the peers share the GPU(s), rank r on GPU r modulo their number (default: 1)")
    bench.add_argument("--backend", choices=("cpu", "cuda"), default="cpu",
                       help="cuda: time the GPU backend (one GPU; --threads ignored), e.g. "
                            "--backend cuda --sizes 100000 1000000 4000000 --precisions f32 f64 (default: cpu)")
    bench.add_argument("--config", type=Path, default=None, help="scene to benchmark (default: dam_break)")
    bench.add_argument("--json", type=Path, default=None, help="write results as JSON here")
    bench.add_argument("--network", action="store_true",
                       help="instead: the 2-peer run over loopback with TLS and with --insecure, and over two "
                            "network-namespace hosts at 0, 1 and 5 ms (root), each with and without "
                            "decomposition.overlap (TLS), interleaved --repeat times")
    bench.add_argument("--repeat", type=_count, default=3, help="--network: rounds of every case (default: 3)")
    bench.add_argument("--until", type=_positive_float, default=None, metavar="T",
                       help="instead of --steps fixed steps: step the dam break from rest to T simulated seconds "
                            "with each solver's adaptive step and report simulated seconds per wall second; "
                            "with --external, SPlisHSPlasH's DFSPH too (its CFL step, the same tolerances), twice: "
                            "with the viscosity our scene's fluid acts with, and with 0.01 m^2/s as compared before. "
                            "E.g. --until 0.5 --sizes 50000 --solvers wcsph dfsph --precisions f32 --threads 2")
    bench.add_argument("--solvers", nargs="+", choices=("wcsph", "dfsph"), default=["dfsph"],
                       help="--until: our solvers to run (default: dfsph)")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s", datefmt="%H:%M:%S")
    # numba-cuda logs every device allocation and free at INFO: keep it to warnings unless --verbose
    logging.getLogger("numba").setLevel(logging.INFO if args.verbose else logging.WARNING)
    if args.command in ("run", "peer", "viewer", "validate", "study", "bench"):
        from launch.compiling import report_compiling
        report_compiling()  # a scene's first run compiles its kernels for minutes: say so, with the time
    from nodes.endpoint import TransportError
    from sphcore.backends import BackendUnavailable
    from sphcore.scene import SceneError
    from sphcore.solver import SimulationError
    from nodes.rerun_sinks import SinkError
    from nodes.security import SecurityError
    from sphcore.checkpoint import CheckpointError
    from nodes.driver import OutputError
    try:
        if args.command == "run":
            return _cmd_run(args)
        if args.command == "peer":
            return _cmd_peer(args)
        if args.command == "viewer":
            return _cmd_viewer(args)
        if args.command == "replay":
            return _cmd_replay(args)
        if args.command == "control":
            return _cmd_control(args)
        if args.command == "certs":
            return _cmd_certs(args)
        if args.command == "render":
            return _cmd_render(args)
        if args.command == "validate":
            from launch.validate import CASES, ORDER_KEYS, case_orders, run_validate
            names = list(CASES) if args.all else args.cases
            unknown = [c for c in names if c not in CASES]
            if not names or unknown:
                raise UsageError(f"validate {' '.join(unknown) or '(nothing)'}: choose from {', '.join(CASES)} "
                                 "or --all")
            spacing = [o for o in args.overrides if o.split("=", 1)[0].strip() == "particles.spacing"]
            if spacing:
                raise UsageError(f"validate --set {spacing[0]}: each case sets its own spacing (full, or --quick); "
                                 "the metrics' reference depends on it")
            varied = [o for o in args.overrides if o.split("=", 1)[0].strip() in ORDER_KEYS]
            many = [(n, case_orders(n, args.orders)) for n in names if case_orders(n, args.orders) > 1]
            if varied and many:
                raise UsageError(f"validate --set {varied[0]}: {many[0][0]} runs in {many[0][1]} orders of its sums "
                                 f"(--orders{'' if args.orders else ', its default'}), which vary "
                                 f"{' and '.join(ORDER_KEYS)} themselves; drop the --set or add --orders 1")
            if args.backend == "cuda":
                _require_cuda()
            return run_validate(names, args.quick, _output_dir("--out", args.out), args.backend,
                                tuple(args.overrides), args.orders)
        if args.command == "study":
            from launch.study import CASES as STUDY_CASES, run_study
            names = args.cases or list(STUDY_CASES)
            unknown = [c for c in names if c not in STUDY_CASES]
            if unknown:
                raise UsageError(f"study {' '.join(unknown)}: choose from {', '.join(STUDY_CASES)}")
            return run_study(names, args.quick, _output_dir("--out", args.out), args.docs, not args.no_terms)
        if args.command == "scene":
            return _cmd_scene(args)
        if args.command == "examples":
            return _cmd_examples(args)
        if args.command == "bench":
            _check_bench(args)
            from launch.bench import run_bench
            return run_bench(args)
    except (SceneError, UsageError, BackendUnavailable, SecurityError, SinkError, CheckpointError,
            OutputError) as e:
        print(f"sph {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationError as e:
        print(f"sph {args.command}: simulation stopped: {e}", file=sys.stderr)
        return EXIT_SIMULATION
    except TransportError as e:
        print(f"sph {args.command}: run stopped: {e}", file=sys.stderr)
        return EXIT_PEER
    except KeyboardInterrupt:
        print(f"sph {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout left (`sph scene ... | head`): stop quietly, as a shell tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's flush at exit would fail again
        return 128 + 13  # SIGPIPE's exit status
    return 0


def _lists_text(scene) -> str:
    """How sph scene says the neighbours are found (on the CPU backend, where it reports)."""
    from sphcore.scene import list_skin
    if scene.run.neighbours == "walk":
        return "no lists: every pass walks the cells"
    skin = list_skin(scene)
    if not skin:
        return "lists built every step"
    auto = " (run.neighbour_skin = -1: auto)" if scene.run.neighbour_skin < 0 else ""
    return f"lists reused within a skin of {skin:g} H{auto}"


def _cmd_scene(args) -> int:
    from sphcore.initial import scene_report
    from sphcore.scene import load_scene, scene_toml, size_text
    scene = load_scene(args.config, args.overrides)
    report = scene_report(scene)  # what sph run checks before its first step (SceneError: exit 2)
    if args.full:
        sys.stdout.write(scene_toml(scene.to_dict()))
        return 0
    info, dx = scene.scene, scene.particles.spacing
    lines = [f"{info.name}: {info.description or '(no description)'}",
             f"  file          {scene.source} ({scene.dim}D){' with --set ' + ' '.join(args.overrides) if args.overrides else ''}"]
    for i, (block, n) in enumerate(zip(scene.fluid.blocks, report["blocks"])):
        lines.append(f"  fluid.blocks[{i}] {block.shape:6s} {n} particles{' (clip = true)' if block.clip else ''}")
    for i, inlet in enumerate(report["inlets"]):
        lines.append(f"  inlets[{i}]     {inlet['per_layer'] * inlet['layers']} particles ({inlet['layers']} layers of "
                     f"{inlet['per_layer']}, replacing the blocks' there; a new layer every "
                     f"{inlet['layer_every_s']:.3g} s)")
    lines += [
        f"  particles     {report['particles']} (spacing {dx:g} m, at most {scene.particles.max_particles})",
        f"  memory        about {size_text(report['memory'])} of arrays in one process ({report['cells']:.3g} grid "
        "cells; Python and its libraries: ~260 MB more)",
        f"  neighbours    about {report['neighbours']} per particle in the bulk (support {scene.sph.support:g} "
        f"spacings, {scene.sph.kernel}); {_lists_text(scene)}",
        f"  first dt      {report['dt']:.3g} s ({report['dt_limit']} limit; time.mode = {scene.time.mode}, "
        f"cfl {scene.time.cfl:g})",
        f"  solver        {scene.sph.solver}, {scene.sph.density} density, {scene.sph.viscosity} viscosity, "
        f"{scene.time.integrator}, {scene.time.steps} steps by default",
        f"  domain        {scene.domain.container}, {len(scene.domain.planes)} planes, {len(scene.obstacles)} "
        "obstacles",
        "(sph scene --full prints every resolved key as TOML)",
    ]
    print("\n".join(lines))
    return 0


def _examples_dir() -> Path:
    """configs/ next to the working folder, else the checkout this package runs from."""
    for folder in (Path("configs"), Path(__file__).resolve().parent.parent / "configs"):
        if folder.is_dir() and any(folder.glob("*.toml")):
            return folder
    raise UsageError("no configs/ folder here or beside the package (a pip install from a wheel does not ship "
                     "the scenes: clone the repository, or pass --dir)")


def _cmd_examples(args) -> int:
    from sphcore.scene import SceneError, load_scene
    folder = args.dir if args.dir is not None else _examples_dir()
    files = sorted(Path(folder).glob("*.toml"))
    if not files:
        raise UsageError(f"--dir {str(folder)!r}: no .toml scene files there")
    width = max(len(str(f)) for f in files)
    for f in files:
        try:
            scene = load_scene(f)
            line = f"{scene.dim}D  {scene.scene.description or scene.scene.name}"
        except SceneError as e:
            line = f"(not a valid scene: {e})"
        print(f"{str(f):{width}s}  {line}")
    print("(sph scene FILE: particles, memory and time step; sph run FILE --out runs/NAME: run it)")
    return 0


def _check_threads(threads):
    if threads is not None:
        import numba
        if not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
            raise UsageError(f"--threads {threads}: allowed 1..{numba.config.NUMBA_NUM_THREADS} on this machine")


def _check_backend(args):
    """--backend cuda needs a GPU (or the simulator): say so before any process starts."""
    if getattr(args, "device", None) is not None and args.backend != "cuda":
        raise UsageError(f"--device {args.device}: only with --backend cuda")
    if args.backend == "cuda":
        _require_cuda()
        if args.threads:
            raise UsageError("--threads: the CUDA backend runs on the GPU; give no --threads")


CUDA_EXTRA = ("the CUDA packages (numba-cuda, the CUDA runtime, NVVM, NVRTC) are the sphfluid[cuda] extra, not "
              "installed here: pip install 'sphfluid[cuda]' (in a checkout: pip install -e '.[cuda]')")


def _require_cuda():
    """sphcore.backends.cuda.require(), naming the [cuda] extra when its packages are missing."""
    import importlib.util

    from sphcore.backends import BackendUnavailable
    extra_missing = importlib.util.find_spec("numba_cuda") is None
    try:
        from sphcore.backends import cuda
        cuda.require()
    except (BackendUnavailable, ImportError) as e:
        if not extra_missing:
            raise
        raise UsageError(f"--backend cuda: {CUDA_EXTRA} ({e})") from None


def _output_folder(args, scene) -> Path:
    """The output folder, checked without creating anything: it is a folder (or will be one) and the
    nearest existing folder above it is writable. The run creates it just before its first step."""
    if args.out is None:
        out = Path("runs") / _folder_name(scene.scene.name)
    elif str(args.out) in ("", "."):  # Path("") is "."; neither names a run's own folder
        raise UsageError(f"--out {str(args.out)!r}: name a folder for the run's outputs, e.g. --out runs/NAME")
    else:
        out = args.out
    return _output_dir("--out", out)


def _output_dir(flag: str, out: Path) -> Path:
    """``out`` is a folder or can become one: the nearest existing folder above it takes a new file
    (tried with a temporary file, removed at once: a permission bit does not tell, e.g. under /proc).
    Nothing is created."""
    import os
    import tempfile
    try:
        if out.exists() and not out.is_dir():
            raise UsageError(f"{flag} {str(out)!r}: exists and is not a folder")
        above = out.absolute()
        while not above.exists():
            above = above.parent
    except (OSError, ValueError) as e:  # a name too long, a NUL byte: the OS's own refusal, on one line
        raise UsageError(f"{flag} {_short_text(str(out))}: not a usable path ({getattr(e, 'strerror', None) or e})") from None
    if not above.is_dir():
        raise UsageError(f"{flag} {str(out)!r}: {above} is a file, so no folder can be made under it")
    if not os.access(above, os.W_OK | os.X_OK):
        raise UsageError(f"{flag} {str(out)!r}: {above} is not writable by this user")
    try:
        with tempfile.TemporaryFile(dir=above):
            pass
    except OSError as e:
        raise UsageError(f"{flag} {str(out)!r}: cannot write there (nothing can be written in {above}: "
                         f"{e.strerror or e})") from None
    return out


def _output_file(flag: str, path: Path):
    """A file an option asks to write at the end of a long run, checked before anything runs: not a
    folder, and its folder is one or can become one (``_output_dir``)."""
    try:
        folder = path.is_dir()
    except (OSError, ValueError) as e:  # a name too long, a NUL byte
        raise UsageError(f"{flag} {_short_text(str(path))}: not a usable path ({getattr(e, 'strerror', None) or e})") from None
    if folder:
        raise UsageError(f"{flag} {str(path)!r}: is a folder; name a file, e.g. {flag} results.json")
    _output_dir(flag, path.absolute().parent)


def _short_text(text: str, most: int = 80) -> str:
    return repr(text) if len(text) <= most else repr(text[:most]) + f"... ({len(text)} characters)"


def _folder_name(name: str) -> str:
    """scene.name as the default output folder under runs/: one plain path component (letters, digits,
    spaces, . _ - +), not '.' or '..', at most 100 characters; else UsageError asking for --out (a
    scene file's name must not choose where a run writes: '../x' or '/etc' would leave runs/)."""
    plain = re.fullmatch(r"[\w .+-]{1,100}", name) and name.strip(" .") and not name.startswith("-")
    if not plain:
        raise UsageError(f"scene.name = {_short_text(name)}: not a plain folder name for runs/NAME (letters, digits, "
                         f"spaces, . _ - +; at most 100 characters; not '.' or '..'); give --out FOLDER")
    return name


def _check_bench(args):
    """sph bench's options, before anything runs."""
    import numba
    threads_available = numba.config.NUMBA_NUM_THREADS
    for t in args.threads:
        if t < 1 or t > threads_available:
            raise UsageError(f"--threads {t}: this machine allows 1..{threads_available}")
    if args.after and (args.external or args.peers != [1] or args.until is not None or args.network):
        raise UsageError(f"--after {args.after}: the other codes and the peer runs start from rest, so --after "
                         "does not combine with --external, --peers, --until or --network")
    if any(s > 0 for s in args.skins) and (args.network or args.backend != "cpu" or "walk" in args.neighbours):
        raise UsageError(f"--skins {' '.join(f'{s:g}' for s in args.skins)}: reused lists are timed on the CPU "
                         "backend with lists (not with --network, --backend cuda or --neighbours walk; -1 or 0 "
                         "there)")
    if args.until is not None:
        if args.network or args.backend != "cpu" or args.peers != [1] or args.neighbours != ["lists"]:
            raise UsageError("--until times one CPU process with neighbour lists: it does not combine with "
                             "--network, --backend cuda, --peers or --neighbours walk")
        if args.until > 10.0:
            raise UsageError(f"--until {args.until:g}: at most 10 simulated seconds (the dam break has settled "
                             "long before)")
    if args.json is not None:
        _output_file("--json", args.json)
    if args.backend == "cuda":
        _require_cuda()
        if args.external:
            raise UsageError("--backend cuda: --external compares CPU codes; run it without --backend cuda")


def _check_peers(scene, n_peers: int, backend: str = "cpu"):
    """The scene's decomposition fits n_peers on ``backend`` (checked before any process starts)."""
    from nodes.peer import decomposition_for
    from sphcore.solver import Simulation
    if n_peers == 1 and not any(scene.decomposition.dims):
        return
    grid = Simulation.grid_for(scene, backend)
    try:
        decomposition_for(scene, grid, n_peers)
    except ValueError as e:
        raise UsageError(f"--peers {n_peers}: {e}") from None


def _scene_for_run(args):
    """The scene and the checkpoint to resume from (or None)."""
    from sphcore.scene import load_scene, scene_from_dict
    if args.resume is None:
        if args.config is None:
            raise UsageError("give a scene file (e.g. configs/dam_break.toml) or --resume DIR")
        return load_scene(args.config, args.overrides, backend=args.backend), None
    from sphcore.checkpoint import CheckpointError, load
    if args.config is not None:
        raise UsageError("--resume uses the scene saved with the checkpoint: give no scene file (--set may change "
                         "the keys that can change during a run)")
    try:
        ckpt = load(args.resume)
    except CheckpointError as e:
        raise UsageError(f"--resume: {e}") from None
    if args.precision and args.precision != ckpt.manifest["precision"]:
        raise UsageError(f"--precision {args.precision}: the checkpoint is {ckpt.manifest['precision']}")
    from sphcore.scene import SceneError
    try:
        scene = scene_from_dict(ckpt.manifest["scene"], source=str(ckpt.path))
    except SceneError as e:
        raise UsageError(f"--resume: {ckpt.path}/manifest.json: its scene: {e}") from None
    from sphcore.scene import live_change
    for text in args.overrides:  # only what a running run could change (sphcore/scene.py LIVE)
        try:
            scene = live_change(scene, text)[1]
        except SceneError as e:
            raise UsageError(f"--resume with --set {text}: {e}") from None
    return scene, ckpt


def _cmd_run(args) -> int:
    if args.vtk is not None:
        if args.resume is not None:
            raise UsageError("--vtk with --resume: the checkpoint's scene decides (output.vtk_every)")
        args.overrides = args.overrides + [f"output.vtk_every={args.vtk}"]  # reaches every peer too
    if args.peers < 1:
        raise UsageError(f"--peers {args.peers}: at least one peer is needed")
    if args.device is not None and (args.peers > 1 or args.hosts is not None):
        raise UsageError("--device picks the GPU of a one-process run; peers take GPU rank modulo the GPUs visible")
    _check_backend(args)
    if args.no_viewer and (args.record or args.spawn or args.serve_web or args.rerun_url):
        raise UsageError("--no-viewer cannot be combined with --record, --spawn, --serve-web or --connect")
    if args.record is not None and args.record.suffix != ".rrd":
        raise UsageError(f"--record {str(args.record)!r}: the file name must end in .rrd")
    if args.hosts is not None:
        from launch.hosts import read_hosts, run_hosts
        if args.resume is not None:
            raise UsageError("--resume with --hosts: start the peers with sph peer --resume (see docs/USAGE.md)")
        scene, _ = _scene_for_run(args)
        try:
            hosts = read_hosts(args.hosts)
        except ValueError as e:
            raise UsageError(f"--hosts: {e}") from None
        if args.peers not in (1, len(hosts)):
            raise UsageError(f"--peers {args.peers} --hosts {args.hosts}: the hosts file lists {len(hosts)} peers")
        _check_peers(scene, len(hosts), args.backend)
        _check_restarts(args, scene)
        from sphcore.initial import scene_report
        scene_report(scene)  # the blocks, as each peer will fill them, before anything starts
        if args.insecure:
            from nodes.security import is_loopback
            remote = [h.name for h in hosts if not is_loopback(h.name)]
            if remote:
                raise UsageError(f"--insecure with --hosts {args.hosts}: {', '.join(remote)} is not a loopback "
                                 "address; plain TCP across a network lets anyone join or read the run (drop "
                                 "--insecure: every link is then mutually authenticated TLS)")
        return run_hosts(args.config, args.hosts, args, _output_folder(args, scene))
    _check_threads(args.threads)
    scene, ckpt = _scene_for_run(args)
    out = _output_folder(args, scene)
    _check_restarts(args, scene)
    if args.peers > 1:
        _check_peers(scene, args.peers, args.backend)
        if ckpt is None:  # the blocks, as each peer will fill them, before OUT/tls or any process
            from sphcore.initial import scene_report
            scene_report(scene)
        from launch.local import run_local_peers
        config = args.config
        if ckpt is not None:  # the viewer reads the checkpoint's scene from a file
            import tempfile

            import tomli_w
            tmp = tempfile.NamedTemporaryFile("w", suffix=".toml", delete=False)
            tmp.write(tomli_w.dumps(ckpt.manifest["scene"]))
            tmp.close()
            config = Path(tmp.name)
        try:
            code = run_local_peers(config, args.peers, out, args, viewer=viewer_options(args, scene, out))
        finally:
            if ckpt is not None:
                config.unlink(missing_ok=True)
        if code == 0 and not args.quiet:
            _print_done(out)
        return code
    from launch.run import run_scene
    summary = run_scene(scene, out, args.precision or (ckpt.manifest["precision"] if ckpt else None), args.steps,
                        args.until, args.threads, progress=not args.quiet, viewer=viewer_options(args, scene, out),
                        resume=ckpt, checkpoint_every=args.checkpoint_every, backend=args.backend,
                        device=args.device, control=args.control, secure=not args.insecure)
    if summary.get("status") == "interrupted":
        stop = summary["interrupted"]
        print(f"sph run: interrupted ({stop['signal']}) at step {stop['step']}; the outputs of that step are in "
              f"{out}/ (summary.json status 'interrupted')", file=sys.stderr)
        return 130
    if not args.quiet:
        _print_done(out, summary)
    return 0


def _check_restarts(args, scene):
    """--restarts needs peer processes; without checkpoints every restart starts from step 0."""
    if not args.restarts:
        return
    if args.peers < 2 and args.hosts is None:
        raise UsageError(f"--restarts {args.restarts}: only with --peers N (N >= 2) or --hosts FILE; a run in "
                         "this process has no peer to lose")
    every = args.checkpoint_every if args.checkpoint_every is not None else scene.output.checkpoint_every
    if not every:
        logging.getLogger("sph.launch").warning(
            "--restarts %d without checkpoints (--checkpoint-every K or output.checkpoint_every): a restart "
            "starts the run again from step 0", args.restarts)


def viewer_options(args, scene, out: Path) -> dict | None:
    """Where the frames go, or None for no frames at all."""
    if args.no_viewer or scene.render.every == 0:
        return None
    return {"record": args.record or out / "run.rrd", "spawn": args.spawn, "serve_web": args.serve_web,
            "grpc_port": args.grpc_port, "web_port": args.web_port, "live_fps": args.live_fps,
            "connect": args.rerun_url,
            "expected_frames": args.steps // scene.render.every if args.steps else None}  # the size estimate


def _cmd_viewer(args) -> int:
    import os

    from nodes import wire
    from nodes.frames import domain_box
    from nodes.viewer import open_recording, run_viewer
    from sphcore.scene import load_scene
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    try:
        wire.check_run_id(args.run_id)
    except ValueError as e:
        raise UsageError(f"--run-id: {e}") from None
    if not (args.zenoh or args.listen):
        raise UsageError("give --zenoh (a peer's endpoint) and/or --listen")
    if not (args.record or args.spawn or args.serve_web or args.rerun_url):
        raise UsageError("say where the frames go: --record FILE.rrd, --spawn, --serve-web or --rerun-url URL")
    from nodes import security
    trust = trust_for(args, security.VIEWER, args.world)
    security.check_endpoints(args.listen, args.zenoh, trust is not None)
    scene = load_scene(args.config, args.overrides)
    rec = open_recording(args.run_id, args.record, args.spawn, args.serve_web, args.rerun_url, args.grpc_port,
                         args.web_port, args.live_fps)
    import signal
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # stopped by the launcher: flush the recording
    if args.watch_stdin:  # the launcher is gone: stop as if it had said so (SIGTERM: flush, then exit)
        from nodes.supervise import watch_stdin
        watch_stdin(lambda: os.kill(os.getpid(), signal.SIGTERM))

    def ready():
        print("viewer ready", flush=True)

    frames = run_viewer(scene, args.run_id, args.listen, args.zenoh, rec, domain_box(scene), args.world, 0,
                        ready=ready, idle_timeout=args.idle_timeout, stats_path=args.stats, trust=trust,
                        record=args.record)
    print(f"sph viewer: {frames} frames", file=sys.stderr)
    return 0


def _cmd_control(args) -> int:
    import threading
    import time

    import zenoh

    from nodes import control, security, wire
    from nodes.zenoh_transport import zenoh_config
    words = list(args.words)
    if args.run_id is None or not args.zenoh:
        if len(words) < 2 or not Path(words[0]).is_dir():
            raise UsageError("say which run: sph control OUT_DIR COMMAND (the run's output folder, with the "
                             "run.json sph run --peers/--hosts writes) or --run-id ID --zenoh ENDPOINT COMMAND")
        _use_run_info(args, read_run_info(Path(words.pop(0))))
    text = " ".join(words)
    try:
        control.parse(text)
        wire.check_run_id(args.run_id)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if len(text.encode()) > control.MAX_TEXT:
        raise UsageError(f"command of {len(text.encode())} bytes: at most {control.MAX_TEXT}")
    trust = trust_for(args, security.CONTROL, args.world)
    command_id = control.new_id()
    answer, answered = {}, threading.Event()

    def on_ack(sample):  # rank 0's answers to every controller of the run: ours has our id
        try:
            _, (step, _), arrays = wire.decode(sample.payload.to_bytes(), args.run_id, wire.CONTROLLER, 1,
                                               sources=(0,), max_bytes=control.MAX_MESSAGE)
            ack = control.read_ack(arrays)
        except ValueError:  # wire.WireError included: not an answer of this run's rank 0
            return
        if ack["id"] == command_id and not answered.is_set():
            answer.update(ack, step=step)
            answered.set()

    where = ", ".join(args.zenoh)
    session = zenoh.open(zenoh_config([], args.zenoh, trust=trust))
    try:
        session.declare_subscriber(wire.ack_key(args.run_id), on_ack)  # before sending: no answer is missed
        pub = session.declare_publisher(wire.control_key(args.run_id),
                                        congestion_control=zenoh.CongestionControl.BLOCK)
        deadline = time.monotonic() + args.timeout
        while not pub.matching_status.matching:  # rank 0 of that run subscribes to commands
            if time.monotonic() > deadline:
                print(f"sph control: no run {args.run_id!r} is listening at {where} after {args.timeout:g} s "
                      "(connect to rank 0's endpoint); nothing was sent", file=sys.stderr)
                return EXIT_PEER
            time.sleep(0.05)
        pub.put(wire.encode(args.run_id, -1, "control", wire.CONTROLLER, 0, control.command_arrays(command_id, text)))
        answered.wait(max(0.0, deadline - time.monotonic()))
    finally:
        session.close()
    if not answer:
        print(f"sph control: {text!r} was sent to run {args.run_id}, but rank 0 did not answer within "
              f"{args.timeout:g} s: it may not be applied (run over, or rank 0 stuck?)", file=sys.stderr)
        return EXIT_PEER
    if answer["result"] == "accepted":
        print(f"sph control: accepted at step {answer['step']}", file=sys.stderr)
        return 0
    print(f"sph control: rejected: {answer['reason']}", file=sys.stderr)
    return EXIT_BAD_INPUT


def read_run_info(out: Path) -> dict:
    """OUT/run.json (launch/local.py write_run_info), checked; UsageError names what is wrong."""
    import json
    path = out / "run.json"
    try:
        info = json.loads(path.read_text())
    except OSError as e:
        raise UsageError(f"{path}: cannot read it ({e.strerror}); runs started with sph run --peers N, --hosts "
                         "or --control (one process) write it") from None
    except (ValueError, RecursionError) as e:
        raise UsageError(f"{path}: not JSON ({str(e)[:120]})") from None
    ok = (isinstance(info, dict) and isinstance(info.get("run_id"), str)
          and isinstance(info.get("world"), int) and not isinstance(info.get("world"), bool) and info["world"] >= 1
          and isinstance(info.get("endpoints"), list) and info["endpoints"]
          and all(isinstance(e, str) for e in info["endpoints"])
          and (info.get("tls") is None or isinstance(info.get("tls"), str)))
    if not ok:
        raise UsageError(f"{path}: expected {{run_id: str, world: int >= 1, endpoints: [str, ...], tls: str or "
                         "null}")
    return info


def _use_run_info(args, info: dict):
    """Fill --run-id, --zenoh (rank 0's endpoint), --world and --tls/--insecure from run.json where
    the command line does not give them."""
    args.run_id = args.run_id or info["run_id"]
    args.zenoh = args.zenoh or [info["endpoints"][0]]
    args.world = args.world or info["world"]
    if args.tls is None and not args.insecure:
        if info["tls"] is None:
            args.insecure = True  # the run itself is --insecure: there are no credentials to use
        else:
            args.tls = Path(info["tls"])


def _cmd_certs(args) -> int:
    from nodes import security
    hosts = [[h] for h in args.peer_host] if args.peer_host else [[] for _ in range(args.peers)]
    if not hosts:
        raise UsageError("--peers 0: a run has at least one peer")
    security.make_run_credentials(args.dir, hosts, args.viewer_host, args.days)
    print(f"sph certs: {args.dir}/: ca.pem, peer-0..{len(hosts) - 1}, viewer and control (.pem + .key, readable "
          "only by you); give each machine ca.pem and its own pair", file=sys.stderr)
    return 0


def trust_for(args, name: str, world: int | None):
    """The Trust (nodes/security.py) of this process from --tls / --tls-stdin / --insecure, or
    None for --insecure (with a warning that says what that gives away)."""
    from nodes import security
    stdin = getattr(args, "tls_stdin", False)
    given = [o for o, v in (("--tls", args.tls is not None), ("--tls-stdin", stdin), ("--insecure", args.insecure))
             if v]
    if len(given) != 1:
        raise UsageError(("choose one of " + " ".join(given)) if given else
                         "say how this process proves who it is: --tls DIR (the run's credentials: sph run "
                         "makes them in OUT/tls, sph certs by hand) or --insecure (plain TCP on loopback, no "
                         "authentication)")
    if args.insecure:
        logging.getLogger("sph.security").warning(
            "--insecure: plain TCP, no authentication, no encryption: any process that reaches these ports can "
            "join, read or steer the run")
        return None
    if world is None:
        raise UsageError("--world N is needed with TLS (the access-control list names every peer)")
    identity = security.Identity.from_json(sys.stdin.readline()) if stdin else security.load_identity(args.tls, name)
    if identity.name != name:
        raise UsageError(f"the credentials given are {identity.name!r}'s; this process is {name!r}")
    return security.Trust(identity, args.run_id, world)


def _cmd_render(args) -> int:
    from launch.render import render_series
    log = logging.getLogger("sph.render")

    def progress(i, n):
        if i == n or i % max(1, n // 10) == 0:
            log.info("frame %d/%d", i, n)

    try:
        written = render_series(args.out, args.frames or args.out / "frames", args.particles, not args.no_mp4,
                                args.size[0], args.size[1], args.fps, progress)
    except (FileNotFoundError, ValueError) as e:
        raise UsageError(str(e)) from None
    print(f"sph render: {len(written)} files, last {written[-1]}", file=sys.stderr)
    return 0


RRD_MAGIC = b"RRF"  # every Rerun recording's first bytes (RRF2 since Rerun 0.15: the version follows)


def _cmd_replay(args) -> int:
    import os
    import subprocess

    from nodes.rerun_sinks import rerun_executable, serve_web
    if not args.file.is_file():
        raise UsageError(f"{str(args.file)!r}: no such recording")
    try:
        with open(args.file, "rb") as f:
            head = f.read(4)
    except OSError as e:
        raise UsageError(f"{str(args.file)!r}: cannot read it ({e.strerror or e})") from None
    if not head.startswith(RRD_MAGIC):
        raise UsageError(f"{str(args.file)!r}: not a Rerun recording (an .rrd file starts with "
                         f"{RRD_MAGIC.decode()}; this one with {head!r})")
    os.environ["RERUN_ANALYTICS"] = "0"
    if args.serve_web:
        import signal
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # stop the server with us
        proc, _, page = serve_web(args.grpc_port, args.web_port, recording=args.file)
        print(f"sph replay: {args.file} on {page} (Ctrl-C stops)", file=sys.stderr, flush=True)
        return proc.wait()
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise UsageError("no display for the native viewer here; use --serve-web and open the printed URL, "
                         "or copy the .rrd to a machine with a display and run: rerun FILE.rrd")
    return subprocess.call([rerun_executable(), str(args.file)])


def _print_done(out: Path, summary: dict | None = None):
    import json
    if summary is None:
        summary = json.loads((out / "summary.json").read_text())
    print(f"{summary['particles']} particles, {summary['peers']} peer(s), {summary['steps']} steps, "
          f"t = {summary['sim_time']:.4g} s, {summary['particle_steps_per_s']:.3g} particle-steps/s, "
          f"leaks {summary['leaks']} -> {out}/", file=sys.stderr)


def _cmd_peer(args) -> int:
    if args.world < 1 or args.rank >= args.world:
        raise UsageError(f"--rank {args.rank} --world {args.world}: need 0 <= rank < world")
    if not args.listen and not args.zenoh:
        raise UsageError("give --listen and/or --zenoh endpoints (e.g. --listen tls/127.0.0.1:7447)")
    from nodes import wire
    try:
        wire.check_run_id(args.run_id)
    except ValueError as e:
        raise UsageError(f"--run-id: {e}") from None
    for ep in args.listen + args.zenoh:
        if "/" not in ep:
            raise UsageError(f"endpoint {ep!r}: expected PROTOCOL/ADDRESS:PORT, e.g. tls/127.0.0.1:7447")
    from nodes import security
    trust = trust_for(args, security.peer_name(args.rank), args.world)
    security.check_endpoints(args.listen, args.zenoh, trust is not None)
    _check_threads(args.threads)
    _check_backend(args)
    scene, ckpt = _scene_for_run(args)
    out = _output_folder(args, scene)
    _check_peers(scene, args.world, args.backend)
    if args.threads:
        import numba
        numba.set_num_threads(args.threads)
    logging.getLogger().handlers[0].setFormatter(
        logging.Formatter(f"%(asctime)s peer {args.rank} %(name)s %(levelname)s %(message)s", "%H:%M:%S"))
    restarts = _restart_history(args.restart_history)
    from nodes import supervise
    if args.watch_stdin:  # after anything that reads a first line from stdin (--tls-stdin)
        supervise.watch_stdin(supervise.exit_when_launcher_gone(f"peer {args.rank}", EXIT_PEER))
    from nodes.driver import RunPlan, run_peer
    from nodes.zenoh_transport import ZenohEndpoint
    try:
        endpoint = ZenohEndpoint(args.run_id, args.rank, args.world, args.listen, args.zenoh, args.timeout,
                                 trust=trust)
    except Exception as e:  # zenoh raises ZError for endpoints it cannot use
        raise UsageError(f"cannot open Zenoh with --listen {args.listen} --zenoh {args.zenoh}: {e}") from None
    try:
        plan = RunPlan(args.steps, args.until, out if args.rank == 0 else None, args.checkpoint_every,
                       out / "checkpoints", progress=not args.quiet,
                       report=supervise.ProgressReport() if args.report_progress else None, restarts=restarts)
        run_peer(scene, args.rank, args.world, endpoint, plan,
                 args.precision or (ckpt.manifest["precision"] if ckpt else None), args.backend, args.device,
                 resume=ckpt, frames=not args.no_frames, startup_timeout=args.timeout)
    finally:
        endpoint.close()
    return 0


def _restart_history(text: str | None) -> list | None:
    """--restart-history: a JSON list of the launcher's restarts (launch/supervise.py)."""
    if text is None:
        return None
    import json
    try:
        history = json.loads(text)
    except ValueError as e:
        raise UsageError(f"--restart-history: not JSON ({e})") from None
    if not isinstance(history, list) or not all(isinstance(h, dict) for h in history):
        raise UsageError("--restart-history: expected a JSON list of objects")
    return history


if __name__ == "__main__":
    sys.exit(main())
