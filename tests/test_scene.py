"""Scene validation: shipped configs, bad inputs, --set overrides and the to_dict round trip.

Every rejected input must raise ``SceneError`` whose message names the offending key path and the
bad value or what would be allowed.
"""
import copy
import dataclasses
import re
import tomllib

import pytest
import tomli_w

from sphcore.scene import SceneError, load_scene, parse_override, scene_from_dict, scene_toml

from conftest import CONFIGS

pytestmark = pytest.mark.fast  # make check runs this whole module

CONFIG_FILES = sorted(CONFIGS.glob("*.toml"))
CONFIG_IDS = [p.stem for p in CONFIG_FILES]


# ---------------------------------------------------------------------------------------------
# Shipped configs
# ---------------------------------------------------------------------------------------------

def test_configs_folder_holds_the_six_scenes():
    assert set(CONFIG_IDS) >= {"dam_break", "dam_break_2d", "hydrostatic_2d", "obstacle", "taylor_green_2d",
                               "tiny"}


@pytest.mark.parametrize("path", CONFIG_FILES, ids=CONFIG_IDS)
def test_every_config_loads(path):
    s = load_scene(path)
    assert s.source == str(path)
    assert s.scene.name == path.stem
    assert s.fluid.blocks, "a shipped scene must have fluid"
    # 2D scenes are padded to 3 components; every vector ends up with 3
    assert len(s.forces.gravity) == 3 and len(s.domain.center) == 3


_STRING = re.compile(r'"(?:[^"\\]|\\.)*"|\'[^\']*\'')
_KEY_LINE = re.compile(r"^\s*([A-Za-z0-9_-]+)\s*=(.*)$")


def _leaf_key_count(data) -> int:
    """Number of key = value pairs in parsed TOML (arrays of tables counted per table)."""
    n = 0
    for value in data.values():
        if isinstance(value, dict):
            n += _leaf_key_count(value)
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            n += sum(_leaf_key_count(v) for v in value)
        else:
            n += 1
    return n


@pytest.mark.parametrize("path", CONFIG_FILES, ids=CONFIG_IDS)
def test_every_key_of_every_config_has_a_comment_on_its_line(path):
    # Given the raw lines of a shipped config
    text = path.read_text()
    missing, key_lines = [], 0
    # When every key = value line is inspected (strings removed, so a '#' inside one does not count)
    for lineno, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#") or stripped.startswith("["):
            continue
        m = _KEY_LINE.match(line)
        assert m, f"{path.name}:{lineno}: not a single-line key = value: {line!r}"
        key_lines += 1
        rest = _STRING.sub('""', m.group(2))
        if not re.search(r"#\s*\S", rest):
            missing.append(f"{path.name}:{lineno}: {m.group(1)}")
    # Then none lacks a comment, and every key of the parsed file was seen on its own line
    assert not missing, "keys without a comment: " + ", ".join(missing)
    assert key_lines == _leaf_key_count(tomllib.loads(text))


# ---------------------------------------------------------------------------------------------
# Bad inputs
# ---------------------------------------------------------------------------------------------

def base(dim: int = 3) -> dict:
    """A small valid scene as raw TOML data."""
    return {
        "scene": {"name": "t", "dim": dim},
        "particles": {"spacing": 0.05},
        "fluid": {"blocks": [{"shape": "box", "min": [0.0] * dim, "max": [0.2] * dim}]},
        "forces": {"gravity": [0.0, -9.81, 0.0][:dim]},
        "domain": {"container": "box", "center": [0.25] * dim, "size": [0.5] * dim},
    }


def with_keys(data: dict, changes: dict) -> dict:
    """Deep-copy ``data`` and set each 'section.key' / 'fluid.blocks[0].key' path to its value."""
    out = copy.deepcopy(data)
    for path, value in changes.items():
        parts = []
        for seg in path.split("."):
            m = re.fullmatch(r"(\w+)\[(\d+)\]", seg)
            parts += [m.group(1), int(m.group(2))] if m else [seg]
        node = out
        for seg in parts[:-1]:
            node = node[seg] if isinstance(seg, int) else node.setdefault(seg, {})
        node[parts[-1]] = value
    return out


BAD = [
    # (id, dim, changes, fragments the message must contain)
    ("unknown-section", 3, {"sphh": {"kernel": "muller"}}, ["sphh", "sph", "particles"]),
    ("unknown-key-typo", 3, {"sph.kernal": "muller"}, ["sph.kernal", "kernel"]),
    ("unknown-key-in-block", 3, {"fluid.blocks[0].colour": "blue"}, ["fluid.blocks[0].colour", "velocity"]),
    ("unknown-key-in-obstacle", 3, {"obstacles": [{"shape": "sphere", "radious": 0.1}]},
     ["obstacles[0].radious", "radius"]),
    ("section-not-a-table", 3, {"sph": 3}, ["sph", "table"]),
    ("string-for-float", 3, {"sph.support": "2.3"}, ["sph.support", "'2.3'", "a number"]),
    ("float-for-int", 3, {"time.steps": 10.5}, ["time.steps", "10.5", "an integer"]),
    ("bool-for-float", 3, {"sph.sound_speed": True}, ["sph.sound_speed", "True", "a number"]),
    ("bool-for-int", 3, {"time.steps": False}, ["time.steps", "False", "an integer"]),
    ("number-for-bool", 3, {"sph.clamp_negative_pressure": 1}, ["sph.clamp_negative_pressure", "1",
                                                               "true or false"]),
    ("number-for-string", 3, {"sph.kernel": 2}, ["sph.kernel", "2", "a string"]),
    ("string-for-vector", 3, {"forces.gravity": "down"}, ["forces.gravity", "'down'", "an array"]),
    ("bool-in-vector", 3, {"forces.gravity": [0.0, True, 0.0]}, ["forces.gravity", "finite numbers"]),
    ("number-in-bool-vector", 3, {"domain.periodic": [1, 0, 0]}, ["domain.periodic", "true/false"]),
    ("nan", 3, {"sph.support": float("nan")}, ["sph.support", "nan", "finite"]),
    ("inf-in-vector", 3, {"forces.gravity": [0.0, float("-inf"), 0.0]}, ["forces.gravity", "finite"]),
    ("huge-int-for-float", 3, {"sph.sound_speed": 10**400}, ["sph.sound_speed", "number"]),
    ("huge-int-in-vector", 3, {"forces.gravity": [0, 10**400, 0]}, ["forces.gravity", "number"]),
    ("support-too-small", 3, {"sph.support": 0.5}, ["sph.support", "0.5", "[1.5, 4]"]),
    ("support-too-large", 3, {"sph.support": 4.5}, ["sph.support", "4.5", "[1.5, 4]"]),
    ("spacing-zero", 3, {"particles.spacing": 0.0}, ["particles.spacing", "0.0", "(0, inf]"]),
    ("spacing-negative", 3, {"particles.spacing": -0.01}, ["particles.spacing", "-0.01", "(0, inf]"]),
    ("cfl-zero", 3, {"time.cfl": 0}, ["time.cfl", "0", "(0, 2]"]),
    ("max-particles-zero", 3, {"particles.max_particles": 0}, ["particles.max_particles", "0", "[1, "]),
    ("restitution-above-one", 3, {"boundary.restitution": 1.5}, ["boundary.restitution", "1.5", "[0, 1]"]),
    ("kernel-gaussian", 3, {"sph.kernel": "gaussian"}, ["sph.kernel", "'gaussian'", "'muller'",
                                                        "'cubic_spline'", "'wendland_c2'"]),
    ("viscosity-choice", 3, {"sph.viscosity": "sutherland"}, ["sph.viscosity", "'sutherland'", "'morris'"]),
    ("container-choice", 3, {"domain.container": "cube"}, ["domain.container", "'cube'", "'cylinder'"]),
    ("dim-4", 3, {"scene.dim": 4}, ["scene.dim", "4", "2, 3"]),
    ("obstacle-shape", 3, {"obstacles": [{"shape": "cone"}]}, ["obstacles[0].shape", "'cone'", "'sphere'"]),
    ("obstacles-not-array", 3, {"obstacles": {"shape": "sphere"}}, ["obstacles", "array of tables"]),
    ("blocks-not-array", 3, {"fluid.blocks": {"min": [0, 0, 0]}}, ["fluid.blocks", "array of tables"]),
    ("vector-too-long", 3, {"forces.gravity": [0.0, -9.81, 0.0, 0.0]}, ["forces.gravity", "2 or 3 components"]),
    ("vector-too-short", 3, {"domain.size": [1.0]}, ["domain.size", "2 or 3 components"]),
    ("2-vector-in-3d", 3, {"forces.gravity": [0.0, -9.81]}, ["forces.gravity", "[0.0, -9.81]",
                                                             "3D scene needs 3 components"]),
    ("2-vector-in-3d-block", 3, {"fluid.blocks[0].velocity": [1.0, 0.0]}, ["fluid.blocks[0].velocity",
                                                                          "3 components"]),
    ("periodic-rotated", 3, {"domain.periodic": [True, False, False], "domain.rotation": [0.0, 10.0, 0.0]},
     ["domain.periodic", "domain.rotation"]),
    ("periodic-scaled", 3, {"domain.periodic": [True, False, False], "domain.scale": 2.0},
     ["domain.periodic", "domain.scale"]),
    ("periodic-sphere", 3, {"domain.periodic": [True, False, False], "domain.container": "sphere"},
     ["domain.periodic", "'sphere'", "'box'"]),
    ("taylor-green-3d", 3, {"fluid.initial_flow": "taylor_green", "domain.periodic": [True, True, False]},
     ["fluid.initial_flow", "taylor_green", "dim = 2"]),
    ("taylor-green-not-periodic", 2, {"fluid.initial_flow": "taylor_green"},
     ["fluid.initial_flow", "domain.periodic"]),
    ("cylinder-2d", 2, {"domain.container": "cylinder"}, ["domain.container", "'cylinder'", "2D"]),
    ("2d-gravity-z", 2, {"forces.gravity": [0.0, -9.81, 1.0]}, ["forces.gravity", "z must be 0"]),
    ("2d-rotation-x", 2, {"domain.rotation": [10.0, 0.0, 0.0]}, ["domain.rotation", "about z only"]),
    ("block-max-equals-min", 3, {"fluid.blocks[0].max": [0.2, 0.0, 0.2]},
     ["fluid.blocks[0].max", "fluid.blocks[0].min", "[0.2, 0.0, 0.2]"]),
    ("block-max-below-min-2d", 2, {"fluid.blocks[0].min": [0.1, 0.1], "fluid.blocks[0].max": [0.3, 0.05]},
     ["fluid.blocks[0].max", "fluid.blocks[0].min"]),
    ("sphere-block-no-radius", 3, {"fluid.blocks": [{"shape": "sphere", "center": [0.2, 0.2, 0.2]}]},
     ["fluid.blocks[0].radius", "positive"]),
    ("morris-nu-zero", 3, {"sph.viscosity": "morris", "sph.nu": 0.0}, ["sph.nu", "0.0", "'morris'", "nu > 0"]),
    ("muller-nu-zero", 3, {"sph.viscosity": "muller", "sph.nu": 0}, ["sph.nu", "'muller'", "nu > 0"]),
    ("none-container-bounds", 3, {"domain.container": "none", "domain.bounds_min": [0.0, 0.0, 0.0],
                                  "domain.bounds_max": [1.0, 0.0, 1.0]},
     ["domain.bounds_max", "domain.bounds_min", "[1.0, 0.0, 1.0]"]),
    ("none-container-no-bounds", 2, {"domain.container": "none"}, ["domain.bounds_max", "domain.bounds_min"]),
    ("box-size-zero", 3, {"domain.size": [1.0, 0.0, 1.0]}, ["domain.size", "positive"]),
    ("plane-normal-zero", 3, {"domain.planes": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]},
     ["domain.planes[0].normal", "non-zero"]),
    ("no-fluid-blocks", 3, {"fluid.blocks": []}, ["fluid.blocks", "at least one"]),
    ("alpha-nu-with-morris", 2, {"sph.viscosity": "morris", "sph.nu": 1e-6, "sph.alpha_nu": 1e-4},
     ["sph.alpha_nu", "0.0001", "'morris'", "sph.nu"]),
    ("alpha-nu-too-large", 2, {"sph.alpha_nu": 5.0}, ["sph.alpha_nu", "5.0", "alpha =", "above 10"]),
    ("switch-with-morris", 3, {"sph.viscosity": "morris", "sph.nu": 1e-6, "sph.viscosity_switch": "balsara"},
     ["sph.viscosity_switch", "'balsara'", "'morris'", "'artificial'"]),
]


def test_the_artificial_viscosity_given_as_a_viscosity_keeps_it_at_every_spacing():
    from sphcore.model import Model
    # Given the 2D dam break with its artificial viscosity given as nu = alpha c0 h / 8 (2D)
    nus = []
    for dx in (0.01, 0.005, 0.0025):
        scene = scene_from_dict(with_keys(base(2), {"particles.spacing": dx, "sph.alpha_nu": 4.3125e-4,
                                                    "sph.sound_speed": 30.0, "sph.support": 2.3}))
        model = Model(scene, "f64", "cpu")
        nus.append((model.prm.alpha, model.prm.alpha * 30.0 * model.h / 8.0))
    # Then alpha halves with every halving of h, and the viscosity it acts with stays
    assert [round(a, 12) for a, _ in nus] == [0.01, 0.02, 0.04]
    assert all(nu == pytest.approx(4.3125e-4, rel=1e-12) for _, nu in nus)
    # and without it, alpha is the scene's own
    plain = Model(scene_from_dict(with_keys(base(2), {"sph.alpha": 0.03})), "f64", "cpu")
    assert plain.prm.alpha == 0.03


@pytest.mark.parametrize("dim,changes,fragments", [c[1:] for c in BAD], ids=[c[0] for c in BAD])
def test_bad_scene_is_rejected_naming_key_and_value(dim, changes, fragments):
    # Given a valid scene with one deliberate mistake
    data = with_keys(base(dim), changes)
    # When it is validated
    with pytest.raises(SceneError) as err:
        scene_from_dict(data)
    # Then the message names the key and the bad value or what is allowed
    msg = str(err.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} missing from {msg!r}"


def test_scene_without_fluid_section_is_rejected():
    data = base(3)
    del data["fluid"]
    with pytest.raises(SceneError, match=r"fluid\.blocks.*at least one"):
        scene_from_dict(data)


def test_the_base_scenes_used_above_are_valid():
    # (so each bad case fails because of its own mistake, not the base)
    for dim in (2, 3):
        s = scene_from_dict(base(dim))
        assert s.dim == dim


def test_load_scene_missing_file_and_invalid_toml(tmp_path):
    with pytest.raises(SceneError, match="nope.toml"):
        load_scene(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[sph]\nkernel = \n")
    with pytest.raises(SceneError, match="bad.toml.*not valid TOML"):
        load_scene(bad)


# ---------------------------------------------------------------------------------------------
# --set overrides
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text,path,value", [
    ("sph.kernel=cubic_spline", ["sph", "kernel"], "cubic_spline"),
    ('scene.name="my run"', ["scene", "name"], "my run"),
    ("scene.description=a bare sentence", ["scene", "description"], "a bare sentence"),
    ("sph.support=2.5", ["sph", "support"], 2.5),
    ("time.steps=10", ["time", "steps"], 10),
    ("sph.nu=1e-3", ["sph", "nu"], 1e-3),
    ("forces.gravity=[0,-1,0]", ["forces", "gravity"], [0, -1, 0]),
    ("domain.periodic=[true, false]", ["domain", "periodic"], [True, False]),
    ("sph.clamp_negative_pressure=false", ["sph", "clamp_negative_pressure"], False),
    ("fluid.blocks[0].velocity=[1,0,0]", ["fluid", "blocks", 0, "velocity"], [1, 0, 0]),
    ("obstacles[1].radius=0.2", ["obstacles", 1, "radius"], 0.2),
    (" sph.alpha = 0.1 ", ["sph", "alpha"], 0.1),
])
def test_parse_override(text, path, value):
    got_path, got_value = parse_override(text)
    assert got_path == path
    assert got_value == value and type(got_value) is type(value)


def test_overrides_are_applied_and_validated_like_the_file():
    # Given the tiny scene (two blocks, no [terms] section) and several overrides
    overrides = [
        "sph.kernel=cubic_spline", "sph.support=2.0", "time.steps=7", "particles.spacing=0.02",
        "forces.gravity=[0,-1,0]", "sph.clamp_negative_pressure=false", "fluid.blocks[0].velocity=[1,0,0]",
        "terms.xsph=0.1", "sph.alpha=0.5", "sph.alpha=0.25",
    ]
    # When it is loaded
    s = load_scene(CONFIGS / "tiny.toml", overrides)
    # Then every override shows in the dataclasses, normalised (ints to floats, arrays to tuples)
    assert s.sph.kernel == "cubic_spline"
    assert s.sph.support == 2.0
    assert s.time.steps == 7 and type(s.time.steps) is int
    assert s.particles.spacing == 0.02
    assert s.forces.gravity == (0.0, -1.0, 0.0) and all(type(g) is float for g in s.forces.gravity)
    assert s.sph.clamp_negative_pressure is False
    assert s.fluid.blocks[0].velocity == (1.0, 0.0, 0.0)
    assert s.fluid.blocks[1].velocity == (0.0, -1.0, 0.0)  # the other block is untouched
    assert s.terms.xsph == 0.1  # a section the file does not have
    assert s.sph.alpha == 0.25  # the last --set of a key wins
    # and the rest of the file is as written
    assert s.sph.sound_speed == 20.0 and s.domain.size == (0.15, 0.2, 0.15)


def test_override_of_2d_scene_is_padded():
    s = load_scene(CONFIGS / "dam_break_2d.toml", ["forces.gravity=[0,-1]"])
    assert s.forces.gravity == (0.0, -1.0, 0.0)


BAD_OVERRIDES = [
    ("sph.kernal=muller", ["sph.kernal", "kernel"]),
    ("sphh.kernel=muller", ["sphh", "sph"]),
    ("sph.kernel=gaussian", ["sph.kernel", "'gaussian'", "'wendland_c2'"]),
    ("sph.support=0.5", ["sph.support", "0.5", "[1.5, 4]"]),
    ("particles.spacing=0", ["particles.spacing", "0", "(0, inf]"]),
    ("particles.spacing=-1", ["particles.spacing", "-1", "(0, inf]"]),
    ("sph.support=abc", ["sph.support", "'abc'", "a number"]),
    ("sph.support=true", ["sph.support", "True", "a number"]),
    ("time.steps=2.5", ["time.steps", "2.5", "an integer"]),
    ("sph.clamp_negative_pressure=1", ["sph.clamp_negative_pressure", "true or false"]),
    ("sph.support=inf", ["sph.support", "finite"]),
    ("sph.support=" + "9" * 400, ["sph.support", "number"]),
    ("sph.support=" + "9" * 5000, ["sph.support", "number"]),
    ("forces.gravity=[0,-1]", ["forces.gravity", "3 components"]),
    ("forces.gravity=[0,-1,0,0]", ["forces.gravity", "2 or 3 components"]),
    ("fluid.blocks[0].colour=1", ["fluid.blocks[0].colour"]),
    ("fluid.blocks[5].velocity=[1,0,0]", ["fluid.blocks[5]", "index 5", "out of range"]),
    ("fluid.blocks[x].velocity=[1,0,0]", ["fluid.blocks[x]", "[x]", "non-negative integer"]),
    ("fluid.blocks[0.velocity=[1,0,0]", ["fluid.blocks[0.velocity"]),
    ("sph.kernel.name=x", ["sph.kernel.name", "'kernel' is not a table"]),
    ("sph.kernel", ["sph.kernel", "section.key=value"]),
    ("sph=muller", ["sph=muller", "section.key=value"]),
    ("sph..kernel=muller", ["sph..kernel", "empty key segment"]),
]


@pytest.mark.parametrize("text,fragments", BAD_OVERRIDES, ids=[b[0] if len(b[0]) < 50 else f"{b[0][:15]}...({len(b[0])} chars)" for b in BAD_OVERRIDES])
def test_bad_override_is_rejected_naming_key_and_value(text, fragments):
    with pytest.raises(SceneError) as err:
        load_scene(CONFIGS / "tiny.toml", [text])
    msg = str(err.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} missing from {msg!r}"


# ---------------------------------------------------------------------------------------------
# to_dict round trip
# ---------------------------------------------------------------------------------------------

def _round_trip(s, tmp_path):
    f = tmp_path / "scene.toml"
    f.write_text(tomli_w.dumps(s.to_dict()))
    return load_scene(f)


@pytest.mark.parametrize("path", CONFIG_FILES, ids=CONFIG_IDS)
def test_to_dict_round_trips_through_toml(path, tmp_path):
    # Given a shipped scene
    s = load_scene(path)
    # When its to_dict() is written with tomli_w and loaded again
    s2 = _round_trip(s, tmp_path)
    # Then the dataclasses are equal (only the source file differs)
    assert s2.source != s.source
    assert dataclasses.replace(s2, source=s.source) == s


def test_to_dict_round_trips_with_planes_and_obstacles(tmp_path):
    data = with_keys(base(3), {
        "domain.planes": [{"point": [0.0, 0.1, 0.0], "normal": [0.0, 1.0, 0.2]}],
        "obstacles": [{"shape": "box", "center": [0.3, 0.1, 0.3], "size": [0.05, 0.05, 0.05]}],
        "sph.kernel": "muller", "terms.xsph": 0.2,
    })
    s = scene_from_dict(data)
    assert dataclasses.replace(_round_trip(s, tmp_path), source="") == s


def test_to_dict_is_complete_and_plain():
    d = load_scene(CONFIGS / "tiny.toml").to_dict()
    assert "source" not in d
    assert set(d) == {"scene", "particles", "fluid", "sph", "terms", "forces", "time", "domain", "obstacles",
                      "boundary", "run", "decomposition", "render", "output", "probes", "inlets", "outlets",
                      "damping_zones"}
    assert d["sph"]["eos"] == "tait" and d["boundary"]["gap"] == 0.25  # defaults are resolved
    assert d["forces"]["gravity"] == [0.0, -9.81, 0.0]  # lists, not tuples
    assert len(d["fluid"]["blocks"]) == 2 and d["fluid"]["blocks"][1]["shape"] == "sphere"


@pytest.mark.parametrize("value, message", [
    ("[2, 0, 1]", "give all three counts"),
    ("[2, 1]", "expected 3 components"),
    ("[2, -1, 1]", "integers >= 0"),
    ("[2.5, 1, 1]", "integers >= 0"),
])
def test_decomposition_dims_are_all_set_or_all_zero(value, message):
    with pytest.raises(SceneError, match=message):
        load_scene(CONFIGS / "tiny.toml", [f"decomposition.dims={value}"])
    assert load_scene(CONFIGS / "tiny.toml", ["decomposition.dims=[2, 1, 1]"]).decomposition.dims == (2, 1, 1)


@pytest.mark.parametrize("path", CONFIG_FILES, ids=CONFIG_IDS)
def test_scene_toml_reads_back_to_the_same_scene_with_one_line_per_key(path):
    scene = load_scene(path, ['scene.description="a \\"quoted\\" \\\\ word\\u007f\\n é"', "forces.ramp_time=0.0123456789"])
    text = scene_toml(scene.to_dict())
    again = scene_from_dict(tomllib.loads(text), source=scene.source)
    assert again == scene
    assert all(" = " in line or line.startswith("[") or not line for line in text.splitlines())


def test_a_misspelled_key_gets_the_close_name():
    with pytest.raises(SceneError, match=r"unknown key 'time.integrater' \(did you mean 'integrator'\?\)"):
        load_scene(CONFIGS / "tiny.toml", ["time.integrater=leapfrog"])
    with pytest.raises(SceneError) as e:
        load_scene(CONFIGS / "tiny.toml", ["time.zzz=1"])
    assert "did you mean" not in str(e.value)


@pytest.mark.fast
@pytest.mark.parametrize("planes, again", [
    ('[[domain.planes]]\npoint = [0.3, 0.0]\nnormal = [0.0, 2.0]\n', "a wall of the container again"),
    ('[[domain.planes]]\npoint = [0.1, 0.2]\nnormal = [1.0, 0.0]\n[[domain.planes]]\npoint = [0.1, 0.5]\n'
     'normal = [1e-300, 0.0]\n', "domain.planes[0] again"),
])
def test_a_wall_given_twice_is_refused(planes, again, tmp_path):
    """A plane on the box's floor pushed the fluid twice there: 70 x the compression of the same tank
    without it, exit 0 (hostile-input sweep, 2026-12-06). A normal as small as 1e-300 still has its
    direction (np.linalg.norm's square underflowed to 0: NaN walls)."""
    from sphcore.model import Model
    path = tmp_path / "twice.toml"
    path.write_text((CONFIGS / "dam_break_2d.toml").read_text() + "\n" + planes)
    with pytest.raises(SceneError, match=re.escape(again)):
        Model(load_scene(path), "f64", "cpu")


@pytest.mark.fast
def test_a_scene_file_with_a_byte_order_mark_loads(tmp_path):
    """An editor's UTF-8 byte-order mark used to give 'not valid TOML: Invalid statement (at line 1,
    column 1)', which did not say why (hostile-input sweep, 2026-12-06)."""
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + (CONFIGS / "tiny.toml").read_bytes())
    assert load_scene(path).scene.name == load_scene(CONFIGS / "tiny.toml").scene.name
