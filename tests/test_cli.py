"""The ``sph`` command line: exit codes, error messages, the run outputs contract, help texts.

Everything goes through ``launch.cli.main([...])`` in-process, except one real run of the installed
``sph`` console script, which proves the entry point and its exit code.
"""
import dataclasses
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from launch.cli import main
from sphcore.scene import load_scene, scene_from_dict

from conftest import CONFIGS, ROOT

TINY = str(CONFIGS / "tiny.toml")
DAM_BREAK = str(CONFIGS / "dam_break.toml")
STAGE_STATS = ("mean_s", "median_s", "std_s")


# ---------------------------------------------------------------------------------------------
# One real run of the console script
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """``sph run configs/tiny.toml --steps 5`` through the installed console script."""
    sph = Path(sys.executable).with_name("sph")
    assert sph.exists(), f"console script missing: {sph} (pip install -e .)"
    out = tmp_path_factory.mktemp("cli") / "tiny_run"
    proc = subprocess.run([str(sph), "run", TINY, "--steps", "5", "--out", str(out), "--quiet"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    return proc, out


def test_console_script_run_exits_0_and_writes_the_outputs_and_the_recording(tiny_run):
    proc, out = tiny_run
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["final.npz", "run.rrd", "scene.toml", "summary.json"]


def test_summary_json_contract(tiny_run):
    proc, out = tiny_run
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    for key in ("particles", "steps", "sim_time", "wall_s", "peers", "backend", "precision",
                "particle_steps_per_s", "stages", "leaks"):
        assert key in summary, key
    assert 0 < summary["particles"] <= 1000
    assert summary["steps"] == 5
    assert summary["sim_time"] > 0
    assert summary["wall_s"] > 0
    assert summary["peers"] == 1
    assert summary["backend"] == "cpu"
    assert summary["precision"] == "f64"  # the scene's run.precision
    assert summary["particle_steps_per_s"] > 0
    assert summary["leaks"] == 0
    for stage in ("grid", "density", "forces", "integrate"):
        stats = summary["stages"][stage]
        for k in STAGE_STATS:
            assert isinstance(stats[k], float) and stats[k] >= 0, (stage, k)
        assert stats["mean_s"] > 0, stage


def test_final_npz_contract(tiny_run):
    proc, out = tiny_run
    assert proc.returncode == 0, proc.stderr
    n = json.loads((out / "summary.json").read_text())["particles"]
    with np.load(out / "final.npz") as f:
        assert set(f.files) == {"id", "x", "v", "rho"}
        ids, x, v, rho = f["id"], f["x"], f["v"], f["rho"]
    assert ids.shape == (n,) and np.issubdtype(ids.dtype, np.integer)
    assert np.all(np.diff(ids) > 0), "ids must be sorted ascending and unique"
    assert x.shape == (n, 3) and v.shape == (n, 3) and rho.shape == (n,)
    assert np.isfinite(x).all() and np.isfinite(v).all() and np.isfinite(rho).all()
    assert (rho > 0).all()
    # the drop was released at 1 m/s downwards: after 5 steps it still falls
    assert v[:, 1].min() < -0.5


def test_scene_toml_reloads_to_the_same_scene(tiny_run):
    proc, out = tiny_run
    assert proc.returncode == 0, proc.stderr
    written = load_scene(out / "scene.toml")
    original = load_scene(TINY)
    assert original.run.precision == "auto" and written.run.precision == "f64"  # resolved: what ran
    ran = dataclasses.replace(original, run=dataclasses.replace(original.run, precision="f64"))
    assert dataclasses.replace(written, source=original.source) == ran


# ---------------------------------------------------------------------------------------------
# In-process runs
# ---------------------------------------------------------------------------------------------

def test_until_stops_exactly_at_the_requested_time(tmp_path):
    # Given a run that must stop at T, which is not a whole number of CFL steps
    T = 1.23e-3
    out = tmp_path / "until"
    # When it runs
    rc = main(["run", TINY, "--until", repr(T), "--out", str(out), "--quiet"])
    # Then it exits 0 and the simulated time is T, reached in several steps
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert abs(summary["sim_time"] - T) <= 1e-9 * T
    assert summary["steps"] > 2
    assert (out / "final.npz").exists() and (out / "scene.toml").exists()


def test_precision_and_set_reach_the_run(tmp_path):
    out = tmp_path / "f32"
    rc = main(["run", TINY, "--steps", "2", "--precision", "f32", "--set", "particles.spacing=0.02",
               "--out", str(out), "--quiet"])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["precision"] == "f32" and summary["steps"] == 2
    assert summary["particles"] < 300  # coarser spacing than the file's 0.0125 (498 particles)
    with np.load(out / "final.npz") as f:
        assert f["x"].dtype == np.float32
    assert load_scene(out / "scene.toml").particles.spacing == 0.02


# ---------------------------------------------------------------------------------------------
# Bad input: exit 2, the key named on stderr, nothing written
# ---------------------------------------------------------------------------------------------

BAD_RUNS = [
    ("unknown-key", [TINY, "--set", "sph.kernal=muller"], ["sph.kernal"]),
    ("unknown-section", [TINY, "--set", "sphh.kernel=muller"], ["sphh"]),
    ("bad-value", [TINY, "--set", "sph.support=0.5"], ["sph.support", "0.5", "[1.5, 4]"]),
    ("bad-choice", [TINY, "--set", "sph.kernel=gaussian"], ["sph.kernel", "gaussian", "wendland_c2"]),
    ("bad-type", [TINY, "--set", "particles.spacing=fine"], ["particles.spacing", "fine"]),
    ("bad-override-syntax", [TINY, "--set", "sph.kernel"], ["sph.kernel", "section.key=value"]),
    ("missing-config", [str(CONFIGS / "no_such_scene.toml")], ["no_such_scene.toml"]),
    ("peers-dims", [TINY, "--peers", "3", "--set", "decomposition.dims=[2, 1, 1]"],
     ["--peers 3", "decomposition.dims = [2, 1, 1]", "2 blocks"]),
    ("peers-too-many", [TINY, "--peers", "1000"], ["--peers 1000", "do not fit"]),
    ("device-without-cuda", [TINY, "--device", "1"], ["--device 1", "only with --backend cuda"]),
    # (--backend cuda without a GPU: tests/test_cuda.py, in a subprocess without the simulator)
    ("record-suffix", [TINY, "--record", "x.txt"], ["--record", "x.txt", "must end in .rrd"]),
    ("no-viewer-spawn", [TINY, "--no-viewer", "--spawn"], ["--no-viewer", "--spawn"]),
    # found by a hostile-input sweep (2026-12-06): each was a traceback or a run that went wrong
    ("spacing-beyond-domain", [TINY, "--set", "particles.spacing=1e300"],
     ["particles.spacing = 1e+300", "not smaller than the domain"]),
    ("spacing-tiny", [TINY, "--set", "particles.spacing=1e-300"], ["particles.spacing = 1e-300", "max_particles"]),
    ("block-radius-huge", [TINY, "--set", "fluid.blocks[1].radius=1e300"], ["inf particles", "max_particles"]),
    ("rest-density-tiny", [TINY, "--set", "fluid.rest_density=1e-300"],
     ["fluid.rest_density = 1e-300", "[0.001, 1e+06]"]),
    ("floating-body-huge", [str(CONFIGS / "floating_box_2d.toml"), "--set", "obstacles[0].shape='sphere'", "--set",
                            "obstacles[0].radius=1e300"], ["obstacles[0].radius = 1e+300", "not smaller than the domain"]),
    ("floating-body-outside", [str(CONFIGS / "floating_box_2d.toml"), "--set", "obstacles[0].center=[5,5]"],
     ["obstacles[0].center = [5.0, 5.0]", "outside the domain's box"]),
    ("box-negative-edge", [str(CONFIGS / "floating_box_2d.toml"), "--set", "obstacles[0].size=[-0.2,0.1]"],
     ["obstacles[0].size = [-0.2, 0.1]", "must be > 0"]),
    ("name-control-character", [TINY, "--set", 'scene.name="x\nsph run: error: forged"'],
     ["scene.name = ", "forged", "control or format characters"]),
]


@pytest.mark.fast
@pytest.mark.parametrize("args,fragments", [b[1:] for b in BAD_RUNS], ids=[b[0] for b in BAD_RUNS])
def test_bad_input_exits_2_names_the_problem_and_writes_nothing(args, fragments, tmp_path, capsys):
    # Given an output folder that does not exist yet
    out = tmp_path / "out"
    # When sph run is given bad input
    rc = main(["run", *args, "--steps", "1", "--out", str(out), "--quiet"])
    # Then it exits 2 with a one-line error naming the problem, and writes nothing
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("sph run: error: "), err
    for frag in fragments:
        assert frag in err, f"{frag!r} missing from {err!r}"
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.fast
@pytest.mark.filterwarnings("error::RuntimeWarning")  # the refusal is the message, not numpy's overflow warnings
def test_a_wall_path_whose_speed_is_not_a_number_is_refused(tmp_path, capsys):
    """A path of +-1.7e308 m makes the largest speed inf - inf = NaN, which `speed >= c0` let through:
    the run went on with the wall at an infinite speed (hostile-input sweep, 2026-12-06)."""
    scene = tmp_path / "gate.toml"
    scene.write_text((CONFIGS / "dam_break_2d.toml").read_text() + '\n[[obstacles]]\nshape = "box"\n'
                     'center = [0.6, 0.3]\nsize = [0.02, 0.6]\npath = [[0, 0, 0], [1, 1.7e308, 0], [2, -1.7e308, 0]]\n')
    out = tmp_path / "out"
    rc = main(["run", str(scene), "--steps", "1", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "obstacles[0].path" in err and "nan m/s" in err and "Traceback" not in err, err
    assert not out.exists()


@pytest.mark.fast
@pytest.mark.parametrize("name", ["../escaped", "/tmp/elsewhere", "..", "", ".", "-x"])
def test_a_scene_name_never_chooses_a_folder_outside_runs(name, tmp_path, monkeypatch, capsys):
    """Without --out a run writes to runs/<scene.name>: a name that is not one plain path component
    ('../x', '/abs', '..') would have written outside runs/ (hostile-input sweep, 2026-12-06)."""
    monkeypatch.chdir(tmp_path)
    rc = main(["run", TINY, "--steps", "1", "--quiet", "--set", f"scene.name={name!r}"])
    err = capsys.readouterr().err
    assert rc == 2 and "scene.name" in err and "give --out FOLDER" in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []  # nothing written, not even runs/


@pytest.mark.fast
def test_an_output_path_the_system_refuses_is_one_line(tmp_path, capsys):
    for out, fragment in [(tmp_path / ("a" * 300), "not a usable path"), (Path(""), "name a folder")]:
        rc = main(["run", TINY, "--steps", "1", "--quiet", "--out", str(out)])
        err = capsys.readouterr().err
        assert rc == 2 and fragment in err and "Traceback" not in err, err


@pytest.mark.parametrize("args,fragments", [
    (["--steps", "3", "--until", "0.1"], ["--until", "--steps", "not allowed"]),
    (["--steps", "-1"], ["--steps", "must be >= 0"]),
    (["--until", "0"], ["--until", "must be > 0"]),
    (["--until", "inf"], ["--until", "must be finite"]),
    (["--steps", "99999999999999"], ["--steps", "at most 1,000,000,000 steps"]),
    (["--precision", "f16"], ["--precision", "f16"]),
    (["--backend", "opencl"], ["--backend", "opencl"]),
], ids=["steps-and-until", "negative-steps", "until-zero", "until-inf", "steps-huge", "precision-f16",
        "backend-opencl"])
@pytest.mark.fast
def test_bad_options_exit_2_before_anything_runs(args, fragments, tmp_path, capsys):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exc:
        main(["run", TINY, *args, "--out", str(out)])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    for frag in fragments:
        assert frag in err, f"{frag!r} missing from {err!r}"
    assert not out.exists()


@pytest.mark.parametrize("argv,fragments", [
    (["bench", "--sizes", "0"], ["--sizes", "must be >= 1"]),
    (["bench", "--steps", "0"], ["--steps", "must be >= 1"]),
    (["bench", "--peers", "0"], ["--peers", "must be >= 1"]),
    (["bench", "--network", "--repeat", "0"], ["--repeat", "must be >= 1"]),
    (["render", "runs/x", "--size", "0", "10"], ["--size", "must be >= 1"]),
    (["render", "runs/x", "--size", "20000", "10"], ["--size", "at most 16,384 pixels"]),
    (["render", "runs/x", "--fps", "0"], ["--fps", "must be >= 1"]),
    (["peer", "x.toml", "--rank", "0", "--world", "0", "--run-id", "r"], ["--world", "must be >= 1"]),
], ids=["bench-sizes-0", "bench-steps-0", "bench-peers-0", "bench-repeat-0", "render-size-0", "render-size-huge",
        "render-fps-0", "peer-world-0"])
@pytest.mark.fast
def test_counts_of_zero_are_refused_before_anything_runs(argv, fragments, capsys):
    # sph bench --sizes 0 divided by zero after set-up; --steps 0 after every case had run
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    for frag in fragments:
        assert frag in err, f"{frag!r} missing from {err!r}"


@pytest.mark.fast
def test_output_paths_nothing_can_be_written_to_are_refused_before_anything_runs(tmp_path, capsys):
    # /proc takes no new file although root passes its permission check; a file is no folder
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cases = [
        (["bench", "--sizes", "1000", "--json", "/proc/x.json"], "cannot write there"),
        (["bench", "--sizes", "1000", "--json", str(tmp_path)], "is a folder"),
        (["bench", "--sizes", "1000", "--json", str(a_file / "x.json")], "exists and is not a folder"),
        (["validate", "hydrostatic", "--quick", "--out", "/proc/x"], "cannot write there"),
        (["validate", "hydrostatic", "--quick", "--out", str(a_file)], "exists and is not a folder"),
        (["study", "--quick", "--out", "/proc/x"], "cannot write there"),
        (["run", TINY, "--steps", "1", "--quiet", "--out", "/proc/x"], "cannot write there"),
    ]
    for argv, fragment in cases:
        rc = main(argv)
        err = capsys.readouterr().err
        assert rc == 2 and fragment in err and "Traceback" not in err, (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


@pytest.mark.fast
def test_replay_refuses_a_file_that_is_not_a_recording(tmp_path, capsys):
    for name, content in [("notes.rrd", b"root:x:0:0"), ("empty.rrd", b"")]:
        path = tmp_path / name
        path.write_bytes(content)
        rc = main(["replay", str(path), "--serve-web"])
        err = capsys.readouterr().err
        assert rc == 2 and "not a Rerun recording" in err and "Traceback" not in err, err


# ---------------------------------------------------------------------------------------------
# sph scene
# ---------------------------------------------------------------------------------------------

@pytest.mark.fast
def test_scene_prints_the_resolved_scene_with_overrides(capsys):
    # When the dam break is printed with a kernel override
    rc = main(["scene", DAM_BREAK, "--set", "sph.kernel=muller", "--full"])
    out = capsys.readouterr().out
    # Then the TOML carries the override and every resolved default, and is itself a valid scene
    assert rc == 0
    assert 'kernel = "muller"' in out
    data = tomllib.loads(out)
    assert data["sph"]["kernel"] == "muller"
    assert data["boundary"]["gap"] == 0.25  # a default the file does not set
    s = scene_from_dict(data)
    assert s.sph.kernel == "muller" and s.particles.spacing == 0.0125


@pytest.mark.fast
def test_scene_full_writes_every_vector_on_one_line(capsys):
    rc = main(["scene", TINY, "--full"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "gravity = [0.0, -9.81, 0.0]" in out
    assert all(not line.strip().startswith(("0", "-", "1")) for line in out.splitlines()), out
    # one line per key: every line is blank, a table header or "key = value" (a vector written one
    # component per line leaves lines of bare numbers and brackets)
    assert all(line == "" or line.startswith("[") or " = " in line for line in out.splitlines()), out


@pytest.mark.fast
def test_scene_summary_counts_the_particles_of_each_block_as_the_run_makes_them(capsys):
    # Given tiny.toml: a box pool and a sphere drop, 498 particles in all (the run's count)
    rc = main(["scene", TINY])
    out = capsys.readouterr().out
    assert rc == 0
    assert "fluid.blocks[0] box    432 particles" in out
    assert "fluid.blocks[1] sphere 66 particles" in out
    assert "particles     498 " in out
    for word in ("memory        about", "neighbours    about", "first dt", "acoustic limit"):
        assert word in out, word
    assert len(out.splitlines()) < 20


@pytest.mark.fast
def test_examples_lists_every_shipped_scene_with_its_description(capsys):
    rc = main(["examples"])
    out = capsys.readouterr().out
    assert rc == 0
    lines = [line for line in out.splitlines() if line.split()[0].endswith(".toml")]
    assert len(lines) == len(list(CONFIGS.glob("*.toml")))
    assert any("tiny.toml" in line and "a drop falls into a shallow pool" in line for line in lines)


@pytest.mark.parametrize("argv,names", [
    (["--until", "0.5", "--peers", "1", "2"], "--peers"),
    (["--until", "0.5", "--network"], "--network"),
    (["--until", "0.5", "--neighbours", "walk"], "--neighbours"),
    (["--until", "20"], "at most 10"),
], ids=["peers", "network", "walk", "too-long"])
@pytest.mark.fast
def test_bench_until_refuses_what_it_does_not_time(argv, names, capsys):
    rc = main(["bench", *argv])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("sph bench: error: --until") and names in err, err


@pytest.mark.fast
def test_scene_with_bad_override_exits_2(capsys):
    rc = main(["scene", DAM_BREAK, "--set", "sph.kernel=gaussian"])
    cap = capsys.readouterr()
    assert rc == 2
    assert cap.out == ""
    assert cap.err.startswith("sph scene: error: ") and "sph.kernel" in cap.err and "gaussian" in cap.err


@pytest.mark.fast
@pytest.mark.parametrize("override,hint", [
    ("obstacles.0.density=nan", "obstacles[0].density"),          # a dotted index into [[obstacles]]
    ("fluid.blocks.0.velocity=[1,0]", "fluid.blocks[0].velocity"),
    ("obstacles.density=2", "obstacles[0].density"),              # no index at all
])
def test_an_override_into_an_array_of_tables_without_an_index_names_the_form(capsys, override, hint):
    rc = main(["scene", str(ROOT / "configs" / "floating_box_2d.toml"), "--set", override])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("sph scene: error: --set ") and "array of tables" in err, err
    assert f"e.g. {hint}" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


# ---------------------------------------------------------------------------------------------
# Help
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv,mentions", [
    (["--help"], ["run", "bench", "scene", "--verbose"]),
    (["run", "--help"], ["--steps", "--until", "--out", "--precision", "--set", "--quiet", "--peers",
                         "--backend", "--threads", "config"]),
    (["bench", "--help"], ["--sizes", "--precisions", "--threads", "--steps", "--external", "--json", "--until",
                           "--solvers"]),
    (["scene", "--help"], ["--set", "config"]),
], ids=["sph", "run", "bench", "scene"])
@pytest.mark.fast
def test_help_exits_0_and_lists_options(argv, mentions, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out = capsys.readouterr().out
    assert exc.value.code == 0
    for m in mentions:
        assert m in out, f"{m!r} missing from help of {argv}"


@pytest.mark.fast
def test_no_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    assert "COMMAND" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# Help texts and flag names (issue 21)
# ---------------------------------------------------------------------------------------------

def _subparsers():
    import argparse

    from launch.cli import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


@pytest.mark.fast
@pytest.mark.parametrize("command", sorted(_subparsers()))
def test_every_option_of_every_command_has_help_and_states_its_default_once(command, capsys):
    import argparse
    parser = _subparsers()[command]
    for action in parser._actions:
        if action.help == argparse.SUPPRESS or isinstance(action, argparse._HelpAction):
            continue
        assert action.help, f"sph {command} {action.option_strings or action.dest}: no help"
        assert action.help.count("(default") <= 1, f"sph {command} {action.option_strings}: {action.help}"
    assert parser.formatter_class is argparse.HelpFormatter  # no argparse default after the author's own
    with pytest.raises(SystemExit):
        parser.parse_args(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: None)" not in text and ") (default" not in text, text


@pytest.mark.fast
@pytest.mark.parametrize("command", ["peer", "viewer", "control"])
def test_zenoh_endpoints_are_zenoh_and_the_old_connect_still_works_with_a_deprecation(command, capsys):
    from launch.cli import build_parser
    required = {"peer": ["--rank", "0", "--world", "1", "--run-id", "r"], "viewer": ["x.toml", "--run-id", "r"],
                "control": ["--run-id", "r", "pause"]}[command]
    new = build_parser().parse_args([command, *required, "--zenoh", "tcp/127.0.0.1:7447"])
    assert new.zenoh == ["tcp/127.0.0.1:7447"]
    assert "deprecated" not in capsys.readouterr().err
    old = build_parser().parse_args([command, *required, "--connect", "tcp/127.0.0.1:7447", "--connect",
                                     "tcp/127.0.0.1:7448"])
    assert old.zenoh == ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448"]
    err = capsys.readouterr().err
    assert err.count("--connect is deprecated here, use --zenoh") == 1, err


@pytest.mark.fast
def test_run_connect_is_still_the_rerun_url():
    from launch.cli import build_parser
    args = build_parser().parse_args(["run", TINY, "--connect", "rerun+http://127.0.0.1:9876/proxy"])
    assert args.rerun_url == "rerun+http://127.0.0.1:9876/proxy"


@pytest.mark.fast
@pytest.mark.parametrize("text,fragment", [
    (None, "cannot read it"),
    ("{", "not JSON"),
    ('{"run_id": "r", "world": 0, "endpoints": ["tcp/127.0.0.1:1"], "tls": null}', "expected {run_id"),
    ('{"run_id": "r", "world": 2, "endpoints": [], "tls": null}', "expected {run_id"),
])
def test_control_out_dir_with_a_bad_run_json_exits_2(text, fragment, tmp_path, capsys):
    if text is not None:
        (tmp_path / "run.json").write_text(text)
    assert main(["control", str(tmp_path), "pause"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sph control: error: ") and fragment in err and "Traceback" not in err, err


@pytest.mark.fast
def test_control_without_a_run_says_how_to_name_one(capsys):
    assert main(["control", "pause"]) == 2
    assert "sph control OUT_DIR COMMAND" in capsys.readouterr().err


@pytest.mark.fast
def test_control_out_dir_reads_the_run_from_run_json(tmp_path, capsys):
    # Given the run.json of an --insecure run whose rank 0 is gone (a port nobody listens on)
    from launch.local import free_ports, write_run_info

    class Args:
        tls_dir = None
    endpoint = f"tcp/127.0.0.1:{free_ports(1)[0]}"
    write_run_info(tmp_path, "abc123", 2, [endpoint, "tcp/127.0.0.1:1"], Args())
    # When sph control is given only the folder
    rc = main(["control", "--timeout", "0.5", str(tmp_path), "pause"])
    # Then it looked for run abc123 at rank 0's endpoint (and found nobody: exit 4)
    err = capsys.readouterr().err
    assert rc == 4
    assert "no run 'abc123' is listening at " + endpoint in err, err


@pytest.mark.fast
def test_backend_cuda_without_the_extra_names_it(monkeypatch, tmp_path, capsys):
    # Given a machine without the CUDA packages (numba_cuda not importable) and so no usable GPU
    import importlib.util

    from sphcore.backends import cuda
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "numba_cuda"
                        else real_find_spec(name, *a))

    def no_gpu(device=None):
        raise cuda.CudaUnavailable("--backend cuda: no CUDA driver or GPU found")
    monkeypatch.setattr(cuda, "require", no_gpu)
    # When a run asks for the GPU backend
    rc = main(["run", TINY, "--backend", "cuda", "--out", str(tmp_path / "out"), "--quiet"])
    # Then the one line says which extra to install, and nothing is written
    err = capsys.readouterr().err
    assert rc == 2 and "sphfluid[cuda]" in err and "pip install" in err, err
    assert not (tmp_path / "out").exists()


def test_bench_peers_says_how_the_peers_split_the_domain(tmp_path, capsys):
    # each multi-peer line names the blocks (the automatic layout: the dam break's width is cut)
    out = tmp_path / "bench.json"
    rc = main(["bench", "--sizes", "3000", "--precisions", "f32", "--threads", "1", "--peers", "1", "2",
               "--steps", "3", "--json", str(out)])
    assert rc == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if "peer(s) x" in x]
    assert len(lines) == 2 and "blocks" not in lines[0] and "blocks 1x1x2," in lines[1], lines
    runs = [r for r in json.loads(out.read_text())["results"] if "peers" in r]
    assert [r["blocks"] for r in runs] == [[1, 1, 1], [1, 1, 2]]
