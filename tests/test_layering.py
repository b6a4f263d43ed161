"""Layering: sphcore/ (physics) <- nodes/ (processes, transports, the run driver) <- launch/ (the
`sph` command); no module imports a layer above its own, no import cycles hide inside functions,
every endpoint implements the declared ``Endpoint`` protocol, and every run goes through one driver."""
import ast
import inspect
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("sphcore", "nodes", "launch")
ABOVE = {"sphcore": {"nodes", "launch"}, "nodes": {"launch"}, "launch": set()}


def modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports_of(name: str, path: Path) -> set[str]:
    """Every project module that ``name`` imports, at module level or inside a function."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)  # from nodes import wire -> nodes.wire
    return {m for m in out if m.split(".")[0] in PACKAGES}


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {name: {m for m in imports_of(name, path) if m in mods and m != name} for name, path in mods.items()}


def test_no_module_imports_a_layer_above_its_own():
    bad = [f"{name} imports {m}" for name, deps in graph().items() for m in deps
           if m.split(".")[0] in ABOVE[name.split(".")[0]]]
    assert not bad, bad


def test_no_import_cycles_even_inside_functions():
    g = graph()
    cycles, state = [], {}

    def visit(node, path):
        state[node] = "open"
        for dep in sorted(g[node]):
            if dep in ("sphcore", "nodes", "launch"):  # a package's __init__ imports nothing of its own
                continue
            if state.get(dep) == "open":
                cycles.append(path[path.index(dep):] + [dep])
            elif dep not in state:
                visit(dep, path + [dep])
        state[node] = "done"

    for node in sorted(g):
        if node not in state:
            visit(node, [node])
    assert not cycles, [" -> ".join(c) for c in cycles]


def test_wire_keys_and_addresses_live_in_wire():
    # Given every module of nodes/ and launch/ but the wire itself
    for name, path in modules().items():
        if name == "nodes.wire" or name.split(".")[0] == "sphcore":
            continue
        text = path.read_text()
        # Then none spells a key expression or defines a header address of its own
        assert 'f"sph/{' not in text or name == "nodes.security", name
        assert "VIEWER = -1" not in text and "CONTROLLER = -2" not in text, name


# -- the endpoint protocol ---------------------------------------------------------------------------
def protocol_members(protocol) -> dict[str, object]:
    """Name -> declaration (function, property or annotation) of every member of ``protocol``,
    its bases' included (sphcore.halo.Transport), without typing's own."""
    members = {}
    for cls in reversed(protocol.__mro__):
        if cls.__module__ in ("typing", "builtins", "abc"):
            continue
        members.update({k: "attribute" for k in cls.__dict__.get("__annotations__", {})})
        members.update({k: v for k, v in cls.__dict__.items() if not k.startswith("_")})
    return members


def endpoint_classes():
    from nodes.transport import InProcessEndpoint
    from nodes.zenoh_transport import ZenohEndpoint
    return [InProcessEndpoint, ZenohEndpoint]


@pytest.mark.parametrize("cls", endpoint_classes(), ids=lambda c: c.__name__)
def test_every_endpoint_provides_every_member_of_the_protocol(cls):
    from nodes.endpoint import Endpoint
    members = protocol_members(Endpoint)
    assert {"send", "recv", "drops", "dropped", "take_commands", "idle", "wait_for_peers"} <= set(members)
    init = inspect.getsource(cls.__init__)
    for name, declared in members.items():
        if declared == "attribute":  # data: set on every instance
            assert f"self.{name} = " in init or f"self.{name}, " in init, f"{cls.__name__}.{name}"
            continue
        have = getattr(cls, name, None)
        assert have is not None, f"{cls.__name__} lacks {name}"
        if isinstance(declared, property):
            assert isinstance(have, property), f"{cls.__name__}.{name} is not a property"
            continue
        want = list(inspect.signature(declared).parameters)
        got = list(inspect.signature(have).parameters)
        assert got == want, f"{cls.__name__}.{name}{tuple(got)}, the protocol says {tuple(want)}"
        gen = inspect.isgeneratorfunction(declared) or name in ("recv", "idle")
        if gen:  # generators in the protocol are generators (or blocking ones) in every endpoint
            assert inspect.isgeneratorfunction(have), f"{cls.__name__}.{name} is not a generator"


def test_an_in_process_endpoint_is_an_endpoint_at_run_time():
    from nodes.endpoint import Endpoint
    from nodes.transport import InProcessNetwork
    end = InProcessNetwork().endpoint(0)
    for name in protocol_members(Endpoint):
        assert hasattr(end, name), name


# -- one driver -----------------------------------------------------------------------------------
def test_the_cluster_through_the_run_driver_writes_the_single_process_outputs(tmp_path):
    # Given a small 2D dam break run in this process (sph run's path) and on three in-process peers,
    # both through nodes.driver.drive, with checkpoints every 10 steps
    from launch.run import run_scene
    from nodes.cluster import InProcessCluster
    from nodes.driver import RunPlan
    from sphcore.scene import load_scene
    sc = load_scene(ROOT / "configs" / "dam_break_2d.toml", ["particles.spacing=0.02"])
    one = run_scene(sc, tmp_path / "one", "f64", 30, None, None, progress=False, checkpoint_every=10)
    cluster = InProcessCluster(sc, 3, "f64", dims=(3, 1, 1))
    three = cluster.run(RunPlan(steps=30, out=tmp_path / "three", checkpoint_every=10, progress=False))
    # Then the final particles are bitwise the same, and so are the checkpoints' steps
    a, b = np.load(tmp_path / "one" / "final.npz"), np.load(tmp_path / "three" / "final.npz")
    for key in ("id", "x", "v", "rho"):
        assert np.array_equal(a[key], b[key]), key
    assert one["checkpoints"]["written"] == three["checkpoints"]["written"] == 3
    assert (tmp_path / "three" / "checkpoints" / "step_00000030").is_dir()
    # ... the summaries are the single-process one and the multi-peer one
    assert one["peers"] == 1 and "per_peer" not in one
    assert three["peers"] == 3 and len(three["per_peer"]) == 3 and three["steps"] == one["steps"] == 30
    assert three["bytes_sent"] > 0 and "positions" in three["bytes_sent_per_phase"]
    assert three["dropped_messages"] == 0


def test_the_in_process_scheduler_names_a_deadlock_of_a_whole_run():
    from nodes.cluster import DeadlockError, _drive
    from nodes.transport import InProcessNetwork
    net = InProcessNetwork()
    a = net.endpoint(0)

    def waits_forever():
        yield from a.recv(1, (0, "never"))

    with pytest.raises(DeadlockError, match="nobody sends"):
        _drive([waits_forever()], network=net)


def test_the_numba_cache_hash_covers_every_file_compiled_code_can_see_and_no_other():
    # The oracle: this file's ast import graph, from the sphcore modules that import numba
    import sphcore
    g, mods = graph(), modules()
    numba_users = {name for name, path in mods.items() if name.startswith("sphcore")
                   and any(m == "numba" or m.startswith("numba.") for m in _all_imports(path))}
    seen, todo = set(), sorted(numba_users)
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(g[name])
    assert {p.resolve() for p in sphcore.kernel_sources()} == {mods[n].resolve() for n in seen}
    hashed = {p.name for p in sphcore.kernel_sources()}
    assert {"walls.py", "grid.py", "stages.py", "generate.py", "cuda.py", "kernels.py"} <= hashed
    # a scene or checkpoint edit must not throw away minutes of compiled kernels
    assert not {"scene.py", "checkpoint.py", "halo.py", "solver.py"} & hashed


def _all_imports(path):
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
    return out
